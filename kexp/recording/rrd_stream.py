"""A Rerun recording's streams and file, kept apart from what is drawn (:mod:`kexp.recording.render`): the
blueprint's stream built so that it can be released, and a flush that notices a failed write."""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import KexpError

APPLICATION_ID = "kexp"
STALL_S = 30   # seconds without the recording's file growing while its flush waits: a failed write


class RenderError(KexpError, OSError):
    """The recording cannot be written (Rerun disabled by the environment, output path = the log, ...)."""


# -- the streams' lifetime -------------------------------------------------------------------------------------
# Each Rerun RecordingStream runs two native threads (ChunkBatcher, RecordingStream) until the SDK drops it, and
# rerun-sdk 0.41 drops a stream only when nothing refers to it *and* its orphans are cleaned up
# (bindings.flush_and_cleanup_orphaned_recordings; RecordingStream.__del__ only disconnects them).  The default
# blueprint of ``save(path, default_blueprint=...)`` is a second stream (rerun.blueprint.api.create_in_memory_blueprint)
# whose memory sink and its storage refer to each other, so it is never dropped: 4 threads and ~2 MB per render,
# 200 renders in a sweep worker → 800 threads.  :func:`kexp.recording.render.render` builds that blueprint stream itself (as
# create_in_memory_blueprint does) so that it can disconnect it, which breaks the cycle.
def blueprint_stream(rr, blueprint):
    """The blueprint's own stream and its in-memory storage (what ``save`` takes as ``default_blueprint``)."""
    stream = rr.RecordingStream._from_native(rr.bindings.new_blueprint(
        application_id=APPLICATION_ID, make_default=False, make_thread_default=False, default_enabled=True))
    stream.set_time("blueprint", sequence=0)
    blueprint.to_blueprint()._log_to_stream(stream)
    return stream, stream.memory_recording().storage


def flush(rec, rrd_path: Path, tmp: Path) -> None:
    """Flush the recording to its file ``tmp`` (to become ``rrd_path``); a failed write raises RenderError.  Rerun
    (0.41) does not report a failed write (a full disk, a file-size limit): its flush then waits forever.  So it is
    waited for in steps of one second, and given up when the file cannot grow (:func:`_cannot_grow`) or has not
    grown for :data:`STALL_S` seconds."""
    last, still = -1, 0
    while True:
        try:
            rec.flush(timeout_sec=1.0)
            return
        except RuntimeError as exc:
            if "timed out" not in str(exc):   # "File-writer thread shut down prematurely"
                raise RenderError(f"cannot write {rrd_path}: {exc}") from None
        size = tmp.stat().st_size if tmp.exists() else 0
        reason = _cannot_grow(tmp, size)
        still = still + 1 if size == last else 0
        if reason is None and still >= STALL_S:
            reason = f"the file has not grown for {STALL_S} s (at {size} bytes)"
        if reason:
            raise RenderError(f"cannot write {rrd_path}: {reason}")
        last = size


def _cannot_grow(path: Path, size: int) -> str | None:
    """Why the file at ``path``, of ``size`` bytes, cannot grow (this process's file-size limit reached, no free
    block left), or None."""
    import resource
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if soft != resource.RLIM_INFINITY and size >= soft:
        return f"File too large (EFBIG): the file-size limit is {soft} bytes"
    try:
        st = os.statvfs(path.parent)
    except OSError:
        return None
    if (st.f_bfree if os.geteuid() == 0 else st.f_bavail) == 0:
        return "No space left on device (ENOSPC)"
    return None
