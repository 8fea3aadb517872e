"""The LMPC's condensed QP in one compiled pass: the exact rollout, its sensitivities and the QP's data.

The input is constant within a move block, so the exact zero-order-hold map E_b (k+1, k+1) of block b and its
derivatives L_b,i = ∂E_b/∂u_i are formed once per block (:func:`block_maps_poly` from the polynomial of
:mod:`kexp.control.zoh_poly` for one input, with the degree each block's input needs; :func:`block_maps_expm` from
the exponential and its Fréchet derivatives for any number of inputs, by Padé).  :func:`condense` then steps through the
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

from .expm_kernels import expm_frechet, expm_frechet_pade
from .kernels import _augmented, _directions, poly_degree


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
    D1 = _directions(B, b, dt)[0]
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
    input i, M_c = [[Λ + Σ_i U[c, i] B_i, Σ_i U[c, i] b_i], [0, 0]]Δ: any number of inputs, any input size
    (:func:`kexp.control.expm_kernels.expm_frechet_pade`, the exponential's work shared by the inputs)."""
    D = _directions(B, b, dt)
    for blk in range(U.shape[0]):
        expm_frechet_pade(_augmented(lam, B, b, U[blk], dt), D, E[blk], L[blk])


def balancing(lam, B, b, dt: float, rho: float):
    """A diagonal similarity S = diag(s) (s powers of two, so S⁻¹MS is exact in floating point) that balances the
    block generators M(u) = [[Λ + Σu_iB_i, Σu_ib_i], [0, 0]]Δ over |u| ≤ ``rho`` (LAPACK's balancing of
    |X| + ρΣ|Y_i|), for :func:`block_maps_expm`: expm(S⁻¹MS) = S⁻¹expm(M)S, and its scaling and squaring needs
    ‖S⁻¹MS‖₁/θ₁₃ halvings instead of ‖M‖₁/θ₁₃.  Eigen-coordinates of a monomial dictionary make B far from
    normal: on the 4-state cart-pole (k = 34, |u| ≤ 5) ‖M‖₁ = 172 balanced to 12, a block's map 3× faster
    (0.35 → 0.12 ms) and closer to the Van Loan reference (error 6e-15 → 1.6e-15).  Returns (Λ_b, B_b, b_b, ratio)
    with ratio[r, c] = s_r/s_c (E = ratio ∘ E_b), or None when balancing would not save a halving (then nothing
    changes)."""
    import scipy.linalg as sla
    lam, B, b = (np.asarray(a, dtype=float) for a in (lam, B, b))
    k = lam.shape[0]
    W = np.zeros((k + 1, k + 1))
    W[:k, :k] = np.abs(lam) + rho * np.abs(B).sum(axis=0)
    W[:k, k] = rho * np.abs(b).sum(axis=0)
    W *= dt
    if not (np.all(np.isfinite(W)) and np.isfinite(rho)):
        return None
    _, (s, _) = sla.matrix_balance(W, permute=False, separate=True)
    s = np.asarray(s, dtype=float)
    if not np.all(np.exp2(np.round(np.log2(s))) == s):   # LAPACK scales by the radix, 2: never otherwise
        return None
    ratio = s[:, None] / s[None, :]
    norm = np.abs(W).sum(axis=0).max()
    if not np.abs(W / ratio).sum(axis=0).max() <= 0.5 * norm:
        return None
    inv = 1.0 / ratio                                     # W_b = S⁻¹WS: entry (r, c) times s_c/s_r
    lam_b = np.ascontiguousarray(lam * inv[:k, :k])
    B_b = np.ascontiguousarray(B * inv[None, :k, :k])
    b_b = np.ascontiguousarray(b * inv[None, :k, k])
    return lam_b, B_b, b_b, ratio


@njit(cache=True, fastmath={"reassoc", "contract"})
def _dot(a, b):
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return acc


