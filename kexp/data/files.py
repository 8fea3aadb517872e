"""Recorded runs -> :class:`~kexp.data.Dataset` (and back): NPZ or CSV files, one run each, and kexp's own
``run.mcap`` logs.

Layout of one run (T+1 samples, n states, m inputs; time-first, one row per sample):

- **NPZ**: arrays ``t`` (T+1,), ``x`` (T+1, n) and optionally ``u`` (T, m) (the input held over
  [t_k, t_{k+1})); no other arrays.
- **CSV**: a header row ``t,x1,…,xn`` or ``t,x1,…,xn,u1,…,um``, then one row per sample; the last row's u
  cells are empty (no input follows the last sample).  Numbers as ``%.17g`` round-trip exactly.
- **MCAP**: a ``run.mcap`` written by ``kexp``: its ``/step`` channel has t, x, u per control step (the state
  and the input held until the next step); the final state after the last step is not logged.

Checks (each a one-line :class:`~kexp.errors.DataError` naming the file, and the line and column or the array
entry): every value is read strictly (:mod:`kexp.data.parse`: decimal numbers within ±1e30, NaN or an empty CSV
cell for a missing sample; no inf, text, hex floats, complex or object arrays; size limits against bombs),
missing or extra arrays/columns, a state dimension
other than the system's, input columns other than the system's m, t not increasing in steps of ``dt`` (within
1e-6·dt: kexp refuses irregular or differently sampled runs, it does not resample), and runs without any
finite sample.  A sample (row) with NaN in x or u is masked (``valid`` False; u set to 0 there) and counted in
the report; runs of different lengths are padded at the end with masked samples (x NaN, u 0).  Each run's time
is taken relative to its first sample.

Reading (kexp.data.streaming) is run by run: ``open_runs`` gives a streamed source that holds one file at a
time; ``read_runs`` fills one in-memory Dataset from it.
"""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataError, is_number
from .checks import require_path, require_type, short
from .dataset import DT_TOLERANCE, Dataset
from .parse import check_file_size, check_values, npz_headers, read_csv

FORMATS = ("auto", "npz", "csv", "mcap")
SOURCE_KINDS = ("simulate", "files", "plant")
_SUFFIX = {".npz": "npz", ".csv": "csv", ".mcap": "mcap"}


@dataclass(frozen=True)
class DataSource:
    """Where the data comes from: ``kind='simulate'`` (collect(), the default), ``kind='files'``: recorded runs
    at ``path`` (a file, or a folder whose ``*.npz`` / ``*.csv`` / ``*.mcap`` files, searched recursively, are
    read in sorted order), ``format`` auto (by file suffix), npz, csv or mcap; or ``kind='plant'``: runs of the
    configured plant (a Gymnasium environment, a user's class: :func:`kexp.plants.collect.collect_from_plant`)."""

    kind: str = "simulate"
    path: str | None = None
    format: str = "auto"

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in SOURCE_KINDS:
            raise ConfigError(f"data.source.kind={self.kind!r}; valid: {SOURCE_KINDS}")
        if not isinstance(self.format, str) or self.format not in FORMATS:
            raise ConfigError(f"data.source.format={self.format!r}; valid: {FORMATS}")
        if self.path is not None:
            require_path(self.path, "data.source.path")
        if self.kind == "files" and not self.path:
            raise ConfigError("data.source.kind=files needs data.source.path (a file or folder of recorded runs)")


@dataclass(frozen=True)
class DataBounds:
    """The bounding box of the recorded samples, (n,) each: where a model identified from files is fit."""

    low: tuple[float, ...]
    high: tuple[float, ...]

    def contains(self, x, center=None) -> bool:
        x = np.asarray(x, dtype=float)
        return bool(np.all((x >= np.asarray(self.low)) & (x <= np.asarray(self.high))))

    def describe(self) -> str:
        return "the bounding box of the recorded data " + " × ".join(
            f"[{a:.4g}, {b:.4g}]" for a, b in zip(self.low, self.high))


