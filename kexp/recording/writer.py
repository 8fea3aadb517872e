"""RunLogger: one MCAP file per run, written as the run goes, flushed every ``flush_every`` seconds of
simulated time so a killed run keeps all but its last second.

The file is framed by :class:`~kexp.recording.mcap_file.McapFile` (byte-identical to mcap's Writer, tests).
``log_step`` only keeps the step's record (and its plan, when one is logged); at the next flush the kept steps'
/step and /timing messages are encoded a kind at a time, each batch in one orjson call
(:mod:`kexp.recording.steps`, byte-identical to one call per message), code that runs faster together than spread
between control steps.  Each closed chunk is compressed and written on McapFile's thread (``compress_thread``;
zstd releases the GIL) while the loop runs its next steps, so a flushed chunk reaches the file about a millisecond
after the flush.  Other messages (``write``) are encoded at once, in their place among the steps: a write closes
the segment of steps before it, which takes its sequence numbers then.  Measured in
``benchmarks/logging_overhead.py`` (the README's logging table): 20.1 µs per step inside the run at the defaults
(plans every 20 steps, the LMPC's rollouts for them included) and 15.1 µs without plans, against 23.1 and 16.6
for the previous logger (one message per step encoded at the flush) in the same conditions.

With ``background=True`` each flush hands its batch (the kept steps and messages, in order) to a writer thread,
which encodes and frames it while the loop runs on: the file is byte-identical to a synchronous one (a test), an
error on the thread is raised in the caller's thread by the next ``write``, flush or ``close``, unchanged.  The
loop's direct cost then falls to ~7 µs per step, but the encoding still needs the GIL, which the loop waits for
outside its compiled kernels: in every run so far its wall time was above the synchronous writer's (+8.2 % paired
against +3.9 %), so ``kexp`` runs write synchronously or, with ``logging.writer=process``, in a child process
(:mod:`kexp.recording.process_log`); the thread option stays for machines where it pays, and the
benchmark keeps measuring it.
"""
from __future__ import annotations

import json
import queue
import threading
from pathlib import Path

import numpy as np

from ..errors import ConfigError, is_number, require_number
from .mcap_file import McapFile
from .schema import CHANNELS, encode
from .steps import log_times, prediction_message, step_messages, timing_messages

LIBRARY = "kexp-recording/1"   # fixed, so the file bytes do not change with the mcap package version


def _ns(t: float) -> int:
    return int(round(float(t) * 1e9))


def logged_plan(prediction_every: int, rec, control_step, model):
    """The predicted z (Np+1, k) of a step whose plan is logged — every ``prediction_every`` steps (0: never),
    when the controller made one and a model is given to map it to x — else None."""
    if (prediction_every and control_step is not None and control_step.predicted is not None
            and model is not None and rec.k % prediction_every == 0):
        return control_step.predicted
    return None


def check_settings(flush_every, prediction_every) -> None:
    """A log's settings, for both writers: ``flush_every`` finite seconds > 0, ``prediction_every`` an int >= 0
    (0: never); ConfigError otherwise (inf never flushed: a killed run lost its log; -1 or 2.5 logged no plan)."""
    require_number(flush_every, "logging.flush_every")
    if not 0 < flush_every < float("inf"):
        raise ConfigError(f"logging.flush_every={flush_every}: use seconds > 0 (finite)")
    require_number(prediction_every, "logging.prediction_every", integer=True)
    if prediction_every < 0:
        raise ConfigError(f"logging.prediction_every={prediction_every}: use an int >= 0 (0: never)")


def check_message(t, payload) -> None:
    """A message's log time (finite seconds >= 0: MCAP's times are unsigned nanoseconds) and payload (a dict: the
    log's messages are JSON objects); ConfigError otherwise (was struct.error or OverflowError, or a list written
    that read_log could not read back).  A bool is not a time: True would pass for 1 s."""
    if not (is_number(t) and 0 <= t < float("inf")):
        raise ConfigError(f"log time t={t!r}: use a finite number of seconds >= 0")
    if not isinstance(payload, dict):
        raise ConfigError(f"payload {type(payload).__name__}: a log message is a dict (a JSON object)")


class FlushClock:
    """When a log flushes: at each step whose time reaches the next flush time (1e-12 s early, against rounding),
    the step included; then the flush time moves on by ``every`` simulated seconds.  RunLogger's rule, which the
    log-writer process's hand-overs follow too."""

    __slots__ = ("every", "next")

    def __init__(self, every: float):
        self.every = every
        self.next = every

    def due(self, t: float) -> bool:
        """Whether a step at time ``t`` flushes."""
        return t + 1e-12 >= self.next

    def advance(self) -> None:
        """After a flush: the next flush time."""
        self.next += self.every