@njit(cache=True, fastmath={"reassoc", "contract"})
def _dots4(a0, a1, a2, a3, b):
    """(a0·b, a1·b, a2·b, a3·b): four dot products sharing the loads of b."""
    s0 = s1 = s2 = s3 = 0.0
    for i in range(b.shape[0]):
        x = b[i]
        s0 += a0[i] * x
        s1 += a1[i] * x
        s2 += a2[i] * x
        s3 += a3[i] * x
    return s0, s1, s2, s3


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


@njit(cache=True, fastmath={"reassoc", "contract"})
def _propagate(Eb, S, j, nc, k):
    """S[c, j+1] ← A S[c, j] for the columns c < nc, A = Eb[:k, :k]: two columns by four rows at a time, so that
    eight dot products share their loads (measured 2.2× the rate of one dot product at a time, 12.7 GFMA/s)."""
    for c0 in range(0, nc, 2):
        two = c0 + 1 < nc
        s0 = S[c0, j]
        d0 = S[c0, j + 1]
        s1 = S[c0 + 1, j] if two else s0
        d1 = S[c0 + 1, j + 1] if two else d0
        r = 0
        while r + 3 < k:
            e0 = Eb[r]
            e1 = Eb[r + 1]
            e2 = Eb[r + 2]
            e3 = Eb[r + 3]
            a0 = a1 = a2 = a3 = b0 = b1 = b2 = b3 = 0.0
            for l in range(k):
                x0 = s0[l]
                x1 = s1[l]
                a0 += e0[l] * x0
                a1 += e1[l] * x0
                a2 += e2[l] * x0
                a3 += e3[l] * x0
                b0 += e0[l] * x1
                b1 += e1[l] * x1
                b2 += e2[l] * x1
                b3 += e3[l] * x1
            d0[r] = a0
            d0[r + 1] = a1
            d0[r + 2] = a2
            d0[r + 3] = a3
            if two:
                d1[r] = b0
                d1[r + 1] = b1
                d1[r + 2] = b2
                d1[r + 3] = b3
            r += 4
        while r < k:
            er = Eb[r]
            a0 = b0 = 0.0
            for l in range(k):
                a0 += er[l] * s0[l]
                b0 += er[l] * s1[l]
            d0[r] = a0
            if two:
                d1[r] = b0
            r += 1


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})
def condense(E, L, block_of_step, first_step, z0, ub, C, use_c, scale, rdiag, P, terminal, r_hat, want_rows,
             Z, S, Y, HS, q, H, g, rows, Vbar, h_rows, zz, PS):
    """One pass over the horizon (module docstring) at the guess ``ub`` = vec(U) (nu,).  Inputs: the block maps
    E (nb, n, n) and L (nb, m, n, n) at ub; block_of_step (Np,); first_step (nu,), the step at which column c's
    block starts; z0 (k,); the output map C (p, k), used when ``use_c`` (else y = z); the cost's ``scale`` (2Δw)
    and input diagonal ``rdiag`` (nu,); P (k, k) and r̂, used when ``want_rows``.  Written in place: Z (Np+1, k),
    the rollout; S (nu, Np+1, k), S[c, j] = ∂z_j/∂vec(U)_c for j > first_step[c] (the entries before are never
    written, and read as zeros: allocate S zeroed); HS (nu, nu) = Σ_j Y_jᵀY_j and q (nu,) = Σ_j Y_jᵀy_j over j = 1..Np; the QP's
    H[:nu, :nu] = scale·HS + diag(rdiag) and g[:nu] = scale·(q − HS·ub) (the cost of y_j ≈ y_j(ub) + Y_j(U − ub)),
    plus, when ``terminal`` w_T > 0, the terminal cost w_T·V(z_Np): 2w_T S_Npᵀ P S_Np and 2w_T S_Npᵀ P (z_Np − S_Np ub);
    with ``want_rows``, rows (Np, nu), row j−1 = 2 z_jᵀP S_j, Vbar (Np,) = z_jᵀP z_j and h_rows (Np,) =
    r̂ − Vbar + rows·ub (the linearised (21e): rows·U − s ≤ h_rows).  Work buffers: Y (nu + 1, Np+1, p) when
    ``use_c`` (C S per column, and C Z last), zz (k+1,), PS (nu, k)."""
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
        # A s_c(j) for every started column; block blk's own columns are still zero at its first step (never
        # written), and get + (L_i [z_j; 1])[:k]
        _propagate(Eb, S, j, (blk + 1) * m, k)
        for i in range(m):
            dst = S[blk * m + i, j + 1]
            Li = L[blk, i]
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
        q[c] = _dot(flat[c][lo:stop], out[lo:stop])
    for d in range(nu):                           # the columns c ≤ d are non-zero wherever d is: four at a time
        lo = (first_step[d] + 1) * width
        yd = flat[d][lo:stop]
        c = 0
        while c + 3 <= d:
            v0, v1, v2, v3 = _dots4(flat[c][lo:stop], flat[c + 1][lo:stop], flat[c + 2][lo:stop],
                                    flat[c + 3][lo:stop], yd)
            HS[c, d] = HS[d, c] = v0
            HS[c + 1, d] = HS[d, c + 1] = v1
            HS[c + 2, d] = HS[d, c + 2] = v2
            HS[c + 3, d] = HS[d, c + 3] = v3
            c += 4
        while c <= d:
            v = _dot(flat[c][lo:stop], yd)
            HS[c, d] = HS[d, c] = v
            c += 1
    for c in range(nu):
        Hc = H[c]
        hs = HS[c]
        for d in range(nu):
            Hc[d] = scale * hs[d]
        Hc[c] += rdiag[c]
        g[c] = scale * (q[c] - _dot(hs, ub))
    if terminal > 0.0:                            # w_T V(z_Np), z_Np ≈ z̄_Np + S_Np (U − ub)
        e = zz[:k]
        e[:] = Z[Np]
        for d in range(nu):
            ud = ub[d]
            sd = S[d, Np]
            for r in range(k):
                e[r] -= ud * sd[r]
        for c in range(nu):
            _matvec_into(P, S[c, Np], PS[c], k)
        w2 = 2.0 * terminal
        for c in range(nu):
            pc = PS[c]
            g[c] += w2 * _dot(pc, e)
            Hc = H[c]
            for d in range(nu):
                Hc[d] += w2 * _dot(pc, S[d, Np])
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


