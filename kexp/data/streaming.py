"""Recorded runs as a streamed :class:`~kexp.data.runs.PairSource`: :class:`RecordedRuns` reads one file at a
time, every time identification visits the runs, so memory does not grow with the number of pairs.

:func:`open_runs` makes one first pass over the files (each read and checked once; layouts and checks in
:mod:`kexp.data.files`) and keeps only what the whole data set is needed for: per run its length, whether it
is forced and how many pairs it gives, and in all the report's counts, the SHA-256 digest of the files' bytes,
and the kept samples' count, bounding box, max |x| and Σ(x − x_eq)² (for ``data_rms``, ``bounds`` and the
dictionary's auto scale).  Measurement noise (:meth:`RecordedRuns.with_noise`) keeps each run's random-generator
state, so a run's noise is the same on every pass and equal to the in-memory Dataset's.
:func:`read_runs` reads the same runs into one in-memory :class:`~kexp.data.Dataset`.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..errors import ConfigError, DataError, require_number
from .checks import require_path, short, state_vector
from .collect import RegionFilter
from .dataset import PAIR_RULES, DataReport, Dataset
from .files import FORMATS, DataBounds, _check_time, list_runs, read_run
from .parse import check_file_size
from .noise import DATA_NOISE, noise_rng
from .runs import Run, SampleStats, count_pairs, pair_chunks, sample_stats, split_indices
from .smoothing import segments, smooth_run


def _load(f: Path, fmt: str, n: int, m: int, dt: float, system_name, region_filter, x_eq, store=None, digest=None):
    """(x (T+1, n) NaN where masked, valid (T+1,), u (T, m) or None, warning, NaN rows, dropped) of one file (a CSV
    file through ``store``, :mod:`kexp.data.parsed`, when given)."""
    t, xi, ui, warning = read_run(f, fmt, n, m, system_name, store, digest)
    _check_time(f, t, dt)
    ok = np.all(np.isfinite(xi), axis=1)
    if ui is not None:
        ok[:-1] &= np.all(np.isfinite(ui), axis=1)
        ui = np.where(np.isfinite(ui), ui, 0.0)
        ui[~ok[:-1]] = 0.0
    if not ok.any():
        raise DataError(f"{f}: no sample has finite x{' and u' if ui is not None else ''}; fix or remove the run")
    n_nan = int((~ok).sum())
    dropped = False
    if region_filter is not None and region_filter.active:
        _, kept, _, n_drop = region_filter.apply(xi[None], ok[None], None, x_eq)
        dropped = n_drop > 0
        ok = ok if dropped else kept[0]
    return np.where(ok[:, None], xi, np.nan), ok, ui, warning, n_nan, dropped


@dataclass(frozen=True, eq=False)
class RecordedRuns:
    """Recorded runs read file by file (frozen; see the module docstring).  ``files``/``formats`` the kept runs
    (a run dropped by the region filter is left out), ``t_len`` the longest run's T+1 over all files,
    ``forced_runs``/``pairs_runs`` (n_traj,) per run; ``noise_sigma`` (n,) and ``noise_states``
    (one generator state per run) when measurement noise was added.  Build it with :func:`open_runs`."""

    files: tuple
    formats: tuple
    n: int
    m: int
    dt: float
    pair_rule: str
    system_name: str
    has_inputs: bool
    t_len: int
    forced_runs: np.ndarray
    pairs_runs: np.ndarray
    report: DataReport
    region_filter: object = None
    x_eq: np.ndarray | None = None
    drift: Callable | None = None
    expect_system: str | None = None   # an MCAP log recorded with another system is refused
    noise_sigma: np.ndarray | None = None
    noise_states: tuple | None = None
    cached_stats: tuple = field(default=())   # SampleStats of the clean full set, about 0 and x_eq
    smooth: object = None                      # a SmoothConfig applied after the noise, run by run
    digests: tuple = ()                        # SHA-256 of each file's bytes (the parsed entries' names)
    store: object = None                       # the ParsedStore CSV files are read through (kexp.data.parsed)

    @property
    def n_traj(self) -> int:
        return len(self.files)

    @property
    def n_pairs(self) -> int:
        return int(self.pairs_runs.sum())

    @property
    def forced(self) -> bool:
        return bool(self.forced_runs.any())

    def run_forced(self) -> np.ndarray:
        return self.forced_runs.copy()

    def runs(self) -> Iterator[Run]:
        """The runs one at a time, read from their files (length T+1 of each run, not padded)."""
        for j, (f, fmt) in enumerate(zip(self.files, self.formats)):
            x, ok, u, *_ = _load(f, fmt, self.n, self.m, self.dt, self.expect_system, self.region_filter, self.x_eq,
                                 self.store, self.digests[j] if self.digests else None)
            if self.has_inputs and u is None:
                u = np.zeros((x.shape[0] - 1, self.m))
            fx = None
            if self.pair_rule == "euler":
                fx = np.zeros_like(x)
                fx[ok] = self.drift(x[ok])
            if self.noise_states is not None:
                rng = np.random.default_rng(0)
                rng.bit_generator.state = self.noise_states[j]
                x = x + rng.standard_normal((self.t_len, self.n))[: x.shape[0]] * self.noise_sigma
            if self.smooth is not None:
                x = smooth_run(x, ok, self.smooth)[0]
            yield Run(x, ok, u, fx)

    def iter_pairs(self, chunk_size: int = 20000, *, with_inputs: bool = False, instrument_lag: int = 0):
        return pair_chunks(self, chunk_size, with_inputs=with_inputs, instrument_lag=instrument_lag)

    def subset(self, traj) -> "RecordedRuns":
        traj = np.asarray(traj, dtype=int)
        return replace(self, files=tuple(self.files[i] for i in traj), formats=tuple(self.formats[i] for i in traj),
                       forced_runs=self.forced_runs[traj],
                       digests=tuple(self.digests[i] for i in traj) if self.digests else (),
                       pairs_runs=self.pairs_runs[traj], cached_stats=(),
                       noise_states=None if self.noise_states is None else tuple(self.noise_states[i] for i in traj))

    def split(self, holdout: float, seed: int = 0) -> tuple["RecordedRuns", "RecordedRuns | None"]:
        train, test = split_indices(self.n_traj, holdout, seed)
        return (self, None) if test is None else (self.subset(train), self.subset(test))

    def stats(self, center=None) -> SampleStats:
        c = np.zeros(self.n) if center is None else np.asarray(center, float).reshape(self.n)
        for s in self.cached_stats:
            if np.array_equal(s.center, c):
                return s
        return sample_stats(self.runs(), self.n, c)

    def with_noise(self, sigma: np.ndarray, seed: int) -> "RecordedRuns":
        """Noise σ·N(0, 1) from the data noise's stream of ``seed`` (kexp.data.noise.noise_rng) drawn run after run
        over (t_len, n) each, as the in-memory Dataset draws over its (n_traj, T+1, n) array; only each run's
        generator state is kept."""
        rng, states = noise_rng(seed, DATA_NOISE), []
        for _ in range(self.n_traj):
            states.append(rng.bit_generator.state)
            rng.standard_normal((self.t_len, self.n))
        sigma = np.asarray(sigma, float)
        return replace(self, noise_sigma=sigma, noise_states=tuple(states), cached_stats=(),
                       report=replace(self.report, noise_std=tuple(float(s) for s in sigma)))

    def with_smoothing(self, cfg) -> "RecordedRuns":
        """Each run filtered by ``cfg`` (a :class:`~kexp.data.smoothing.SmoothConfig`) as it is read, after the
        noise; one pass counts the kept samples in stretches too short for the window (the report's)."""
        if not cfg.active:
            return self
        short = sum(sum(b - a for a, b in segments(r.valid) if b - a < cfg.window) for r in self.runs())
        return replace(self, smooth=cfg, cached_stats=(),
                       report=replace(self.report, smoothing=cfg.describe(), n_unsmoothed_samples=short))

    def to_dataset(self) -> Dataset:
        """The runs in one in-memory Dataset: x (n_traj, t_len, n) padded with masked NaN samples."""
        x = np.full((self.n_traj, self.t_len, self.n), np.nan)
        valid = np.zeros((self.n_traj, self.t_len), dtype=bool)
        u = np.zeros((self.n_traj, self.t_len - 1, self.m)) if self.has_inputs else None
        fx = np.zeros_like(x) if self.pair_rule == "euler" else None
        for i, run in enumerate(self.runs()):
            T1 = run.x.shape[0]
            x[i, :T1], valid[i, :T1] = run.x, run.valid
            if u is not None:
                u[i, :T1 - 1] = run.u
            if fx is not None:
                fx[i, :T1] = run.fx
        return Dataset(t=np.arange(self.t_len) * self.dt, x=x, valid=valid, dt=self.dt, pair_rule=self.pair_rule,
                       system_name=self.system_name, u=u, fx=fx, report=self.report)


def open_runs(path: str | Path, *, n: int, m: int, dt: float, format: str = "auto", pair_rule: str = "next",
              system_name: str | None = None, drift=None, region_filter=None, x_eq=None,
              parsed_dir: str | Path | None = None) -> RecordedRuns:
    """The recorded runs at ``path`` as a streamed :class:`RecordedRuns`, after one pass that reads and checks
    every file (the arguments and checks as :func:`read_runs`).  CSV files are parsed once, into memory-mapped
    entries in ``parsed_dir`` (None: a temporary folder of this process), which every later pass reads
    (:mod:`kexp.data.parsed`); an entry already there (an earlier run, another job of a sweep) is not parsed
    again."""
    _check_args("open_runs", path, n, m, dt, format, pair_rule, system_name, drift, region_filter, x_eq)
    files, formats = list_runs(path, format)
    x_eq = np.zeros(n) if x_eq is None else np.asarray(x_eq, float).reshape(n)
    digest = hashlib.sha256()
    kept, all_lengths, forced, pairs, warnings = [], [], [], [], []
    has_inputs, n_nan, n_dropped = False, 0, 0
    about = (np.zeros(n), x_eq)
    sums = [np.zeros(n), np.zeros(n)]
    count, low, high, absmax = 0, np.full(n, np.inf), np.full(n, -np.inf), np.zeros(n)
    store = None
    if "csv" in formats:
        from .parsed import ParsedStore, private_store
        store = private_store() if parsed_dir is None else ParsedStore(parsed_dir)
    file_digests = []
    for i, (f, fmt) in enumerate(zip(files, formats)):
        check_file_size(f)   # a file past the size limit is never read whole
        own = hashlib.sha256()
        digest.update(f.name.encode())
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 16), b""):
                digest.update(block)
                own.update(block)
        file_digests.append(own.hexdigest())
        x, ok, u, warning, nan_rows, dropped = _load(f, fmt, n, m, dt, system_name, region_filter, x_eq, store,
                                                     file_digests[-1])
        has_inputs |= u is not None
        n_nan += nan_rows
        all_lengths.append(x.shape[0])
        if warning:
            warnings.append(warning)
        if dropped:
            n_dropped += 1
            continue
        kept.append(i)
        forced.append(u is not None and bool(np.any(u != 0)))
        pairs.append(count_pairs(Run(x, ok), pair_rule))
        xs = x[ok]
        count += xs.shape[0]
        if xs.shape[0]:
            low, high = np.minimum(low, xs.min(axis=0)), np.maximum(high, xs.max(axis=0))
            absmax = np.maximum(absmax, np.abs(xs).max(axis=0))
            sums = [np.concatenate([s[None], (xs - c) ** 2]).sum(axis=0) for s, c in zip(sums, about)]
    if count == 0:
        raise DataError("recorded data: the filter removed every sample; widen data.filter")
    t_len = max(all_lengths)
    n_kept = len(kept)
    flt, region = ("none", "none") if region_filter is None or not region_filter.active else \
        (region_filter.mode, region_filter.describe(n))
    report = DataReport(n_traj=len(files), n_samples=n_kept * t_len, n_pairs=int(sum(pairs)),
                        n_masked_samples=n_kept * t_len - count, n_dropped_traj=n_dropped, filter=flt, region=region,
                        source=f"{len(files)} {formats[0]} file(s) at {path}" + (
                            f" ({len(warnings)} log(s) cut short or unfinished: {warnings[0]})" if warnings else ""),
                        n_nan_samples=n_nan, n_padded_samples=int(sum(t_len - all_lengths[i] for i in kept)),
                        digest=digest.hexdigest()[:20])
    stats = tuple(SampleStats(count=count, low=low, high=high, absmax=absmax, sumsq=s, center=c)
                  for s, c in zip(sums, about))
    return RecordedRuns(files=tuple(files[i] for i in kept), formats=tuple(formats[i] for i in kept), n=n, m=m,
                        dt=dt, pair_rule=pair_rule, system_name=system_name or "recorded", has_inputs=has_inputs,
                        t_len=t_len, forced_runs=np.array(forced, bool),
                        pairs_runs=np.array(pairs, dtype=np.int64), report=report, region_filter=region_filter,
                        x_eq=x_eq, drift=drift, expect_system=system_name, cached_stats=stats,
                        digests=tuple(file_digests[i] for i in kept), store=store)


