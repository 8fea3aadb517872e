"""The Dataset: sampled trajectories plus the masks and pair rule that turn them into snapshot pairs.

Shapes (time-first inside a trajectory): ``x`` (n_traj, T+1, n); ``u`` (n_traj, T, m) or None (unforced);
``valid`` (n_traj, T+1) marks samples kept by the filters; ``fx`` (n_traj, T+1, n), F at each sample, only for
Euler pairs.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np

from ..errors import ConfigError, DataError
from .checks import is_real, short
from .noise import DATA_NOISE, noise_rng
from .runs import Run, SampleStats, pair_chunks, split_indices

PAIR_RULES = ("next", "euler")
DT_TOLERANCE = 1e-6  # relative to dt: how far a sample spacing may be from dt (recorded runs and Dataset.t)


def _frozen(a):
    if a is None:
        return None
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class DataReport:
    """What collection and filtering did: counts for the summary."""

    n_traj: int
    n_samples: int
    n_pairs: int
    n_masked_samples: int
    n_dropped_traj: int
    filter: str
    region: str
    source: str = "simulated"        # or "<N> npz file(s) at <path>" (kexp.data.files)
    n_nan_samples: int = 0           # recorded rows with NaN in x or u (masked, part of n_masked_samples)
    n_padded_samples: int = 0        # masked samples padding shorter recorded runs (part of n_masked_samples)
    digest: str = ""                 # of the recorded files' bytes ("" for simulated data)
    noise_std: tuple | None = None   # σ per state of the measurement noise added (kexp.data.noise); None: none
    smoothing: str = "none"          # the filter applied before identification (kexp.data.smoothing)
    n_unsmoothed_samples: int = 0    # kept samples in stretches shorter than the smoothing window (left as they are)

    def lines(self) -> list[str]:
        out = [f"trajectories: {self.n_traj} ({self.n_dropped_traj} dropped by the filter)",
               f"samples: {self.n_samples} ({self.n_masked_samples} masked: {self.filter}, region {self.region})",
               f"snapshot pairs: {self.n_pairs}"]
        if self.source != "simulated" and not self.digest:
            out.insert(0, self.source)
        elif self.source != "simulated":
            out.insert(0, f"{self.source} (sha256 {self.digest}); {self.n_nan_samples} NaN row(s) masked, "
                          f"{self.n_padded_samples} padding sample(s) after shorter runs")
        if self.noise_std is not None:
            out.append("measurement noise σ per state: [" + ", ".join(f"{s:.4g}" for s in self.noise_std) + "]")
        if self.smoothing != "none":
            out.append(f"smoothed: {self.smoothing} ({self.n_unsmoothed_samples} kept sample(s) in stretches "
                       "shorter than the window left as they are)")
        return out


@dataclass(frozen=True)
class Dataset:
    """Sampled trajectories of one system (frozen, arrays read-only), what :func:`~kexp.data.collect` returns:
    ``t`` (T+1,) sample times, ``x`` (n_traj, T+1, n) states, ``valid`` (n_traj, T+1) bool (False: masked by the
    region filter or not finite), ``dt`` the sampling time, ``pair_rule`` 'next' (x_k, x_{k+1}) or 'euler'
    (x_k, x_k + F(x_k)·dt, needs ``fx`` (n_traj, T+1, n)), ``u`` (n_traj, T, m) the held inputs of a forced
    collection (None: unforced), ``report`` what collection dropped and why.  ``iter_pairs`` yields snapshot
    pairs in bounded memory.  Raises :class:`~kexp.errors.DataError` / ConfigError for inconsistent shapes or an
    unknown pair rule."""

    t: np.ndarray
    x: np.ndarray
    valid: np.ndarray
    dt: float
    pair_rule: str
    system_name: str
    u: np.ndarray | None = None
    fx: np.ndarray | None = None
    report: DataReport | None = field(default=None, compare=False)

    def __post_init__(self):
        for name in ("t", "x", "valid", "u", "fx"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        if self.x.ndim != 3:
            raise DataError(f"Dataset.x must have shape (n_traj, T+1, n), got {self.x.shape}")
        if self.valid.shape != self.x.shape[:2]:
            raise DataError(f"Dataset.valid shape {self.valid.shape} must equal x.shape[:2] = {self.x.shape[:2]}")
        if self.valid.dtype != bool:
            raise DataError(f"Dataset.valid has dtype {self.valid.dtype}; give a bool mask (True: sample kept)")
        if not (is_real(self.dt) and np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"Dataset.dt={short(self.dt)}: use the sampling time, a finite number > 0")
        if self.t.shape != self.x.shape[1:2]:
            raise DataError(f"Dataset.t shape {self.t.shape} must be (T+1,) = ({self.x.shape[1]},), one time per "
                            "sample of x")
        if self.t.dtype.kind not in "iuf":
            raise DataError(f"Dataset.t has dtype {self.t.dtype}; give the sample times as numbers")
        steps = np.diff(self.t)
        bad = np.flatnonzero(~(np.abs(steps - self.dt) <= DT_TOLERANCE * self.dt))
        if bad.size:
            k = int(bad[0])
            raise DataError(f"Dataset.t[{k + 1}] - t[{k}] = {steps[k]:.12g}, but dt={self.dt:g}: t must be spaced "
                            f"dt apart (tolerance {DT_TOLERANCE:g}·dt) in {bad.size} step(s)")
        if not isinstance(self.pair_rule, str) or self.pair_rule not in PAIR_RULES:
            raise ConfigError(f"data.pairs={self.pair_rule!r}; valid: {PAIR_RULES}")
        if self.pair_rule == "euler" and self.fx is None:
            raise DataError("Euler pairs need F(x) at the samples (fx)")
        if self.fx is not None and self.fx.shape != self.x.shape:
            raise DataError(f"Dataset.fx shape {self.fx.shape} must equal x.shape = {self.x.shape}")
        if self.u is not None and self.u.shape[:2] != (self.x.shape[0], self.x.shape[1] - 1):
            raise DataError(f"Dataset.u shape {self.u.shape} must be (n_traj, T, m)")

    @property
    def n_traj(self) -> int:
        return self.x.shape[0]

    @property
    def n(self) -> int:
        return self.x.shape[2]

    @property
    def forced(self) -> bool:
        return self.u is not None and bool(np.any(self.u != 0))

    def pair_mask(self) -> np.ndarray:
        """(n_traj, T) for 'next' pairs (x_k, x_{k+1}), (n_traj, T+1) for Euler pairs (x_k, x_k + F(x_k)Δ)."""
        if self.pair_rule == "next":
            return self.valid[:, :-1] & self.valid[:, 1:]
        return self.valid.copy()

    @property
    def n_pairs(self) -> int:
        return int(self.pair_mask().sum())

    @property
    def has_inputs(self) -> bool:
        return self.u is not None

    def run_forced(self) -> np.ndarray:
        """(n_traj,) bool: trajectory i has a nonzero input."""
        if self.u is None:
            return np.zeros(self.n_traj, dtype=bool)
        return np.any(self.u != 0, axis=(1, 2))

    def runs(self) -> Iterator[Run]:
        """The trajectories one at a time (views, padded to T+1 samples)."""
        for i in range(self.n_traj):
            yield Run(self.x[i], self.valid[i], None if self.u is None else self.u[i],
                      None if self.fx is None else self.fx[i])

    def iter_pairs(self, chunk_size: int = 20000, *, with_inputs: bool = False, instrument_lag: int = 0
                   ) -> Iterator[tuple[np.ndarray, ...]]:
        """Yield (X, Y) chunks of at most ``chunk_size`` snapshot pairs, each (rows, n); memory O(chunk_size).
        ``with_inputs``: (X, U, Y) with U (rows, m) the input held over each pair (zeros for unforced runs of a
        dataset with inputs; needs 'next' pairs and a dataset with ``u``).  ``instrument_lag`` L >= 1: the sample L
        steps earlier on the same trajectory in front, (Z, X, Y) / (Z, X, U, Y), pairs without one left out.
        See :func:`kexp.data.runs.pair_chunks`."""
        return pair_chunks(self, chunk_size, with_inputs=with_inputs, instrument_lag=instrument_lag)

    def stats(self, center=None) -> SampleStats:
        """:class:`~kexp.data.runs.SampleStats` of the kept, finite samples (Σ(x − center)² about ``center``)."""
        xs = self.valid_samples()
        xs = xs[np.all(np.isfinite(xs), axis=1)]
        c = np.zeros(self.n) if center is None else np.asarray(center, float).reshape(self.n)
        if xs.shape[0] == 0:
            return SampleStats(0, np.full(self.n, np.inf), np.full(self.n, -np.inf), np.zeros(self.n),
                               np.zeros(self.n), c)
        return SampleStats(count=xs.shape[0], low=xs.min(axis=0), high=xs.max(axis=0),
                           absmax=np.abs(xs).max(axis=0), sumsq=np.sum((xs - c) ** 2, axis=0), center=c)

    def with_noise(self, sigma: np.ndarray, seed: int) -> "Dataset":
        """x + σ·N(0, 1) drawn from the data noise's stream of ``seed`` (kexp.data.noise.noise_rng) over x's shape
        (n_traj, T+1, n) in C order; the report's ``noise_std`` is σ (n,)."""
        noisy = self.x + noise_rng(seed, DATA_NOISE).standard_normal(self.x.shape) * sigma
        report = self.report or DataReport(
            n_traj=self.n_traj, n_samples=int(self.valid.size), n_pairs=self.n_pairs,
            n_masked_samples=int((~self.valid).sum()), n_dropped_traj=0, filter="none", region="all")
        return replace(self, x=noisy, report=replace(report, noise_std=tuple(float(s) for s in sigma)))

    def with_smoothing(self, cfg) -> "Dataset":
        """Each run's kept stretches filtered by ``cfg`` (a :class:`~kexp.data.smoothing.SmoothConfig`); the
        report says which filter and how many kept samples were in stretches too short for it."""
        from .smoothing import smooth_run
        if not cfg.active:
            return self
        x, short = np.array(self.x, copy=True), 0
        for i in range(self.n_traj):
            x[i], s = smooth_run(self.x[i], self.valid[i], cfg)
            short += s
        report = self.report or DataReport(
            n_traj=self.n_traj, n_samples=int(self.valid.size), n_pairs=self.n_pairs,
            n_masked_samples=int((~self.valid).sum()), n_dropped_traj=0, filter="none", region="all")
        return replace(self, x=x, report=replace(report, smoothing=cfg.describe(), n_unsmoothed_samples=short))

    def valid_samples(self) -> np.ndarray:
        """All kept samples, (n_valid, n)."""
        return self.x[self.valid]

    def subset(self, traj: np.ndarray) -> "Dataset":
        traj = np.asarray(traj)
        return replace(self, x=self.x[traj], valid=self.valid[traj],
                       u=None if self.u is None else self.u[traj],
                       fx=None if self.fx is None else self.fx[traj])

    def split(self, holdout: float, seed: int = 0) -> tuple["Dataset", "Dataset | None"]:
        """Split by trajectories into (train, test) (:func:`kexp.data.runs.split_indices`)."""
        train, test = split_indices(self.n_traj, holdout, seed)
        return (self, None) if test is None else (self.subset(train), self.subset(test))
