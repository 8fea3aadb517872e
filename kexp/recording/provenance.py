"""Where two logs came from: the package versions and lock file each run recorded on ``/run_info``.

``/run_info`` is a wall-clock channel that :func:`~kexp.recording.diff.diff_logs` ignores by default; it is read
here anyway, so that a diff of logs made with different packages says so (a warning, never a failure)."""
from __future__ import annotations

from .reader import RunLog


def _run_info(log: RunLog) -> dict:
    info = log.one("/run_info")
    return info if isinstance(info, dict) else {}


def version_warnings(log_a: RunLog, log_b: RunLog) -> list[str]:
    """One line per kind of difference: package versions both logs recorded that differ, and lock files (sha256)
    that differ.  A log without ``/run_info`` (a killed run) or without a lock hash gives no warning."""
    ia, ib = _run_info(log_a), _run_info(log_b)
    out = []
    va, vb = ia.get("versions") or {}, ib.get("versions") or {}
    differ = [f"{pkg} {va[pkg]} vs {vb[pkg]}" for pkg in sorted(set(va) & set(vb)) if va[pkg] != vb[pkg]]
    if differ:
        out.append(f"the logs come from different package versions ({log_a.path.name} vs {log_b.path.name}): "
                   + ", ".join(differ))
    ha, hb = (ia.get("lock") or {}).get("sha256"), (ib.get("lock") or {}).get("sha256")
    if ha and hb and ha != hb:
        out.append(f"the logs come from different lock files (sha256 {ha[:12]} vs {hb[:12]})")
    return out
