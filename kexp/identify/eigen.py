"""Koopman eigenfunctions from K and the Koopman canonical transform (KCT) to real coordinates.

With φ(y) ≈ K φ(x), an eigenfunction is ψ = wᵀφ where w is an eigenvector of **Kᵀ** (a left eigenvector of K):
ψ(y) = wᵀφ(y) ≈ wᵀKφ(x) = λ̃ ψ(x).  Continuous eigenvalues: λ = log(λ̃)/Δ for true next-sample pairs and
λ = (λ̃ − 1)/Δ for Euler pairs y = x + F(x)Δ (there K = I + ΔL exactly).

Real coordinates: a real ψ gives one coordinate; a complex pair (λ = a + ib, b > 0) gives [2Re ψ, −2Im ψ],
whose generator block is [[a, b], [−b, a]] (the paper's |λ|[[cos∠λ, sin∠λ], [−sin∠λ, cos∠λ]] for the
continuous λ).  Row form: z = φ(x) @ T with T (N, k) real.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, KexpError


class IdentificationError(KexpError, ValueError):
    """The fitted operator cannot be turned into a usable model; the message says what to change."""


class IdentificationWarning(UserWarning):
    """Identification went on but the model deserves a look: K is near-defective (ill-determined
    eigenfunctions), real eigenvalues ≤ 0 of K were dropped, or no eigenfunction is constant although the
    dictionary has a constant.  The same notes are kept in the model's report (``warnings``)."""


@dataclass(frozen=True)
class Eigenfunctions:
    """Real eigen-coordinates.  Per coordinate j (k of them): ``eigenvalues[j]`` (continuous, complex; a pair's
    two coordinates hold λ and λ̄), ``discrete[j]`` (λ̃), ``block[j]`` (index of its 1×1 or 2×2 block),
    ``condition[j]`` (eigenvalue condition number ‖w‖‖v‖/|wᵀv|).  ``T`` (N, k): z = φ(x) @ T.
    ``Lambda`` (k, k): block diagonal generator.  ``constant``: coordinate of the constant eigenfunction or -1.
    """

    T: np.ndarray
    Lambda: np.ndarray
    eigenvalues: np.ndarray
    discrete: np.ndarray
    block: np.ndarray
    condition: np.ndarray
    constant: int
    eigvec_cond: float
    warnings: tuple[str, ...]

    @property
    def k(self) -> int:
        return self.T.shape[1]

    def blocks(self) -> list[np.ndarray]:
        return [np.flatnonzero(self.block == b) for b in range(int(self.block.max()) + 1)]


def continuous_eigenvalues(discrete: np.ndarray, dt: float, pair_rule: str) -> np.ndarray:
    d = np.asarray(discrete, dtype=complex)
    if pair_rule == "euler":
        return (d - 1.0) / dt
    if pair_rule == "next":
        return np.log(d) / dt
    raise ConfigError(f"pair rule {pair_rule!r}; valid: 'next', 'euler'")


def real_block(lam: complex) -> np.ndarray:
    """Generator block of the coordinates [2Re ψ, −2Im ψ] for the eigenvalue λ (Im λ > 0)."""
    return np.array([[lam.real, lam.imag], [-lam.imag, lam.real]])


