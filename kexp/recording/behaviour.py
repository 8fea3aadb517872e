"""What a logged model does, independent of its eigen-coordinates: the set of its eigenvalues and its
prediction of the state from the run's x0 under the run's inputs.  Used by the ``portable`` diff policy to
compare two models whose Λ, B, b, C entries may differ by a change of basis or by rounding in ill-conditioned
modes while the model behaves the same.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from threadpoolctl import threadpool_limits

PREDICTION_STEPS = 100    # 1 s at Δ = 0.01 (the LMPC horizon): long enough to exercise B, short enough that
                          # an unstable spurious mode does not turn rounding into overflow


def eigenvalues(model_msg: dict) -> np.ndarray:
    """The continuous eigenvalues of a /model message as complex numbers (k,)."""
    re = np.asarray(model_msg.get("eigenvalues_re") or [], dtype=float)
    im = np.asarray(model_msg.get("eigenvalues_im") or [], dtype=float)
    return re + 1j * im if re.shape == im.shape else np.array([], dtype=complex)


def set_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Hausdorff distance between two finite sets of complex numbers and the index in ``a`` where it is reached
    (order-free: a perturbation may reorder close eigenvalues).  Sets of different sizes: (inf, -1)."""
    if a.size != b.size:
        return float("inf"), -1
    if a.size == 0:
        return 0.0, -1
    d = np.abs(a[:, None] - b[None, :])
    da, db = d.min(axis=1), d.min(axis=0)
    i = int(np.argmax(da))
    return float(max(da[i], db.max())), i


def prediction(model_msg: dict, z0, inputs) -> np.ndarray | None:
    """x̂ (T+1, n) of the bilinear model ż = Λz + Σ uᵢ(Bᵢz + bᵢ), x̂ = x_eq + Cz, from ``z0`` (k,) under inputs
    (T, m) held for Δ each (exact zero-order hold).  None if the message lacks a piece or shapes disagree."""
    try:
        lam = np.asarray(model_msg["Lambda"], dtype=float)
        B = np.asarray(model_msg["B"], dtype=float)
        b = np.asarray(model_msg["b"], dtype=float)
        C = np.asarray(model_msg["C"], dtype=float)
        x_eq = np.asarray(model_msg["x_eq"], dtype=float)
        dt = float(model_msg["dt"])
        z = np.asarray(z0, dtype=float)
        U = np.asarray(inputs, dtype=float).reshape(len(inputs), -1)
    except (KeyError, TypeError, ValueError):
        return None
    k = lam.shape[0]
    if lam.shape != (k, k) or B.shape[1:] != (k, k) or b.shape != (B.shape[0], k) or z.shape != (k,) \
            or C.shape[1:] != (k,) or U.shape[1] != B.shape[0]:
        return None
    out = [z]
    aug = np.zeros((k + 1, k + 1))
    for u in U:
        aug[:k, :k] = lam + np.einsum("i,ijk->jk", u, B)
        aug[:k, k] = u @ b
        e = sla.expm(aug * dt)
        z = e[:k, :k] @ z + e[:k, k]
        out.append(z)
    return x_eq + np.asarray(out) @ C.T


@threadpool_limits.wrap(limits=1)     # tiny products: BLAS threads only spin (design §2.11)
def model_predictions(log_a, log_b) -> tuple[np.ndarray, np.ndarray] | None:
    """Both logs' models predicting from their own z(x0) (first /step message) under log a's first
    PREDICTION_STEPS inputs; None when either log has no model or no steps."""
    ma, mb = log_a.one("/model"), log_b.one("/model")
    sa, sb = log_a.messages("/step")[:PREDICTION_STEPS], log_b.messages("/step")[:1]
    if not (ma and mb and sa and sb):
        return None
    try:
        inputs = [s["u"] for s in sa]
        pa, pb = prediction(ma, sa[0]["z"], inputs), prediction(mb, sb[0]["z"], inputs)
    except (KeyError, TypeError):
        return None
    if pa is None or pb is None:
        return None
    return pa, pb
