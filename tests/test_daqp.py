"""DAQP as the LMPC's QP solver (``qp_solver='daqp'``, :class:`kexp.control.qp.DenseQp`): its solutions against
kexp's interior point, PIQP and QPs of known solution, checked by KKT residuals computed here; the warm start; its
statuses; and a closed loop against the interior point's."""
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import nnls

from kexp.control import Lmpc, LmpcConfig
from kexp.control.qp import DenseQp
from kexp.errors import ConfigError
from kexp.simulate import SimConfig, closed_loop

from test_lmpc import vdp  # noqa: F401   the benchmark problem's model, CLF and h (a module fixture)


def _committed_qps():
    """Six real LMPC QPs (tests/data/ipm_cycling_qps.npz: 20 moves and the (21e) slack; H symmetric)."""
    d = np.load(Path(__file__).parent / "data" / "ipm_cycling_qps.npz")
    return [tuple(d[f"{k}_{i}"] for k in ("H", "g", "G", "h", "x_l", "x_u")) for i in range(6)]


def _kkt(qp, x, tol):
    """(stationarity ‖Hx + g + Aᵀλ‖∞ with λ ≥ 0 fitted by NNLS on the constraints active within tol, largest
    violation, the active bound indices): independent of any solver's multipliers."""
    H, g, G, h, xl, xu = qp
    n = len(x)
    rows, act = [], []
    r = G @ x - h
    rows += [G[i] for i in range(len(h)) if r[i] >= -tol]
    for j in range(n):
        if np.isfinite(xl[j]) and x[j] <= xl[j] + tol:
            rows.append(-np.eye(n)[j])
            act.append(j)
        elif np.isfinite(xu[j]) and x[j] >= xu[j] - tol:
            rows.append(np.eye(n)[j])
            act.append(j)
    grad = H @ x + g
    if rows:
        A = np.array(rows)
        lam, _ = nnls(A.T, -grad)
        grad = grad + A.T @ lam
    viol = max(float(np.max(r, initial=0.0)), float(np.max(xl - x)), float(np.max(x - xu)))
    return float(np.max(np.abs(grad))), viol, act


def _f(qp, x):
    return 0.5 * x @ qp[0] @ x + qp[1] @ x


def test_daqp_solves_the_committed_lmpc_qps_exactly_and_no_worse_than_ipm_or_piqp():
    """On the six real QPs DAQP's answer is feasible to 1e-9 and stationary to 1e-9 × the gradient's scale (the
    slack's weight 1e4 sets it; an active-set solution solves its KKT system to rounding, cond(H) ~1e6 here), with
    an input at a bound exactly on it; its objective is no worse than the IPM's or PIQP's (theirs stop ~1e-6 inside
    active bounds: a larger objective, by ≤ 1e-6 relative)."""
    for qp in _committed_qps():
        H = qp[0]
        res = {s: DenseQp(21, 1, solver=s).solve(np.asfortranarray(H), *qp[1:]) for s in ("daqp", "ipm", "piqp")}
        assert all(r.success and r.status == "solved" for r in res.values()), {s: r.status for s, r in res.items()}
        x = res["daqp"].x
        scale = max(1.0, float(np.max(np.abs(qp[1]))))
        stat, viol, act = _kkt(qp, x, 1e-9)
        assert viol <= 1e-9 and stat <= 1e-9 * scale, (stat, viol)
        for j in act:                          # exactly on the bound it holds active
            assert x[j] in (qp[4][j], qp[5][j])
        for s in ("ipm", "piqp"):
            fd, fs = _f(qp, x), _f(qp, res[s].x)
            assert fd <= fs + 1e-12 * max(1.0, abs(fs))
            assert fs - fd <= 1e-6 * max(1.0, abs(fd))


def _known_qp(rng, n=12, m_rows=2):
    """A random strictly convex QP whose solution x* is known by construction: some inputs at a bound with a
    positive multiplier, one row active, the rest strictly inside; g = −Hx* − Aᵀλ."""
    Q = rng.standard_normal((n, n))
    H = Q @ Q.T + np.eye(n)
    xl, xu = -np.ones(n), np.ones(n)
    x = rng.uniform(-0.5, 0.5, n)
    idx = rng.choice(n, 4, replace=False)
    lo, hi = idx[:2], idx[2:]
    x[lo], x[hi] = -1.0, 1.0
    G = rng.standard_normal((m_rows, n))
    h = G @ x + np.array([0.0] + [0.5] * (m_rows - 1))      # row 0 active, the others inside by 0.5
    grad = np.zeros(n)
    grad[lo] -= rng.uniform(0.5, 2.0, 2)                     # −λ for x ≥ xl (its row is −e_j)
    grad[hi] += rng.uniform(0.5, 2.0, 2)
    grad += rng.uniform(0.5, 2.0) * G[0]
    g = -H @ x - grad
    return (H, g, G, h, xl, xu), x


