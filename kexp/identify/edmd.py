"""Streamed least squares for EDMD.

One pass over snapshot-pair chunks reduces the tall matrix A = [Φ_X | Φ_Y | Lφ_1 … Lφ_m] (one sample a row;
Lφ_i = (∂φ/∂x)·G_i, the dictionary's Lie derivative along input field i) to a triangular factor R with
RᵀR = AᵀA, in memory independent of the number of pairs:
- ``method="qr"`` (default): TSQR, R ← qr([R; chunk]); the solve sees Φ_X's own conditioning.
- ``method="gram"``: accumulate AᵀA, then Cholesky (normal equations: cheaper, squares the condition number).

Everything after the pass works on R.  Writing R = [[R11, R1t], [0, Rout]] (R11 is N×N), the least-squares
coefficients of a target block are R11⁻¹R1t and the norm of its part outside span(Φ_X) is ‖Rout‖.
Returned K follows the paper: φ(y) ≈ K φ(x); D_i: Lφ_i ≈ D_i φ.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, DataError
from .fixed_point import solve_fixed_point

METHODS = ("qr", "gram")


class _StreamedQR:
    """TSQR in one reusable Fortran-ordered buffer [R; chunk] factored in place by LAPACK dgeqrf, so a chunk
    costs one buffer and no stacking copies."""

    def __init__(self, width: int):
        self.width = width
        self.r = np.zeros((width, width))
        self._buf = None

    def buffer(self, rows: int) -> np.ndarray:
        """Return the (width + rows, width) work buffer whose rows [width:] receive the next chunk."""
        if self._buf is None or self._buf.shape[0] != self.width + rows:
            self._buf = np.empty((self.width + rows, self.width), order="F")
        return self._buf

    def factor_buffer(self) -> None:
        buf = self._buf
        buf[: self.width] = self.r
        # a blocked factorisation needs a large workspace (the default minimal one runs unblocked, ~2× slower)
        qr, _tau, _work, info = sla.lapack.dgeqrf(buf, lwork=64 * self.width, overwrite_a=1)
        if info != 0:
            raise DataError(f"QR factorisation failed (LAPACK info {info})")
        self.r = np.triu(qr[: self.width])

    def factor(self) -> np.ndarray:
        return self.r


class _StreamedGram:
    def __init__(self, width: int):
        self.width = width
        self.g = np.zeros((width, width))
        self._buf = None

    def buffer(self, rows: int) -> np.ndarray:
        if self._buf is None or self._buf.shape[0] != rows:
            self._buf = np.empty((rows, self.width), order="F")
        return self._buf

    def factor_buffer(self) -> None:
        self.g += self._buf.T @ self._buf

    def factor(self) -> np.ndarray:
        g = 0.5 * (self.g + self.g.T)
        jitter = 0.0
        for _ in range(8):
            try:
                return sla.cholesky(g + jitter * np.eye(len(g)), lower=False)
            except np.linalg.LinAlgError:
                jitter = max(jitter * 100, 1e-15 * np.trace(g))
        raise DataError("the Gram matrix is not positive definite even with jitter; use identification.method=qr")


class TriangularFacts:
    """What follows from a fit's triangular factor: the leading block ``r11`` (N×N, r11ᵀr11 = Φ_XᵀΦ_X) and
    ``rcond`` give Φ_X's singular values, condition number and numerical rank, and the truncated solve."""

    def singular_values(self) -> np.ndarray:
        return sla.svdvals(self.r11)

    @property
    def cond(self) -> float:
        sv = self.singular_values()
        return float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")

    @property
    def rank(self) -> int:
        sv = self.singular_values()
        return int(np.sum(sv > self.rcond * sv[0]))

    def solve(self, lhs: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """Least squares min ‖lhs·X − rhs‖ with the fit's rcond (lhs, rhs in R coordinates)."""
        return sla.lstsq(lhs, rhs, cond=self.rcond, check_finite=False)[0]


@dataclass(frozen=True)
class LeastSquaresFit(TriangularFacts):
    """Triangular factor of [Φ_X | Φ_Y | Lφ_1 … Lφ_m] and what follows from it.  ``R`` is (W, W) with
    W = N(2 + m); ``rcond`` truncates singular values of Φ_X below rcond·σ_max."""

    R: np.ndarray
    N: int
    m: int
    n_pairs: int
    method: str
    rcond: float
    n_extra: int = 0   # 1: a column of ones follows Φ_X (the constant, for B and b when φ has none)
    fixed_point: np.ndarray | None = field(default=None, compare=False)   # φ(x_eq) (N,): K φ(x_eq) = φ(x_eq)

    @property
    def r11(self) -> np.ndarray:
        """(N, N) with r11ᵀr11 = Φ_XᵀΦ_X, so ‖Φ_X w‖ = ‖r11 w‖."""
        return self.R[: self.N, : self.N]

    def _block(self, j: int) -> slice:
        start = (1 + j) * self.N + self.n_extra
        return slice(start, start + self.N)

    @property
    def r_ext(self) -> np.ndarray:
        """(N + e, N + e): the factor of [Φ_X | 1] (e = n_extra; equal to r11 when e = 0)."""
        e = self.N + self.n_extra
        return self.R[:e, :e]

    def inside(self, j: int, extended: bool = False) -> np.ndarray:
        """Target block j (0: Φ_Y, 1+i: Lφ_i) in span(Φ_X) (or span[Φ_X, 1] if ``extended``), as R coordinates."""
        rows = self.N + (self.n_extra if extended else 0)
        return self.R[:rows, self._block(j)]

    def outside(self, j: int, extended: bool = False) -> np.ndarray:
        """The part of target block j orthogonal to span(Φ_X) (or span[Φ_X, 1])."""
        rows = self.N + (self.n_extra if extended else 0)
        return self.R[rows:, self._block(j)]

    @property
    def k_lhs(self) -> np.ndarray:
        """(N, N) the left side of K's solve in R coordinates (least squares: r11; an IV fit: the instrument rows
        of the regressor columns, kexp.identify.iv)."""
        return self.r11

    @property
    def k_rhs(self) -> np.ndarray:
        """(N, N) the right side of K's solve: Kᵀ = solve(k_lhs, k_rhs) (least squares: Φ_Y in span Φ_X)."""
        return self.inside(0)

    @property
    def K(self) -> np.ndarray:
        """(N, N) φ(y) ≈ K φ(x), with K φ(x_eq) = φ(x_eq) imposed when ``fixed_point`` is given (fixed_point.py)."""
        return solve_fixed_point(self.solve, self.k_lhs, self.k_rhs, self.fixed_point, self.fixed_point).T

    @property
    def raw_K(self) -> np.ndarray:
        """(N, N) the unconstrained K (the plain EDMD fit, or IV's; equal to K without ``fixed_point``)."""
        return self.solve(self.k_lhs, self.k_rhs).T

    @property
    def D(self) -> np.ndarray:
        return np.stack([self.solve(self.r11, self.inside(1 + i)).T for i in range(self.m)]) if self.m \
            else np.zeros((0, self.N, self.N))

    def relative_residual(self, j: int, T: np.ndarray | None = None) -> float:
        """‖part of target block j (times T) outside span(Φ_X)‖ / ‖target block j (times T)‖."""
        T = np.eye(self.N) if T is None else T
        out = np.linalg.norm(self.outside(j, extended=j > 0) @ T)
        tot = np.hypot(np.linalg.norm(self.inside(j, extended=j > 0) @ T), out)
        return float(out / tot) if tot > 0 else 0.0


def fit_least_squares(chunks: Iterable[tuple[np.ndarray, np.ndarray]], lift: Callable[[np.ndarray], np.ndarray],
                      *, lie_inputs: Callable[[np.ndarray], np.ndarray] | None = None, m: int = 0,
                      method: str = "qr", rcond: float = 1e-13, add_constant: bool = False,
                      fixed_point: np.ndarray | None = None) -> LeastSquaresFit:
    """One streamed pass over (X, Y) chunks (rows, n).  ``lift(X)`` -> (rows, N); ``lie_inputs(X)`` ->
    (rows, N, m), the dictionary's Lie derivatives along the m input fields (omit for K only).
    ``add_constant``: put a column of ones after Φ_X, so the input terms can be projected on [Ψ, 1] when the
    dictionary has no constant (it does not change K: QR is sequential in the columns).  ``fixed_point``: φ(x_eq)
    (N,), imposed as K φ(x_eq) = φ(x_eq) (x_eq an equilibrium of the unforced system; fixed_point.py)."""
    if method not in METHODS:
        raise ConfigError(f"identification.method={method!r}; valid: {METHODS}")
    if not 0 < rcond < 1:
        raise ConfigError(f"identification.rcond={rcond}: use a number in (0, 1)")
    m = m if lie_inputs is not None else 0
    acc, n_pairs, N = None, 0, 0
    for X, Y in chunks:
        X = np.asarray(X, dtype=float)
        Y = np.asarray(Y, dtype=float)
        if X.shape != Y.shape or X.ndim != 2:
            raise DataError(f"pair chunk shapes X {X.shape}, Y {Y.shape}: both must be (rows, n)")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
            raise DataError("snapshot pairs contain NaN/inf; filter the data (data.filter) or fix the system")
        px = lift(X)
        rows, N = X.shape[0], px.shape[1]
        e = 1 if add_constant else 0
        if acc is None:
            width = N * (2 + m) + e
            acc = _StreamedQR(width) if method == "qr" else _StreamedGram(width)
        buf = acc.buffer(rows)
        top = acc.width if method == "qr" else 0
        buf[top:, :N] = px
        del px
        if e:
            buf[top:, N] = 1.0
        buf[top:, N + e:2 * N + e] = lift(Y)
        if m:
            lg = lie_inputs(X)
            for i in range(m):
                buf[top:, (2 + i) * N + e:(3 + i) * N + e] = lg[:, :, i]
            del lg
        acc.factor_buffer()
        n_pairs += rows
    if acc is None or n_pairs == 0:
        raise DataError("no snapshot pairs: collect more data or loosen data.filter")
    if n_pairs < N:
        raise DataError(f"{n_pairs} snapshot pairs for a dictionary of {N} functions: need at least {N} "
                        "(more trajectories, a longer duration, or a lower degree)")
    return LeastSquaresFit(R=acc.factor(), N=N, m=m, n_pairs=n_pairs, method=method, rcond=rcond,
                           n_extra=1 if add_constant else 0, fixed_point=_fixed(fixed_point, N))


def _fixed(value, N: int) -> np.ndarray | None:
    """φ(x_eq) as a read-only (N,) array (None: no constraint)."""
    if value is None:
        return None
    out = np.array(value, dtype=float).reshape(-1)
    if out.shape != (N,) or not np.isfinite(out).all():
        raise ConfigError(f"fixed_point: φ(x_eq) must be {N} finite numbers, got shape {np.shape(value)}")
    out.setflags(write=False)
    return out
