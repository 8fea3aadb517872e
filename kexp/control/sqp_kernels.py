"""Compiled kernels of the SQP oracle (:mod:`kexp.control.sqp_oracle`): the cost of a rollout and the Gauss–Newton
QP of the single-shooting problem, condensed by a backward recursion.

The problem (that of :class:`~kexp.control.oracle.NmpcOracle`): states X (N+1, n) from the rollout of block inputs
U (nb, m) (step j holds U[bos[j]]; block b spans ``sizes[b]`` steps),

    f(U) = Σ_{j=1..N} e_jᵀ Q_j e_j + w_r Σ_b sizes[b] ‖U_b‖²,   e_j = X_j − x_eq,  Q_j = w_q I (j < N),  Q_N = w_q I + X_T.

With A_j = ∂X_{j+1}/∂X_j and B_j = ∂X_{j+1}/∂u_j (from the compiled RK4, ``AB[j] = [A_j | B_j]``) and the
sensitivities S_{j,c} = A_{j−1}⋯A_{c+1}B_c, the Gauss–Newton model of f around U is f + 2gᵀδ + δᵀHδ with (per step,
before summing the steps of each block)

    g_c = B_cᵀλ_{c+1},  λ_N = Q_N e_N,  λ_j = Q_j e_j + A_jᵀλ_{j+1}          (the adjoint: ½∇f)
    H_{cd} = S_{d+1,c}ᵀ W_{d+1} B_d  (c ≤ d),  W_N = Q_N,  W_j = Q_j + A_jᵀ W_{j+1} A_j

plus the input weight.  That is O(N²·n²·m) work instead of the O(N³·n·m) of forming SᵀQS (the sum over j is
carried by W), about 20 µs for N = 100, n = 2.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def cost(X, U, sizes, xe, wq, wr, XT):
    """f(U) of the rollout X (N+1, n) (module docstring)."""
    N = X.shape[0] - 1
    n = X.shape[1]
    f = 0.0
    for j in range(1, N + 1):
        for i in range(n):
            d = X[j, i] - xe[i]
            f += wq * d * d
    for i in range(n):
        di = X[N, i] - xe[i]
        for k in range(n):
            f += di * XT[i, k] * (X[N, k] - xe[k])
    for b in range(U.shape[0]):
        for i in range(U.shape[1]):
            f += wr * sizes[b] * U[b, i] * U[b, i]
    return f


@njit(cache=True, nogil=True)
def gauss_newton(AB, X, U, bos, sizes, xe, wq, wr, XT, want_h, H, g, W, lam, WB, T, T2, M):
    """g (nb·m,) and, when ``want_h``, H (nb·m, nb·m) of the Gauss–Newton QP  min ½δᵀHδ + gᵀδ  in the block
    inputs (module docstring; g is ½∇f; without ``want_h`` H is left as it is).  Work buffers: W (N+1, n, n),
    lam (N+1, n), WB (N, n, m), T and T2 (n, m), M (n, n)."""
    N = bos.shape[0]
    n = X.shape[1]
    m = U.shape[1]
    # the adjoint λ_j, j = N..1, and g_c = B_cᵀ λ_{c+1} + the input weight
    for i in range(n):
        acc = wq * (X[N, i] - xe[i])
        for k in range(n):
            acc += XT[i, k] * (X[N, k] - xe[k])
        lam[N, i] = acc
    for j in range(N - 1, 0, -1):
        for i in range(n):
            acc = wq * (X[j, i] - xe[i])
            for k in range(n):
                acc += AB[j, k, i] * lam[j + 1, k]
            lam[j, i] = acc
    g[:] = 0.0
    for c in range(N):
        for i in range(m):
            acc = 0.0
            for k in range(n):
                acc += AB[c, k, n + i] * lam[c + 1, k]
            g[bos[c] * m + i] += acc
    for b in range(U.shape[0]):
        for i in range(m):
            g[b * m + i] += wr * sizes[b] * U[b, i]
    if not want_h:
        return
    # W_N = Q_N, W_j = w_q I + A_jᵀ W_{j+1} A_j;  WB_d = W_{d+1} B_d
    for i in range(n):
        for k in range(n):
            W[N, i, k] = XT[i, k]
        W[N, i, i] += wq
    for j in range(N - 1, 0, -1):
        for k in range(n):        # M = W_{j+1} A_j
            for l in range(n):
                acc = 0.0
                for p in range(n):
                    acc += W[j + 1, k, p] * AB[j, p, l]
                M[k, l] = acc
        for i in range(n):
            for l in range(n):
                acc = wq if i == l else 0.0
                for k in range(n):
                    acc += AB[j, k, i] * M[k, l]
                W[j, i, l] = acc
    for d in range(N):
        for i in range(n):
            for c in range(m):
                acc = 0.0
                for k in range(n):
                    acc += W[d + 1, i, k] * AB[d, k, n + c]
                WB[d, i, c] = acc
    # H_cd = S_{d+1,c}ᵀ WB_d for c ≤ d, S_{c+1,c} = B_c, S_{d+1,c} = A_d S_{d,c}; summed into the blocks
    H[:, :] = 0.0
    for c in range(N):
        a = bos[c]
        for k in range(n):
            for i in range(m):
                T[k, i] = AB[c, k, n + i]
        for d in range(c, N):
            if d > c:
                for k in range(n):
                    for i in range(m):
                        acc = 0.0
                        for p in range(n):
                            acc += AB[d, k, p] * T[p, i]
                        T2[k, i] = acc
                for k in range(n):
                    for i in range(m):
                        T[k, i] = T2[k, i]
            b = bos[d]
            for i in range(m):
                for l in range(m):
                    acc = 0.0
                    for k in range(n):
                        acc += T[k, i] * WB[d, k, l]
                    H[a * m + i, b * m + l] += acc
                    if d > c:
                        H[b * m + l, a * m + i] += acc
    for b in range(U.shape[0]):
        for i in range(m):
            H[b * m + i, b * m + i] += wr * sizes[b]
