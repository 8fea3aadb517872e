"""Seeded measurement noise: ``data.noise`` on the collected data set and ``sim.noise`` on what the controller
sees in the closed loop.

A noise level ``std`` is one number for every state or one per state.  ``relative: true`` (the default) means
a fraction of the data's RMS per state, RMS_i = sqrt(mean over the kept samples of (x_i − x_eq,i)²), as in the
robustness table σ ∈ {0, 1 %, 3 %}; ``relative: false`` means absolute units of the state.  Noise is Gaussian,
zero mean, independent across samples and states.

Each purpose draws from its own stream (:func:`noise_rng`): the data's noise, the closed loop's measurement noise
and its input disturbance are independent of each other even with equal seeds (all three default to seed 0), and
the same seed gives the same draws run to run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ConfigError, require_seed
from .checks import short, state_vector
from .runs import PairSource


# the purposes that draw noise, each its own stream: SeedSequence(seed, spawn_key=(id,)) (numpy's way to derive
# independent streams from one seed; no id is 0, so no stream is default_rng(seed) itself)
DATA_NOISE, MEASUREMENT_NOISE, DISTURBANCE = "data.noise", "sim.noise", "sim.disturbance"
_STREAM_IDS = {DATA_NOISE: 1, MEASUREMENT_NOISE: 2, DISTURBANCE: 3}


def noise_rng(seed: int, purpose: str, x0=None) -> np.random.Generator:
    """The random generator of ``purpose`` (:data:`DATA_NOISE`, :data:`MEASUREMENT_NOISE` or :data:`DISTURBANCE`)
    for ``seed`` (an int >= 0): ``default_rng(SeedSequence(seed, spawn_key=(id,)))`` with one id per purpose, so
    that streams of different purposes are independent whatever their seeds, and one purpose's stream is the same
    for the same seed in every run.  ``x0`` (the closed loop's initial state, for ``noise.per_x0``): the x0's
    float64 bits join the spawn key, so every initial condition of a sweep draws its own stream, reproducible from
    the run's config alone."""
    require_seed(seed, f"{purpose}.seed")
    key = (_STREAM_IDS[purpose],)
    if x0 is not None:
        key += tuple(int(w) for w in np.ascontiguousarray(x0, dtype=np.float64).reshape(-1).view(np.uint64))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def _check_std(std: Any, where: str) -> None:
    values = list(std) if isinstance(std, (list, tuple)) else [std]
    if not values:
        raise ConfigError(f"{where}=[]: give one number >= 0, or one per state")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ConfigError(f"{where}={std!r}: use a finite number >= 0 (or one per state), e.g. {where}=0.01")


def _std_active(std: Any) -> bool:
    """True if a std (a number or a tuple of them) is > 0 anywhere."""
    return any(v > 0 for v in (std if isinstance(std, tuple) else (std,)))


def _std_vector(std: Any, n: int, where: str, per: str) -> np.ndarray:
    """A std given as one number or ``n`` numbers (one per ``per``), as an (n,) array; otherwise a ConfigError
    naming ``where``."""
    arr = np.asarray(std, float).reshape(-1)
    if arr.size not in (1, n):
        raise ConfigError(f"{where}={list(std) if isinstance(std, tuple) else std}: give one number or {n} "
                          f"(one per {per})")
    return np.broadcast_to(arr, (n,)).astype(float)


@dataclass(frozen=True)
class NoiseConfig:
    """Measurement noise (frozen): ``std`` a number >= 0 or one per state (a list); ``relative`` true: a fraction
    of the data's RMS per state, false: absolute state units; ``seed`` of its stream (:func:`noise_rng`).
    ``std`` = 0: none.  ``per_x0`` (the closed loop's noise only): each initial condition draws its own stream
    (:func:`noise_rng` with x0), so a sweep over 100 x0 measures 100 noise draws, not one draw 100 times.
    Raises :class:`~kexp.errors.ConfigError` for a negative or non-finite std or a non-integer seed."""

    std: Any = 0.0
    relative: bool = True
    seed: int = 0
    per_x0: bool = False

    def __post_init__(self):
        if isinstance(self.std, list):
            object.__setattr__(self, "std", tuple(self.std))
        _check_std(self.std, "noise.std")
        if not isinstance(self.relative, bool):
            raise ConfigError(f"noise.relative={self.relative!r}: expected true or false")
        require_seed(self.seed, "noise.seed")
        if not isinstance(self.per_x0, bool):
            raise ConfigError(f"noise.per_x0={self.per_x0!r}: expected true or false")

    @property
    def active(self) -> bool:
        return _std_active(self.std)

    def sigma(self, n: int, rms: np.ndarray | None = None) -> np.ndarray:
        """The absolute standard deviation per state, (n,).  ``rms`` (n,) is needed when ``relative``."""
        std = _std_vector(self.std, n, "noise.std", "state")
        if not self.relative:
            return std
        if rms is None:
            raise ConfigError("noise.relative=true needs the data's RMS per state: pass it (closed_loop(..., "
                              "noise_scale=data_rms(dataset))) or give an absolute std with relative=false")
        return std * np.asarray(rms, float)


def data_rms(dataset: PairSource, x_eq=None) -> np.ndarray:
    """RMS per state of the kept, finite samples about ``x_eq`` (default 0), (n,); any
    :class:`~kexp.data.runs.PairSource` (a file-backed one streams its runs)."""
    _check_source(dataset, "data_rms")
    state_vector(x_eq, dataset.n, "data_rms: x_eq")
    return dataset.stats(x_eq).rms


def add_measurement_noise(dataset: PairSource, std, relative: bool = True, seed: int = 0, *, x_eq=None):
    """A new frozen source of the same kind whose states ``x`` (n_traj, T+1, n) carry Gaussian noise of standard
    deviation σ_i per state; its ``report.noise_std`` is σ (n,).  σ = ``std`` × the data's RMS per state about
    ``x_eq`` (:func:`data_rms`) if ``relative``, else ``std`` itself.  Every sample gets noise (masks, inputs and
    times are unchanged); with Euler pairs the derivative ``fx`` stays the clean F(x) (y = x̃ + F(x)Δ).  The same
    seed gives the same noise, drawn over (n_traj, T+1, n) in C order for a Dataset and for recorded runs alike;
    ``std`` = 0 returns ``dataset`` unchanged.  ``std`` may also be a :class:`NoiseConfig`."""
    _check_source(dataset, "add_measurement_noise")
    state_vector(x_eq, dataset.n, "add_measurement_noise: x_eq")
    cfg = std if isinstance(std, NoiseConfig) else NoiseConfig(std=std, relative=relative, seed=seed)
    if not cfg.active:
        return dataset
    rms = data_rms(dataset, x_eq) if cfg.relative else None
    return dataset.with_noise(cfg.sigma(dataset.n, rms), cfg.seed)


def _check_source(dataset, who: str) -> None:
    if not (callable(getattr(dataset, "stats", None)) and callable(getattr(dataset, "with_noise", None))):
        raise ConfigError(f"{who}: dataset={short(dataset)}: expected a Dataset or RecordedRuns (collect, read_runs, "
                          "open_runs)")
