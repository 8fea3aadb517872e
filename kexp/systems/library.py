"""The systems that ship with kexp: the paper's examples, a linear system, systems with known Koopman
invariant subspaces, and a Duffing oscillator.  All vectorised over leading axes of ``x`` (..., n)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import SystemDefinitionError, is_number
from .base import ControlAffineSystem


def _require_finite(system, *keys: str) -> None:
    """Raise a one-line SystemDefinitionError unless each parameter ``keys`` of ``system`` is a finite real number
    (not a bool): a NaN parameter would otherwise reach the integrator, which does not stop on NaN."""
    for key in keys:
        value = getattr(system, key)
        if not (is_number(value) and np.isfinite(value)):
            raise SystemDefinitionError(f"system {system.name!r}: {key}={value!r}; use a finite number "
                                        f"(system.params.{key})")


def _matrix(value, key: str) -> np.ndarray:
    """``value`` as a float matrix, refusing strings, bools and ragged or non-numeric entries in one line."""
    try:
        raw = np.asarray(value)
        ok = raw.dtype.kind in "iuf"
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise SystemDefinitionError(f"linear system: {key}={value!r}; give a matrix of numbers (a list of rows)")
    return np.asarray(raw, dtype=float)


def _const_input(x: np.ndarray, g: np.ndarray) -> np.ndarray:
    x = np.asarray(x)
    return np.broadcast_to(g, x.shape[:-1] + g.shape).copy()


def _on_x2(x: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """G = [0, gain(x)]ᵀ of a two-state system with one input acting on ẋ2: (..., 2, 1)."""
    g = np.zeros(np.shape(x)[:-1] + (2, 1))
    g[..., 1, 0] = gain
    return g


def _pair(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(..., 2) from two (...) arrays: np.stack's result in a third of its time (the integrator calls drift(x)
    about 14 times per control step)."""
    out = np.empty(np.shape(first) + (2,))
    out[..., 0] = first
    out[..., 1] = second
    return out


@dataclass(frozen=True)
class VanDerPol(ControlAffineSystem):
    """Paper eq. (Van):  ẋ1 = x2,  ẋ2 = μ(1 − x1²)x2 − x1 + u.  Unstable focus at 0, limit cycle around it."""

    mu: float = 1.0
    name: ClassVar[str] = "vanderpol"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = True

    def __post_init__(self):
        _require_finite(self, "mu")

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2 = x[..., 0], x[..., 1]
        return _pair(x2, self.mu * (1.0 - x1**2) * x2 - x1)

    def input_matrix(self, x):
        return _const_input(x, np.array([[0.0], [1.0]]))


class _AngleAndRate:
    """The states of a pendulum: an angle (theta) of period 2π and its rate (omega)."""

    @property
    def state_names(self):
        return ("theta", "omega")

    @property
    def angle_period(self):
        return (2 * np.pi, None)


@dataclass(frozen=True)
class Pendulum(_AngleAndRate, ControlAffineSystem):
    """Paper eq. (pen):  ẋ1 = x2,  ẋ2 = c·x2 − sin(x1) + u  with c = 0.01 (the paper's sign: the origin is a
    weakly *unstable* focus, Re λ = c/2).  x1 is an angle of period 2π."""

    c: float = 0.01
    name: ClassVar[str] = "pendulum"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = True

    def __post_init__(self):
        _require_finite(self, "c")

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2 = x[..., 0], x[..., 1]
        return _pair(x2, self.c * x2 - np.sin(x1))

    def input_matrix(self, x):
        return _const_input(x, np.array([[0.0], [1.0]]))


@dataclass(frozen=True)
class Duffing(ControlAffineSystem):
    """ẋ1 = x2,  ẋ2 = −δx2 + αx1 − βx1³ + u.  For α > 0 the origin is a saddle (unstable)."""

    alpha: float = 1.0
    beta: float = 1.0
    delta: float = 0.5
    name: ClassVar[str] = "duffing"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = True

    def __post_init__(self):
        _require_finite(self, "alpha", "beta", "delta")

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2 = x[..., 0], x[..., 1]
        return _pair(x2, -self.delta * x2 + self.alpha * x1 - self.beta * x1**3)

    def input_matrix(self, x):
        return _const_input(x, np.array([[0.0], [1.0]]))


