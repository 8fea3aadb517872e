"""Control matrices B_i, b_i and output matrix C by projection in eigenfunction coordinates.

Row form on the data: Lφ_i ≈ Φ_X D_iᵀ.  For the kept coordinates S (z_S = Φ T_S − Ψ0_S) and the projection
set S' = S ∪ {constant}, B'_i minimises ‖Lφ_i T_S − Φ T_{S'} B'_iᵀ‖ (Assumption 1 of the paper in least-squares
form).  Then B_i = B'_i restricted to S and b_i = B'_i Ψ0_{S'}, so at z = 0 the input keeps the authority
that the constant eigenfunction carries (design pitfall 4).
"""
from __future__ import annotations

import numpy as np

from .edmd import LeastSquaresFit


def input_matrices(fit: LeastSquaresFit, T: np.ndarray, keep: np.ndarray, constant: int, psi0: np.ndarray,
                   lie_targets: list[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns B (m, k, k), b (m, k) and the relative projection residual per input (m,) over the data,
    which measures how far Assumption 1 fails for this dictionary and these eigenfunctions.  ``lie_targets``:
    the Lie derivatives of φ per input in the fit's R coordinates when they come from a regression
    (regression.BilinearFit.lie_targets; they lie in span[φ, 1] by construction); default: the fit's own
    columns computed from G."""
    keep = np.asarray(keep)
    proj = keep if constant < 0 else np.append(keep, constant)
    ts, tp = T[:, keep], T[:, proj]
    e = fit.n_extra  # the dictionary has no constant: project on [Ψ_S, 1] with the fit's column of ones
    tpe = np.zeros((T.shape[0] + e, proj.size + e))
    tpe[: T.shape[0], : proj.size] = tp
    if e:
        tpe[-1, -1] = 1.0
    lhs = fit.r_ext @ tpe
    Bs, bs, res = [], [], []
    for i in range(fit.m):
        target_in = (fit.inside(1 + i, extended=True) if lie_targets is None else lie_targets[i]) @ ts
        coef = fit.solve(lhs, target_in)  # (|S'| + e, |S|) = [B'ᵀ; cᵀ]
        bprime = coef[: proj.size].T
        Bs.append(bprime[:, : keep.size])
        bs.append(bprime @ psi0[proj] + (coef[-1] if e else 0.0))
        miss_in = np.linalg.norm(target_in - lhs @ coef)
        miss_out = 0.0 if lie_targets is not None else np.linalg.norm(fit.outside(1 + i, extended=True) @ ts)
        total = np.hypot(np.linalg.norm(target_in), miss_out)
        res.append(np.hypot(miss_in, miss_out) / total if total > 0 else 0.0)
    k = keep.size
    B = np.stack(Bs) if Bs else np.zeros((0, k, k))
    b = np.stack(bs) if bs else np.zeros((0, k))
    return B, b, np.array(res)


def output_matrix_exact(T: np.ndarray, keep: np.ndarray, linear_idx: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """C with x − x_eq = C z exactly, valid when T is square and invertible and only a constant coordinate
    (identically zero after the shift) is left out: x = φ E s and φ = Ψ T⁻¹."""
    E = np.zeros((T.shape[0], len(linear_idx)))
    E[linear_idx, np.arange(len(linear_idx))] = scale
    full = np.linalg.solve(T, E)  # (k_full, n): x = Ψ_full @ full
    return full[keep].T


def output_matrix_lstsq(fit: LeastSquaresFit, T: np.ndarray, keep: np.ndarray, constant: int, psi0: np.ndarray,
                        linear_idx: np.ndarray, scale: np.ndarray, x_eq: np.ndarray) -> tuple[np.ndarray, float]:
    """C minimising ‖(x − x_eq) − z C ᵀ‖ over the data, for a subset of eigenfunctions.  The offset is absorbed
    exactly when the dictionary has a constant.  Returns C (n, k) and the relative fit residual."""
    E = np.zeros((T.shape[0], len(linear_idx)))
    E[linear_idx, np.arange(len(linear_idx))] = scale
    proj = keep if constant < 0 else np.append(keep, constant)
    lhs = fit.r11 @ T[:, proj]
    rhs = fit.r11 @ E
    coef = fit.solve(lhs, rhs)  # x ≈ Ψ_proj @ coef
    C = coef[: keep.size].T
    resid = np.linalg.norm(rhs - lhs @ coef) / max(np.linalg.norm(rhs), 1e-300)
    return C, float(resid)
