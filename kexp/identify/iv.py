"""Instrumental variables (IV) for EDMD: ``identification.estimator=iv``, streamed in one pass.

Least squares on noisy regressors is biased (errors in variables): with measurement noise ε on x, Φ_X's noise
enters the normal equations as E[φ(x̃)φ(x̃)ᵀ] ≠ E[φ(x)φ(x)ᵀ] and shrinks/rotates K.  An instrument Z that is
correlated with Φ_X but not with its noise removes the bias: here Z = φ(x̃_{t−L}), the lift of the sample L steps
earlier on the same trajectory (its noise is independent of the noise of x̃_t and x̃_{t+1}; ``identification.
iv_lag`` = L).  Two-stage least squares (2SLS) regresses φ(y) on the projection of Φ_X onto span Z.

One streamed TSQR (or Gram) pass factors A = [Φ_Z | Φ_X | (1) | Φ_Y | Lφ_1 … Lφ_m] into R (RᵀR = AᵀA).  With
R_zx, R_zy the rows of the instrument block in the regressor and target columns, P_Z Φ_X = Q_z R_zx and
P_Z Φ_Y = Q_z R_zy, so the 2SLS coefficients are lstsq(R_zx, R_zy): the same solve as least squares (r11,
inside(0)) with other sides, exposed as ``k_lhs``/``k_rhs`` (``coef_lhs``/``coef_rhs`` for regressed inputs).
Everything that is not the operator (r11 for eigenfunction normalisation, the projection of L_GΨ, C, cond,
rank, residuals) stays least squares on Φ_X: the factor of A's columns after the instruments, qr(R[:, N:]), has
the same Gram matrix, so one pass gives both (the fits below *are* least-squares fits with another K).
Pairs whose instrument sample would fall before the run's start (the first L pairs of each run) are left out.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, DataError
from .edmd import METHODS, LeastSquaresFit, _fixed, _StreamedGram, _StreamedQR
from .regression import BilinearFit, input_monomials

ESTIMATORS = ("ls", "iv")


def _accumulator(method: str, width: int):
    if method not in METHODS:
        raise ConfigError(f"identification.method={method!r}; valid: {METHODS}")
    return _StreamedQR(width) if method == "qr" else _StreamedGram(width)


def _check_chunk(arrays, names: str) -> list[np.ndarray]:
    arrays = [np.asarray(a, dtype=float) for a in arrays]
    rows = arrays[0].shape[0]
    if any(a.ndim != 2 or a.shape[0] != rows for a in arrays):
        raise DataError(f"instrument chunk shapes {names} {[a.shape for a in arrays]}: each must be (rows, ·)")
    if not all(np.isfinite(a).all() for a in arrays):
        raise DataError("snapshot pairs, instruments or inputs contain NaN/inf; filter the data (data.filter)")
    return arrays


def _ls_factor(R: np.ndarray, skip: int) -> np.ndarray:
    """The triangular factor of A's columns after the first ``skip`` (the instruments): qr(R[:, skip:]) has the
    same Gram matrix R[:, skip:]ᵀR[:, skip:] = A[:, skip:]ᵀA[:, skip:]."""
    return np.linalg.qr(R[:, skip:], mode="r")


def _canonical(r_zx: np.ndarray, r_xx: np.ndarray) -> np.ndarray:
    """Canonical correlations between span Z and span X (descending): the singular values of R_zx·R_xx⁻¹
    (Q_zᵀQ_x, with Φ_X = Q_x R_xx).  Directions where Φ_X is numerically rank deficient are left out."""
    _, s, vt = np.linalg.svd(r_xx)
    if s[0] == 0:
        return np.zeros(0)
    keep = s > 1e-12 * s[0]
    # X = Q_x R_xx = (Q_x U) S Vᵀ: orthonormal basis of span X is Φ_X V S⁻¹ on the kept directions
    basis = vt[keep].T / s[keep]
    return np.clip(sla.svdvals(r_zx @ basis), 0.0, 1.0)


@dataclass(frozen=True)
class IVFit(LeastSquaresFit):
    """An EDMD fit whose K is the 2SLS estimate with instruments φ(x̃_{t−lag}); everything else (``R``: the
    least-squares factor of [Φ_X | (1) | Φ_Y | Lφ…] over the same pairs) is least squares.  ``R_iv`` (N + W,
    N + W) is the factor of [Φ_Z | that]; ``n_pairs`` counts the pairs used (with an instrument)."""

    R_iv: np.ndarray | None = None
    lag: int = 1

    @property
    def k_lhs(self) -> np.ndarray:
        """(N, N) R_zx: the instruments' rows of the Φ_X columns."""
        return self.R_iv[: self.N, self.N:2 * self.N]

    @property
    def k_rhs(self) -> np.ndarray:
        """(N, N) R_zy: the instruments' rows of the Φ_Y columns."""
        start = 2 * self.N + self.n_extra
        return self.R_iv[: self.N, start:start + self.N]

    @property
    def K_ls(self) -> np.ndarray:
        """The least-squares K on the same pairs (a reference; the fit's K is the IV one)."""
        return self.solve(self.r11, self.inside(0)).T

    @property
    def canonical_correlations(self) -> np.ndarray:
        """(≤ N,) between φ(Z) and φ(X), descending; the smallest measures the weakest instrument direction."""
        return _canonical(self.k_lhs, self.r11)


