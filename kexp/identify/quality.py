"""Measured quality of eigenfunctions and models on trajectories (held-out where available).

Windows: every start sample s of a trajectory with samples s..s+h all valid (subsampled to at most
``max_windows``, evenly; :func:`kexp.data.runs.window_samples`, streamed run by run).  Errors are relative:
sqrt(Σ‖x̂ − x‖²) / sqrt(Σ‖x − x_eq‖²) over all windows.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..data.runs import PairSource, window_samples
from ..errors import DataError


def eigenfunction_residuals(dataset: PairSource, lift_full, T: np.ndarray, eigenvalues: np.ndarray,
                            block: np.ndarray, h: int) -> np.ndarray:
    """Per coordinate: relative error of ψ(x(t+hΔ)) ≈ e^{λhΔ} ψ(x(t)) (complex ψ for pairs; both coordinates
    of a pair get the pair's value).  NaN if the data has no window of h steps."""
    x0, xh, _ = window_samples(dataset, h)
    k = T.shape[1]
    if x0.shape[0] == 0:
        return np.full(k, np.nan)
    z0 = lift_full(x0) @ T
    z1 = lift_full(xh) @ T
    out = np.empty(k)
    for b in np.unique(block):
        idx = np.flatnonzero(block == b)
        lam = eigenvalues[idx[0]]
        if idx.size == 1:
            p0, p1 = z0[:, idx[0]], z1[:, idx[0]]
        else:  # z = [2Re ψ, −2Im ψ]
            p0 = (z0[:, idx[0]] - 1j * z0[:, idx[1]]) / 2
            p1 = (z1[:, idx[0]] - 1j * z1[:, idx[1]]) / 2
        pred = np.exp(lam * h * dataset.dt) * p0
        denom = np.linalg.norm(p1)
        out[idx] = np.linalg.norm(p1 - pred) / denom if denom > 0 else np.nan
    return out


def prediction_error(model, dataset: PairSource, h: int, max_forced_windows: int = 500) -> float:
    """Relative error of the model's h-step prediction: unforced x̂(t+hΔ) = x_eq + C·e^{ΛhΔ} z(x(t)), or, for
    a forced dataset, under the recorded inputs held over each sample (at most ``max_forced_windows``)."""
    if dataset.n != model.n:
        raise DataError(f"prediction_error: the data have n={dataset.n} states, the model n={model.n}; "
                        "use data of the model's system")
    if not abs(dataset.dt - model.dt) <= 1e-9 * model.dt:
        raise DataError(f"prediction_error: the data are sampled at dt={dataset.dt:g}, the model at "
                        f"dt={model.dt:g}; use data with the model's sampling time")
    forced = dataset.forced
    x0, truth, U = window_samples(dataset, h, max_forced_windows if forced else 20000, inputs=forced)
    if x0.shape[0] == 0:
        return float("nan")
    with np.errstate(over="ignore", invalid="ignore"):   # a model that blows up scores inf, without a warning
        return _relative_error(model, x0, truth, U, h, forced)


def _relative_error(model, x0, truth, U, h, forced) -> float:
    z0 = model.lift(x0)
    if forced:
        zh = z0
        for j in range(h):
            zh = model.step_batch(zh, U[:, j], substeps=2)
    else:   # model.free_response's steps, keeping only the last: (w, k), not (h+1, w, k)
        ad, zh = sla.expm(model.Lambda * model.dt), z0
        for _ in range(h):
            zh = zh @ ad.T
    xh = model.to_state(zh)
    if not np.isfinite(xh).all():   # overflowed (inf, or inf·0 = nan in the products): unbounded
        return float("inf")
    denom = np.linalg.norm(truth - model.x_eq)
    return float(np.linalg.norm(xh - truth) / denom) if denom > 0 else float("nan")