def read_runs(path: str | Path, *, n: int, m: int, dt: float, format: str = "auto", pair_rule: str = "next",
              system_name: str | None = None, drift=None, region_filter=None, x_eq=None) -> Dataset:
    """The :class:`Dataset` of the recorded runs at ``path`` (layouts and checks: :mod:`kexp.data.files`):
    ``x`` (n_traj, T_max+1, n), ``valid`` False at NaN rows and at the padding of shorter runs, ``u`` (n_traj,
    T_max, m) if any run has inputs (0 for runs without), else None.  ``dt`` must match the files' spacing.
    Euler pairs need ``drift`` (F, to evaluate at the samples).  ``region_filter`` (a
    :class:`~kexp.data.RegionFilter` around ``x_eq``) masks or drops samples as for simulated data.  The report
    counts NaN rows and padding and holds a SHA-256 digest of the files' bytes (``report.digest``), e.g. for
    cache keys.  With ``system_name``, an MCAP log recorded with another system is refused.  The same runs
    streamed, without holding them all: :func:`open_runs`.  Bad arguments raise a one-line ConfigError."""
    _check_args("read_runs", path, n, m, dt, format, pair_rule, system_name, drift, region_filter, x_eq)
    return open_runs(path, n=n, m=m, dt=dt, format=format, pair_rule=pair_rule, system_name=system_name,
                     drift=drift, region_filter=region_filter, x_eq=x_eq).to_dataset()