@dataclass(frozen=True)
class BilinearIVFit(BilinearFit):
    """A regression fit (regression.BilinearFit) whose coefficients are 2SLS with instruments [φ̄(z), u^α φ̄(z)]
    (the input is exogenous); ``R`` is the least-squares factor of [φ̄(X) | u^α φ̄(X) … | φ(Y)], ``R_iv`` the
    factor of the instruments and that."""

    R_iv: np.ndarray | None = None
    lag: int = 1

    @property
    def coef_lhs(self) -> np.ndarray:
        P = self.P
        return self.R_iv[:P, P:2 * P]

    @property
    def coef_rhs(self) -> np.ndarray:
        P = self.P
        return self.R_iv[:P, 2 * P:]

    @property
    def K_ls(self) -> np.ndarray:
        P = self.P
        return self.solve(self.R[:P, :P], self.R[:P, P:])[: self.N].T

    @property
    def canonical_correlations(self) -> np.ndarray:
        return _canonical(self.coef_lhs, self.R[: self.P, : self.P])


def _check_lag(lag) -> int:
    if isinstance(lag, bool) or not isinstance(lag, (int, np.integer)) or lag < 1:
        raise ConfigError(f"identification.iv_lag={lag!r}: use an int >= 1 (samples between instrument and pair)")
    return int(lag)


def fit_iv(chunks: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], lift: Callable[[np.ndarray], np.ndarray], *,
           lie_inputs: Callable[[np.ndarray], np.ndarray] | None = None, m: int = 0, method: str = "qr",
           rcond: float = 1e-13, add_constant: bool = False, lag: int = 1,
           fixed_point: np.ndarray | None = None) -> IVFit:
    """One streamed pass over (Z, X, Y) chunks (rows, n) (:func:`kexp.data.runs.pair_chunks` with
    ``instrument_lag``); arguments as :func:`kexp.identify.edmd.fit_least_squares`.  Memory independent of the
    number of pairs."""
    lag = _check_lag(lag)
    if not 0 < rcond < 1:
        raise ConfigError(f"identification.rcond={rcond}: use a number in (0, 1)")
    m = m if lie_inputs is not None else 0
    e = 1 if add_constant else 0
    acc, n_pairs, N = None, 0, 0
    for Z, X, Y in chunks:
        Z, X, Y = _check_chunk((Z, X, Y), "Z, X, Y")
        if not Z.shape == X.shape == Y.shape:
            raise DataError(f"instrument chunk shapes Z {Z.shape}, X {X.shape}, Y {Y.shape}: all must be (rows, n)")
        pz = lift(Z)
        rows, N = X.shape[0], pz.shape[1]
        if acc is None:
            acc = _accumulator(method, N * (3 + m) + e)
        buf = acc.buffer(rows)
        top = acc.width if method == "qr" else 0
        buf[top:, :N] = pz
        buf[top:, N:2 * N] = lift(X)
        if e:
            buf[top:, 2 * N] = 1.0
        buf[top:, 2 * N + e:3 * N + e] = lift(Y)
        if m:
            lg = lie_inputs(X)
            for i in range(m):
                buf[top:, (3 + i) * N + e:(4 + i) * N + e] = lg[:, :, i]
        acc.factor_buffer()
        n_pairs += rows
    if acc is None or n_pairs == 0:
        raise DataError(f"no snapshot pairs with an instrument {lag} sample(s) earlier: the runs are shorter than "
                        f"identification.iv_lag + 2 = {lag + 2} samples; lower iv_lag or record longer runs")
    if n_pairs < 2 * N:
        raise DataError(f"{n_pairs} snapshot pairs with an instrument for a dictionary of {N} functions: need at least "
                        f"{2 * N} (more or longer runs, a lower identification.iv_lag, or a lower degree)")
    R_iv = acc.factor()
    return IVFit(R=_ls_factor(R_iv, N), N=N, m=m, n_pairs=n_pairs, method=method, rcond=rcond, n_extra=e,
                 R_iv=R_iv, lag=lag, fixed_point=_fixed(fixed_point, N))