class _Steps:
    """A segment of logged steps: the records, their plans and the first sequence number of each of their
    channels, taken when the segment was closed (so that the writer thread encodes them to the same bytes)."""

    __slots__ = ("recs", "plans", "s0", "t0", "p0")

    def __init__(self, recs, plans, s0, t0, p0):
        self.recs, self.plans, self.s0, self.t0, self.p0 = recs, plans, s0, t0, p0

    def encode(self, out: list, channels: dict) -> None:
        """Append the segment's messages to ``out`` as McapFile.add_messages takes them, in step order: each
        step's /step and /timing (:mod:`kexp.recording.steps`, each kind in one batch) and its /prediction."""
        recs, s0, t0 = self.recs, self.s0, self.t0
        ch_step, ch_timing, ch_pred = channels["/step"], channels["/timing"], channels["/prediction"]
        plans = {i: (j, Z, model) for j, (i, Z, model) in enumerate(self.plans)}
        for i, (ns, step, timing) in enumerate(zip(log_times(recs), step_messages(recs), timing_messages(recs))):
            out += ((ch_step, s0 + i, ns, ns, step), (ch_timing, t0 + i, ns, ns, timing))
            if i in plans:
                j, Z, model = plans[i]
                out.append((ch_pred, self.p0 + j, ns, ns, prediction_message(recs[i], Z, model)))


