"""Smoothing of noisy state samples before identification (``data.smooth``).

Least squares on noisy regressors is biased (errors in variables: the noise in Ψ(x_k) shrinks K towards zero,
and the identified model loses instability the system has).  At Δ = 0.01 s the dynamics are much slower than
the sampling, so a Savitzky–Golay filter (a local polynomial fit of degree ``order`` over ``window`` samples,
``scipy.signal.savgol_filter``) removes most of white measurement noise while keeping the trajectory: on a
polynomial of degree ≤ order it is exact.  Each run's contiguous stretches of kept samples are filtered on their
own (never across a masked sample); stretches shorter than ``window`` are left as they are and counted.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, require_number


@dataclass(frozen=True)
class SmoothConfig:
    """``window`` samples (odd, ≥ order + 2; 0 = off) and polynomial ``order`` (≥ 1) of the Savitzky–Golay filter."""

    window: int = 0
    order: int = 3

    def __post_init__(self):
        require_number(self.window, "smooth.window", integer=True)
        require_number(self.order, "smooth.order", integer=True)
        if self.window == 0:
            return
        if self.order < 1:
            raise ConfigError(f"smooth.order={self.order}: use an int >= 1")
        if self.window < self.order + 2 or self.window % 2 == 0:
            raise ConfigError(f"smooth.window={self.window}: use 0 (off) or an odd int >= order + 2 "
                              f"= {self.order + 2}")

    @property
    def active(self) -> bool:
        return self.window > 0

    def describe(self) -> str:
        return "none" if not self.active else f"Savitzky–Golay, window {self.window}, order {self.order}"


def segments(valid: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True in ``valid`` (T+1,)."""
    v = np.concatenate([[False], np.asarray(valid, bool), [False]])
    edges = np.flatnonzero(np.diff(v.astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def smooth_run(x: np.ndarray, valid: np.ndarray, cfg: SmoothConfig) -> tuple[np.ndarray, int]:
    """(x smoothed (T+1, n), samples left unsmoothed in kept stretches shorter than the window)."""
    if not cfg.active:
        return x, 0
    from scipy.signal import savgol_filter
    out = np.array(x, dtype=float, copy=True)
    short = 0
    for a, b in segments(valid):
        if b - a < cfg.window:
            short += b - a
            continue
        out[a:b] = savgol_filter(out[a:b], cfg.window, cfg.order, axis=0, mode="interp")
    return out, short
