"""The exact zero-order-hold map of a one-input bilinear model as a polynomial in the input, for the LMPC's
rollout and sensitivities.

For u held over Δ, [z⁺; 1] = E(u)·[z; 1] with E(u) = expm(X + uY), X = [[Λ, 0], [0, 0]]Δ, Y = [[B, b], [0, 0]]Δ
(one input).  E is entire in u, E(u) = Σ_d C_d u^d, and C_d is the (0, d) block of expm of the block upper
bidiagonal matrix with X on the diagonal and Y above it (the Van Loan construction for higher derivatives).  The
coefficients are computed once per model, scaled to v = u/ρ on |u| ≤ ρ (Ĉ_d = C_d ρ^d), and the series is
truncated where its remainder, bounded by e^{‖X‖}·Σ_{d>D} (ρ‖Y‖)^d/d! (and one degree more for dE/du), is below
rounding.  Then E(u) and dE/du cost 2(D+1) scaled matrix additions instead of a matrix exponential and its
Fréchet derivative: the same numbers to rounding.  Inputs outside |u| ≤ ρ are left to the exponential
(:func:`kexp.control.condense.block_maps_poly` does so per block).
"""
from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

MAX_DEGREE = 40
TAIL = 2.0 ** -54
_MEMO: OrderedDict = OrderedDict()   # the last few models' polynomials: a sweep worker runs many jobs on one model
MEMO_SIZE = 8


@dataclass(frozen=True)
class ZohPolynomial:
    """E(u) = Σ_d coef[d]·(u/rho)^d for |u| ≤ rho; coef (D+1, k+1, k+1); norms (D+1,) the coefficients'
    ∞-norms (:func:`kexp.control.condense.poly_degree` cuts the series for a smaller |u| with them)."""

    coef: np.ndarray
    rho: float
    norms: np.ndarray

    @property
    def degree(self) -> int:
        return self.coef.shape[0] - 1


def zoh_degree(norm_x: float, norm_y: float, max_degree: int = MAX_DEGREE) -> int | None:
    """Smallest D whose remainders e^{‖X‖}·Σ_{d>D} c^d/d! and c·e^{‖X‖}·Σ_{d>D} c^{d−1}/(d−1)! (c = ρ‖Y‖∞, the
    bounds on the coefficients of E and of dE/dv) are below 2⁻⁵⁴·max(1, c·e^{‖X‖}); None above ``max_degree``."""
    c = norm_y
    scale = math.exp(norm_x)
    for D in range(1, max_degree + 1):
        # Σ_{d>D} c^d/d! ≤ c^{D+1}/(D+1)! · 1/(1 − c/(D+2)) for c < D+2; the derivative's tail is one degree
        # lower: Σ_{d>D} c^{d−1}/(d−1)! ≤ c^D/D! · 1/(1 − c/(D+1))
        if c >= D + 1:
            continue
        tail_e = c ** (D + 1) / math.factorial(D + 1) / (1 - c / (D + 2))
        tail_d = c ** D / math.factorial(D) / (1 - c / (D + 1))
        if scale * tail_e <= TAIL and scale * c * tail_d <= TAIL * max(1.0, c * scale):
            return D
    return None


def zoh_polynomial(lam, B, b, dt: float, rho: float) -> ZohPolynomial | None:
    """The polynomial of the exact ZOH map on |u| ≤ rho for a one-input model (Λ (k, k), B (1, k, k), b (1, k));
    None when the model has more inputs or the degree would exceed :data:`MAX_DEGREE` (use the exponential)."""
    lam, B, b = (np.ascontiguousarray(a, dtype=float) for a in (lam, B, b))
    if B.shape[0] != 1 or not (np.isfinite(rho) and rho > 0):
        return None
    h = hashlib.sha256()
    for a in (lam, B, b, np.array([dt, rho], float)):
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    key = h.hexdigest()
    if key in _MEMO:     # the same inputs to the bit: the same coefficients (0.1–0.3 s saved per sweep job)
        _MEMO.move_to_end(key)
        return _MEMO[key]
    out = _coefficients(lam, B, b, dt, rho)
    _MEMO[key] = out
    while len(_MEMO) > MEMO_SIZE:
        _MEMO.popitem(last=False)
    return out


def _coefficients(lam, B, b, dt, rho):
    k = lam.shape[0]
    n = k + 1
    X = np.zeros((n, n))
    X[:k, :k] = lam * dt
    Y = np.zeros((n, n))
    Y[:k, :k] = B[0] * dt * rho
    Y[:k, k] = b[0] * dt * rho
    D = zoh_degree(float(np.max(np.abs(X).sum(1))), float(np.max(np.abs(Y).sum(1))))
    if D is None:
        return None
    big = np.kron(np.eye(D + 1), X) + np.kron(np.eye(D + 1, k=1), Y)
    top = sla.expm(big)[:n]
    coef = np.ascontiguousarray(top.reshape(n, D + 1, n).transpose(1, 0, 2))
    coef[:, k, :] = 0.0          # the constant row [0 … 0 1] of E is exact
    coef[0, k, k] = 1.0
    return ZohPolynomial(coef, float(rho), np.abs(coef).sum(axis=2).max(axis=1))
