"""Compiled kernels (numba): the matrix exponential of the LMPC's small generators and its Fréchet derivative.

:func:`expm_small`: expm(M) by scaling and squaring of a Taylor series summed to machine precision (its degree
chosen from the norm so that the remainder is at rounding), evaluated by Paterson–Stockmeyer: the exact
zero-order-hold map of the bilinear model's augmented generator in :mod:`kexp.control.kernels`' rollouts.
:func:`expm_frechet`: expm(M) and its Fréchet derivative along one direction D (the top-right block of
expm([[M, D], [0, M]]), Van Loan) by Taylor scaling and squaring on the pairs (A^j, ∂A^j);
:func:`expm_frechet_pade`: the same along several directions at once by the [13/13] Padé approximant (Al-Mohy and
Higham), its powers and LU shared by the directions.  These two give :mod:`kexp.control.condense` a move block's
map and its derivatives with respect to the inputs.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _taylor_degree(theta):
    """Smallest p (at most 30) with θ^{p+1}/(p+1)! ≤ 2⁻⁵⁴·e^θ.  The Taylor remainder of exp for ‖A‖ ≤ θ is at
    most θ^{p+1}/(p+1)!·e^θ ≤ 2⁻⁵⁴·e^{2θ}, which for the scaled θ ≤ 0.5 is ≤ e·2⁻⁵⁴ ≈ 1.5e-16: at rounding."""
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
    norm so that the remainder is at rounding (:func:`_taylor_degree`), evaluated by Paterson–Stockmeyer (about
    2√p matrix products instead of p)."""
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
