"""Initial-condition samplers.  Each returns an array of shape (n_traj, n), centred on the equilibrium where
that makes sense, from ``numpy.random.default_rng(seed)`` (never global seeding)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, require_number
from .checks import is_real, items, real_vector, short


@dataclass(frozen=True)
class Circle:
    """Points on the circle (sphere for n > 2) of radius ``radius`` around ``center`` (default: equilibrium):
    angles uniform at random, or evenly spaced with ``even=True`` (n = 2 only: with n != 2, sample() refuses it)."""

    n_traj: int
    radius: float
    even: bool = False

    def __post_init__(self):
        _check_count(self.n_traj)
        require_number(self.radius, "data.sampler.radius")
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ConfigError(f"data.sampler.radius={self.radius}: use a finite number > 0")
        if not isinstance(self.even, (bool, np.bool_)):
            raise ConfigError(f"data.sampler.even={short(self.even)}: expected true or false")

    def sample(self, center: np.ndarray, seed: int) -> np.ndarray:
        n = center.size
        if self.even and n != 2:
            raise ConfigError(f"data.sampler.even=true spaces the angles evenly on a circle (n = 2 only), but the "
                              f"system has n={n}: set even=false (random directions on the sphere)")
        rng = np.random.default_rng(seed)
        if n == 2:
            a = (np.arange(self.n_traj) / self.n_traj * 2 * np.pi if self.even
                 else rng.uniform(0, 2 * np.pi, self.n_traj))
            d = np.stack([np.cos(a), np.sin(a)], axis=1)
        else:
            d = rng.normal(size=(self.n_traj, n))
            d /= np.linalg.norm(d, axis=1, keepdims=True)
        return center + self.radius * d

    def contains(self, x: np.ndarray, center: np.ndarray) -> bool:
        return bool(np.linalg.norm(np.asarray(x) - center) <= self.radius * (1 + 1e-12))

    def describe(self) -> str:
        return f"the circle/ball of radius {self.radius:g} around x_eq"


@dataclass(frozen=True)
class Box:
    """Uniform samples in the box [low, high] (per state; a scalar applies to all states)."""

    n_traj: int
    low: tuple[float, ...] | float
    high: tuple[float, ...] | float

    def __post_init__(self):
        _check_count(self.n_traj)
        hint = "give a finite number or a list of them (one per state)"
        lo, hi = real_vector(self.low, "data.sampler.low", hint), real_vector(self.high, "data.sampler.high", hint)
        if lo.shape != hi.shape and lo.size != 1 and hi.size != 1:
            raise ConfigError(f"data.sampler low={self.low} and high={self.high} must have the same length")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
            raise ConfigError(f"data.sampler: need finite low < high, got low={self.low}, high={self.high}")

    def sample(self, center: np.ndarray, seed: int) -> np.ndarray:
        n = center.size
        self._check_dim(n)
        lo = np.broadcast_to(np.atleast_1d(self.low).astype(float), (n,))
        hi = np.broadcast_to(np.atleast_1d(self.high).astype(float), (n,))
        return np.random.default_rng(seed).uniform(lo, hi, (self.n_traj, n))

    def contains(self, x: np.ndarray, center: np.ndarray) -> bool:
        x = np.asarray(x)
        self._check_dim(x.shape[-1] if x.ndim else 1)
        lo = np.broadcast_to(np.asarray(self.low, dtype=float), x.shape)
        hi = np.broadcast_to(np.asarray(self.high, dtype=float), x.shape)
        return bool(np.all((x >= lo) & (x <= hi)))

    def describe(self) -> str:
        return f"the box [{self.low}, {self.high}]"

    def _check_dim(self, n: int) -> None:
        sizes = {np.size(self.low), np.size(self.high)} - {1}
        if sizes and sizes != {n}:
            raise ConfigError(f"data.sampler low={self.low}, high={self.high} have {max(sizes)} entries, but the "
                              f"system has n={n}: give one number or {n}")


@dataclass(frozen=True)
class Points:
    """An explicit list of initial conditions (n_traj, n)."""

    points: tuple[tuple[float, ...], ...]

    def __post_init__(self):
        pts = self.points
        if isinstance(pts, np.ndarray):
            ok = pts.ndim == 2 and pts.dtype.kind in "iuf"
        else:
            ok = (isinstance(pts, Sequence) and not isinstance(pts, (str, bytes))
                  and all(not is_real(r) and items(r) is not None for r in pts) and len({len(r) for r in pts}) <= 1)
        if not ok:
            raise ConfigError(f"data.sampler.points={short(self.points)}: give a list of states, each a list of n "
                              "numbers (all of the same length)")
        p = np.asarray(self.points, dtype=float)
        if p.ndim != 2 or p.shape[0] < 1 or p.shape[1] < 1:
            raise ConfigError(f"data.sampler.points must be a non-empty list of states, got shape {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ConfigError("data.sampler.points contain NaN/inf; give finite initial conditions")

    @property
    def n_traj(self) -> int:
        return len(self.points)

    def sample(self, center: np.ndarray, seed: int) -> np.ndarray:
        p = np.asarray(self.points, dtype=float)
        if p.shape[1] != center.size:
            raise ConfigError(f"data.sampler.points have {p.shape[1]} components; the system has n={center.size}")
        return p.copy()

    def contains(self, x: np.ndarray, center: np.ndarray) -> bool:
        p = np.asarray(self.points, dtype=float)
        return bool(np.all((x >= p.min(axis=0)) & (x <= p.max(axis=0))))

    def describe(self) -> str:
        return "the bounding box of data.sampler.points"


def _check_count(n_traj):
    if not (isinstance(n_traj, (int, np.integer)) and not isinstance(n_traj, bool) and n_traj >= 1):
        raise ConfigError(f"data.sampler.n_traj={n_traj!r}: use an int >= 1")


SAMPLERS = {"circle": Circle, "box": Box, "points": Points}


def make_sampler(kind: str, **params):
    """The initial-condition sampler ``kind`` ('circle', 'box' or 'points', see :data:`SAMPLERS`) built from its
    keyword ``params`` (e.g. ``make_sampler("box", n_traj=100, low=-2.0, high=2.0)``); its ``sample(center,
    seed)`` returns (n_traj, n) initial states.  Raises :class:`~kexp.errors.ConfigError` for an unknown kind or
    bad parameters."""
    if kind not in SAMPLERS:
        raise ConfigError(f"unknown sampler {kind!r}; valid: {sorted(SAMPLERS)}")
    try:
        return SAMPLERS[kind](**params)
    except TypeError as exc:
        raise ConfigError(f"sampler {kind!r}: bad parameters {params} ({exc})") from None