def list_runs(path: str | Path, format: str = "auto") -> tuple[list[Path], list[str]]:
    """(files, their formats) at ``path``: the file itself, or the matching files under a folder, sorted."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"data.source.path={str(path)!r} does not exist; give a file or folder of recorded runs")
    if path.is_file():
        files = [path]
    else:
        suffixes = set(_SUFFIX) if format == "auto" else {f".{format}"}
        files = sorted(p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in suffixes)
        if not files:
            raise DataError(f"data.source.path={str(path)!r} holds no {' / '.join(sorted(suffixes))} files")
    formats = []
    for f in files:
        fmt = _SUFFIX.get(f.suffix.lower()) if format == "auto" else format
        if fmt is None:
            raise DataError(f"{f}: unknown suffix {f.suffix!r}; set data.source.format=npz|csv|mcap")
        formats.append(fmt)
    if len(set(formats)) > 1:
        raise DataError(f"data.source.path={str(path)!r} mixes formats {sorted(set(formats))}; keep one format per "
                        "folder or set data.source.format")
    return files, formats


# ---- one run ------------------------------------------------------------------------------------------------

def _check_columns(f: Path, header: list[str], n: int, m: int) -> bool:
    """True if the CSV has input columns; raise for missing or extra columns."""
    xs = [f"x{i + 1}" for i in range(n)]
    us = [f"u{i + 1}" for i in range(m)]
    if header in (["t"] + xs, ["t"] + xs + us):
        return header == ["t"] + xs + us
    n_given = sum(1 for h in header if h.startswith("x") and h[1:].isdigit())
    m_given = sum(1 for h in header if h.startswith("u") and h[1:].isdigit())
    known = set(["t"] + xs + us)
    extra = [h for h in header if h not in known and not (h[:1] in "xu" and h[1:].isdigit())]
    if extra:
        raise DataError(f"{f}: extra column(s) {extra}; expected t,{','.join(xs)}[,{','.join(us)}]")
    if "t" not in header:
        raise DataError(f"{f}: missing column 't'; expected t,{','.join(xs)}[,{','.join(us)}]")
    if n_given != n:
        raise DataError(f"{f}: {n_given} state column(s) {[h for h in header if h.startswith('x')]}, but the system "
                        f"has n={n}; expected t,{','.join(xs)}[,{','.join(us)}]")
    if m_given and m_given != m:
        raise DataError(f"{f}: {m_given} input column(s), but the system has m={m}; expected {','.join(us)}")
    raise DataError(f"{f}: columns {header}; expected t,{','.join(xs)}[,{','.join(us)}] in this order")


def _npz_layout(f: Path, n: int, m: int) -> bool:
    """True if the .npz has u; raise for missing or extra arrays and wrong shapes (from the headers alone)."""
    shapes = npz_headers(f)
    missing = [k for k in ("t", "x") if k not in shapes]
    extra = sorted(set(shapes) - {"t", "x", "u"})
    if missing or extra:
        raise DataError(f"{f}: " + ("; ".join(filter(None, [
            f"missing array(s) {missing}" if missing else "", f"extra array(s) {extra}" if extra else ""])))
            + "; expected t (T+1,), x (T+1, n) and optionally u (T, m)")
    T1 = shapes["t"][0] if len(shapes["t"]) == 1 else -1
    if T1 < 2:
        raise DataError(f"{f}: t has shape {shapes['t']}; expected (T+1,) with at least 2 samples")
    xs = shapes["x"]
    if len(xs) != 2 or xs[0] != T1:
        raise DataError(f"{f}: x has shape {xs}; expected (T+1, n) = ({T1}, {n})")
    if xs[1] != n:
        raise DataError(f"{f}: x has {xs[1]} state column(s), but the system has n={n}")
    if "u" in shapes and tuple(shapes["u"]) != (T1 - 1, m):
        raise DataError(f"{f}: u has shape {shapes['u']}; expected (T, m) = ({T1 - 1}, {m})")
    return "u" in shapes


def _read_mcap(f: Path, n: int, m: int, system_name: str | None = None):
    from ..recording.reader import LogError, read_log
    try:
        log = read_log(f)
    except LogError as exc:
        raise DataError(str(exc)) from None
    def field(d, key):
        return d.get(key) if isinstance(d, dict) else None

    logged = field(field(log.one("/config"), "config"), "system") or {}
    logged = logged if isinstance(logged, dict) else {}
    if system_name and logged.get("name") and logged["name"] != system_name:
        raise DataError(f"{f}: recorded with system {logged['name']!r}, but system.name={system_name!r}; read it "
                        f"with system={logged['name']} or remove it from data.source.path")
    steps = log.messages("/step")
    if not all(isinstance(s, dict) for s in steps):
        raise DataError(f"{f}: a /step message is not a JSON object; not a log kexp wrote")
    if len(steps) < 2:
        raise DataError(f"{f}: {len(steps)} /step message(s); a run needs at least 2 control steps")

    def number(v, key, k):
        if v is None:
            return np.nan
        if not is_number(v):
            raise DataError(f"{f}: /step message {k + 1}: {key} holds {short(v, 40)}, not a number")
        return float(v)

    def arr(key, width, what):
        out = np.full((len(steps), width), np.nan)
        for k, s in enumerate(steps):
            r = s.get(key)
            if r is None:
                continue
            r = r if isinstance(r, list) else [r]
            if len(r) != width:
                raise DataError(f"{f}: /step.{key} has {len(r)} entries, but the system has {what}={width}")
            out[k] = [number(v, key, k) for v in r]
        check_values(f, f"/step.{key}", out)
        return out

    t = np.array([number(s.get("t"), "t", k) for k, s in enumerate(steps)], dtype=float)
    return t, arr("x", n, "n"), arr("u", m, "m")[:-1], log.warning


def read_run(f: Path, fmt: str, n: int, m: int, system_name: str | None = None, store=None, digest=None):
    """(t (T+1,), x (T+1, n), u (T, m) or None, warning) of one run, read strictly (:mod:`kexp.data.parse`): its
    layout is checked first (NPZ: from the arrays' headers, before any is loaded), then its values; the warning
    says if an MCAP log was cut short or its run did not finish (its steps up to there are read).  A CSV file is
    read through ``store`` (a :class:`~kexp.data.parsed.ParsedStore`) when given: parsed once, then memory-mapped
    (``digest``: the SHA-256 of its bytes, if known)."""
    if fmt == "npz":
        has_u = _npz_layout(f, n, m)
        try:
            with np.load(f, allow_pickle=False) as z:
                arrays = {k: np.asarray(z[k], float) for k in (("t", "x", "u") if has_u else ("t", "x"))}
        except (ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise DataError(f"{f}: arrays t, x, u must hold numbers ({msg})") from None
        for k, a in arrays.items():
            check_values(f, k, a)
        return arrays["t"], arrays["x"], arrays.get("u"), ""
    if fmt == "csv":
        if store is not None:   # parsed once into a memory-mapped entry (kexp.data.parsed)
            header, data = store.csv(f, digest)
        else:
            header, data, _lines = read_csv(f)
        has_u = _check_columns(f, header, n, m)
        if data.shape[0] < 2:
            raise DataError(f"{f}: {data.shape[0]} data row(s); a run needs at least 2 samples")
        return data[:, 0], data[:, 1:1 + n], (data[:-1, 1 + n:] if has_u else None), ""
    check_file_size(f)
    return _read_mcap(f, n, m, system_name)


def _check_time(f: Path, t: np.ndarray, dt: float) -> None:
    if not np.all(np.isfinite(t)):
        raise DataError(f"{f}: t has {int((~np.isfinite(t)).sum())} NaN/inf value(s); give every sample's time")
    d = np.diff(t)
    bad = np.flatnonzero(np.abs(d - dt) > DT_TOLERANCE * dt)
    if bad.size:
        k = int(bad[0])
        spacing = np.median(d)
        hint = (f"set data.dt={spacing:.12g}" if np.all(np.abs(d - spacing) <= DT_TOLERANCE * spacing)
                else "resample the run to a regular grid first (kexp does not resample)")
        raise DataError(f"{f}: irregular or mismatched sampling: t[{k + 1}] - t[{k}] = {d[k]:.12g}, but data.dt="
                        f"{dt:g} (tolerance {DT_TOLERANCE:g}·dt) in {bad.size} step(s); {hint}")


# ---- writing ------------------------------------------------------------------------------------------------

def write_runs(dataset: Dataset, folder: str | Path, format: str = "npz", *, prefix: str = "run") -> list[Path]:
    """Write each trajectory of ``dataset`` to ``folder/{prefix}_{i:04d}.{format}`` (npz or csv), in the layout
    :func:`~kexp.data.streaming.read_runs` reads: masked samples are written as NaN rows, trailing masked samples
    are left out.
    Returns the paths."""
    require_type(dataset, Dataset, "write_runs: dataset", " (from collect or read_runs)")
    if not isinstance(format, str) or format not in ("npz", "csv"):
        raise ConfigError(f"format={format!r}; valid: 'npz', 'csv'")
    require_path(folder, "write_runs: folder")
    if not isinstance(prefix, str) or not prefix or "/" in prefix:
        raise ConfigError(f"write_runs: prefix={prefix!r}: give a plain file-name prefix, e.g. 'run'")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(dataset.n_traj):
        keep = np.flatnonzero(dataset.valid[i])
        if keep.size == 0:
            continue
        T1 = int(keep[-1]) + 1
        t = dataset.t[:T1] - dataset.t[0]
        x = np.where(dataset.valid[i, :T1, None], dataset.x[i, :T1], np.nan)
        u = None if dataset.u is None else dataset.u[i, :T1 - 1]
        p = folder / f"{prefix}_{i:04d}.{format}"
        if format == "npz":
            np.savez(p, t=t, x=x, **({} if u is None else {"u": u}))
        else:
            n, m = dataset.n, (0 if u is None else u.shape[1])
            header = ["t"] + [f"x{j + 1}" for j in range(n)] + [f"u{j + 1}" for j in range(m)]
            with open(p, "w", newline="") as fh:
                fh.write(",".join(header) + "\n")
                for k in range(T1):
                    cells = [t[k], *x[k]] + (list(u[k]) if m and k < T1 - 1 else [])
                    row = ",".join("nan" if not np.isfinite(c) else repr(float(c)) for c in cells)
                    fh.write(row + ("," * m if m and k == T1 - 1 else "") + "\n")
        paths.append(p)
    return paths


