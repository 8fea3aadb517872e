"""The LMPC's condensed QP in one compiled pass: the exact rollout, its sensitivities and the QP's data.

The input is constant within a move block, so the exact zero-order-hold map E_b (k+1, k+1) of block b and its
derivatives L_b,i = ∂E_b/∂u_i are formed once per block (:func:`block_maps_poly` from the polynomial of
:mod:`kexp.control.zoh_poly` for one input, with the degree each block's input needs; :func:`block_maps_expm` from
the exponential and its Fréchet derivatives for any number of inputs).  :func:`condense` then steps through the
horizon once,

    z_{j+1} = (E_b [z_j; 1])[:k],     s_c(j+1) = A_b s_c(j)  (+ (L_b,i [z_j; 1])[:k] for block b's own columns),

A_b = E_b[:k, :k], s_c(j) = ∂z_j/∂vec(U)_c, and forms the Gauss–Newton Hessian and gradient of the cost
Σ_j ‖y_j‖² (y = z, or y = Cz for a cost on x) and, when asked, the linearised (21e) rows 2 z_jᵀP S_j with V(z_j).
Causality: s_c(j) is zero until column c's block starts, so the propagation runs over the started columns only and
every entry of the Gram matrix is one dot product over the steps where both of its columns are non-zero, stored
contiguously (S is kept per column: (nu, Np+1, k)).

Numba note, measured: an index that LLVM cannot prove non-negative (``a[start + i]``, ``a[j, l]`` with ``j`` an
argument) keeps a negative-index wrap-around test in the loop and stops vectorisation (a dot product of 2000 ran
5× slower), so the loops here run over views with indices from ``range(n)``.

The numbers equal :func:`kexp.control.kernels.rollout_sensitivity`'s and the dense products' to rounding
(tests/test_condense.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import _augmented, expm_frechet

TAIL = 2.0 ** -54


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
def poly_map_and_derivative(coef_flat, top, v, inv_rho, E_flat, L_flat):
    """E ← Σ_{d≤top} C_d v^d and L ← (1/ρ)·Σ_{1≤d≤top} d·C_d v^(d−1), by one Horner pass over the coefficients
    (flat views: coef_flat (D+1, n²), E_flat and L_flat (n²,))."""
    nn = E_flat.shape[0]
    ct = coef_flat[top]
    for i in range(nn):
        E_flat[i] = ct[i]
        L_flat[i] = top * ct[i]
    for t in range(top - 2):
        d = top - 1 - t                    # d = top−1 .. 2
        cd = coef_flat[d]
        for i in range(nn):
            E_flat[i] = E_flat[i] * v + cd[i]
            L_flat[i] = L_flat[i] * v + d * cd[i]
    if top >= 2:
        c1 = coef_flat[1]
        for i in range(nn):
            E_flat[i] = E_flat[i] * v + c1[i]
            L_flat[i] = L_flat[i] * v + c1[i]
    c0 = coef_flat[0]
    for i in range(nn):
        E_flat[i] = E_flat[i] * v + c0[i]
        L_flat[i] *= inv_rho


@njit(cache=True, nogil=True)
def block_maps_poly(coef, norms, rho, lam, B, b, dt, U, E, L):
    """E[c] ← E(U[c]) and L[c, 0] ← dE/du at U[c] for every block c of a one-input model, from the polynomial
    ``coef`` on |u| ≤ ``rho`` (:class:`kexp.control.zoh_poly.ZohPolynomial`, ``norms`` its coefficients'
    ∞-norms), cut for each block at :func:`poly_degree`; by :func:`expm_frechet` outside the range."""
    k = lam.shape[0]
    n = k + 1
    top = coef.shape[0] - 1
    coef_flat = coef.reshape(top + 1, n * n)
    D1 = np.zeros((n, n))
    for r in range(k):
        for c in range(k):
            D1[r, c] = B[0, r, c] * dt
        D1[r, k] = b[0, r] * dt
    for blk in range(U.shape[0]):
        u = U[blk, 0]
        if abs(u) <= rho:
            v = u / rho
            deg = poly_degree(norms, v, top)
            poly_map_and_derivative(coef_flat, deg, v, 1.0 / rho, E[blk].reshape(n * n), L[blk, 0].reshape(n * n))
        else:
            expm_frechet(_augmented(lam, B, b, U[blk], dt), D1, E[blk], L[blk, 0])


@njit(cache=True, nogil=True)
def block_maps_expm(lam, B, b, dt, U, E, L):
    """E[c] ← expm(M_c) and L[c, i] ← its Fréchet derivative along [[B_i, b_i], [0, 0]]Δ for every block c and
    input i, M_c = [[Λ + Σ_i U[c, i] B_i, Σ_i U[c, i] b_i], [0, 0]]Δ: any number of inputs, any input size."""
    k = lam.shape[0]
    m = B.shape[0]
    n = k + 1
    D = np.zeros((m, n, n))
    for i in range(m):
        for r in range(k):
            for c in range(k):
                D[i, r, c] = B[i, r, c] * dt
            D[i, r, k] = b[i, r] * dt
    for blk in range(U.shape[0]):
        M = _augmented(lam, B, b, U[blk], dt)
        for i in range(m):
            expm_frechet(M, D[i], E[blk], L[blk, i])


@njit(cache=True, fastmath={"reassoc", "contract"})
def _dot(a, b):
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return acc


@njit(cache=True, fastmath={"reassoc", "contract"})
def _matvec_into(A, x, out, rows):
    """out[r] ← A[r, :len(x)]·x for r < rows."""
    nx = x.shape[0]
    for r in range(rows):
        Ar = A[r]
        acc = 0.0
        for l in range(nx):
            acc += Ar[l] * x[l]
        out[r] = acc


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def condense(E, L, block_of_step, first_step, z0, ub, C, use_c, scale, rdiag, P, r_hat, want_rows,
             Z, S, Y, HS, q, H, g, rows, Vbar, h_rows, zz):
    """One pass over the horizon (module docstring) at the guess ``ub`` = vec(U) (nu,).  Inputs: the block maps
    E (nb, n, n) and L (nb, m, n, n) at ub; block_of_step (Np,); first_step (nu,), the step at which column c's
    block starts; z0 (k,); the output map C (p, k), used when ``use_c`` (else y = z); the cost's ``scale`` (2Δw)
    and input diagonal ``rdiag`` (nu,); P (k, k) and r̂, used when ``want_rows``.  Written in place: Z (Np+1, k),
    the rollout; S (nu, Np+1, k), S[c, j] = ∂z_j/∂vec(U)_c for j > first_step[c] (the entries before are never
    written: allocate S zeroed); HS (nu, nu) = Σ_j Y_jᵀY_j and q (nu,) = Σ_j Y_jᵀy_j over j = 1..Np; the QP's
    H[:nu, :nu] = scale·HS + diag(rdiag) and g[:nu] = scale·(q − HS·ub) (the cost of y_j ≈ y_j(ub) + Y_j(U − ub));
    with ``want_rows``, rows (Np, nu), row j−1 = 2 z_jᵀP S_j, Vbar (Np,) = z_jᵀP z_j and h_rows (Np,) =
    r̂ − Vbar + rows·ub (the linearised (21e): rows·U − s ≤ h_rows).  Work buffers: Y (nu + 1, Np+1, p) when
    ``use_c`` (C S per column, and C Z last), zz (k+1,)."""
    k = Z.shape[1]
    m = L.shape[1]
    nu = S.shape[0]
    Np = block_of_step.shape[0]
    Z[0, :] = z0
    for j in range(Np):
        blk = block_of_step[j]
        Eb = E[blk]
        zz[:k] = Z[j]
        zz[k] = 1.0
        _matvec_into(Eb, zz, Z[j + 1], k)
        for c in range((blk + 1) * m):
            dst = S[c, j + 1]
            if j > first_step[c]:                 # propagate: A s_c(j)
                src = S[c, j]
                for r in range(k):
                    Er = Eb[r]
                    acc = 0.0
                    for l in range(k):
                        acc += Er[l] * src[l]
                    dst[r] = acc
            else:
                dst[:] = 0.0
            if c >= blk * m:                      # block blk's own input: + (L_i [z_j; 1])[:k]
                Li = L[blk, c - blk * m]
                for r in range(k):
                    dst[r] += _dot(Li[r], zz)
    # the cost's outputs and their sensitivities, flat per column; entry (c, d) of the Gram matrix runs over the
    # steps after both columns' blocks have started
    if use_c:
        p = C.shape[0]
        for c in range(nu + 1):
            src3 = Z if c == nu else S[c]
            j0 = 0 if c == nu else first_step[c] + 1
            for j in range(Np + 1 - j0):
                _matvec_into(C, src3[j0 + j], Y[c, j0 + j], p)
        width = p
        flat = Y.reshape(nu + 1, (Np + 1) * p)
        out = flat[nu]
    else:
        width = k
        flat = S.reshape(nu, (Np + 1) * k)
        out = Z.reshape((Np + 1) * k)
    stop = (Np + 1) * width
    for c in range(nu):
        lo = (first_step[c] + 1) * width
        yc = flat[c]
        q[c] = _dot(yc[lo:stop], out[lo:stop])
        for d in range(c, nu):
            lo_d = (max(first_step[c], first_step[d]) + 1) * width
            v = _dot(yc[lo_d:stop], flat[d][lo_d:stop])
            HS[c, d] = v
            HS[d, c] = v
    for c in range(nu):
        Hc = H[c]
        hs = HS[c]
        for d in range(nu):
            Hc[d] = scale * hs[d]
        Hc[c] += rdiag[c]
        g[c] = scale * (q[c] - _dot(hs, ub))
    if want_rows:                                 # (21e): 2 z_jᵀP S_j and V(z_j), j = 1..Np
        pz = zz[:k]
        for j in range(Np):
            zj = Z[j + 1]
            _matvec_into(P, zj, pz, k)
            Vbar[j] = _dot(pz, zj)
            row = rows[j]
            for c in range(nu):
                if j + 1 > first_step[c]:
                    row[c] = 2.0 * _dot(pz, S[c, j + 1])
                else:
                    row[c] = 0.0
            h_rows[j] = r_hat - Vbar[j] + _dot(row, ub)
