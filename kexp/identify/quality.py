"""Measured quality of eigenfunctions and models on trajectories (held-out where available).

Windows: every start sample s of a trajectory with samples s..s+h all valid (subsampled to at most
``max_windows``, evenly).  Errors are relative: sqrt(Σ‖x̂ − x‖²) / sqrt(Σ‖x − x_eq‖²) over all windows.
"""
from __future__ import annotations

import numpy as np

from ..data.dataset import Dataset


def windows(dataset: Dataset, h: int, max_windows: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """(traj, start) index arrays of windows of h steps with every sample valid."""
    v = dataset.valid.astype(np.int64)
    if h >= v.shape[1]:
        return np.zeros(0, int), np.zeros(0, int)
    c = np.concatenate([np.zeros((v.shape[0], 1), np.int64), np.cumsum(v, axis=1)], axis=1)
    ok = (c[:, h + 1:] - c[:, : -h - 1]) == h + 1  # samples s..s+h all valid
    ti, si = np.nonzero(ok)
    if ti.size > max_windows:
        pick = np.linspace(0, ti.size - 1, max_windows).round().astype(int)
        ti, si = ti[pick], si[pick]
    return ti, si


def eigenfunction_residuals(dataset: Dataset, lift_full, T: np.ndarray, eigenvalues: np.ndarray,
                            block: np.ndarray, h: int) -> np.ndarray:
    """Per coordinate: relative error of ψ(x(t+hΔ)) ≈ e^{λhΔ} ψ(x(t)) (complex ψ for pairs; both coordinates
    of a pair get the pair's value).  NaN if the data has no window of h steps."""
    ti, si = windows(dataset, h)
    k = T.shape[1]
    if ti.size == 0:
        return np.full(k, np.nan)
    z0 = lift_full(dataset.x[ti, si]) @ T
    z1 = lift_full(dataset.x[ti, si + h]) @ T
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


def prediction_error(model, dataset: Dataset, h: int, max_forced_windows: int = 500) -> float:
    """Relative error of the model's h-step prediction: unforced x̂(t+hΔ) = x_eq + C·e^{ΛhΔ} z(x(t)), or, for
    a forced dataset, under the recorded inputs held over each sample (at most ``max_forced_windows``)."""
    ti, si = windows(dataset, h, max_forced_windows if dataset.forced else 20000)
    if ti.size == 0:
        return float("nan")
    z0 = model.lift(dataset.x[ti, si])
    if dataset.forced:
        zh = z0
        for j in range(h):
            zh = model.step_batch(zh, dataset.u[ti, si + j], substeps=2)
    else:
        zh = model.free_response(z0, h)[-1]
    xh = model.to_state(zh)
    truth = dataset.x[ti, si + h]
    denom = np.linalg.norm(truth - model.x_eq)
    return float(np.linalg.norm(xh - truth) / denom) if denom > 0 else float("nan")
