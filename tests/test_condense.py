"""The compiled condensing (kexp.control.condense) against the per-step reference kernel and dense numpy products,
the per-block cut of the ZOH polynomial against scipy's exponential, and the LMPC's one-row (21e) QP against the
QP with all Np rows."""
import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla

from kexp.control import Lmpc, LmpcConfig
from kexp.control.blocking import block_of_step, block_sizes
from kexp.control.condense import block_maps_poly, linearised_vmax, rows_hold
from kexp.control.kernels import poly_degree, rollout_sensitivity
from kexp.control.qp import DenseQp
from kexp.control.zoh_poly import zoh_polynomial
from test_lmpc import condensed, vdp, with_inputs  # noqa: F401 - vdp: the Van der Pol model, CLF and law


@pytest.mark.parametrize("m", [1, 2])
@pytest.mark.parametrize("use_c", [False, True])
def test_condense_equals_the_reference_products(vdp, m, use_c):
    """Rollout, sensitivities, H, g and the (21e) rows from the one-pass kernel equal the per-step Van Loan
    reference kernel with the dense products written out in numpy (H = 2Δw·Σ Y_jᵀY_j + diag, g = 2Δw·Σ Y_jᵀ(y_j −
    Y_j ub), with a terminal cost w_T·V(z_Np); rows 2 z_jᵀP S_j, h = r̂ − V(z_j) + rows·ub), relative to each
    array's size: measured ≤ 1e-14; asserted 1e-12.  One input from the cut ZOH polynomial, two from the
    exponential; a cost on z and on x = Cz."""
    _, model, clf, _ = vdp
    rng = np.random.default_rng(11)
    lam, B, b = with_inputs(model, m, rng)
    C = np.ascontiguousarray(model.C)
    P = np.ascontiguousarray(clf.P)
    zp = zoh_polynomial(lam, B, b, model.dt, 5.0) if m == 1 else None
    bos = block_of_step(block_sizes(100, 5, 20))
    for scale in (1.0, 0.05):
        U = rng.uniform(-5, 5, (20, m)) * scale
        z0 = model.lift(rng.uniform(-1.5, 1.5, 2))
        out, rdiag = condensed(lam, B, b, model.dt, z0, U, bos, C if use_c else np.zeros((1, model.k)), use_c,
                                   P, zp)
        Z0, S0 = rollout_sensitivity(lam, B, b, model.dt, z0, U, bos)      # S0 (Np+1, k, nu)
        ub = U.reshape(-1)
        Ys = S0[1:] if not use_c else np.einsum("pk,jkc->jpc", C, S0[1:])
        ys = Z0[1:] if not use_c else Z0[1:] @ C.T
        HS = np.einsum("jpc,jpd->cd", Ys, Ys)
        sn = S0[-1]                               # (k, nu): the terminal cost 0.7·V(z_Np)
        H = 0.02 * HS + np.diag(rdiag) + 1.4 * sn.T @ P @ sn
        g = 0.02 * np.einsum("jpc,jp->c", Ys, ys - np.einsum("jpc,c->jp", Ys, ub)) + 1.4 * sn.T @ P @ (Z0[-1]
                                                                                                       - sn @ ub)
        rows = 2 * np.einsum("jk,jkc->jc", Z0[1:] @ P, S0[1:])
        V = np.sum((Z0[1:] @ P) * Z0[1:], 1)

        def rel(a, ref):
            return np.max(np.abs(a - ref)) / np.max(np.abs(ref))

        assert rel(out["Z"], Z0) <= 1e-12
        assert rel(out["S"].transpose(1, 2, 0), S0) <= 1e-12
        assert rel(out["H"][:-1, :-1], H) <= 1e-12
        assert rel(out["g"][:-1], g) <= 1e-12
        assert rel(out["rows"], rows) <= 1e-12
        assert rel(out["Vbar"], V) <= 1e-12
        assert rel(out["h_rows"], 1.5 - V + rows @ ub) <= 1e-12
        first = np.repeat(np.concatenate([[0], np.flatnonzero(np.diff(bos)) + 1]), m)
        for c in range(ub.size):                   # causality: nothing before a column's block starts
            assert not out["S"][c, : first[c] + 1].any()