@dataclass(frozen=True)
class CartPendulum(_AngleAndRate, ControlAffineSystem):
    """An inverted pendulum on a cart whose acceleration is the input:  ẋ1 = x2,
    ẋ2 = (g/l)·sin(x1) − d·x2 − cos(x1)·u/l,  x1 the angle from upright.  The origin is a saddle (eigenvalues
    ≈ +0.95 and −1.05 with the defaults), and G = [0, −cos(x1)/l]ᵀ varies with the state: the input loses its grip
    as the pendulum tilts and acts the other way past the horizontal (|x1| > π/2), so L_G of a polynomial dictionary
    leaves its span (Assumption 1 holds only approximately).  x1 is an angle of period 2π."""

    g_over_l: float = 1.0
    length: float = 1.0
    damping: float = 0.1
    name: ClassVar[str] = "cart_pendulum"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 1

    def __post_init__(self):
        _require_finite(self, "g_over_l", "length", "damping")
        if self.length <= 0:
            raise SystemDefinitionError(f"system 'cart_pendulum': length={self.length!r}; use a length > 0 "
                                        "(system.params.length)")

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2 = x[..., 0], x[..., 1]
        return _pair(x2, self.g_over_l * np.sin(x1) - self.damping * x2)

    def input_matrix(self, x):
        return _on_x2(x, -np.cos(np.asarray(x, dtype=float)[..., 0]) / self.length)


@dataclass(frozen=True)
class Linear(ControlAffineSystem):
    """ẋ = A x + B u.  Its Koopman eigenvalues on monomials of degree ≤ d are the sums of ≤ d eigenvalues of A."""

    A: tuple = ((0.0, 1.0), (-2.0, -0.3))
    B: tuple = ((0.0,), (1.0,))
    name: ClassVar[str] = "linear"
    constant_input_matrix: ClassVar[bool] = True

    def __post_init__(self):
        a = _matrix(self.A, "A")
        b = _matrix(self.B, "B")
        if a.ndim != 2 or a.shape[0] != a.shape[1]:
            raise SystemDefinitionError(f"linear system: A must be square, got shape {a.shape}")
        if b.ndim != 2 or b.shape[0] != a.shape[0]:
            raise SystemDefinitionError(f"linear system: B must have shape ({a.shape[0]}, m), got {b.shape}")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise SystemDefinitionError("linear system: A and B must be finite")
        object.__setattr__(self, "_a", a)
        object.__setattr__(self, "_b", b)

    @property
    def n(self):  # type: ignore[override]
        return self._a.shape[0]

    @property
    def m(self):  # type: ignore[override]
        return self._b.shape[1]

    def drift(self, x):
        return np.asarray(x, dtype=float) @ self._a.T

    def input_matrix(self, x):
        return _const_input(x, self._b)


@dataclass(frozen=True)
class SlowManifold(ControlAffineSystem):
    """ẋ1 = μ x1,  ẋ2 = λ(x2 − x1²)  (+ inputs).  The span of {1, x1, x2, x1²} is Koopman invariant, with
    eigenvalues {0, μ, λ, 2μ} and eigenfunctions 1, x1, x1², x2 − λ/(λ − 2μ)·x1².  More generally, monomials
    x1^a x2^b with a + 2b ≤ d (weighted degree, weights (1, 2)) span an invariant subspace.

    ``inputs``: "x2" (G = [0, 1]ᵀ, m = 1), "both" (G = I, m = 2) or "x2_varying" (G = [0, 1 + x1]ᵀ, m = 1, a G
    that varies with the state); each keeps L_G of the invariant span inside it (L_G x1^a x2^b = b(1 + x1) x1^a
    x2^(b-1) lowers the weighted degree), so the bilinear model is exact on it.
    """

    mu: float = -0.3
    lam: float = -1.0
    inputs: str = "x2"
    name: ClassVar[str] = "slow_manifold"
    n: ClassVar[int] = 2

    def __post_init__(self):
        _require_finite(self, "mu", "lam")
        if self.inputs not in ("x2", "both", "x2_varying"):
            raise SystemDefinitionError(f"slow_manifold: inputs={self.inputs!r}; use 'x2', 'both' or 'x2_varying' "
                                        "(system.params.inputs)")
        if abs(self.lam - 2 * self.mu) < 1e-12:
            raise SystemDefinitionError("slow_manifold: lam must differ from 2*mu (resonance)")

    @property
    def m(self):  # type: ignore[override]
        return 2 if self.inputs == "both" else 1

    @property
    def constant_input_matrix(self):  # type: ignore[override]
        return self.inputs != "x2_varying"

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2 = x[..., 0], x[..., 1]
        return _pair(self.mu * x1, self.lam * (x2 - x1**2))

    def input_matrix(self, x):
        if self.inputs == "x2_varying":
            return _on_x2(x, 1.0 + np.asarray(x, dtype=float)[..., 0])
        return _const_input(x, np.array([[0.0], [1.0]]) if self.inputs == "x2" else np.eye(2))

    def eigenpairs(self):
        """Exact continuous eigenvalues and eigenfunction coefficients on the basis [1, x1, x2, x1²]."""
        c = self.lam / (self.lam - 2 * self.mu)
        return {0.0: [1, 0, 0, 0], self.mu: [0, 1, 0, 0], 2 * self.mu: [0, 0, 0, 1], self.lam: [0, 0, 1, -c]}
