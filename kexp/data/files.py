"""Recorded runs -> :class:`~kexp.data.Dataset` (and back): NPZ or CSV files, one run each, and kexp's own
``run.mcap`` logs.

Layout of one run (T+1 samples, n states, m inputs; time-first, one row per sample):

- **NPZ**: arrays ``t`` (T+1,), ``x`` (T+1, n) and optionally ``u`` (T, m) (the input held over
  [t_k, t_{k+1})); no other arrays.
- **CSV**: a header row ``t,x1,…,xn`` or ``t,x1,…,xn,u1,…,um``, then one row per sample; the last row's u
  cells are empty (no input follows the last sample).  Numbers as ``%.17g`` round-trip exactly.
- **MCAP**: a ``run.mcap`` written by ``kexp``: its ``/step`` channel has t, x, u per control step (the state
  and the input held until the next step); the final state after the last step is not logged.

Checks (each a one-line :class:`~kexp.errors.DataError`): missing or extra arrays/columns, a state dimension
other than the system's, input columns other than the system's m, t not increasing in steps of ``dt`` (within
1e-6·dt: kexp refuses irregular or differently sampled runs, it does not resample), and runs without any
finite sample.  A sample (row) with NaN in x or u is masked (``valid`` False; u set to 0 there) and counted in
the report; runs of different lengths are padded at the end with masked samples (x NaN, u 0).  Each run's time
is taken relative to its first sample.

Reading (kexp.data.streaming) is run by run: ``open_runs`` gives a streamed source that holds one file at a
time; ``read_runs`` fills one in-memory Dataset from it.
"""
from __future__ import annotations

import csv
import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DataError
from .checks import require_path, require_type
from .dataset import DT_TOLERANCE, Dataset

FORMATS = ("auto", "npz", "csv", "mcap")
SOURCE_KINDS = ("simulate", "files")
_SUFFIX = {".npz": "npz", ".csv": "csv", ".mcap": "mcap"}


@dataclass(frozen=True)
class DataSource:
    """Where the data comes from: ``kind='simulate'`` (collect(), the default) or ``kind='files'``: recorded runs
    at ``path`` (a file, or a folder whose ``*.npz`` / ``*.csv`` / ``*.mcap`` files, searched recursively, are
    read in sorted order), ``format`` auto (by file suffix), npz, csv or mcap."""

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

def _npz_shapes(f: Path) -> dict:
    """{name: shape} of the arrays in an .npz without loading them."""
    try:
        with zipfile.ZipFile(f) as z:
            out = {}
            for name in z.namelist():
                with z.open(name) as fh:
                    major, _minor = np.lib.format.read_magic(fh)
                    read = np.lib.format.read_array_header_1_0 if major == 1 else \
                        np.lib.format.read_array_header_2_0
                    shape = read(fh)[0]
                out[name[:-4] if name.endswith(".npy") else name] = shape
            return out
    except (zipfile.BadZipFile, ValueError, OSError) as exc:
        raise DataError(f"{f}: not a readable .npz file ({type(exc).__name__}: {exc})") from None


def _csv_header(f: Path) -> tuple[list[str], int]:
    """(header, number of data rows)."""
    with open(f, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        rows = sum(1 for row in reader if row)
    if not header:
        raise DataError(f"{f}: empty CSV file; expected a header row t,x1,…,xn[,u1,…,um]")
    return [h.strip() for h in header], rows


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


def _run_shape(f: Path, fmt: str, n: int, m: int, system_name: str | None = None) -> tuple[int, bool, str]:
    """(number of samples, has inputs, warning) of one run, checking its layout without reading the values; the
    warning says if an MCAP log was cut short or its run did not finish (its steps up to there are read)."""
    if fmt == "npz":
        shapes = _npz_shapes(f)
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
        return T1, "u" in shapes, ""
    if fmt == "csv":
        header, rows = _csv_header(f)
        has_u = _check_columns(f, header, n, m)
        if rows < 2:
            raise DataError(f"{f}: {rows} data row(s); a run needs at least 2 samples")
        return rows, has_u, ""
    t, x, u, warning = _read_mcap(f, n, m, system_name)
    return t.size, True, warning


def _read_mcap(f: Path, n: int, m: int, system_name: str | None = None):
    from ..recording.reader import LogError, read_log
    try:
        log = read_log(f)
    except LogError as exc:
        raise DataError(str(exc)) from None
    logged = ((log.one("/config") or {}).get("config") or {}).get("system") or {}
    if system_name and logged.get("name") and logged["name"] != system_name:
        raise DataError(f"{f}: recorded with system {logged['name']!r}, but system.name={system_name!r}; read it "
                        f"with system={logged['name']} or remove it from data.source.path")
    steps = log.messages("/step")
    if len(steps) < 2:
        raise DataError(f"{f}: {len(steps)} /step message(s); a run needs at least 2 control steps")

    def arr(key, width, what):
        rows = [s.get(key) for s in steps]
        out = np.full((len(rows), width), np.nan)
        for i, r in enumerate(rows):
            if r is None:
                continue
            r = [np.nan if v is None else v for v in np.atleast_1d(r)]
            if len(r) != width:
                raise DataError(f"{f}: /step.{key} has {len(r)} entries, but the system has {what}={width}")
            out[i] = r
        return out

    t = np.array([np.nan if s.get("t") is None else s["t"] for s in steps], dtype=float)
    return t, arr("x", n, "n"), arr("u", m, "m")[:-1], log.warning


def _read_run(f: Path, fmt: str, n: int, m: int):
    """(t (T+1,), x (T+1, n), u (T, m) or None) of one run."""
    if fmt == "npz":
        try:
            with np.load(f, allow_pickle=False) as z:
                return (np.asarray(z["t"], float), np.asarray(z["x"], float),
                        np.asarray(z["u"], float) if "u" in z.files else None)
        except (ValueError, TypeError, OSError, zipfile.BadZipFile) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise DataError(f"{f}: arrays t, x, u must hold numbers ({msg})") from None
    if fmt == "csv":
        header, _ = _csv_header(f)
        with open(f, newline="") as fh:
            lines = [line for line in fh.read().splitlines()[1:] if line.strip()]
        for k, line in enumerate(lines):
            if line.count(",") != len(header) - 1:
                raise DataError(f"{f}: data row {k + 1} has {line.count(',') + 1} cells, the header "
                                f"{len(header)}; give one cell per column (empty for the last row's u)")
        try:
            data = np.genfromtxt(io.StringIO("\n".join(lines)), delimiter=",", dtype=float, ndmin=2)
        except ValueError as exc:
            raise DataError(f"{f}: unreadable CSV ({str(exc).splitlines()[0]})") from None
        if data.shape[1] != len(header):
            raise DataError(f"{f}: rows have {data.shape[1]} cells, the header {len(header)}")
        u = data[:-1, 1 + n:] if len(header) > 1 + n else None
        return data[:, 0], data[:, 1:1 + n], u
    return _read_mcap(f, n, m)[:3]


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


