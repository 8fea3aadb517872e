"""A compiled dense primal–dual interior-point QP solver for the LMPC's small QPs:

    min ½xᵀHx + gᵀx   s.t.   Gx ≤ h,   x_l ≤ x ≤ x_u        (H symmetric positive definite; ±inf bounds allowed)

H and G are read row by row: pass them C-contiguous (a transposed view of a symmetric H is H itself).

Mehrotra's predictor–corrector (Nocedal & Wright, *Numerical Optimization*, §16.6) on the inequalities
a_iᵀx + s_i = b_i, s ≥ 0, with multipliers λ ≥ 0.  The bounds are inequalities with a_i = ±e_j, so each Newton
step is one Cholesky factorisation of the reduced matrix M = H + Gᵀ·diag(λ/s)_G·G + diag(λ/s)_bounds (n × n) and
two solves with it.  For the LMPC (n = 21, one row) that is ~3 000 flops per factorisation, and the whole solve is a
few tens of microseconds in one compiled call; PIQP took 90–140 µs per QP on this path, most of it per-iteration
and call overhead (README, "Speed").

Everything is plain loops in a fixed order, no BLAS, and numba without fastmath (no reassociation, no fused
multiply-adds), so a solve's result should not depend on the CPU's vector width or BLAS kernel (reasoned from how
it is compiled; not tested on another CPU).  Statuses: :data:`SOLVED`, :data:`MAX_ITER` (not converged within the iteration
limit), :data:`INFEASIBLE` (the constraints stay violated while the multipliers grow without bound: no x
satisfies them), :data:`NUMERICAL` (the reduced matrix lost positive definiteness, or a non-finite iterate).
"""
from __future__ import annotations

import numpy as np
from numba import njit

SOLVED, MAX_ITER, NUMERICAL, INFEASIBLE = 0, 1, 2, 3
STATUS_NAMES = {SOLVED: "solved", MAX_ITER: "max_iter_reached", NUMERICAL: "numerical_error",
                INFEASIBLE: "primal_infeasible"}
DIVERGED = 1e12      # multipliers this far beyond the data's scale, with the constraints still violated: infeasible
TAU = 0.995          # fraction of the way to the boundary a step may go
SIGMA_SAFE = 0.5     # the centring of the safeguard's step (solve_qp's safeguard; 0.1–0.9 measured alike)


@njit(cache=True)
def _cholesky(M) -> bool:
    """M ← its lower Cholesky factor L (M = LLᵀ; the strict upper triangle is left as is); False if M is not
    positive definite.  The left-looking dot-product form: 1.1 µs at n = 21 here, against 1.9 µs for the
    right-looking form with contiguous axpy updates (too short to pay for vectorising) and 15 µs for
    scipy.linalg.cholesky (call overhead)."""
    n = M.shape[0]
    for j in range(n):
        d = M[j, j]
        for p in range(j):
            d -= M[j, p] * M[j, p]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        M[j, j] = d
        for i in range(j + 1, n):
            v = M[i, j]
            for p in range(j):
                v -= M[i, p] * M[j, p]
            M[i, j] = v / d
    return True


@njit(cache=True)
def _cho_solve(L, r) -> None:
    """r ← (L Lᵀ)⁻¹ r."""
    n = L.shape[0]
    for i in range(n):
        v = r[i]
        for p in range(i):
            v -= L[i, p] * r[p]
        r[i] = v / L[i, i]
    for i in range(n - 1, -1, -1):
        v = r[i]
        for p in range(i + 1, n):
            v -= L[p, i] * r[p]
        r[i] = v / L[i, i]


@njit(cache=True)
def _apply_a(G, idx, sign, x, out) -> None:
    """out ← A x: the rows of G, then sign_j · x[idx_j] for the bound rows."""
    mg, n = G.shape
    for i in range(mg):
        v = 0.0
        for j in range(n):
            v += G[i, j] * x[j]
        out[i] = v
    for q in range(idx.shape[0]):
        out[mg + q] = sign[q] * x[idx[q]]


@njit(cache=True)
def _apply_at(G, idx, sign, v, out) -> None:
    """out ← Aᵀ v."""
    mg, n = G.shape
    for j in range(n):
        out[j] = 0.0
    for i in range(mg):
        vi = v[i]
        if vi != 0.0:
            for j in range(n):
                out[j] += G[i, j] * vi
    for q in range(idx.shape[0]):
        out[idx[q]] += sign[q] * v[mg + q]