def test_polynomial_cut_per_block_is_the_exponential(vdp):
    """block_maps_poly cuts the ZOH polynomial where a block's |u| lets it (the dropped terms below 2⁻⁵⁴ of the
    map's size): E and dE/du still equal scipy's exponential and the Van Loan derivative to rounding (asserted
    1e-13 relative) at every input size.  The coefficients' norms fall much faster than the a-priori bound that
    fixes the polynomial's degree (19 here): measured 7 terms at |u| = ρ, 5 at |u| = 0.02, 1 at u = 0."""
    _, model, _, _ = vdp
    lam, B, b = (np.ascontiguousarray(a) for a in (model.Lambda, model.B, model.b))
    zp = zoh_polynomial(lam, B, b, model.dt, 5.0)
    k, n = model.k, model.k + 1
    X = np.zeros((n, n))
    X[:k, :k] = model.Lambda * model.dt
    Yb = np.zeros((n, n))
    Yb[:k, :k] = model.B[0] * model.dt
    Yb[:k, k] = model.b[0] * model.dt
    us = np.array([0.0, 1e-4, 0.02, -0.3, 1.0, -2.5, 5.0])
    E, L = np.zeros((len(us), n, n)), np.zeros((len(us), 1, n, n))
    block_maps_poly(zp.coef, zp.norms, zp.rho, lam, B, b, model.dt, us[:, None], E, L)
    degrees = [poly_degree(zp.norms, u / zp.rho, zp.degree) for u in us]
    for i, u in enumerate(us):
        big = sla.expm(np.block([[X + u * Yb, Yb], [np.zeros((n, n)), X + u * Yb]]))
        ref_e, ref_l = big[:n, :n], big[:n, n:]
        assert np.max(np.abs(E[i] - ref_e)) <= 1e-13 * np.max(np.abs(ref_e))
        assert np.max(np.abs(L[i, 0] - ref_l)) <= 1e-13 * np.max(np.abs(ref_l))
    assert degrees[0] == 1 and degrees[-1] <= zp.degree // 2
    assert np.all(np.diff(np.array(degrees)[np.argsort(np.abs(us))]) >= 0)     # fewer terms for smaller |u|


def _full_qp_plan(ctrl, z0):
    """The step's QP with all Np (21e) rows, condensed in numpy from the reference kernel and solved by a fresh
    PIQP problem: the plan (vec U) it returns."""
    model, cfg = ctrl.model, ctrl.cfg
    Ub = ctrl._blocks_from_steps(ctrl._useq)
    ub = Ub.reshape(-1)
    Z0, S0 = rollout_sensitivity(ctrl.lam, ctrl.B, ctrl.b, model.dt, z0, Ub, ctrl.bos)
    Sj = S0[1:]
    nu = ctrl.nu
    H = np.zeros((nu + 1, nu + 1))
    H[:nu, :nu] = 2 * model.dt * cfg.w * np.einsum("jkc,jkd->cd", Sj, Sj) + np.diag(2 * model.dt * ctrl.r_diag)
    H[-1, -1] = 2 * cfg.slack_weight
    c_lin = Z0[1:] - np.einsum("jkc,c->jk", Sj, ub)
    g = np.concatenate([2 * model.dt * cfg.w * np.einsum("jkc,jk->c", Sj, c_lin), [cfg.slack_weight]])
    zP = Z0[1:] @ ctrl.P
    rows = 2 * np.einsum("jk,jkc->jc", zP, Sj)
    G = np.hstack([rows, -np.ones((len(rows), 1))])
    h = ctrl.clf.r_hat - np.sum(zP * Z0[1:], 1) + rows @ ub
    res = DenseQp(nu + 1, len(rows)).solve(H, g, G, h, ctrl.x_l, ctrl.x_u)
    assert res.success
    return res.x[:nu], bool(np.any(G @ res.x - h >= -1e-4 * np.maximum(1, np.abs(h))))


def test_one_row_qp_is_the_full_qp(vdp):
    """Inside Ω_r̂ the LMPC solves a QP with the one (21e) row of least margin and checks its solution against all
    Np rows, solving with all of them only if one is violated.  Its first input equals that of the QP with all Np
    rows solved directly (to the QP's tolerance): with the working r̂ (no row near binding, the one-row QP
    suffices) and with r̂ shrunk to V(z0) at a state where every admissible input (u ∈ [4.99, 5]) raises V, so rows
    bind (the full QP is solved)."""
    _, model, clf, h = vdp
    rng = np.random.default_rng(2)
    cand = rng.uniform(-0.2, 0.2, (400, 2))
    x0s = cand[clf.lyap.value(model.lift(cand)) < 0.9 * clf.r_hat][:4]
    assert len(x0s) == 4
    for x0 in x0s:
        z0 = model.lift(x0)
        ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
        ref, binding = _full_qp_plan(ctrl, z0)
        st = ctrl.step(x0, z0)
        assert st.active == "21e" and not binding
        assert ctrl.qp_e.solves == 0               # the one-row QP sufficed
        assert abs(st.u[0] - ref[0]) <= 1e-6
    # r̂ = V(z0) at a state whose admissible inputs all raise V: rows bind, the one-row solution violates others
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=1) > 0]
    zs = model.lift(grid)
    a, beta = clf.lyap.lie(zs)
    j = int(np.argmax((a + 4.99 * beta[:, 0]) / clf.lyap.value(zs)))
    V0 = float(clf.lyap.value(zs[j]))
    tight = dataclasses.replace(clf, certificate=dataclasses.replace(clf.certificate, r=10 * V0, r_hat=V0))
    with pytest.warns(UserWarning, match="differ from the controller's"):   # on purpose: force a (21e) slack
        ctrl = Lmpc(model, tight, h, LmpcConfig(), 4.99, 5.0)
    ref, binding = _full_qp_plan(ctrl, zs[j])
    st = ctrl.step(grid[j], zs[j])
    assert st.active == "21e" and binding
    assert ctrl.qp_e.solves == 1                   # the full QP was needed and solved
    assert abs(st.u[0] - ref[0]) <= 1e-6