def eigenfunctions(K: np.ndarray, r11: np.ndarray, n_samples: int, dt: float, pair_rule: str, *,
                   constant_index: int | None, on_invalid: str = "error", defect_tol: float = 1e10,
                   constant_tol: float = 1e-8) -> Eigenfunctions:
    """Eigen-decompose K, convert the eigenvalues, normalise each eigenfunction to unit RMS on the data
    (‖Φ_X w‖ = ‖r11 w‖), and build the real transform and block-diagonal Λ.

    ``on_invalid``: 'error' raises for a real λ̃ ≤ 0 with next-sample pairs (log undefined); 'drop' leaves
    such eigenfunctions out with a warning.
    """
    if on_invalid not in ("error", "drop"):
        raise ConfigError(f"identification.on_invalid={on_invalid!r}; valid: 'error', 'drop'")
    N = K.shape[0]
    lam_d, vl, vr = sla.eig(K, left=True, right=True)
    W = vl.conj()  # columns w with wᵀK = λ̃ wᵀ
    notes: list[str] = []
    # eigenvalue condition numbers and eigenvector-matrix condition (near-defective K)
    denom = np.abs(np.einsum("ij,ij->j", W, vr))
    cond_each = np.linalg.norm(W, axis=0) * np.linalg.norm(vr, axis=0) / np.maximum(denom, 1e-300)
    eigvec_cond = float(np.linalg.cond(W))
    if not np.isfinite(eigvec_cond) or eigvec_cond > defect_tol:
        notes.append(f"K is near-defective: eigenvector matrix condition {eigvec_cond:.2e} > {defect_tol:.0e}; "
                     "eigenfunctions are ill-determined (reduce the degree, scale the states, or add data)")
    real = lam_d.imag == 0
    bad = real & (lam_d.real <= 0) & (pair_rule == "next")
    if np.any(bad):
        msg = (f"{int(bad.sum())} real eigenvalue(s) of K ≤ 0 ({', '.join(f'{v.real:.3g}' for v in lam_d[bad])}) "
               "have no continuous-time logarithm")
        if on_invalid == "error":
            raise IdentificationError(msg + "; set identification.on_invalid=drop to leave them out, or improve the "
                                      "data (smaller dt, more samples) or the dictionary")
        notes.append(msg + "; dropped")
    lam_c = continuous_eigenvalues(lam_d, dt, pair_rule)
    # one representative per real eigenvalue or per conjugate pair (Im > 0)
    reps = [i for i in range(N) if not bad[i] and (real[i] or lam_d[i].imag > 0)]
    reps.sort(key=lambda i: (-round(lam_c[i].real, 12), round(abs(lam_c[i].imag), 12), i))
    cols, lams, lds, blocks, conds = [], [], [], [], []
    constant = -1
    rms = lambda w: np.linalg.norm(r11 @ w) / np.sqrt(n_samples)  # noqa: E731
    for b, i in enumerate(reps):
        w = W[:, i]
        if real[i]:
            w = w.real.copy()
            s = rms(w)
            if s == 0:
                raise IdentificationError("an eigenfunction vanishes on the data; the dictionary is degenerate")
            w /= s
            j = int(np.argmax(np.abs(w)))
            w *= np.sign(w[j])
            cols.append(w)
            lams.append(complex(lam_c[i].real, 0.0))
            lds.append(complex(lam_d[i].real, 0.0))
            blocks.append(b)
            conds.append(cond_each[i])
            if constant_index is not None and constant < 0 and _is_constant(w, r11, constant_index, constant_tol):
                constant = len(cols) - 1
        else:
            j = int(np.argmax(np.abs(w)))
            w = w * (abs(w[j]) / w[j])  # fix the phase: largest coefficient real positive
            w = w / (rms(w.real) ** 2 + rms(w.imag) ** 2) ** 0.5 / np.sqrt(2.0)
            cols += [2 * w.real, -2 * w.imag]
            lams += [lam_c[i], np.conj(lam_c[i])]
            lds += [lam_d[i], np.conj(lam_d[i])]
            blocks += [b, b]
            conds += [cond_each[i]] * 2
    T = np.stack(cols, axis=1)
    lams = np.array(lams)
    blocks = np.array(blocks)
    Lam = np.zeros((T.shape[1], T.shape[1]))
    for b in range(len(reps)):
        idx = np.flatnonzero(blocks == b)
        if idx.size == 1:
            Lam[idx[0], idx[0]] = lams[idx[0]].real
        else:
            Lam[np.ix_(idx, idx)] = real_block(lams[idx[0]])
    if constant_index is not None and constant < 0:
        notes.append("the dictionary has a constant but no eigenfunction is constant on the data")
    for note in notes:
        warnings.warn(note, IdentificationWarning, stacklevel=2)
    return Eigenfunctions(T=T, Lambda=Lam, eigenvalues=lams, discrete=np.array(lds), block=blocks,
                          condition=np.array(conds), constant=constant, eigvec_cond=eigvec_cond,
                          warnings=tuple(notes))


def _is_constant(w, r11, constant_index, tol) -> bool:
    """ψ = wᵀφ is constant on the data iff w is (nearly) the constant monomial's unit vector."""
    e = np.zeros_like(w)
    e[constant_index] = w[constant_index]
    return bool(np.linalg.norm(r11 @ (w - e)) <= tol * max(np.linalg.norm(r11 @ w), 1e-300))