def _check_args(who, path, n, m, dt, format, pair_rule, system_name, drift, region_filter, x_eq) -> None:
    """A one-line ConfigError, naming the function and the argument, for any bad argument of open_runs/read_runs."""
    require_path(path, f"{who}: path")
    for key, value in (("n", n), ("m", m)):
        require_number(value, f"{who}: {key}", integer=True)
        if value < 1:
            raise ConfigError(f"{who}: {key}={value}: use an int >= 1 (the system's number of "
                              f"{'states' if key == 'n' else 'inputs'})")
    require_number(dt, f"{who}: dt")
    if not (np.isfinite(dt) and dt > 0):
        raise ConfigError(f"{who}: dt={dt}: use the runs' sampling time (data.dt), a finite number > 0")
    if not isinstance(format, str) or format not in FORMATS:
        raise ConfigError(f"data.source.format={format!r}; valid: {FORMATS}")
    if not isinstance(pair_rule, str) or pair_rule not in PAIR_RULES:
        raise ConfigError(f"data.pairs={pair_rule!r}; valid: {PAIR_RULES}")
    if system_name is not None and not isinstance(system_name, str):
        raise ConfigError(f"{who}: system_name={short(system_name)}: give the system's name (a str) or None")
    if drift is not None and not callable(drift):
        raise ConfigError(f"{who}: drift={short(drift)}: give the system's drift F (a callable, e.g. system.drift) or "
                          "None")
    if pair_rule == "euler" and drift is None:
        raise ConfigError("data.pairs=euler needs the system's drift F for recorded data")
    if region_filter is not None and not isinstance(region_filter, RegionFilter):
        raise ConfigError(f"{who}: region_filter={short(region_filter)}: expected a RegionFilter or None")
    state_vector(x_eq, n, f"{who}: x_eq")


def bounds(dataset) -> DataBounds:
    """The bounding box of the kept samples of a Dataset or :class:`RecordedRuns` (no pass for the latter)."""
    s = dataset.stats()
    return DataBounds(tuple(s.low.tolist()), tuple(s.high.tolist()))
