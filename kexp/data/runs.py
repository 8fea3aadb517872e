"""What identification reads from data, run by run: the :class:`PairSource` protocol and the algorithms on it.

A pair source is a list of runs (trajectories) that can be visited one at a time (:meth:`PairSource.runs`).
The in-memory :class:`~kexp.data.Dataset` and the file-backed :class:`~kexp.data.streaming.RecordedRuns` both
are one; everything identification needs from the whole data set is computed here by streaming over runs, so
memory is one run (plus O(number of runs) bookkeeping), never all samples:

- :func:`pair_chunks`: snapshot pairs (X, Y) or (X, U, Y) in chunks of at most ``chunk_size`` rows, optionally
  with a lagged instrument sample Z in front;
- :func:`split_indices`: the trajectory split for a hold-out set;
- :func:`window_samples`: start and end states (and inputs) of evenly subsampled windows of h valid steps;
- :func:`strided_samples`: every k-th kept sample;
- :func:`sample_stats`: count, bounding box, max |x| and the RMS about a centre of the kept finite samples.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Protocol

import numpy as np

from ..errors import ConfigError, DataError


@dataclass(frozen=True)
class Run:
    """One trajectory: ``x`` (T+1, n), ``valid`` (T+1,) bool, ``u`` (T, m) or None (no inputs in the source),
    ``fx`` (T+1, n) F at the samples (Euler pairs only) or None.  Padding after a shorter run is invalid."""

    x: np.ndarray
    valid: np.ndarray
    u: np.ndarray | None = None
    fx: np.ndarray | None = None


@dataclass(frozen=True)
class SampleStats:
    """Of the kept, finite samples: ``count``, ``low``/``high`` (n,) the bounding box, ``absmax`` (n,) max |x_i|,
    ``sumsq`` (n,) Σ(x_i − center_i)² about ``center`` (n,)."""

    count: int
    low: np.ndarray
    high: np.ndarray
    absmax: np.ndarray
    sumsq: np.ndarray
    center: np.ndarray

    @property
    def rms(self) -> np.ndarray:
        if self.count == 0:
            raise DataError("data RMS: no kept finite samples")
        return np.sqrt(self.sumsq / self.count)


class PairSource(Protocol):
    """The interface identification uses (shapes: n states, m inputs, runs of T+1 samples)."""

    dt: float
    pair_rule: str
    system_name: str
    report: object

    @property
    def n(self) -> int: ...
    @property
    def n_traj(self) -> int: ...
    @property
    def n_pairs(self) -> int: ...
    @property
    def has_inputs(self) -> bool: ...      # runs carry u (zeros for runs recorded without)
    @property
    def forced(self) -> bool: ...          # some input is nonzero
    def run_forced(self) -> np.ndarray: ...   # (n_traj,) bool: run i has a nonzero input
    def runs(self) -> Iterator[Run]: ...
    def subset(self, traj: np.ndarray) -> "PairSource": ...
    def stats(self, center=None) -> SampleStats: ...
    def with_noise(self, sigma: np.ndarray, seed: int) -> "PairSource": ...
    def with_smoothing(self, cfg) -> "PairSource": ...


def pair_mask(run: Run, pair_rule: str) -> np.ndarray:
    """(T,) for 'next' pairs (x_k, x_{k+1}), (T+1,) for Euler pairs (x_k, x_k + F(x_k)Δ)."""
    if pair_rule == "next":
        return run.valid[:-1] & run.valid[1:]
    return run.valid


def count_pairs(run: Run, pair_rule: str) -> int:
    return int(pair_mask(run, pair_rule).sum())


def lagged_pair_mask(run: Run, pair_rule: str, lag: int) -> np.ndarray:
    """:func:`pair_mask` restricted to the pairs k whose instrument sample k − ``lag`` lies in the run and is valid
    (the first ``lag`` pairs of a run have none: dropped)."""
    mask = pair_mask(run, pair_rule).copy()
    mask[:lag] = False
    mask[lag:] &= run.valid[: mask.size - lag]
    return mask


def pair_chunks(source: PairSource, chunk_size: int = 20000, *, with_inputs: bool = False,
                instrument_lag: int = 0) -> Iterator[tuple[np.ndarray, ...]]:
    """(X, Y) chunks of at most ``chunk_size`` pairs, each (rows, n), run after run; ``with_inputs``: (X, U, Y)
    with U (rows, m) the input held over each pair (needs next-sample pairs and a source with inputs).
    ``instrument_lag`` L >= 1: (Z, X, Y) or (Z, X, U, Y) with Z (rows, n) the sample L steps before X on the same
    run (an instrument whose measurement noise is independent of X's and Y's); pairs without a valid sample
    L steps back are left out (:func:`lagged_pair_mask`)."""
    if chunk_size < 1:
        raise ConfigError(f"chunk_size={chunk_size}: use an int >= 1")
    if with_inputs and (not source.has_inputs or source.pair_rule != "next"):
        raise DataError("pairs with inputs need next-sample pairs (data.pairs=next) of a dataset with inputs")
    lag = int(instrument_lag)
    if lag < 0 or lag != instrument_lag:
        raise ConfigError(f"instrument_lag={instrument_lag!r}: use an int >= 0 (0: no instrument)")
    parts, count = [], 0
    for run in source.runs():
        k = np.flatnonzero(lagged_pair_mask(run, source.pair_rule, lag) if lag else pair_mask(run, source.pair_rule))
        start = 0
        while start < k.size:
            take = min(chunk_size - count, k.size - start)
            kk = k[start:start + take]
            x = run.x[kk]
            y = run.x[kk + 1] if source.pair_rule == "next" else x + source.dt * run.fx[kk]
            part = (x, run.u[kk], y) if with_inputs else (x, y)
            parts.append((run.x[kk - lag],) + part if lag else part)
            count += take
            start += take
            if count == chunk_size:
                yield tuple(np.concatenate(c) for c in zip(*parts))
                parts, count = [], 0
    if count:
        yield tuple(np.concatenate(c) for c in zip(*parts))


def split_indices(n_traj: int, holdout: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """(train, test) trajectory indices, sorted; test has round(holdout·n_traj) trajectories (at least 1 if
    holdout > 0 and n_traj ≥ 2), None if empty."""
    if not 0 <= holdout < 1:
        raise ConfigError(f"data.holdout={holdout}: use a fraction in [0, 1)")
    n_test = int(round(holdout * n_traj))
    if holdout > 0 and n_traj >= 2:
        n_test = max(n_test, 1)
    if n_test == 0:
        return np.arange(n_traj), None
    perm = np.random.default_rng(seed).permutation(n_traj)
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


def _window_starts(valid: np.ndarray, h: int) -> np.ndarray:
    """Start samples s of the windows s..s+h with every sample valid, ascending."""
    if h >= valid.size:
        return np.zeros(0, int)
    c = np.concatenate([[0], np.cumsum(valid.astype(np.int64))])
    return np.flatnonzero((c[h + 1:] - c[: -h - 1]) == h + 1)


def window_samples(source: PairSource, h: int, max_windows: int = 20000, *, inputs: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(x0 (w, n), xh (w, n), U (w, h, m) or None) at the windows of h steps with every sample valid, run after
    run; more than ``max_windows`` are subsampled evenly (the same windows whatever the source's kind).  Two
    passes: one counts the windows, one gathers the picked ones."""
    counts = np.array([_window_starts(r.valid, h).size for r in source.runs()], dtype=np.int64)
    total = int(counts.sum())
    pick = np.arange(total)
    if total > max_windows:
        pick = np.linspace(0, total - 1, max_windows).round().astype(np.int64)
    n = source.n
    x0, xh, us = [np.zeros((0, n))], [np.zeros((0, n))], []
    offsets = np.concatenate([[0], np.cumsum(counts)])
    for i, run in enumerate(source.runs()):
        lo, hi = np.searchsorted(pick, [offsets[i], offsets[i + 1]])
        if hi == lo:
            continue
        s = _window_starts(run.valid, h)[pick[lo:hi] - offsets[i]]
        x0.append(run.x[s])
        xh.append(run.x[s + h])
        if inputs:
            us.append(run.u[s[:, None] + np.arange(h)[None, :]])
    U = (np.concatenate(us) if us else np.zeros((0, h, 0))) if inputs else None
    return np.concatenate(x0), np.concatenate(xh), U