def test_daqp_finds_the_known_solution_of_random_qps_with_active_bounds():
    """x* is the unique minimiser (strict complementarity by construction): DAQP returns it to 1e-9 (the KKT
    system's condition number ≤ ~1e3 for these H, times rounding ~1e-15, with room for the active set's
    factorisation); the IPM's answer is within 1e-5 (it ends ~sqrt(eps)·scale inside the active bounds)."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        qp, xs = _known_qp(rng)
        r = DenseQp(12, 2, solver="daqp").solve(*qp)
        assert r.success and r.status == "solved"
        assert np.max(np.abs(r.x - xs)) <= 1e-9
        ri = DenseQp(12, 2, solver="ipm").solve(*qp)
        assert ri.success and np.max(np.abs(ri.x - xs)) <= 1e-5


def test_the_warm_start_gives_the_cold_start_solution():
    """One DenseQp solving the committed QPs in order (each from the previous active set: fewer iterations) returns
    what a fresh one returns for each, to 1e-12 relative: the same active set, the same KKT system."""
    qps = _committed_qps()
    warm = DenseQp(21, 1, solver="daqp")
    iters_warm, iters_cold = [], []
    for qp in qps + qps:
        H = np.asfortranarray(qp[0])
        rw = warm.solve(H, *qp[1:])
        rc = DenseQp(21, 1, solver="daqp").solve(H, *qp[1:])
        assert rw.success and rc.success
        assert np.max(np.abs(rw.x - rc.x)) <= 1e-12 * max(1.0, float(np.max(np.abs(rc.x))))
        iters_warm.append(rw.iterations)
        iters_cold.append(rc.iterations)
    assert iters_warm[len(qps):] == [1] * len(qps) or sum(iters_warm[len(qps):]) < sum(iters_cold[len(qps):])


def test_an_infeasible_qp_returns_a_status_and_the_next_solve_starts_afresh():
    qp = DenseQp(3, 1, solver="daqp")
    H, g, xl, xu = np.eye(3), np.zeros(3), -np.ones(3), np.ones(3)
    bad = qp.solve(H, g, np.ones((1, 3)), np.array([-5.0]), xl, xu)    # Σx ≤ −5 with x ≥ −1: empty
    assert bad is not None and not bad.success and bad.status == "primal_infeasible"
    assert bad.message == "DAQP: primal_infeasible"
    good = qp.solve(H, np.array([1.0, -3.0, 0.0]), np.ones((1, 3)), np.array([0.5]), xl, xu)
    assert good.success and np.allclose(good.x, [-1.0, 1.0, 0.0], atol=1e-12)
    nan = qp.solve(np.full((3, 3), np.nan), g, np.ones((1, 3)), np.ones(1), xl, xu)
    assert not nan.success and nan.status.startswith("invalid_input") and "H" in nan.message


def test_the_solver_setting_is_validated():
    with pytest.raises(ConfigError, match=r"qp_solver='daqpp'.*'daqp'"):
        LmpcConfig(qp_solver="daqpp")
    with pytest.raises(ConfigError, match="valid"):
        DenseQp(3, 1, solver="DAQP")
    assert LmpcConfig(qp_solver="daqp").qp_solver == "daqp"


def test_closed_loop_with_daqp_stabilises_and_applies_the_ipms_inputs(vdp):
    """The benchmark problem's LMPC (horizon 100, 20 blocks) from the design study's first x0 for 8 s: every QP
    solved by DAQP, the state driven into a 0.1-ball, and the inputs those of the interior point within 1e-4 (the
    IPM's solution ends ~1e-6 inside active bounds; 3.1e-6 measured over 5 s; the closed loop is contracting, so
    the difference does not grow)."""
    s, model, clf, h = vdp
    x0 = np.random.default_rng(42).uniform(-1, 1, (2, 100)).T[0]
    runs = {}
    for solver in ("ipm", "daqp"):
        ctrl = Lmpc(model, clf, h, LmpcConfig(qp_solver=solver), -5.0, 5.0)
        runs[solver] = closed_loop(s, ctrl, x0, SimConfig(T=8.0), model=model, lyap=clf.lyap)
    recs = runs["daqp"].records
    assert all(r.qp_status == "solved" and not r.fallback for r in recs)
    print(np.linalg.norm(runs["daqp"].x, axis=1)[::40], np.abs(runs["daqp"].u - runs["ipm"].u).max())
    assert np.max(np.abs(runs["daqp"].x[-1])) <= 0.1
    du = np.max(np.abs(runs["daqp"].u - runs["ipm"].u))
    assert du <= 1e-4, du


def test_changed_bounds_reach_the_warm_started_solver():
    """The same DenseQp with the bounds narrowed, then widened again: each answer is the clipped unconstrained
    minimiser of its own bounds (H = I: the projection is exact), not the previous bounds'."""
    qp = DenseQp(3, 1, solver="daqp")
    H, g, G, h = np.eye(3), np.array([-2.0, 0.3, 2.0]), np.zeros((1, 3)), np.ones(1)
    for b in (1.0, 0.5, 1.0, 0.25):
        r = qp.solve(H, g, G, h, -b * np.ones(3), b * np.ones(3))
        assert r.success and np.array_equal(r.x, np.clip(-g, -b, b)), (b, r.x)


def test_binding_needs_no_interior_point_margin_on_the_daqp_path(vdp):
    """iterate_when='binding': an input 1e-5 of its range inside a bound counts as binding for the interior point
    (its margin 1e-3: it stops short of active bounds) but not for DAQP, whose active bounds are met exactly; an
    input on the bound binds for both, and an interior plan binds for neither."""
    _, model, clf, h = vdp
    ctrls = {s: Lmpc(model, clf, h, LmpcConfig(qp_solver=s, iterate_when="binding", max_iter=3), -5.0, 5.0)
             for s in ("ipm", "daqp")}
    nb, m = ctrls["ipm"].nb, ctrls["ipm"].m
    x = np.zeros(nb * m + 1)
    for u0, want in ((-5.0 + 1e-4, {"ipm": True, "daqp": False}), (-5.0, {"ipm": True, "daqp": True}),
                     (0.3, {"ipm": False, "daqp": False})):
        U = np.full((nb, m), 0.1)
        U[2, 0] = u0
        for s, c in ctrls.items():
            assert c._qp_binds(x, U, "none", np.zeros(m), 0.0) == want[s], (s, u0)
