"""ProcessRunLogger: a run log written by a separate process, so that the control loop only hands its numbers over.

A writer thread cannot take the encoding off the loop: the encoding needs the GIL, and the loop then waits for it
(README, "Logging overhead").  Here a child process (this module's :func:`main`, started with the logger on the
caller's ``sys.path``, so that it runs the caller's kexp and packages even where the caller found them by changing
``sys.path``, and checked to; it imports numpy, orjson and zstandard, not scipy, ~0.2 s; :func:`prestart` starts
it ahead) runs a synchronous :class:`RunLogger` on the same calls: the loop keeps each step's record and, when
RunLogger would flush (every ``flush_every`` simulated seconds), packs the records' fields
(:mod:`kexp.recording.step_frames`: one pickle, arrays stacked as bytes; ~1.2 µs per step, ~3 µs between
control steps, whose code evicts the packing's from the caches) and writes them to the child's stdin in one write;
the child rebuilds the records and, since the hand-over is the flush, encodes, frames and compresses them on the
other core at once (at ``close()`` only the last part-second is left to it, or, where the run's last step is
known, its chunk's compression).  Other messages are encoded in the
caller (so that their payloads may change afterwards) and go with the next hand-over, as bytes; a plan's
x̂ = C z + x_eq is computed in the caller too, as the synchronous logger would.  The file is byte-identical to
:class:`RunLogger`'s (tests).  The child exits without the interpreter's shutdown, and is reaped later.

The child reports at the end, on its stdout: ``close()`` raises its error, if any, in the caller (an error in the
child stops its writing; it keeps reading so the loop is never blocked).  ``abandon()``, or the caller's process
ending without ``close()`` (the child then reads end-of-file), writes what was sent and closes the file without
its summary section, like a killed synchronous run's log.  POSIX pipes; the pipe is enlarged to 1 MiB where Linux
allows, so that a hand-over never waits for the child (100 steps are ~30–50 kB).
"""
from __future__ import annotations

import atexit
import os
import pickle
import struct
import subprocess
import sys
from pathlib import Path

from .schema import CHANNELS, encode
from .step_frames import pack_steps, unpack_steps
from .writer import FlushClock, LogHelpers, RunLogger, check_message, check_settings, logged_plan

_HEAD = struct.Struct("<cI")    # frame: kind, length of what follows
_PIPE_SIZE = 1 << 20
_F_SETPIPE_SZ = 1031            # Linux fcntl
_FIX = "; rerun, or write the log in the run's process: logging.writer=sync"
# the child: the caller's sys.path (its argv) before anything is imported, then main; no interpreter shutdown
_CHILD = ("import sys; sys.path[:] = sys.argv[1:]; from kexp.recording.process_log import _child; _child()")


