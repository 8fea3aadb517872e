"""Noise diagnostics of identification: is the data noisy enough to bias least squares, and did it?

- :func:`difference_noise`: a model-free estimate of the measurement noise per state from third differences
  along each run: Δ³x_k = x_{k+3} − 3x_{k+2} + 3x_{k+1} − x_k.  White noise of σ gives E[(Δ³ε)²] = (1 + 9 + 9 + 1)σ²
  = 20σ²; a smooth signal only (x'''Δ³)², e.g. ~1e-10 for Van der Pol at Δ = 0.01.  So σ̂² = mean((Δ³x)²)/20.
- :func:`residual_lag1`: the lag-1 correlation of the one-step residuals x_{k+1} − x̂_{k+1} along runs: model
  error of a smooth trajectory is smooth (correlation near +1); measurement noise enters twice with opposite
  signs (ε_{k+1} − Jε_k), which pulls the correlation towards −0.5.
- :func:`linearisation`: the n×n Jacobian at x_eq of a fit's one-step map x ↦ (Kφ(x)) on the linear monomials,
  and the continuous eigenvalues of the local dynamics, to compare an LS fit with an IV reference.

Thresholds (measured, README "Noisy data"): least squares moved an eigenvalue by more than 1 % from about 0.14 %
relative noise (Van der Pol, degree 5, box data; 0.2 % → 2 %, 1 % → the real part 0.99 instead of 0.5) and 0.6 %
(slow manifold, μ = −0.7, λ = 0.4, 0.7 % → −1.3 %), so :data:`NOISE_WARN` = 0.1 % of the data's RMS.
Instrument strength (Van der Pol, 80 000 pairs): with the smallest canonical correlation 0.90–0.998 the IV
linearisation was within 3.5 %; at 0.80 8 % off, at 0.44 50 % off, at ≤ 0.40 the oscillation was lost, so
:data:`WEAK_INSTRUMENT` = 0.8.  Every IV fit above 0.44 kept the oscillation (the default experiment's circle
data at 3 %: 0.75, 0.41 ± 0.95i), none at 0.40 and below: :data:`REFERENCE_MIN` = 0.5 for the complex-pair check.
"""
from __future__ import annotations

import numpy as np

from ..data.runs import PairSource

NOISE_WARN = 1e-3         # relative noise (σ̂ / RMS about x_eq) above which least squares is warned about
WEAK_INSTRUMENT = 0.8     # smallest canonical correlation below which the IV fit is uncertain (measured below)
REFERENCE_MIN = 0.5       # ... below which an IV reference cannot tell whether a fit lost or gained a complex pair
_D3 = 20.0                # Σ of the squared coefficients of the third difference (1, −3, 3, −1)


def difference_noise(source: PairSource) -> tuple[np.ndarray, int]:
    """(σ̂ (n,), number of third differences used): the noise estimate per state from every 4 consecutive valid
    samples of every run (streamed run by run).  σ̂ is NaN where no run has 4 consecutive valid samples.

    Forced runs: an input held over each sample makes the steps x_{k+1} − x_k ≈ Δ(F + G u_k), so Δ³x carries
    Δ·G·Δ²u, first order in Δ (measured: 1.1 % "noise" on clean Van der Pol data under u ∈ [−5, 5] changed every
    sample).  Δ³x is then regressed on the input's second and first differences over the window and σ̂ is the
    residual's, with coefficients affine in x_k for a state-dependent G (the input is exogenous: this removes
    almost none of the measurement noise)."""
    n = source.n
    gram, count = None, 0
    for run in source.runs():
        x, v = run.x, run.valid
        if x.shape[0] < 4:
            continue
        ok = v[3:] & v[2:-1] & v[1:-2] & v[:-3]
        if not ok.any():
            continue
        d3 = (x[3:] - 3 * x[2:-1] + 3 * x[1:-2] - x[:-3])[ok]
        if run.u is not None and source.forced:
            u = run.u
            du = np.concatenate([u[2:] - 2 * u[1:-1] + u[:-2], u[2:] - u[1:-1]], axis=1)[ok]   # (w, 2m)
            x0 = np.concatenate([np.ones((du.shape[0], 1)), x[:-3][ok]], axis=1)             # G(x) ≈ G0 + G1 x
            feats = (du[:, :, None] * x0[:, None, :]).reshape(du.shape[0], -1)
        else:
            feats = np.zeros((d3.shape[0], 0))
        block = np.concatenate([feats, d3], axis=1)
        if gram is None or gram.shape[0] != block.shape[1]:
            gram = _grow(gram, block.shape[1], n)
        gram += block.T @ block
        count += int(ok.sum())
    if count == 0:
        return np.full(n, np.nan), 0
    f = gram.shape[0] - n
    total = np.diag(gram)[f:].copy()
    if f:
        a, b = gram[:f, :f], gram[:f, f:]
        coef = np.linalg.lstsq(a, b, rcond=1e-12)[0]
        total -= np.einsum("fi,fi->i", b, coef)
    return np.sqrt(np.maximum(total, 0.0) / (_D3 * max(count - f, 1))), count