def test_row_check_and_linearised_vmax_are_the_numpy_formulas(vdp):
    """rows_hold is all(rows·U − s − h ≤ tol·max(1, |h|)); linearised_vmax is max_j V(z̄_j + S_j du), j ≥ 1, as
    lyap.value computes V (to 1e-12 relative)."""
    _, model, clf, _ = vdp
    rng = np.random.default_rng(4)
    rows, h = rng.normal(size=(30, 6)), rng.normal(size=30)
    seen = set()
    for i in range(40):
        # the slack puts the worst row 1e-9 inside or outside its tolerance, so both answers occur, at the boundary
        x = rng.normal(size=7)
        tol = float(rng.choice([0.0, 1e-8, 1.0]))
        excess = rows @ x[:6] - h - tol * np.maximum(1, np.abs(h))
        x[6] = excess.max() + (1e-9 if i % 2 else -1e-9)
        expected = bool(np.all(rows @ x[:6] - x[6] - h <= tol * np.maximum(1, np.abs(h))))
        assert expected == bool(i % 2)
        assert rows_hold(rows, h, x, tol) == expected
        seen.add((tol, expected))
    assert {e for _, e in seen} == {True, False} and len({t for t, _ in seen}) == 3
    lam, B, b = (np.ascontiguousarray(a) for a in (model.Lambda, model.B, model.b))
    bos = block_of_step(block_sizes(40, 5, 10))
    U = rng.uniform(-2, 2, (10, 1))
    z0 = model.lift(np.array([0.3, -0.4]))
    Z0, S0 = rollout_sensitivity(lam, B, b, model.dt, z0, U, bos)
    first = np.concatenate([[0], np.flatnonzero(np.diff(bos)) + 1]).astype(np.int64)
    S = np.ascontiguousarray(S0.transpose(2, 0, 1))
    du = rng.normal(size=10) * 0.1
    ref = float(np.max(clf.lyap.value(Z0[1:] + np.einsum("jkc,c->jk", S0[1:], du))))
    got = linearised_vmax(Z0, S, du, np.ascontiguousarray(clf.P), first, np.zeros(model.k), np.zeros(model.k))
    assert abs(got - ref) <= 1e-12 * ref


def test_the_21e_rows_bound_V_by_r_hat_not_r(vdp):
    """Inside Ω_r̂ the (21e) rows linearise V(z_j) ≤ r̂ + s at the guess: rows_j = 2 z̄_jᵀP S_j and right-hand side
    r̂ − V(z̄_j) + rows_j·ū (the numpy reference of :func:`_full_qp_plan`).  The CLF's r and r̂ differ (by 40 % of
    r̂ and more here), so a right-hand side built on r is off by r − r̂ in every row."""
    _, model, clf, h = vdp
    assert clf.r - clf.r_hat > 0.4 * clf.r_hat
    rng = np.random.default_rng(7)
    cand = rng.uniform(-0.3, 0.3, (400, 2))
    x0s = cand[clf.lyap.value(model.lift(cand)) < 0.9 * clf.r_hat][:3]
    assert len(x0s) == 3
    for x0 in x0s:
        ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
        z0 = model.lift(x0)
        Ub = ctrl._blocks_from_steps(ctrl._useq) + rng.uniform(-0.5, 0.5, (len(ctrl.sizes), model.m))
        ub = Ub.reshape(-1)
        G, h_u = ctrl._qp_data(z0, np.ascontiguousarray(Ub), "21e", 0.0, np.zeros(model.m))[2:]
        Z0, S0 = rollout_sensitivity(ctrl.lam, ctrl.B, ctrl.b, model.dt, z0, Ub, ctrl.bos)
        zP = Z0[1:] @ ctrl.P
        rows = 2 * np.einsum("jk,jkc->jc", zP, S0[1:])
        V = np.sum(zP * Z0[1:], 1)
        ref = clf.r_hat - V + rows @ ub
        scale = np.max(np.abs(ref))
        assert np.max(np.abs(ctrl._rows - rows)) <= 1e-9 * np.max(np.abs(rows))
        assert np.max(np.abs(ctrl._h_rows - ref)) <= 1e-9 * scale
        assert clf.r - clf.r_hat > 1e6 * 1e-9 * scale        # r in place of r̂ would be far outside the tolerance
        j = int(np.argmax(V))             # the QP's one row: the row of least margin, V(z̄_j) ≤ r̂ + s
        assert np.array_equal(G[0, :-1], ctrl._rows[j]) and G[0, -1] == -1.0 and h_u[0] == ctrl._h_rows[j]
