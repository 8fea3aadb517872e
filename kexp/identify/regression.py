"""Input matrices by regression from forced data (bilinear EDMD), for when the input fields G_i are unknown.

With inputs held over each sample, the lifted next state of a bilinear model is φ̄(x⁺) = K̄(u) φ̄(x), where
K̄(u) = exp(Δ(L̄₀ + Σ uᵢ L̄ᵢ)) and φ̄ = [φ, 1] (the 1 only when the dictionary has no constant).  K̄(u) is not
affine in u: regressing on [φ̄, uᵢφ̄] alone leaves an error of order Δ‖L̄ᵢ‖|u| in the slope (≈ 1e-2 at Δ = 0.01).
So one streamed QR pass regresses φ(x⁺) on [φ̄(x), u^α φ̄(x)] for every monomial u^α of degree 1…p (p =
``identification.input_degree``), which gives K̄(0) = K̄₀ and the first-order coefficients K̄ᵢ = ∂K̄/∂uᵢ(0) up
to the (Δ‖L̄ᵢ‖)^p truncation.  The generator's input part is then exact to that order:

    L̄ᵢ = ∂/∂uᵢ log K̄(u) / Δ at u = 0 = Dlog(K̄₀)[K̄ᵢ] / Δ,

the Fréchet derivative of the matrix logarithm (from logm of the block matrix [[K̄₀, K̄ᵢ], [0, K̄₀]]).  The rows
of L̄ᵢ for φ are the dictionary's Lie derivative along Gᵢ as the data see it, i.e. what projection computes from
G; from there B_i, b_i follow by the same projection on the eigen-coordinates (projection.input_matrices), so
everything downstream is unchanged.  G is never evaluated.
"""
from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable, Iterable

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, DataError
from .edmd import METHODS, TriangularFacts, _StreamedGram, _StreamedQR, _fixed
from .fixed_point import solve_fixed_point


def input_monomials(m: int, degree: int) -> tuple[tuple[int, ...], ...]:
    """Exponent tuples of the input monomials of degree 1…``degree`` in m inputs; the m linear ones first, in
    input order (so monomial i < m is uᵢ)."""
    out = []
    for d in range(1, degree + 1):
        for combo in itertools.combinations_with_replacement(range(m), d):
            out.append(tuple(combo.count(i) for i in range(m)))
    return tuple(out)


@dataclass(frozen=True)
class BilinearFit(TriangularFacts):
    """Triangular factor of [φ̄(X) | u^α φ̄(X) … | φ(Y)] (one row per pair) and what follows from it.  Offers
    what identification reads from an EDMD fit (``K``, ``r11``, ``r_ext``, ``solve``, ``cond``, ``rank``,
    ``n_pairs``, ``relative_residual(0)``) plus the regressed input generators (``lie_targets``)."""

    R: np.ndarray
    N: int
    m: int
    monomials: tuple[tuple[int, ...], ...]
    n_pairs: int
    method: str
    rcond: float
    n_extra: int = 0
    fixed_point: np.ndarray | None = field(default=None, compare=False)   # φ(x_eq) (N,): K̄₀ φ̄(x_eq) = φ̄(x_eq)

    @property
    def n_bar(self) -> int:
        return self.N + self.n_extra

    @property
    def P(self) -> int:
        """Number of regressor columns: N̄ (1 + number of input monomials)."""
        return self.n_bar * (1 + len(self.monomials))

    @property
    def r11(self) -> np.ndarray:
        return self.R[: self.N, : self.N]

    @property
    def r_ext(self) -> np.ndarray:
        return self.R[: self.n_bar, : self.n_bar]

    @property
    def coef_lhs(self) -> np.ndarray:
        """(P, P) the left side of coef's solve in R coordinates (least squares: the regressors' factor; an IV fit:
        the instrument rows of the regressor columns, kexp.identify.iv)."""
        return self.R[: self.P, : self.P]

    @property
    def coef_rhs(self) -> np.ndarray:
        """(P, N) the right side: coef = solve(coef_lhs, coef_rhs) (least squares: φ(Y) in the regressors' span)."""
        return self.R[: self.P, self.P:]

    @cached_property
    def coef(self) -> np.ndarray:
        """(P, N): φ(y) ≈ [φ̄ | u^α φ̄ …] @ coef; with ``fixed_point``, at u = 0 the equilibrium stays put:
        φ̄(x_eq)ᵀ coef[:N̄] = φ(x_eq)ᵀ (so an intercept, the drift at x_eq, is not fitted; fixed_point.py)."""
        P = self.P
        a = None
        if self.fixed_point is not None:
            a = np.zeros(P)
            a[: self.N] = self.fixed_point
            a[self.N: self.n_bar] = 1.0
        return solve_fixed_point(self.solve, self.coef_lhs, self.coef_rhs, a,
                                 None if a is None else self.fixed_point)

    @cached_property
    def raw_coef(self) -> np.ndarray:
        """(P, N) the unconstrained regression (equal to ``coef`` without ``fixed_point``)."""
        return self.solve(self.coef_lhs, self.coef_rhs)

    @property
    def regressor_rank(self) -> int:
        sv = sla.svdvals(self.R[: self.P, : self.P])
        return int(np.sum(sv > self.rcond * sv[0]))

    @property
    def K(self) -> np.ndarray:
        """(N, N) the drift's one-step operator (column form φ(y) ≈ K φ(x) at u = 0)."""
        return self.coef[: self.N].T

    def k_bar(self, block: int) -> np.ndarray:
        """(N̄, N̄) K̄₀ (block 0) or K̄ for input monomial block-1, with the constant's row when N̄ > N."""
        nb = self.n_bar
        out = np.zeros((nb, nb))
        out[: self.N] = self.coef[block * nb:(block + 1) * nb].T
        if self.n_extra and block == 0:
            out[self.N, self.N] = 1.0
        return out

    def relative_residual(self, j: int = 0, T: np.ndarray | None = None) -> float:
        """Relative residual of the lifted next state φ(y) (times T) outside the regressors' span."""
        if j != 0:
            raise ValueError("a regression fit has only the next-state target (j = 0)")
        T = np.eye(self.N) if T is None else T
        P = self.P
        out = np.linalg.norm(self.R[P:, P:] @ T)
        tot = np.hypot(np.linalg.norm(self.R[:P, P:] @ T), out)
        return float(out / tot) if tot > 0 else 0.0

    def generators(self, dt: float) -> list[np.ndarray]:
        """L̄ᵢ (N̄, N̄) = Dlog(K̄₀)[K̄ᵢ] / Δ for each input i (rows: d/dt of φ̄ per unit uᵢ, in terms of φ̄)."""
        k0 = self.k_bar(0)
        nb = self.n_bar
        out = []
        for i in range(self.m):
            ki = self.k_bar(1 + i)
            block = np.block([[k0, ki], [np.zeros_like(k0), k0]])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)   # logm's accuracy note; checked below
                log = sla.logm(block)
            d = log[:nb, nb:]
            if np.iscomplexobj(d):
                if np.abs(d.imag).max() > 1e-8 * max(np.abs(d.real).max(), 1e-300):
                    raise DataError("the regressed one-step operator has eigenvalues without a real logarithm "
                                    "(negative real λ̃): the data cannot give the input generator; sample faster "
                                    "or use identification.inputs=projection")
                d = d.real
            out.append(d / dt)
        return out

    def lie_targets(self, dt: float) -> list[np.ndarray]:
        """Per input, the regressed Lie derivative of φ in the fit's R coordinates ((N̄, N), as projection's
        ``fit.inside(1 + i, extended=True)``)."""
        return [self.r_ext @ g[: self.N].T for g in self.generators(dt)]


