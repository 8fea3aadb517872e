"""The exact zero-order-hold map of a one-input bilinear model as a polynomial in the input, for the LMPC's
rollout and sensitivities.

For u held over Δ, [z⁺; 1] = E(u)·[z; 1] with E(u) = expm(X + uY), X = [[Λ, 0], [0, 0]]Δ, Y = [[B, b], [0, 0]]Δ
(one input).  E is entire in u, E(u) = Σ_d C_d u^d, and C_d is the (0, d) block of expm of the block upper
bidiagonal matrix with X on the diagonal and Y above it (the Van Loan construction for higher derivatives),
computed by :func:`series_expm` (scaling and squaring on the truncated series, not that big exponential).  The
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

MAX_DEGREE = 100
SPREAD_LIMIT = 1e3   # Σ_d ‖Ĉ_d‖ / ‖Ĉ_0‖ above which the polynomial's evaluation could lose more than ~1e-13
TAIL = 2.0 ** -54
_MEMO: OrderedDict = OrderedDict()   # the last few models' polynomials: a sweep worker runs many jobs on one model
MEMO_SIZE = 8


@dataclass(frozen=True)
class ZohPolynomial:
    """E(u) = Σ_d coef[d]·(u/rho)^d for |u| ≤ rho; coef (D+1, k+1, k+1); norms (D+1,) the coefficients'
    ∞-norms (:func:`kexp.control.kernels.poly_degree` cuts the series for a smaller |u| with them)."""

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
    None when the model has more inputs, the degree would exceed :data:`MAX_DEGREE`, or the coefficients' norms
    sum to more than :data:`SPREAD_LIMIT` times the constant term's (then the exponential is used)."""
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
    coef = series_expm(X, Y, D)
    coef[:, k, :] = 0.0          # the constant row [0 … 0 1] of E is exact
    coef[0, k, k] = 1.0
    norms = np.abs(coef).sum(axis=2).max(axis=1)
    # evaluating Σ_d Ĉ_d v^d in floating point errs by up to ~D·2⁻⁵³·Σ_d ‖Ĉ_d‖: large terms that cancel (ρ‖Y‖ ≫ 1)
    # would cost digits the exponential keeps
    if norms.sum() > SPREAD_LIMIT * norms[0]:
        return None
    return ZohPolynomial(coef, float(rho), norms)


def _series_product(P, Q):
    """The coefficients of P(v)·Q(v) up to the degree of P and Q ((D+1, n, n) each): the Cauchy product."""
    out = np.empty_like(P)
    for d in range(P.shape[0]):
        out[d] = np.matmul(P[: d + 1], Q[d::-1]).sum(axis=0)
    return out


def series_expm(X, Y, D: int):
    """The Taylor coefficients C_0..C_D (D+1, n, n) of expm(X + vY) in v: scaling and squaring in the ring of
    matrix polynomials truncated at degree D (the coefficients up to D of a product need only the factors' up to
    D).  With θ = ‖X‖∞ + ‖Y‖∞ ≥ ‖X + vY‖∞ for |v| ≤ 1, M = (X + vY)/2^s with θ/2^s ≤ 1/2, exp(M) by its Taylor
    series to a remainder below 2⁻⁵⁴ (on |v| = 1, hence in every coefficient), then s squarings.  The same
    coefficients as the (0, d) blocks of the block-bidiagonal Van Loan exponential, at (D+1)²/2·s products of
    n×n matrices instead of one exponential of size (D+1)·n (tests/test_lmpc.py)."""
    n = X.shape[0]
    theta = float(np.max(np.abs(X).sum(1)) + np.max(np.abs(Y).sum(1)))
    s = max(0, int(np.ceil(np.log2(theta / 0.5)))) if theta > 0.5 else 0
    A0, A1 = X / 2.0 ** s, Y / 2.0 ** s
    a = theta / 2.0 ** s
    E = np.zeros((D + 1, n, n))
    E[0] = np.eye(n)
    term = E.copy()
    j, bound = 0, 1.0
    while True:
        j += 1
        nxt = term @ A0                                   # (term·M)_d = term_d A0 + term_{d−1} A1
        nxt[1:] += term[:-1] @ A1
        term = nxt / j
        E += term
        bound *= a / j                                    # a^j / j!: the size of this term on |v| ≤ 1
        if bound * math.exp(a) <= TAIL * 1e-2 or j >= 60:
            break
    for _ in range(s):
        E = _series_product(E, E)
    return E