@njit(cache=True, fastmath={"reassoc", "contract"})
def rows_hold(rows, h_rows, x, rel_tol):
    """Whether the linearised (21e) rows hold at the QP variables x = (vec U, s): rows[j]·U − s − h_rows[j] ≤
    rel_tol·max(1, |h_rows[j]|) for every j."""
    nu = rows.shape[1]
    u = x[:nu]
    s = x[nu]
    for j in range(rows.shape[0]):
        h = h_rows[j]
        if _dot(rows[j], u) - s - h > rel_tol * max(1.0, abs(h)):
            return False
    return True


@njit(cache=True, fastmath={"reassoc", "contract"})
def linearised_vmax(Z, S, du, P, first_step, zl, pz):
    """max_{j ≥ 1} V(z̄_j + S_j du), V(z) = zᵀPz: the largest V along the linearised prediction of the plan
    ub + du (the (21e) slack as the QP saw it).  zl and pz are (k,) work buffers."""
    k = Z.shape[1]
    vmax = -np.inf
    for j in range(1, Z.shape[0]):
        zl[:] = Z[j]
        for c in range(S.shape[0]):
            if j > first_step[c]:
                d = du[c]
                sc = S[c, j]
                for r in range(k):
                    zl[r] += d * sc[r]
        _matvec_into(P, zl, pz, k)
        v = _dot(pz, zl)
        if v > vmax:
            vmax = v
    return vmax