def fit_bilinear(chunks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]],
                 lift: Callable[[np.ndarray], np.ndarray], *, m: int, degree: int = 3, method: str = "qr",
                 rcond: float = 1e-13, add_constant: bool = False,
                 fixed_point: np.ndarray | None = None) -> BilinearFit:
    """One streamed pass over (X, U, Y) chunks ((rows, n), (rows, m), (rows, n)); memory independent of the
    number of pairs.  ``add_constant``: a column of ones after φ(X) (for a dictionary without a constant).
    ``fixed_point``: φ(x_eq) (N,): the unforced one-step map keeps x_eq (fixed_point.py)."""
    if method not in METHODS:
        raise ConfigError(f"identification.method={method!r}; valid: {METHODS}")
    if not (isinstance(degree, (int, np.integer)) and 1 <= degree <= 5):
        raise ConfigError(f"identification.input_degree={degree}: use an int in 1..5")
    if m < 1:
        raise ConfigError("regression of the input matrices needs a system with at least one input")
    monos = input_monomials(m, degree)
    expo = np.array(monos, dtype=float)                       # (n_mono, m)
    e = 1 if add_constant else 0
    acc, n_pairs, N = None, 0, 0
    u_seen = np.zeros(m)
    for X, U, Y in chunks:
        X, U, Y = (np.asarray(a, dtype=float) for a in (X, U, Y))
        if X.shape != Y.shape or X.ndim != 2 or U.shape != (X.shape[0], m):
            raise DataError(f"pair chunk shapes X {X.shape}, U {U.shape}, Y {Y.shape}: need (rows, n), (rows, {m}), "
                            "(rows, n)")
        if not (np.isfinite(X).all() and np.isfinite(Y).all() and np.isfinite(U).all()):
            raise DataError("snapshot pairs or inputs contain NaN/inf; filter the data (data.filter)")
        px = lift(X)
        rows, N = X.shape[0], px.shape[1]
        nb = N + e
        if acc is None:
            width = nb * (1 + len(monos)) + N
            acc = _StreamedQR(width) if method == "qr" else _StreamedGram(width)
        buf = acc.buffer(rows)
        top = acc.width if method == "qr" else 0
        base = buf[top:, :nb]
        base[:, :N] = px
        if e:
            base[:, N] = 1.0
        umono = np.prod(U[:, None, :] ** expo[None], axis=2)   # (rows, n_mono)
        for j in range(len(monos)):
            buf[top:, (1 + j) * nb:(2 + j) * nb] = base * umono[:, j:j + 1]
        buf[top:, nb * (1 + len(monos)):] = lift(Y)
        acc.factor_buffer()
        n_pairs += rows
        u_seen = np.maximum(u_seen, np.abs(U).max(axis=0))
    if acc is None or n_pairs == 0:
        raise DataError("no snapshot pairs: collect more data or loosen data.filter")
    if not (u_seen > 0).all():
        idle = [i for i in range(m) if u_seen[i] == 0]
        raise DataError(f"input(s) {idle} are zero in every pair: regression needs forced data (data.excitation)")
    fit = BilinearFit(R=acc.factor(), N=N, m=m, monomials=monos, n_pairs=n_pairs, method=method, rcond=rcond,
                      n_extra=e, fixed_point=_fixed(fixed_point, N))
    if n_pairs < fit.P:
        raise DataError(f"{n_pairs} forced pairs for {fit.P} regressors (dictionary × input monomials): collect "
                        f"more data or lower identification.input_degree")
    return fit