def _grow(gram: np.ndarray | None, width: int, n: int) -> np.ndarray:
    """A Gram matrix of ``width`` columns (input features first, the n states last) holding ``gram``'s sums (an
    unforced run before the first forced one contributes to the states' block only)."""
    out = np.zeros((width, width))
    if gram is not None:
        out[-n:, -n:] = gram[-n:, -n:]
    return out


def residual_lag1(source: PairSource, lift, K: np.ndarray, linear_idx: np.ndarray, scale: np.ndarray,
                  center: np.ndarray) -> np.ndarray:
    """(n,) the lag-1 correlation of the one-step residuals e_k = x_{k+1} − x̂_{k+1} (x̂ from φ(x_k) and the fit's
    K on the linear monomials) over consecutive valid pairs of next-sample runs; NaN without such pairs."""
    n = linear_idx.size
    k_lin = K[linear_idx]
    num, den_a, den_b = np.zeros(n), np.zeros(n), np.zeros(n)
    for run in source.runs():
        x, v = run.x, run.valid
        if x.shape[0] < 3:
            continue
        pair = v[:-1] & v[1:]
        if not pair.any():
            continue
        e = np.zeros((x.shape[0] - 1, n))
        k = np.flatnonzero(pair)
        e[k] = x[k + 1] - (center + scale * (lift(x[k]) @ k_lin.T))
        both = pair[:-1] & pair[1:]
        a, b = e[:-1][both], e[1:][both]
        num += np.sum(a * b, axis=0)
        den_a += np.sum(a * a, axis=0)
        den_b += np.sum(b * b, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / np.sqrt(den_a * den_b)


def linearisation(K: np.ndarray, dictionary, x_eq: np.ndarray, dt: float, pair_rule: str
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(J_d (n, n), λ (n,) complex): J_d = ∂x_{k+1}/∂x_k at x_eq of the fit's one-step map (x_i = c_i + s_i·ξ_i
    read from the linear monomials of Kφ(x)), λ its continuous eigenvalues (log(μ)/Δ for next pairs, (μ − 1)/Δ
    for Euler pairs), sorted by real part, then imaginary part."""
    x_eq = np.asarray(x_eq, float).reshape(1, -1)
    scale = np.ones(dictionary.n) if dictionary.scale is None else np.asarray(dictionary.scale, float)
    J = scale[:, None] * (K[dictionary.linear_indices] @ dictionary.jacobian(x_eq)[0])
    mu = np.linalg.eigvals(J).astype(complex)
    lam = np.log(mu) / dt if pair_rule == "next" else (mu - 1.0) / dt
    return J, lam[np.lexsort((lam.imag, lam.real))]


def complex_pairs(J: np.ndarray) -> int:
    """Number of complex-conjugate eigenvalue pairs of the real matrix J (|Im μ| > 1e-9·max|μ|)."""
    mu = np.linalg.eigvals(J)
    tol = 1e-9 * max(float(np.max(np.abs(mu))), 1e-300)
    return int(np.sum(mu.imag > tol))


def fmt_eigs(lam: np.ndarray) -> str:
    """'0.5 ± 0.866i, -1.2': one entry per real eigenvalue or conjugate pair, 4 significant digits."""
    out = []
    for v in lam:
        paired = v.imag != 0 and bool(np.any(np.isclose(lam, np.conj(v))))
        if paired and v.imag < 0:
            continue
        out.append(f"{v.real:.4g} ± {v.imag:.4g}i" if paired else f"{v.real:.4g}" if v.imag == 0 else f"{v:.4g}")
    return ", ".join(out)
