"""Compiled kernels (numba) for the LMPC: exact sample-and-hold rollout of the bilinear model and its
sensitivities with respect to the (move-blocked) input sequence.

Discretisation: for input u held over Δ the model is linear, ż = A_u z + c_u with A_u = Λ + Σu_iB_i,
c_u = Σu_ib_i, so z⁺ = expm([[A_u, c_u], [0, 0]]Δ)·[z; 1] exactly.  The matrix exponential is a Taylor series
with scaling and squaring, summed to machine precision (terms below 1e-16 relative).  The derivative of z⁺ with
respect to u_i is the corresponding block of expm([[M, E_i], [0, M]]Δ)·[0; z; 1] (Van Loan), also summed to
machine precision.  Hence the rollout and its Jacobian are exact to rounding: no discretisation error beyond
the zero-order hold itself, which *is* the sample-and-hold of the closed loop.

Here: :func:`rollout_sensitivity`, the reference (any number of inputs: E = expm(M) once per move block and the
derivative by a Van Loan vector series once per step); :func:`rollout` and :func:`rollout_poly`, the exact
prediction of a plan (a logged plan, a line search's merit); the matrix exponential and its Fréchet derivative.
The LMPC's rollout with sensitivities and its condensed QP come from :mod:`kexp.control.condense`, equal to the
reference to rounding (tests/test_condense.py).  The top-level kernels release the GIL (``nogil``): a run's log
writer thread works while they run.
"""
from __future__ import annotations

import numpy as np
from numba import njit

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


@njit(cache=True)
def _matmul(a, b):
    n, p = a.shape
    q = b.shape[1]
    out = np.zeros((n, q))
    for i in range(n):
        for l in range(p):
            ail = a[i, l]
            if ail != 0.0:
                for j in range(q):
                    out[i, j] += ail * b[l, j]
    return out


@njit(cache=True)
def _taylor_degree(theta):
    """Smallest p with θ^{p+1}/(p+1)!·e^θ ≤ 2⁻⁵⁴: the Taylor remainder of exp for ‖A‖ ≤ θ is below rounding."""
    term = theta
    p = 1
    bound = np.exp(theta) * 2.0 ** -54
    while p < 30:
        term *= theta / (p + 1)          # θ^{p+1}/(p+1)!
        if term <= bound:
            break
        p += 1
    return p


@njit(cache=True)
def _norm1(M):
    """‖M‖₁, the largest column sum of |M| (each column summed top to bottom); ‖M‖∞ is ``_norm1(M.T)``."""
    nrm = 0.0
    for c in range(M.shape[1]):
        col = 0.0
        for r in range(M.shape[0]):
            col += abs(M[r, c])
        nrm = max(nrm, col)
    return nrm


@njit(cache=True)
def _scaling(M):
    """(s, ‖M‖∞/2^s): the smallest s ≥ 0 with ‖M‖∞/2^s ≤ 0.5 (the scaling of scaling and squaring)."""
    return _halvings(_norm1(M.T), 0.5)


@njit(cache=True)
def _halvings(nrm, theta):
    """(s, nrm/2^s): the smallest s ≥ 0 with nrm/2^s ≤ theta."""
    s = 0
    while nrm > theta:
        nrm *= 0.5
        s += 1
    return s, nrm