class ProcessRunLogger(LogHelpers):
    """:class:`~kexp.recording.writer.RunLogger`'s interface and bytes, written by a child process (module
    docstring).  The file is created at once, exclusively (anything at ``path`` raises FileExistsError, an
    unwritable path OSError, here), and the child writes into it; an unknown topic raises
    KeyError in the caller, as with RunLogger, and messages are encoded in the caller.  What the run logs is
    handed over when RunLogger would flush it (its :class:`~kexp.recording.writer.FlushClock`, every
    ``flush_every`` simulated seconds), so the child flushes as soon as it has it, and a killed run loses what a
    synchronous one would; ``hand_over_every``: at most that many steps per hand-over besides (None: no limit).
    ``last_step``: the time of the run's last step, where known (the app passes it): the steps since the last flush
    are handed over with it, not left to ``close()``, and the child frames steps handed over between flushes at
    once (into the open chunk: the same bytes), so that it has them encoded while the run ends (computing its
    metrics, say) and ``close()`` only waits for the last chunk's compression and the file's end."""

    def __init__(self, path: str | Path, *, flush_every: float = 1.0, prediction_every: int = 0,
                 hand_over_every: int | None = None, last_step: float | None = None):
        check_settings(flush_every, prediction_every)
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        open(self.path, "xb").close()           # the caller learns now if the file cannot be written
        self.flush_every = flush_every
        self.prediction_every = prediction_every
        self.hand_over_every = None if hand_over_every is None else max(1, int(hand_over_every))
        self._last = None if last_step is None else float(last_step) - 1e-12   # FlushClock's margin
        _reap()
        self._clock = FlushClock(flush_every)   # RunLogger's flush times, which the child keeps itself
        self._recs: list = []                   # the records since the last hand-over
        self._plans: list = []                  # (index in _recs, Z, model) of their logged plans
        self._messages: list = []               # (topic, t, encoded) written since the steps packed last
        self._frames: list = []                 # frames packed, in file order, for the next hand-over
        self._closed = False
        self._proc = _take_spare() or _spawn()
        self._frame(b"O", pickle.dumps((str(self.path), flush_every, prediction_every, __file__)))
        self._push()

    # -- the loop's side ---------------------------------------------------------------------------------------
    def log_step(self, rec, control_step=None, model=None) -> None:
        """Keep one control step (as RunLogger.log_step; ``rec`` and the plan must not change until it is handed
        over, at the next flush time)."""
        if self._messages:
            self._pack_messages()
        recs = self._recs
        Z = logged_plan(self.prediction_every, rec, control_step, model)
        if Z is not None:
            self._plans.append((len(recs), Z, model))
        recs.append(rec)
        if self._clock.due(rec.t):
            self._hand_over()
            self._clock.advance()
            return
        if (self._last is not None and rec.t >= self._last) or (self.hand_over_every is not None
                                                                and len(recs) >= self.hand_over_every):
            self._pack()
            self._frame(b"F", b"")              # between flushes: the child frames them at once
            self._push()

    def write(self, topic: str, t: float, payload: dict) -> None:
        """Add one message, encoded here (RunLogger.write's errors, in the caller); handed over with the next
        steps, or at the end."""
        if topic not in CHANNELS:
            raise KeyError(topic)
        check_message(t, payload)
        data = encode(payload)
        if self._recs:                          # the steps logged before it go first
            self._pack_steps()
        self._messages.append((topic, float(t), data))

    def _pack_steps(self) -> None:
        recs, plans = self._recs, self._plans
        self._recs, self._plans = [], []
        self._frame(*pack_steps(recs, [(i, model.dt, model.to_state(Z)) for i, Z, model in plans]))

    def _pack_messages(self) -> None:
        messages, self._messages = self._messages, []
        self._frame(b"W", pickle.dumps(messages, protocol=pickle.HIGHEST_PROTOCOL))

    def _frame(self, kind: bytes, data: bytes) -> None:
        self._frames += (_HEAD.pack(kind, len(data)), data)

    def _pack(self) -> None:
        if self._recs:
            self._pack_steps()
        if self._messages:
            self._pack_messages()

    def _hand_over(self) -> None:
        """Pack what is kept and send every packed frame to the child, in one write."""
        self._pack()
        self._push()

    def _push(self) -> None:
        frames, self._frames = self._frames, []
        try:
            self._proc.stdin.write(b"".join(frames))
            self._proc.stdin.flush()
        except (BrokenPipeError, ValueError) as exc:    # the child is gone (ValueError: its pipe closed here)
            self._closed = True
            raise RuntimeError(f"the log writer process for {self.path} has ended: {self._ending()}{_FIX}") from exc

    def _ending(self) -> str:
        """What the child said on its way out (its exit code and stderr), after it has ended."""
        try:
            self._proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            pass
        err = self._proc.stderr.read().decode(errors="replace").strip()
        rc = self._proc.wait()
        return f"exit code {rc}" + (f": {err.splitlines()[-1]}" if err else "")

    def _finish(self, kind: bytes):
        """Send the rest and the last word (close or abandon), wait for the child; its error, if any."""
        self._pack()
        self._frame(kind, b"")
        self._push()
        self._proc.stdin.close()
        head = self._proc.stdout.read(4)      # the child has closed the file when it answers
        if len(head) < 4:
            raise RuntimeError(f"the log writer process for {self.path} gave no result: {self._ending()}{_FIX}")
        result = pickle.loads(self._proc.stdout.read(struct.unpack("<I", head)[0]))
        _ENDED.append(self._proc)     # reaped later (a thread for it took 2–3 ms to start, measured)
        return result

    def close(self) -> None:
        """Hand over what is kept, let the child finish the file (summary and index), wait for it; raises the
        child's error, if any."""
        if self._closed:
            return
        self._closed = True
        error = self._finish(b"C")
        if error is not None:
            raise error

    def abandon(self) -> None:
        """For a run that stopped with an exception: the child writes what it was given and closes the file
        without its summary section; never raises."""
        if self._closed:
            return
        self._closed = True
        try:
            self._finish(b"A")
        except BaseException:  # noqa: BLE001 - the run's own exception is the one to report
            self._proc.kill()
            self._proc.wait()


def _spawn() -> subprocess.Popen:
    """A writer process on the caller's ``sys.path``, waiting for its log (the "O" frame).  In its own session: a
    Ctrl-C at the terminal reaches the run, whose handler ends the log (abandon or close)."""
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, *map(str, sys.path)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        import fcntl
        fcntl.fcntl(proc.stdin.fileno(), _F_SETPIPE_SZ, _PIPE_SIZE)
    except (ImportError, OSError):          # not Linux, or above the system's limit: the default pipe
        pass
    return proc