@njit(cache=True)
def _factor(H, G, idx, d, M) -> bool:
    """M ← chol(H + Aᵀ diag(d) A) (lower factor, :func:`_cholesky`)."""
    mg, n = G.shape
    for i in range(n):
        for j in range(i + 1):
            M[i, j] = H[i, j]
    for r in range(mg):
        for i in range(n):
            f = d[r] * G[r, i]
            if f != 0.0:
                for j in range(i + 1):
                    M[i, j] += f * G[r, j]
    for q in range(idx.shape[0]):
        M[idx[q], idx[q]] += d[mg + q]
    return _cholesky(M)


@njit(cache=True)
def _newton(G, idx, sign, M, s, lam, rd, rp, rc, dx, ds, dl, w, t) -> None:
    """The Newton step (dx, ds, dλ) of  H dx + Aᵀdλ = −r_d,  A dx + ds = −r_p,  Λ ds + S dλ = −r_c  from the
    factor M of H + Aᵀ(Λ/S)A:  M dx = −r_d + Aᵀ S⁻¹(r_c − Λ r_p),  ds = −r_p − A dx,  dλ = −(r_c + Λ ds)/s."""
    m = s.shape[0]
    for i in range(m):
        w[i] = (rc[i] - lam[i] * rp[i]) / s[i]
    _apply_at(G, idx, sign, w, t)
    for j in range(dx.shape[0]):
        dx[j] = t[j] - rd[j]
    _cho_solve(M, dx)
    _apply_a(G, idx, sign, dx, ds)
    for i in range(m):
        ds[i] = -rp[i] - ds[i]
        dl[i] = -(rc[i] + lam[i] * ds[i]) / s[i]


@njit(cache=True)
def _max_step(v, dv) -> float:
    """The largest α with v + α dv ≥ 0 (inf if dv ≥ 0)."""
    a = np.inf
    for i in range(v.shape[0]):
        if dv[i] < 0.0:
            r = -v[i] / dv[i]
            if r < a:
                a = r
    return a


@njit(cache=True)
def _norm_inf(v) -> float:
    r = 0.0
    for x in v:
        a = abs(x)
        if a > r:
            r = a
    return r