def fit_bilinear_iv(chunks: Iterable[tuple[np.ndarray, ...]], lift: Callable[[np.ndarray], np.ndarray], *, m: int,
                    degree: int = 3, method: str = "qr", rcond: float = 1e-13, add_constant: bool = False,
                    lag: int = 1, fixed_point: np.ndarray | None = None) -> BilinearIVFit:
    """One streamed pass over (Z, X, U, Y) chunks; regressors [φ̄(x), u^α φ̄(x)], instruments [φ̄(z), u^α φ̄(z)];
    arguments as :func:`kexp.identify.regression.fit_bilinear`."""
    lag = _check_lag(lag)
    if not (isinstance(degree, (int, np.integer)) and 1 <= degree <= 5):
        raise ConfigError(f"identification.input_degree={degree}: use an int in 1..5")
    if m < 1:
        raise ConfigError("regression of the input matrices needs a system with at least one input")
    monos = input_monomials(m, degree)
    expo = np.array(monos, dtype=float)
    e = 1 if add_constant else 0
    acc, n_pairs, N, P = None, 0, 0, 0
    u_seen = np.zeros(m)
    for Z, X, U, Y in chunks:
        Z, X, U, Y = _check_chunk((Z, X, U, Y), "Z, X, U, Y")
        if not (Z.shape == X.shape == Y.shape and U.shape[1] == m):
            raise DataError(f"instrument chunk shapes Z {Z.shape}, X {X.shape}, U {U.shape}, Y {Y.shape}: need "
                            f"(rows, n) and U (rows, {m})")
        rows = X.shape[0]
        umono = np.prod(U[:, None, :] ** expo[None], axis=2)   # (rows, n_mono)
        pz = lift(Z)
        N = pz.shape[1]
        nb = N + e
        P = nb * (1 + len(monos))
        if acc is None:
            acc = _accumulator(method, 2 * P + N)
        buf = acc.buffer(rows)
        top = acc.width if method == "qr" else 0
        for col, px in ((0, pz), (P, lift(X))):   # instruments, then regressors: [φ̄ | u^α φ̄ …] each
            base = buf[top:, col:col + nb]
            base[:, :N] = px
            if e:
                base[:, N] = 1.0
            for j in range(len(monos)):
                buf[top:, col + (1 + j) * nb:col + (2 + j) * nb] = base * umono[:, j:j + 1]
        buf[top:, 2 * P:] = lift(Y)
        acc.factor_buffer()
        n_pairs += rows
        u_seen = np.maximum(u_seen, np.abs(U).max(axis=0))
    if acc is None or n_pairs == 0:
        raise DataError(f"no forced pairs with an instrument {lag} sample(s) earlier: the runs are shorter than "
                        f"identification.iv_lag + 2 = {lag + 2} samples; lower iv_lag or record longer runs")
    if not (u_seen > 0).all():
        idle = [i for i in range(m) if u_seen[i] == 0]
        raise DataError(f"input(s) {idle} are zero in every pair: regression needs forced data (data.excitation)")
    if n_pairs < 2 * P:
        raise DataError(f"{n_pairs} forced pairs with an instrument for {P} regressors: collect more data or lower "
                        "identification.input_degree or identification.iv_lag")
    R_iv = acc.factor()
    return BilinearIVFit(R=_ls_factor(R_iv, P), N=N, m=m, monomials=monos, n_pairs=n_pairs, method=method,
                         rcond=rcond, n_extra=e, R_iv=R_iv, lag=lag, fixed_point=_fixed(fixed_point, N))