def prestart() -> None:
    """Start the next :class:`ProcessRunLogger`'s writer process now, so that its start (~0.2 s of imports on the
    other core) runs while the caller does other work — kexp's app calls it at the start of a run whose log the
    writer process will write, before data, identification and CLF — and neither the logger's start nor a short
    run's ``close()`` waits for it.  One waits at most; one left unused ends when the caller exits."""
    if _SPARE and (_SPARE[0][0] != os.getpid() or _SPARE[0][1].poll() is not None):
        _drop_spare()
    if not _SPARE:
        _SPARE.append((os.getpid(), _spawn()))


def _take_spare() -> subprocess.Popen | None:
    """The process :func:`prestart` started, if it is this process's and still running; else None."""
    if not _SPARE:
        return None
    pid, proc = _SPARE.pop()
    if pid != os.getpid():      # a forked copy of the caller: the process is its parent's
        return None
    if proc.poll() is not None:  # it has ended (killed, say): a new one
        _ENDED.append(proc)
        return None
    return proc


def _drop_spare() -> None:
    """End the unused started process (the last word, abandon, with no log: it writes nothing and exits — not
    end-of-file, which a forked copy of the caller holding the pipe would delay) and reap it; at exit too."""
    while _SPARE:
        pid, proc = _SPARE.pop()
        if pid != os.getpid():
            continue
        try:
            proc.stdin.write(_HEAD.pack(b"A", 0))
            proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            pass
        _ENDED.append(proc)
    _reap(block=True)


def _reap(block: bool = False) -> None:
    """Collect the writer processes that have answered (they exit at once; ``block``: wait for them)."""
    for proc in list(_ENDED):
        if block:
            proc.wait()
        if proc.poll() is not None:
            proc.stdout.close()
            proc.stderr.close()
            _ENDED.remove(proc)


_ENDED: list = []       # writer processes that have sent their result, not yet reaped
_SPARE: list = []       # (pid of the process that started it, the writer process) from prestart, not yet used
atexit.register(_reap, True)
atexit.register(_drop_spare)      # first (atexit runs last-registered first)


def main() -> int:
    """The writer process: frames from stdin drive a synchronous RunLogger; the result (None or the error) is
    pickled to stdout at the end.  End-of-file without a last word is an abandon (the caller died)."""
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    logger, error, last = None, None, b"A"
    while True:
        head = inp.read(_HEAD.size)
        if len(head) < _HEAD.size:
            break
        kind, size = _HEAD.unpack(head)
        data = inp.read(size)
        if kind in (b"C", b"A"):
            last = kind
            break
        if error is not None:
            continue                  # keep reading: the caller must never block on a full pipe
        try:
            if kind == b"O":
                path, flush_every, prediction_every, caller_module = pickle.loads(data)
                if os.path.realpath(caller_module) != os.path.realpath(__file__):
                    raise RuntimeError(f"the log writer process runs {__file__}, the run {caller_module}: "
                                       "two copies of kexp; keep one on sys.path, or write the log in the run's "
                                       "process: logging.writer=sync")
                # chunks compressed here, at once: a compression thread would only add its hand-over to close()
                logger = RunLogger(path, flush_every=flush_every, prediction_every=prediction_every,
                                   compress_thread=False, exclusive=False)   # the file the caller created
            elif kind == b"W":
                for topic, t, encoded in pickle.loads(data):
                    logger.write_encoded(topic, t, encoded)
            elif kind == b"F":
                logger.frame_pending()
            else:
                for rec, plan in unpack_steps(kind, data):
                    logger.log_step(rec, plan, plan)
        except BaseException as exc:  # noqa: BLE001 - reported to the caller at the end
            error = exc
    if logger is not None:
        if last == b"C" and error is None:
            try:
                logger.close()
            except BaseException as exc:  # noqa: BLE001
                error = exc
        else:
            logger.abandon()
    try:
        result = pickle.dumps(error)
    except Exception:  # noqa: BLE001 - an error that does not pickle: its type and text
        result = pickle.dumps(RuntimeError(f"{type(error).__name__}: {error}"))
    out.write(struct.pack("<I", len(result)) + result)
    out.flush()
    return 0


def _child() -> None:
    """The writer process's entry: :func:`main`, then exit without the interpreter's shutdown (the file is closed
    and the result sent; a shutdown costs 20–40 ms of CPU)."""
    code = main()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    _child()
