"""RunLogger: one MCAP file per run, written as the run goes, flushed every ``flush_every`` seconds of
simulated time so a killed run keeps all but its last second.

The file is framed by :class:`~kexp.recording.mcap_file.McapFile` (byte-identical to mcap's Writer, tests), and
``log_step`` only queues the step's record with its time stamp: its /step and /timing messages are encoded at the
next flush, in one batch (code that runs faster together than spread between control steps, whose own code evicts
it from the caches).  Each closed chunk is compressed and written on McapFile's thread (``compress_thread``; zstd
releases the GIL), while the loop runs its next steps, so a flushed chunk reaches the file about a millisecond
after the flush.  Measured in ``benchmarks/logging_overhead.py``'s run (the README's logging table; a second run
in brackets; 24.2 in a third, noisier run): 22.8 (23.5) µs per step at the defaults (plans every 20 steps, the LMPC's rollouts for them
included) and 19.0 (16.6) µs without plans, where the README's previous round (mcap's Writer, each step encoded
as it came) had 67.7 and 51.3 µs; 33.9 (30.1) µs at the defaults with ``compress_thread=False``.  Two such runs at
once on the 2 cores (ad hoc, 15 interleaved repeats each) showed no wall-time cost of the thread: 0.687 / 0.677 s
median against 0.708 / 0.666 s without it (0.681 / 0.654 s without a log).

With ``background=True`` the JSON encoding and the MCAP records are written by a writer thread, in the order the
messages were given (the file is byte-identical to a synchronous one, a test): the control loop only queues each
message, and the thread encodes and frames them at each flush, which can overlap the loop's code that releases
the GIL (the LMPC's compiled kernels).  An error on the writer thread is raised by the next ``write`` or by
``close``, unchanged.  Measured on a 2-core machine it is slower than writing synchronously (+31.1 % wall against
+1.1 %, 35.1 against 22.8 µs per step in the run: the loop waits for the GIL more than the thread saves), so
``kexp`` runs write synchronously; the option stays for machines and loops where it pays, and the benchmark keeps
measuring it.
"""
from __future__ import annotations

import json
import queue
import threading
from pathlib import Path

import numpy as np

from .mcap_file import McapFile
from .schema import CHANNELS, encode

LIBRARY = "kexp-recording/1"   # fixed, so the file bytes do not change with the mcap package version


def _ns(t: float) -> int:
    return int(round(float(t) * 1e9))


def _step_json(rec) -> bytes:
    """A /step message: the record's fields as plain numbers, lists and strings."""
    t = float(rec.t)
    u = rec.u
    x_meas, w = getattr(rec, "x_meas", None), getattr(rec, "w", None)
    return encode({
        "k": int(rec.k), "t": t, "x": rec.x.tolist(), "x_meas": (rec.x if x_meas is None else x_meas).tolist(),
        "z": np.asarray(rec.z).tolist(), "u": u.tolist(),
        # np.zeros, not np.zeros_like: the same zeros, without zeros_like's ~1 us of dispatch
        "w": (np.zeros(u.shape, u.dtype) if w is None else np.asarray(w)).tolist(),
        "V": float(rec.V), "Vdot": float(rec.Vdot), "region": rec.region, "active": rec.active,
        "binds": bool(rec.binds), "slack": float(rec.slack), "status": rec.status, "qp_status": rec.qp_status,
        "iterations": int(rec.iterations), "qp_iterations": int(rec.qp_iterations),
        "fallback": bool(rec.fallback), "reason": rec.reason})


def _timing_json(rec) -> bytes:
    return encode({"k": int(rec.k), "t": float(rec.t), "solve_time": float(rec.solve_time)})