@njit(cache=True)
def expm_small(M):
    """expm(M) by scaling (‖M‖∞/2^s ≤ 0.5) and squaring of a Taylor polynomial whose degree p is chosen from the
    norm so that the remainder is below rounding, evaluated by Paterson–Stockmeyer (about 2√p matrix products
    instead of p)."""
    n = M.shape[0]
    s, nrm = _scaling(M)
    A = M * (0.5 ** s)
    p = _taylor_degree(nrm)
    q = max(1, int(np.ceil(np.sqrt(p + 1.0))))
    # powers A^0..A^q
    P = np.empty((q + 1, n, n))
    P[0] = np.eye(n)
    P[1] = A
    for j in range(2, q + 1):
        P[j] = P[j - 1] @ A
    coef = np.empty(p + 1)
    coef[0] = 1.0
    for j in range(1, p + 1):
        coef[j] = coef[j - 1] / j
    # Horner in A^q over chunks of q coefficients, highest chunk first
    nchunks = p // q + 1
    E = np.zeros((n, n))
    for c in range(nchunks - 1, -1, -1):
        chunk = np.zeros((n, n))
        for j in range(q):
            d = c * q + j
            if d <= p:
                chunk += coef[d] * P[j]
        if c == nchunks - 1:
            E = chunk
        else:
            E = E @ P[q] + chunk
    for _ in range(s):
        E = E @ E
    return E


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
def expm_frechet(M, D, E, L):
    """E ← expm(M) and L ← the Fréchet derivative of expm at M in the direction D (all (n, n)), i.e. the
    top-right block of expm([[M, D], [0, M]]): scaling and squaring of a Taylor polynomial on the pairs
    (A^j, ∂A^j) (product rule), with one degree more than :func:`expm_small` so that the derivative's remainder
    is below rounding too.  Used by :mod:`kexp.control.condense` for a block's map and derivatives."""
    n = M.shape[0]
    s, nrm = _scaling(M)
    sc = 0.5 ** s
    p = _taylor_degree(nrm) + 1
    A = M * sc
    dA = D * sc
    coef = 1.0
    Ek = np.eye(n)                       # A^j/j! and its derivative, summed term by term
    dEk = np.zeros((n, n))
    E[:, :] = Ek
    L[:, :] = 0.0
    for j in range(1, p + 1):
        coef = 1.0 / j
        dEk = (dEk @ A + Ek @ dA) * coef
        Ek = (Ek @ A) * coef
        E += Ek
        L += dEk
    for _ in range(s):
        L[:, :] = E @ L + L @ E
        E[:, :] = E @ E


PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
          10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0)
THETA13 = 5.371920351148152   # the 1-norm up to which the [13/13] Padé approximant is exact to rounding


@njit(cache=True)
def expm_frechet_pade(M, D, E, L):
    """E ← expm(M) and L[i] ← its Fréchet derivative along D[i] for every direction i (D, L (m, n, n)), by
    scaling and squaring of the [13/13] Padé approximant and its derivative (Al-Mohy and Higham, SIAM J. Matrix
    Anal. Appl. 30(4), 2009, Algorithm 6.4, degree 13 only): the powers and the Padé numerator and denominator
    are shared by the directions (13 products per direction, their right-hand sides solved together, one LU for
    all), and 2^s = ‖M‖₁/θ₁₃ rounded up instead of ‖M‖∞/0.5: on a two-input model's generators (‖M‖₁ ~ 30–300)
    1.7× faster than m calls of :func:`expm_frechet`, which repeat expm(M)'s own products per direction and square
    ~3 more times (benchmarks/expm_maps.py), and as accurate or more against the Van Loan block
    (tests/test_lmpc.py)."""
    n = M.shape[0]
    m = D.shape[0]
    b = PADE13
    s = _halvings(_norm1(M), THETA13)[0]
    sc = 0.5 ** s
    A = M * sc
    ident = np.eye(n)
    A2 = A @ A
    A4 = A2 @ A2
    A6 = A2 @ A4
    W1 = b[13] * A6 + b[11] * A4 + b[9] * A2
    W2 = b[7] * A6 + b[5] * A4 + b[3] * A2 + b[1] * ident
    Z1 = b[12] * A6 + b[10] * A4 + b[8] * A2
    Z2 = b[6] * A6 + b[4] * A4 + b[2] * A2 + b[0] * ident
    W = A6 @ W1 + W2
    U = A @ W
    V = A6 @ Z1 + Z2
    Q = V - U
    R = np.ascontiguousarray(np.linalg.solve(Q, V + U))
    rhs = np.empty((n, m * n))             # every direction's right-hand side: one more LU for all of them
    for i in range(m):
        Ei = D[i] * sc
        M2 = A @ Ei + Ei @ A
        M4 = A2 @ M2 + M2 @ A2
        M6 = A4 @ M2 + M4 @ A2
        Lw = A6 @ (b[13] * M6 + b[11] * M4 + b[9] * M2) + M6 @ W1 + (b[7] * M6 + b[5] * M4 + b[3] * M2)
        Lu = A @ Lw + Ei @ W
        Lv = A6 @ (b[12] * M6 + b[10] * M4 + b[8] * M2) + M6 @ Z1 + (b[6] * M6 + b[4] * M4 + b[2] * M2)
        rhs[:, i * n:(i + 1) * n] = Lu + Lv + (Lu - Lv) @ R
    X = np.linalg.solve(Q, rhs)
    Ls = np.empty((m, n, n))
    for i in range(m):
        Ls[i] = X[:, i * n:(i + 1) * n]
    for _ in range(s):
        for i in range(m):
            Li = Ls[i]
            Ls[i] = R @ Li + Li @ R
        R = R @ R
    E[:, :] = R
    L[:, :, :] = Ls


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