class LogHelpers:
    """The typed helpers of a run log, all through ``write(topic, t, payload)``; a context manager that closes it."""

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

    def log_open_loop(self, t: np.ndarray, x: np.ndarray) -> None:
        for ti, xi in zip(t, x):
            self.write("/open_loop", float(ti), {"t": float(ti), "x": xi})

    def log_summary(self, t: float, status: str, message: str, metrics: dict, completed: bool,
                    perturbation: dict | None = None) -> None:
        """``perturbation``: the noise and plant mismatch as used ({"noise": …, "plant": …}; kexp.app.experiment)."""
        payload = {"status": status, "message": message, "metrics": metrics, "completed": completed}
        if perturbation is not None:
            payload.update(perturbation)
        self.write("/summary", t, payload)

    def log_run_info(self, t: float, versions: dict, timing: dict, lock: dict | None = None,
                     plant: dict | None = None) -> None:
        payload = {"versions": versions, "timing": timing, "lock": lock}
        if plant is not None:   # the plant's kind, id and package versions (kexp.plants)
            payload["plant"] = plant
        self.write("/run_info", t, payload)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class RunLogger(LogHelpers):
    """Writes one run's MCAP log at ``path`` (parent folders created; the file is created exclusively: anything
    at ``path`` already raises FileExistsError and is left as it is; ``exclusive=False`` replaces a file): every
    channel of :data:`~kexp.recording.schema.CHANNELS` registered with its JSON schema, messages time-stamped with
    simulation time, zstd chunks flushed every ``flush_every`` simulated seconds; ``/prediction`` every
    ``prediction_every`` steps (0: never).  Call the typed helpers (``log_config``, ``log_model``, ``log_clf``,
    ``log_step`` from ``closed_loop``'s ``on_step``, ``log_open_loop``, ``log_summary``, ``log_run_info``) or
    ``write``, then ``close()`` — or use it as a context manager (see the README's Python API).  Writing to an
    unknown topic raises KeyError; a file that cannot be created raises OSError.  ``background=True``: a writer
    thread encodes and writes (see the module's docstring); a payload given to ``write`` must then not be changed
    afterwards.  ``compress_thread=False``: chunks are compressed and written in the caller's thread (the same
    bytes)."""

    def __init__(self, path: str | Path, *, flush_every: float = 1.0, prediction_every: int = 0,
                 background: bool = False, compress_thread: bool = True, exclusive: bool = True):
        check_settings(flush_every, prediction_every)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "xb" if exclusive else "wb")
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
        self._clock = FlushClock(flush_every)
        self._closed = False
        # what waits for the next flush, in file order: messages as McapFile.add_messages takes them (their data
        # a payload still to encode with background=True) and _Steps segments; the steps since the last segment
        self._pending: list = []
        self._steps: list = []     # step records (encoded at the flush, in one batch)
        self._plans: list = []     # (index in _steps, predicted Z, model) of the steps whose plan is logged
        self._queue: queue.SimpleQueue | None = None
        self._error: BaseException | None = None
        if background:
            self._queue = queue.SimpleQueue()
            self._thread = threading.Thread(target=self._drain, name=f"kexp-log:{self.path.name}", daemon=True)
            self._thread.start()

    def write(self, topic: str, t: float, payload: dict) -> None:
        """Add one message (numpy values welcome: :func:`~kexp.recording.schema.encode` converts them)."""
        channel = self._ch[topic]          # an unknown topic raises KeyError here, in the caller's thread
        check_message(t, payload)
        self._raise_thread_error()
        # encoded now (the payload may change after this call), or by the writer thread
        self._add(channel, topic, t, encode(payload) if self._queue is None else payload)

    def write_encoded(self, topic: str, t: float, data: bytes) -> None:
        """Add one message already encoded (``encode(payload)``: the log-writer process's messages)."""
        channel = self._ch[topic]
        self._raise_thread_error()
        self._add(channel, topic, t, data)

    def _add(self, channel: int, topic: str, t: float, data) -> None:
        if self._steps:                    # the steps logged before it go first
            self._seal_steps()
        seq = self._seq[topic]
        self._seq[topic] = seq + 1
        ns = _ns(t)
        self._pending.append((channel, seq, ns, ns, data))

    def _seal_steps(self) -> None:
        """Close the segment of the steps logged since the last one, with its sequence numbers taken now."""
        recs, plans, seq = self._steps, self._plans, self._seq
        self._steps, self._plans = [], []
        self._pending.append(_Steps(recs, plans, seq["/step"], seq["/timing"], seq["/prediction"]))
        seq["/step"] += len(recs)
        seq["/timing"] += len(recs)
        seq["/prediction"] += len(plans)

    def _frame(self, batch: list) -> None:
        """Encode what a flush handed over (each segment's steps in one batch: code that runs faster together than
        spread between control steps, whose own code evicts it from the caches) and frame it."""
        messages = []
        for item in batch:
            if type(item) is _Steps:
                item.encode(messages, self._ch)
            elif isinstance(item[4], bytes):
                messages.append(item)
            else:
                messages.append(item[:4] + (encode(item[4]),))
        self._w.add_messages(messages)

    def _take_batch(self) -> list:
        if self._steps:
            self._seal_steps()
        batch, self._pending = self._pending, []
        return batch

    def _flush(self) -> None:
        batch = self._take_batch()
        if self._queue is None:
            self._frame(batch)
            self._w.flush()
        else:
            self._raise_thread_error()
            self._queue.put(batch)

    def _drain(self) -> None:
        """The writer thread: frames each batch a flush hands over and flushes the file, until the stop mark
        (None); after an error it keeps taking batches (so that close() is not blocked) and writes no more."""
        while True:
            batch = self._queue.get()
            if batch is None:
                return
            if self._error is not None:
                continue
            try:
                self._frame(batch)
                self._w.flush()
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread unchanged
                self._error = exc

    def _raise_thread_error(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def log_step(self, rec, control_step=None, model=None) -> None:
        """Log one control step (/step, /timing; /prediction every ``prediction_every`` steps).  The record is
        only kept now: its messages are encoded at the next flush, with the other steps' (``rec`` and the control
        step's prediction must not change until then; ``closed_loop``'s do not)."""
        Z = logged_plan(self.prediction_every, rec, control_step, model)
        if Z is not None:
            self._plans.append((len(self._steps), Z, model))
        self._steps.append(rec)
        if self._clock.due(rec.t):
            self._flush()
            self._clock.advance()

    def frame_pending(self) -> None:
        """Encode and frame what waits for the next flush now, into the open chunk, which the flush still closes
        (the same bytes: segments keep their sequence numbers, and the chunk's size is checked per message); the
        log-writer process does this with steps handed over between flushes, so that less is left for close().
        With the writer thread the batch is the thread's to encode: nothing happens here."""
        if self._queue is None:
            self._frame(self._take_batch())

    def close(self) -> None:
        """Write what is queued, finish the file (summary and index) and close it; raises the writer thread's
        error, if any (the file is closed either way)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._stop_thread()
            self._raise_thread_error()
            self._frame(self._take_batch())
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
            if self._error is None:
                self._frame(self._take_batch())
                self._w.flush()
        except BaseException:  # noqa: BLE001 - the run's own exception is the one to report
            pass
        finally:
            self._w.stop()
            try:
                self._f.close()      # the file is closed even when its last write fails (a full disk)
            except OSError:
                pass

    def _stop_thread(self) -> None:
        if self._queue is not None and self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()


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
