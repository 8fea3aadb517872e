"""Input excitation for forced data collection: a small registry of signal kinds, each piecewise constant over
blocks of ``hold`` samples (sample-and-hold), drawn from a seeded ``numpy.random.Generator``.

Kinds (:data:`EXCITATION_KINDS`), u of shape (n_traj, n_steps, m), each input and trajectory independent:

- ``uniform``: uniform in [low, high], redrawn every block (kexp's original excitation, the default kind);
- ``prbs``: a random binary sequence, ±amplitude, each block's sign a fair coin (switches only at block starts);
- ``multisine``: amplitude/n_f · Σ_j cos(2π f_j t + φ_j) at the block starts, random phases φ_j, so
  |u| ≤ amplitude; the frequencies ``frequencies`` (Hz) must lie below the Nyquist frequency 1/(2·hold·dt).

``fraction`` is the share of trajectories excited: exactly round(fraction·n_traj) of them (Python's round),
chosen at random; the others get u = 0 (unforced runs in the same data set).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, require_number
from .checks import items, short


def _uniform(exc: "Excitation", n_traj, n_blocks, m, rng, t_blocks):
    return rng.uniform(exc.low, exc.high, (n_traj, n_blocks, m))


def _prbs(exc: "Excitation", n_traj, n_blocks, m, rng, t_blocks):
    return exc.amplitude * (2.0 * rng.integers(0, 2, (n_traj, n_blocks, m)) - 1.0)


def _multisine(exc: "Excitation", n_traj, n_blocks, m, rng, t_blocks):
    f = np.asarray(exc.frequencies, dtype=float)
    phase = rng.uniform(0.0, 2 * np.pi, (n_traj, 1, m, f.size))
    arg = 2 * np.pi * f * t_blocks[None, :, None, None] + phase
    return exc.amplitude / f.size * np.cos(arg).sum(axis=-1)


DEFAULT_FREQUENCIES = (0.1, 0.3, 1.0)  # Hz, multisine
EXCITATION_KINDS = {"uniform": _uniform, "prbs": _prbs, "multisine": _multisine}


@dataclass(frozen=True)
class Excitation:
    """Piecewise-constant input held over ``hold`` samples, of kind ``uniform`` (in [low, high]), ``prbs``
    (±amplitude) or ``multisine`` (amplitude, ``frequencies`` in Hz, default 0.1, 0.3, 1.0); ``fraction`` of the trajectories are
    excited, the rest unforced (u = 0).  See :mod:`kexp.data.excitation`."""

    low: float = -1.0
    high: float = 1.0
    hold: int = 10
    kind: str = "uniform"
    amplitude: float = 1.0
    frequencies: tuple[float, ...] | None = None    # None: DEFAULT_FREQUENCIES
    fraction: float = 1.0

    def __post_init__(self):
        if not isinstance(self.kind, str) or self.kind not in EXCITATION_KINDS:
            raise ConfigError(f"data.excitation.kind={self.kind!r}; valid: {sorted(EXCITATION_KINDS)}")
        require_number(self.low, "data.excitation.low")
        require_number(self.high, "data.excitation.high")
        require_number(self.hold, "data.excitation.hold", integer=True)
        require_number(self.amplitude, "data.excitation.amplitude")
        require_number(self.fraction, "data.excitation.fraction")
        if not (np.isfinite(self.low) and np.isfinite(self.high) and self.low < self.high):
            raise ConfigError(f"data.excitation: need finite low < high, got {self.low}, {self.high}")
        if self.hold < 1:
            raise ConfigError(f"data.excitation.hold={self.hold}: use an int >= 1")
        if not (np.isfinite(self.amplitude) and self.amplitude > 0):
            raise ConfigError(f"data.excitation.amplitude={self.amplitude}: use a finite number > 0")
        if not 0 <= self.fraction <= 1:
            raise ConfigError(f"data.excitation.fraction={self.fraction}: use a share of trajectories in [0, 1]")
        if self.frequencies is not None and items(self.frequencies) is None:
            raise ConfigError(f"data.excitation.frequencies={short(self.frequencies)}: give a list of frequencies "
                              "in Hz")
        freqs = tuple(float(v) for v in np.atleast_1d(np.asarray(
            DEFAULT_FREQUENCIES if self.frequencies is None else self.frequencies, dtype=float)))
        if not freqs or not all(np.isfinite(v) and v > 0 for v in freqs):
            raise ConfigError(f"data.excitation.frequencies={list(freqs)}: give a non-empty list of frequencies > 0 "
                              "in Hz")
        object.__setattr__(self, "frequencies", freqs)

    def check(self, dt: float) -> None:
        """Raise a ConfigError if a multisine frequency is not below the Nyquist frequency of the held input."""
        nyquist = 1.0 / (2 * self.hold * dt)
        if self.kind == "multisine" and max(self.frequencies) >= nyquist:
            raise ConfigError(f"data.excitation.frequencies: {max(self.frequencies):g} Hz is not below the Nyquist "
                              f"frequency 1/(2·hold·dt) = {nyquist:g} Hz; lower it, or data.excitation.hold")

    def n_excited(self, n_traj: int) -> int:
        return int(round(self.fraction * n_traj))

    def draw(self, n_traj: int, n_steps: int, m: int, rng, *, dt: float = 1.0) -> np.ndarray:
        """(n_traj, n_steps, m) inputs, u[:, k] held over [t_k, t_{k+1}), from the Generator ``rng``; ``dt`` is the
        sampling time (multisine)."""
        n_blocks = -(-n_steps // self.hold)
        t_blocks = np.arange(n_blocks) * self.hold * dt
        u = EXCITATION_KINDS[self.kind](self, n_traj, n_blocks, m, rng, t_blocks)
        u = np.repeat(u, self.hold, axis=1)[:, :n_steps]
        if self.fraction < 1:
            excited = np.zeros(n_traj, dtype=bool)
            excited[rng.permutation(n_traj)[:self.n_excited(n_traj)]] = True
            u[~excited] = 0.0
        return u
