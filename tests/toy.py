"""Hand-built bilinear models (identity lift) for tests that need exact control over Λ, B, b."""
import numpy as np

from kexp.dictionary import Monomials
from kexp.identify import KoopmanBilinearModel


def toy_model(Lambda, B, b=None, dt=0.01) -> KoopmanBilinearModel:
    Lambda = np.asarray(Lambda, float)
    k = Lambda.shape[0]
    B = np.asarray(B, float).reshape(-1, k, k)
    b = np.zeros((B.shape[0], k)) if b is None else np.asarray(b, float).reshape(B.shape[0], k)
    lam = np.linalg.eigvals(Lambda)
    return KoopmanBilinearModel(
        Lambda=Lambda, B=B, b=b, C=np.eye(k), T=np.vstack([np.eye(k)]), psi0=np.zeros(k), x_eq=np.zeros(k),
        eigenvalues=lam, discrete=np.exp(lam * dt), block=np.arange(k), residual=np.full(k, np.nan),
        drift=np.zeros(k), dictionary=Monomials(k, 1, include_constant=False), dt=dt, system="toy",
        state_names=tuple(f"z{i + 1}" for i in range(k)))