@njit(cache=True)
def solve_qp(H, g, G, h, x_l, x_u, eps, max_iter, x, safeguard=False):
    """Solve the QP into ``x`` (n,).  Returns (status, iterations).  Converged when, with scales taken from the
    iterate, ‖Hx + g + Aᵀλ‖∞ ≤ eps·(1 + max(‖Hx‖∞, ‖g‖∞, ‖Aᵀλ‖∞)), ‖Ax + s − b‖∞ ≤ eps·(1 + max(‖Ax‖∞, ‖b‖∞))
    and the duality gap sᵀλ ≤ eps·(1 + |gᵀx| + xᵀHx) (PIQP's tests with eps_abs = eps_rel = eps).

    ``safeguard``: once the iterate is primal and dual feasible (to eps), a corrector step that would raise the
    duality gap is replaced by a centring step (σ = :data:`SIGMA_SAFE`, without Mehrotra's second-order term).
    Plain Mehrotra can cycle there: on 6 of 25 052 LMPC QPs (Duffing and the tight Van der Pol preset, a slack
    costing 1e4 against moves costing 0.05) the gap rose and fell in a loop of four iterations until max_iter;
    safeguarded, each was solved in 17–24 iterations, within 4e-7 of PIQP (tests/test_ipm.py).  DenseQp solves
    without it first and again with it only after MAX_ITER, so every QP the plain method solves keeps its
    iterates bit for bit."""
    n = H.shape[0]
    mg = G.shape[0]
    nb = 0
    for j in range(n):
        nb += np.isfinite(x_l[j]) + np.isfinite(x_u[j])
    idx = np.empty(nb, np.int64)
    sign = np.empty(nb)
    m = mg + nb
    b = np.empty(m)
    for i in range(mg):
        b[i] = h[i]
    q = 0
    for j in range(n):
        if np.isfinite(x_l[j]):
            idx[q], sign[q], b[mg + q] = j, -1.0, -x_l[j]
            q += 1
        if np.isfinite(x_u[j]):
            idx[q], sign[q], b[mg + q] = j, 1.0, x_u[j]
            q += 1
    M = np.empty((n, n))
    s, lam, d = np.ones(m), np.ones(m), np.empty(m)
    rp, rc, ds, dl, w, ax = np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    rd, dx, t, hx, atl = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    # start: x in the box (0 where allowed), s = λ = 1, then Mehrotra's shift of the affine step (N&W §16.6)
    for j in range(n):
        x[j] = min(max(0.0, x_l[j]), x_u[j])
    for it in range(max_iter + 1):
        # residuals (Hx as a sum of H's rows: H is symmetric)
        for i in range(n):
            hx[i] = 0.0
        for j in range(n):
            xj = x[j]
            for i in range(n):
                hx[i] += H[j, i] * xj
        _apply_at(G, idx, sign, lam, atl)
        _apply_a(G, idx, sign, x, ax)
        gap = 0.0
        for i in range(m):
            rp[i] = ax[i] + s[i] - b[i]
            gap += s[i] * lam[i]
        mu = gap / m if m > 0 else 0.0
        xhx, gx = 0.0, 0.0
        for j in range(n):
            rd[j] = hx[j] + g[j] + atl[j]
            xhx += x[j] * hx[j]
            gx += g[j] * x[j]
        if it > 0:
            if not (np.isfinite(mu) and np.isfinite(xhx)):
                return NUMERICAL, it
            dual_ok = _norm_inf(rd) <= eps * (1.0 + max(_norm_inf(hx), _norm_inf(g), _norm_inf(atl)))
            primal_ok = _norm_inf(rp) <= eps * (1.0 + max(_norm_inf(ax), _norm_inf(b)))
            if dual_ok and primal_ok and gap <= eps * (1.0 + abs(gx) + abs(xhx)):
                return SOLVED, it
            if it == max_iter:
                return MAX_ITER, it
            if not primal_ok and _norm_inf(lam) > DIVERGED * (1.0 + _norm_inf(g) + _norm_inf(hx)):
                return INFEASIBLE, it
        for i in range(m):
            d[i] = lam[i] / s[i]
        if not _factor(H, G, idx, d, M):
            return NUMERICAL, it
        # predictor (affine scaling)
        for i in range(m):
            rc[i] = s[i] * lam[i]
        _newton(G, idx, sign, M, s, lam, rd, rp, rc, dx, ds, dl, w, t)
        if it == 0:   # the starting point: the affine step's s and λ, moved away from zero
            for j in range(n):
                x[j] += dx[j]
            for i in range(m):
                s[i] = max(1.0, abs(s[i] + ds[i]))
                lam[i] = max(1.0, abs(lam[i] + dl[i]))
            continue
        a = min(1.0, _max_step(s, ds), _max_step(lam, dl))
        gap_aff = 0.0
        for i in range(m):
            gap_aff += (s[i] + a * ds[i]) * (lam[i] + a * dl[i])
        sigma = (gap_aff / gap) ** 3 if gap > 0.0 else 0.0
        # corrector: centring σμ and the second-order term ds∘dλ of the predictor
        for i in range(m):
            rc[i] = s[i] * lam[i] + ds[i] * dl[i] - sigma * mu
        _newton(G, idx, sign, M, s, lam, rd, rp, rc, dx, ds, dl, w, t)
        a = min(1.0, TAU * min(_max_step(s, ds), _max_step(lam, dl)))
        if safeguard and dual_ok and primal_ok:
            gap_new = 0.0
            for i in range(m):
                gap_new += (s[i] + a * ds[i]) * (lam[i] + a * dl[i])
            if gap_new > gap:   # the corrector would raise the gap of a feasible iterate: a centring step instead
                for i in range(m):
                    rc[i] = s[i] * lam[i] - SIGMA_SAFE * mu
                _newton(G, idx, sign, M, s, lam, rd, rp, rc, dx, ds, dl, w, t)
                a = min(1.0, TAU * min(_max_step(s, ds), _max_step(lam, dl)))
        for j in range(n):
            x[j] += a * dx[j]
        for i in range(m):
            s[i] += a * ds[i]
            lam[i] += a * dl[i]
    return MAX_ITER, max_iter
