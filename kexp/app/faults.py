"""Faults while a run writes its files — a full disk (ENOSPC), a file-size limit (EFBIG, ``ulimit -f``), a folder
where a file belongs (EISDIR) — end in one line that says what failed and what was saved
(:func:`fault_message`), and never destroy what was written before: summary.json is replaced whole or not at all
(:func:`write_json`), the other files are created exclusively (:func:`create_exclusive`)."""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from ..errors import KexpError
from .run_folder import RunFolderError, os_error_text


class OutputError(KexpError, OSError):
    """A run's file could not be written (disk full, size limit, a folder in its place, …); the message says what
    was saved."""


@contextlib.contextmanager
def writing(path: str | Path):
    """Name ``path`` in an OSError raised inside (a failed write names no file: ENOSPC, EFBIG)."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None and not isinstance(exc, KexpError):
            exc.filename = str(path)
        raise


def create_exclusive(path: Path, text: str = "") -> None:
    """Create ``path`` with ``text``, refusing to replace anything there (a file, a folder, a link): a
    :class:`~kexp.app.run_folder.RunFolderError` naming it.  A failed write removes the file it created."""
    try:
        f = open(path, "x", encoding="utf-8")
    except FileExistsError:
        raise RunFolderError(f"{path} exists already: its folder holds another run, which kexp never "
                             "overwrites; give another folder") from None
    try:
        with f, writing(path):
            f.write(text)
    except BaseException:
        with contextlib.suppress(OSError):
            path.unlink()
        raise


def write_json(path: Path, data) -> None:
    """Replace ``path`` by ``data`` as JSON, whole or not at all: written to a temporary file beside it and moved
    into place (a full disk leaves the previous content, never an empty or half file)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f, writing(path):
            f.write(json.dumps(data, indent=2))
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


def log_extent(path: Path) -> str | None:
    """What the run log at ``path`` holds as read back, for a message: "the log up to t = 3.00 s (301 steps)",
    "the complete log" or None (no file, or not a log)."""
    from ..recording.reader import read_log
    try:
        log = read_log(path)
    except (OSError, ValueError):
        return None
    if log.completed:
        return "the complete log"
    steps = log.messages("/step")
    if not steps:
        return "the log's header (no control step)"
    return f"the log up to t = {float(steps[-1].get('t', 0.0)):.2f} s ({len(steps)} steps)"


def fault_message(exc: OSError, out_dir: Path) -> str:
    """One line for a fault while the run in ``out_dir`` wrote its files: the error, the file, and what is saved
    (the log as far as it can be read back, the model), e.g. "cannot write …/run.mcap: File too large (EFBIG);
    saved: the log up to t = 3.00 s (301 steps) in …/run.mcap, the model in …/model.npz"."""
    saved = []
    log = out_dir / "run.mcap"
    if log.is_file():
        extent = log_extent(log)
        if extent:
            saved.append(f"{extent} in {log}")
    if (out_dir / "model.npz").is_file() and (out_dir / "model.npz").stat().st_size > 0:
        saved.append(f"the model in {out_dir / 'model.npz'}")
    what = f"cannot write {exc.filename}" if exc.filename else f"a file in {out_dir} could not be written"
    reason = os_error_text(OSError(exc.errno, exc.strerror or str(exc)))
    return f"{what}: {reason}; saved: {', '.join(saved) if saved else 'nothing of this run'}"
