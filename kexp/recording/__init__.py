"""Run logs: writing (MCAP), reading, diffing and rendering.  The names below load on first use, so that a process
that only writes a log (the log-writer process, :mod:`kexp.recording.process_log`) does not import scipy."""
from __future__ import annotations

import importlib

_NAMES = {"DiffResult": "diff", "Divergence": "diff", "diff_logs": "diff", "LogError": "reader",
          "RunLog": "reader", "read_log": "reader", "RunLogger": "writer", "copy_log": "writer",
          "ProcessRunLogger": "process_log"}

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    module = _NAMES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value