def strided_samples(source: PairSource, max_rows: int = 5000) -> np.ndarray:
    """Every k-th kept sample (run after run), k = max(1, number kept // max_rows): (≈max_rows, n)."""
    total = sum(int(r.valid.sum()) for r in source.runs())
    step = max(1, total // max_rows)
    out, offset = [np.zeros((0, source.n))], 0
    for run in source.runs():
        xs = run.x[run.valid]
        first = (-offset) % step
        out.append(xs[first::step])
        offset += xs.shape[0]
    return np.concatenate(out)


def sample_stats(runs: Iterable[Run], n: int, center=None) -> SampleStats:
    """:class:`SampleStats` of the kept, finite samples of ``runs`` in one pass.  Σ(x − c)² is summed sample after
    sample in order, as numpy sums the rows of one array, so it equals the in-memory result."""
    c = np.zeros(n) if center is None else np.asarray(center, float).reshape(n)
    count, sumsq = 0, np.zeros(n)
    low, high, absmax = np.full(n, np.inf), np.full(n, -np.inf), np.zeros(n)
    for run in runs:
        xs = run.x[run.valid]
        xs = xs[np.all(np.isfinite(xs), axis=1)]
        if xs.shape[0] == 0:
            continue
        count += xs.shape[0]
        low, high = np.minimum(low, xs.min(axis=0)), np.maximum(high, xs.max(axis=0))
        absmax = np.maximum(absmax, np.abs(xs).max(axis=0))
        sumsq = np.concatenate([sumsq[None], (xs - c) ** 2]).sum(axis=0)
    return SampleStats(count=count, low=low, high=high, absmax=absmax, sumsq=sumsq, center=c)


FLOAT_ROOM = 308   # decades: the Gram sums of a dictionary on the data must stay below 1e308 (floats end at 1.8e308)


def check_dictionary_range(stats: SampleStats, degree: int, scale=None, center=None) -> None:
    """A one-line DataError if monomials up to ``degree`` of ξ = (x − center)/scale (``scale``, ``center``: (n,)
    or None for 1 and 0, as :class:`~kexp.dictionary.Monomials`) could overflow on the kept samples of ``stats``:
    with M = max(1, max_i |ξ_i|) over the data's bounding box, every monomial is at most M^degree, so the Gram
    sums Σ φ_i φ_j over the ``count`` samples (and the squared norms a QR forms) are at most count·M^(2·degree),
    which must stay below 1e308.  The per-value limit of the files (±1e30, :mod:`kexp.data.parse`) is this rule
    for the default degree 5 and up to 1e8 samples; a higher degree on large values needs this check
    (measured: 1e30 in one cell, degree 8, method=gram ended in a traceback, ``array must not contain infs or
    NaNs``)."""
    if stats.count == 0:
        return
    n = stats.low.size
    c = np.zeros(n) if center is None else np.asarray(center, float).reshape(-1) * np.ones(n)
    s = np.ones(n) if scale is None else np.asarray(scale, float).reshape(-1) * np.ones(n)
    xi = np.maximum(np.abs(stats.high - c), np.abs(stats.low - c)) / s
    i = int(np.argmax(xi))
    decades = np.log10(stats.count) + 2 * degree * np.log10(max(1.0, float(xi[i])))
    if decades > FLOAT_ROOM:
        scaled = "" if scale is None else f" (scaled: {xi[i]:.3g})"
        raise DataError(f"the data reach |x{i + 1}| = {xi[i] * s[i]:.3g}{scaled}: "
                        f"monomials up to dictionary.degree={degree} reach 1e{degree * np.log10(xi[i]):.0f} and their "
                        f"sums of squares over {stats.count} samples 1e{decades:.0f}, past the float range (1e308); "
                        "use dictionary.scale=auto, a lower dictionary.degree, or rescale the data")