class RunLogger:
    """Writes one run's MCAP log at ``path`` (parent folders created, an existing file replaced): every channel of
    :data:`~kexp.recording.schema.CHANNELS` registered with its JSON schema, messages time-stamped with simulation
    time, zstd chunks flushed every ``flush_every`` simulated seconds; ``/prediction`` every ``prediction_every``
    steps (0: never).  Call the typed helpers (``log_config``, ``log_model``, ``log_clf``, ``log_step`` from
    ``closed_loop``'s ``on_step``, ``log_open_loop``, ``log_summary``, ``log_run_info``) or ``write``, then
    ``close()`` — or use it as a context manager (see the README's Python API).  Writing to an unknown topic
    raises KeyError; a file that cannot be opened raises OSError.  ``background=True``: a writer thread encodes and
    writes (see the module's docstring); a payload given to ``write`` must then not be changed afterwards.
    ``compress_thread=False``: chunks are compressed and written in the caller's thread (the same bytes)."""

    def __init__(self, path: str | Path, *, flush_every: float = 1.0, prediction_every: int = 0,
                 background: bool = False, compress_thread: bool = True):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._w = McapFile(self._f, chunk_size=1 << 20, thread=compress_thread)
        self._w.start(profile="", library=LIBRARY)
        self._ch = {}
        for topic, schema in CHANNELS.items():
            sid = self._w.register_schema(name=schema["title"], encoding="jsonschema",
                                          data=json.dumps(schema, sort_keys=True).encode())
            self._ch[topic] = self._w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._seq = {t: 0 for t in CHANNELS}
        self.flush_every = flush_every
        self.prediction_every = prediction_every
        self._next_flush = flush_every
        self._closed = False
        # messages waiting for the next flush: (channel, sequence, log time, data, encoder); data is encoded
        # (encoder None) or turned into bytes by encoder(data) at the flush
        self._pending: list = []
        self._queue: queue.SimpleQueue | None = None
        self._error: BaseException | None = None
        if background:
            self._queue = queue.SimpleQueue()
            self._thread = threading.Thread(target=self._drain, name=f"kexp-log:{self.path.name}", daemon=True)
            self._thread.start()

    def write(self, topic: str, t: float, payload: dict) -> None:
        """Add one message (numpy values welcome: :func:`~kexp.recording.schema.encode` converts them)."""
        if self._queue is None:   # encoded now: the payload may change after this call
            self._put(topic, _ns(t), encode(payload), None)
        else:
            self._put(topic, _ns(t), payload, encode)

    def _put(self, topic: str, ns: int, data, encoder) -> None:
        channel = self._ch[topic]          # an unknown topic raises KeyError here, in the caller's thread
        seq = self._seq[topic]
        self._seq[topic] = seq + 1
        if self._queue is None:
            self._pending.append((channel, seq, ns, data, encoder))
            return
        self._raise_thread_error()
        self._queue.put((channel, seq, ns, data, encoder))

    def _write_pending(self) -> None:
        """Encode what waits (in one batch: code that runs faster together than spread between control steps,
        whose own code evicts it from the caches) and frame it."""
        self._w.add_messages([(channel, seq, ns, ns, data if encoder is None else encoder(data))
                              for channel, seq, ns, data, encoder in self._pending])
        self._pending.clear()

    def _flush(self) -> None:
        if self._queue is None:
            self._write_pending()
            self._w.flush()
        else:
            self._queue.put(None)

    def _drain(self) -> None:
        """The writer thread: collects the messages and, at each flush (None), encodes and writes them, until the
        stop mark (False); what waits then is written by close() or abandon()."""
        while True:
            item = self._queue.get()
            if item is False:
                return
            if self._error is not None:
                continue               # keep draining so that close() is not blocked; the error is raised there
            try:
                if item is None:
                    self._write_pending()
                    self._w.flush()
                else:
                    self._pending.append(item)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread unchanged
                self._error = exc

    def _raise_thread_error(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    # -- typed helpers -----------------------------------------------------------------------------------------
    def log_config(self, config: dict, config_hash: str) -> None:
        self.write("/config", 0.0, {"config": config, "config_hash": config_hash})

    def log_model(self, model) -> None:
        r = model.report
        self.write("/model", 0.0, {
            "eigenvalues_re": model.eigenvalues.real, "eigenvalues_im": model.eigenvalues.imag,
            "Lambda": model.Lambda, "B": model.B, "b": model.b, "C": model.C, "dt": model.dt, "k": model.k,
            "m": model.m, "n": model.n, "state_names": list(model.state_names), "x_eq": model.x_eq,
            "report": {key: r[key] for key in ("cond_phi_x", "prediction_error", "input_projection_residual",
                                               "drift_at_equilibrium", "kept", "dropped", "warnings") if key in r}})

    def log_clf(self, clf, boundary_r=None, boundary_r_hat=None) -> None:
        self.write("/clf", 0.0, {"P": clf.P, "r": clf.r, "r_hat": clf.r_hat, "status": clf.status,
                                 "certificate": clf.certificate.to_dict(),
                                 "boundary_r": [] if boundary_r is None else boundary_r,
                                 "boundary_r_hat": [] if boundary_r_hat is None else boundary_r_hat})

    def log_step(self, rec, control_step=None, model=None) -> None:
        """Log one control step (/step, /timing; /prediction every ``prediction_every`` steps).  Only the time
        stamps are taken now: the messages are encoded from ``rec`` at the next flush (``rec`` must not change
        until then; ``closed_loop``'s records do not)."""
        ns = _ns(rec.t)
        self._put("/step", ns, rec, _step_json)
        self._put("/timing", ns, rec, _timing_json)
        if (self.prediction_every and control_step is not None and control_step.predicted is not None
                and model is not None and rec.k % self.prediction_every == 0):
            Z = control_step.predicted
            self._put("/prediction", ns, {"k": rec.k, "t": rec.t,   # new arrays: encoded at the flush
                                           "t_pred": rec.t + model.dt * np.arange(len(Z)),
                                           "x_pred": model.to_state(Z)}, encode)
        if rec.t + 1e-12 >= self._next_flush:
            self._flush()
            self._next_flush += self.flush_every

    def log_open_loop(self, t: np.ndarray, x: np.ndarray) -> None:
        for ti, xi in zip(t, x):
            self.write("/open_loop", float(ti), {"t": float(ti), "x": xi})

    def log_summary(self, t: float, status: str, message: str, metrics: dict, completed: bool,
                    perturbation: dict | None = None) -> None:
        """``perturbation``: the noise and plant mismatch as used ({"noise": …, "plant": …}; kexp.app.main)."""
        payload = {"status": status, "message": message, "metrics": metrics, "completed": completed}
        if perturbation is not None:
            payload.update(perturbation)
        self.write("/summary", t, payload)

    def log_run_info(self, t: float, versions: dict, timing: dict, lock: dict | None = None) -> None:
        self.write("/run_info", t, {"versions": versions, "timing": timing, "lock": lock})

    def close(self) -> None:
        """Write what is queued, finish the file (summary and index) and close it; raises the writer thread's
        error, if any (the file is closed either way)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._stop_thread()
            self._raise_thread_error()
            self._write_pending()
            self._w.finish()
        finally:
            self._w.stop()
            self._f.close()

    def abandon(self) -> None:
        """For a run that stopped with an exception: write what is queued and the open chunk, close the file
        without its summary section (readable message by message, like a killed run's log); never raises."""
        if self._closed:
            return
        self._closed = True
        try:
            self._stop_thread()
            self._write_pending()
            self._w.flush()
        except BaseException:  # noqa: BLE001 - the run's own exception is the one to report
            pass
        finally:
            self._w.stop()
            self._f.close()

    def _stop_thread(self) -> None:
        if self._queue is not None and self._thread.is_alive():
            self._queue.put(False)
            self._thread.join()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def copy_log(src: str | Path, dst: str | Path, edit=None) -> Path:
    """Rewrite the run log ``src`` to ``dst`` message by message (same channels, log times and order), letting
    ``edit(topic, payload)`` change each payload in place first: for tests of diffing and replay against a known
    change (a perturbed input at one step, another model basis, other package versions).  Returns ``dst``."""
    from .reader import read_log
    log = read_log(src)
    with RunLogger(dst) as out:
        for topic, msgs in log.channels.items():
            for t_ns, payload in msgs:
                if edit is not None:
                    edit(topic, payload)
                out.write(topic, t_ns / 1e9, payload)
    return Path(dst)
