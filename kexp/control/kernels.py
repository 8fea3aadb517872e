"""Compiled kernels (numba) for the LMPC: exact sample-and-hold rollout of the bilinear model and its
sensitivities with respect to the (move-blocked) input sequence.

Discretisation: for input u held over Δ the model is linear, ż = A_u z + c_u with A_u = Λ + Σu_iB_i,
c_u = Σu_ib_i, so z⁺ = expm([[A_u, c_u], [0, 0]]Δ)·[z; 1] exactly, the matrix exponential summed to machine
precision (:func:`kexp.control.expm_kernels.expm_small`).  The derivative of z⁺ with respect to u_i is the
corresponding block of expm([[M, E_i], [0, M]]Δ)·[0; z; 1] (Van Loan), also summed to machine precision.  Hence
the rollout and its Jacobian are exact to rounding: no discretisation error beyond the zero-order hold itself,
which *is* the sample-and-hold of the closed loop.

Here: :func:`rollout_sensitivity`, the reference (any number of inputs: E = expm(M) once per move block and the
derivative by a Van Loan vector series once per step); :func:`rollout` and :func:`rollout_poly`, the exact
prediction of a plan (a logged plan, a line search's merit), the latter with the ZOH polynomial cut per block at
:func:`poly_degree`; the augmented generator and its input directions (``_augmented``, ``_directions``, also
used by :mod:`kexp.control.condense`).  The matrix exponential and its Fréchet derivative are in
:mod:`kexp.control.expm_kernels`.  The LMPC's rollout with sensitivities and its condensed QP come from
:mod:`kexp.control.condense`, equal to the reference to rounding (tests/test_condense.py).  The top-level kernels
release the GIL (``nogil``): a run's log writer thread works while they run.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .expm_kernels import expm_small
from .zoh_poly import TAIL


@njit(cache=True)
def _augmented(lam, B, b, u, dt):
    k = lam.shape[0]
    M = np.zeros((k + 1, k + 1))
    for r in range(k):
        for c in range(k):
            acc = lam[r, c]
            for i in range(u.shape[0]):
                acc += u[i] * B[i, r, c]
            M[r, c] = acc * dt
        acc = 0.0
        for i in range(u.shape[0]):
            acc += u[i] * b[i, r]
        M[r, k] = acc * dt
    return M


@njit(cache=True)
def _directions(B, b, dt):
    """D (m, k+1, k+1), D_i = [[B_i, b_i], [0, 0]]Δ: the derivative of the augmented generator along input i."""
    m, k = B.shape[0], B.shape[1]
    D = np.zeros((m, k + 1, k + 1))
    for i in range(m):
        for r in range(k):
            for c in range(k):
                D[i, r, c] = B[i, r, c] * dt
            D[i, r, k] = b[i, r] * dt
    return D


@njit(cache=True, fastmath={"reassoc", "contract"})  # reassociation lets LLVM vectorise the two dot products
def _dexp_vec(M, Ei, v, w, y, tw, ty, nw, ny):
    """w ← top block of expm([[M, Ei], [0, M]])·[0; v]: the derivative of expm(M)v along Ei (M, Ei already
    multiplied by Δ).  y, tw, ty, nw, ny are work buffers of the same length as v."""
    n = M.shape[0]
    nrm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(M[i, j]) + abs(Ei[i, j])
        nrm = max(nrm, row)
    q = 1
    while nrm / q > 0.5:
        q *= 2
    inv_q = 1.0 / q
    w[:] = 0.0
    y[:] = v
    for _ in range(q):
        tw[:] = w
        ty[:] = y
        for p in range(1, 40):
            scale = inv_q / p
            big_t = 0.0
            big_s = 0.0
            for i in range(n):
                aw = 0.0
                ay = 0.0
                for j in range(n):
                    aw += M[i, j] * tw[j] + Ei[i, j] * ty[j]
                    ay += M[i, j] * ty[j]
                nw[i] = aw * scale
                ny[i] = ay * scale
            for i in range(n):
                tw[i] = nw[i]
                ty[i] = ny[i]
                w[i] += nw[i]
                y[i] += ny[i]
                big_t = max(big_t, abs(nw[i]), abs(ny[i]))
                big_s = max(big_s, abs(w[i]), abs(y[i]))
            if big_t <= 1e-16 * big_s:
                break


@njit(cache=True, nogil=True)   # the run's log writer thread works meanwhile
def rollout(lam, B, b, dt, z0, U, block_of_step):
    """Z (Np+1, k): exact rollout for block inputs U (nb, m) applied per step via block_of_step (Np,)."""
    k = lam.shape[0]
    Np = block_of_step.shape[0]
    Z = np.empty((Np + 1, k))
    Z[0] = z0
    zz = np.empty(k + 1)
    last = -1
    E = np.eye(k + 1)
    for j in range(Np):
        blk = block_of_step[j]
        if blk != last:
            E = expm_small(_augmented(lam, B, b, U[blk], dt))
            last = blk
        zz[:k] = Z[j]
        zz[k] = 1.0
        Z[j + 1] = (E @ zz)[:k]
    return Z


@njit(cache=True, nogil=True)   # the run's log writer thread works meanwhile
def rollout_sensitivity(lam, B, b, dt, z0, U, block_of_step):
    """Z (Np+1, k) and S (Np+1, k, nb·m) with S[j] = ∂z_j/∂vec(U) (U row-major: block, then input)."""
    k = lam.shape[0]
    m = B.shape[0]
    Np = block_of_step.shape[0]
    nb = U.shape[0]
    nu = nb * m
    Z = np.empty((Np + 1, k))
    S = np.zeros((Np + 1, k, nu))
    Z[0] = z0
    zz = np.empty(k + 1)
    last = -1
    E = np.eye(k + 1)
    M = np.zeros((k + 1, k + 1))
    Ei = _directions(B, b, dt)
    d = np.empty(k + 1)
    b1 = np.empty(k + 1)
    b2 = np.empty(k + 1)
    b3 = np.empty(k + 1)
    b4 = np.empty(k + 1)
    b5 = np.empty(k + 1)
    for j in range(Np):
        blk = block_of_step[j]
        if blk != last:
            M = _augmented(lam, B, b, U[blk], dt)
            E = expm_small(M)
            last = blk
        zz[:k] = Z[j]
        zz[k] = 1.0
        Z[j + 1] = (E @ zz)[:k]
        ncols = (blk + 1) * m
        # S[j+1] = E_k S[j] (only the columns of blocks up to the current one are non-zero)
        for r in range(k):
            for l in range(k):
                e = E[r, l]
                for c in range(ncols):
                    S[j + 1, r, c] += e * S[j, l, c]
        for i in range(m):
            _dexp_vec(M, Ei[i], zz, d, b1, b2, b3, b4, b5)
            for r in range(k):
                S[j + 1, r, blk * m + i] += d[r]
    return Z, S


@njit(cache=True)
def poly_degree(norms, v, top):
    """The lowest degree D ≤ ``top`` at which the polynomial Σ_d C_d v^d (‖C_d‖∞ = norms[d]) and its derivative
    can stop: the dropped terms Σ_{d>D} norms[d]|v|^d and Σ_{d>D} d·norms[d]|v|^(d−1) are below 2⁻⁵⁴ of
    norms[0] and of norms[1] (the sizes of E and of dE/dv at v = 0) respectively."""
    a = abs(v)
    if a == 0.0:
        return 1
    tol_e = TAIL * norms[0]
    tol_l = TAIL * norms[1]
    pw = np.empty(top + 1)
    pw[0] = 1.0
    for d in range(top):
        pw[d + 1] = pw[d] * a
    tail_e = 0.0
    tail_l = 0.0
    for t in range(top - 1):
        d = top - t                       # d = top .. 2
        tail_e += norms[d] * pw[d]
        tail_l += d * norms[d] * pw[d - 1]
        if tail_e > tol_e or tail_l > tol_l:
            return d
    return 1


@njit(cache=True, fastmath={"reassoc", "contract"})
def _poly_map(coef, v, E, top):
    """E ← Σ_{d≤top} coef[d] v^d (Horner over whole matrices): the map alone, for :func:`rollout_poly`."""
    n = coef.shape[1]
    ct = coef[top]
    for r in range(n):
        for c in range(n):
            E[r, c] = ct[r, c]
    for t in range(top):
        cd = coef[top - 1 - t]
        for r in range(n):
            for c in range(n):
                E[r, c] = E[r, c] * v + cd[r, c]


@njit(cache=True, fastmath={"reassoc", "contract"})
def _map_state(E, zz, z_next, k):
    """z_next ← (E·zz)[:k]: one step of a block's map E on the augmented state zz = [z; 1]."""
    for r in range(k):
        acc = 0.0
        for l in range(k + 1):
            acc += E[r, l] * zz[l]
        z_next[r] = acc


