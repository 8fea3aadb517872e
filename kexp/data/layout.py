"""What a folder of recorded runs holds before kexp knows the system: n, m and the sampling time of its first run
(:func:`run_layout`), for a system known only from its data (``system=data``, ``kexp.fit(path)``).  The files
themselves are then read and checked by :mod:`kexp.data.streaming` with these n and m, so every run must agree
with the first (a run that does not is refused there, naming the file)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataError, is_number
from .files import list_runs
from .parse import npz_headers, read_csv


@dataclass(frozen=True)
class RunLayout:
    """Of the first run at ``path``: ``n`` states, ``m`` inputs (0: no input column or array), ``dt`` its sample
    spacing (the median of its time steps to 12 significant digits; None if it has fewer than 2 finite times),
    ``system`` the system a ``run.mcap`` was recorded with (None for NPZ and CSV), ``first`` the file read."""

    n: int
    m: int
    dt: float | None
    system: str | None
    first: Path


def _spacing(t) -> float | None:
    d = np.diff(np.asarray(t, float))
    d = d[np.isfinite(d)]
    return float(f"{np.median(d):.12g}") if d.size else None   # 0.01, not 0.010000000000000009 from t's rounding


def _columns(f: Path, header: list[str], prefix: str) -> int:
    """The number of columns x1…xk (or u1…uk) in ``header``, which must be numbered from 1 without gaps."""
    cols = [h for h in header if h.startswith(prefix) and h[1:].isdigit()]
    if cols != [f"{prefix}{i + 1}" for i in range(len(cols))]:
        raise DataError(f"{f}: columns {header}; expected t,x1,…,xn[,u1,…,um] in this order")
    return len(cols)


def run_layout(path, format: str = "auto") -> RunLayout:
    """The :class:`RunLayout` of the first recorded run at ``path`` (a file or folder; the layouts of
    :mod:`kexp.data.files`).  One-line DataError for a path without runs or a first run kexp cannot read."""
    files, formats = list_runs(path, format)
    f, fmt = files[0], formats[0]
    if fmt == "csv":
        header, data, _ = read_csv(f)
        n, m = _columns(f, header, "x"), _columns(f, header, "u")
        if header[:1] != ["t"] or n < 1 or len(header) != 1 + n + m:
            raise DataError(f"{f}: columns {header}; expected t,x1,…,xn[,u1,…,um] in this order")
        return RunLayout(n, m, _spacing(data[:, 0]), None, f)
    if fmt == "npz":
        shapes = npz_headers(f)
        x, u = shapes.get("x"), shapes.get("u")
        if x is None or len(x) != 2 or "t" not in shapes:
            raise DataError(f"{f}: arrays {sorted(shapes)}; expected t (T+1,), x (T+1, n) and optionally u (T, m)")
        if u is not None and len(u) != 2:
            raise DataError(f"{f}: u has shape {u}; expected (T, m)")
        with np.load(f, allow_pickle=False) as z:
            t = np.asarray(z["t"], float)
        return RunLayout(int(x[1]), 0 if u is None else int(u[1]), _spacing(t), None, f)
    from ..recording.reader import LogError, read_log
    try:
        log = read_log(f)
    except LogError as exc:
        raise DataError(str(exc)) from None
    steps = [s for s in log.messages("/step") if isinstance(s, dict)]
    if len(steps) < 2:
        raise DataError(f"{f}: {len(steps)} /step message(s); a run needs at least 2 control steps")
    width = lambda v: len(v) if isinstance(v, list) else 1  # noqa: E731
    config = log.one("/config")
    system = ((config or {}).get("config") or {}).get("system") if isinstance(config, dict) else None
    name = system.get("name") if isinstance(system, dict) else None
    times = [s["t"] if is_number(s.get("t")) else np.nan for s in steps]
    return RunLayout(width(steps[0].get("x")), width(steps[0].get("u")), _spacing(times),
                     name if isinstance(name, str) else None, f)
