"""LQR on the identified model's own linearisation at the equilibrium (F stays unknown): one Riccati solution
serves the lqr_x CLF (V ≈ xᵀP_x x) and the explicit law h(z) = −K_x·Cz."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ClfError


@dataclass(frozen=True)
class ModelLqr:
    """``A`` (n, n) = CΛJ and ``B`` (n, m) = Cbᵀ: the model's linearisation in x at x_eq (z ≈ J(x − x_eq),
    x − x_eq ≈ Cz); ``P`` (n, n) the stabilising solution of the continuous Riccati equation with Q = q·I,
    R = r·I; ``K`` (m, n) = R⁻¹BᵀP, so that u = −K(x − x_eq) is the model's LQR law."""

    A: np.ndarray
    B: np.ndarray
    P: np.ndarray
    K: np.ndarray
    q: float
    r: float

    def residual(self) -> float:
        """‖AᵀP + PA − PBR⁻¹BᵀP + Q‖ / ‖Q‖ (Frobenius): how well P solves the Riccati equation."""
        n = self.A.shape[0]
        res = self.A.T @ self.P + self.P @ self.A - self.P @ self.B @ self.K + self.q * np.eye(n)
        return float(np.linalg.norm(res) / (self.q * np.sqrt(n)))


def model_lqr(model, q: float = 1.0, r: float = 1.0) -> ModelLqr:
    """The LQR of ``model``'s linearisation with weights Q = q·I, R = r·I.  Raises :class:`ClfError` when the
    weights are not > 0 or the linearisation (CΛJ, Cbᵀ) is not stabilisable."""
    import scipy.linalg as sla
    if not (np.isfinite(q) and np.isfinite(r) and q > 0 and r > 0):
        raise ClfError(f"LQR weights q_x={q}, r_u={r}: both must be finite and > 0")
    J = model.lift_jacobian(model.x_eq[None])[0]          # (k, n)
    A = model.C @ model.Lambda @ J
    B = model.C @ model.b.T                                # (n, m)
    try:
        P = sla.solve_continuous_are(A, B, q * np.eye(model.n), r * np.eye(model.m))
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ClfError(f"the model's linearisation (A = CΛJ, B = Cb) is not stabilisable ({exc}); use "
                       "clf.method=sdp or improve the data near the equilibrium") from None
    K = B.T @ P / r
    for a in (A, B, P, K):
        a.setflags(write=False)
    return ModelLqr(A=A, B=B, P=P, K=K, q=float(q), r=float(r))