@njit(cache=True, nogil=True)
def rollout_poly(coef, norms, rho, lam, B, b, dt, z0, U, block_of_step):
    """:func:`rollout` for a one-input model with the ZOH polynomial ``coef`` on |u| ≤ ``rho`` (``norms`` its
    coefficients' ∞-norms): the block's map from the polynomial cut at :func:`poly_degree` for its input (the
    exponential outside the range), once per block.  A logged plan or a line search's merit costs a tenth of the
    exponential's (equal to :func:`rollout` to rounding, tests/test_lmpc.py)."""
    k = lam.shape[0]
    n = k + 1
    Np = block_of_step.shape[0]
    Z = np.empty((Np + 1, k))
    Z[0] = z0
    zz = np.empty(n)
    E = np.zeros((n, n))
    top = coef.shape[0] - 1
    last = -1
    for j in range(Np):
        blk = block_of_step[j]
        if blk != last:
            u = U[blk, 0]
            if abs(u) <= rho:
                _poly_map(coef, u / rho, E, poly_degree(norms, u / rho, top))
            else:
                E[:, :] = expm_small(_augmented(lam, B, b, U[blk], dt))
            last = blk
        zz[:k] = Z[j]
        zz[k] = 1.0
        _map_state(E, zz, Z[j + 1], k)
    return Z
