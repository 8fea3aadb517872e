"""kexp's compiled interior-point QP solver (kexp.control.ipm): exact answers where they are known in closed form,
the KKT conditions on random QPs, agreement with PIQP, infeasibility, and bit-identical repeats."""
import numpy as np
import piqp
import pytest
from scipy.optimize import nnls

from kexp.control.ipm import SOLVED, STATUS_NAMES, solve_qp
from kexp.control.qp import DenseQp


def random_qp(rng, n, mg, *, infinite=0.2):
    A = rng.normal(size=(n, n))
    H = A @ A.T + 0.1 * np.eye(n)
    g = 3 * rng.normal(size=n)
    G = rng.normal(size=(mg, n))
    h = rng.normal(size=mg) + 1.0
    x_l, x_u = -rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
    x_l[rng.random(n) < infinite] = -np.inf
    x_u[rng.random(n) < infinite] = np.inf
    return H, g, G, h, x_l, x_u


def kkt(H, g, G, h, x_l, x_u, x):
    """Stationarity with non-negative multipliers on the constraints within 1e-5 of active (NNLS: an interior point
    ends inside its active constraints by ~gap/λ), and the primal violation: both zero at a solution."""
    act_g = G @ x - h >= -1e-5
    act_l, act_u = x - x_l <= 1e-5, x_u - x <= 1e-5
    A = np.vstack([G[act_g], -np.eye(len(x))[act_l], np.eye(len(x))[act_u]])
    grad = H @ x + g
    stat = nnls(A.T, -grad)[1] if len(A) else np.linalg.norm(grad)
    viol = max(np.max(G @ x - h, initial=0.0), np.max(x_l - x), np.max(x - x_u))
    return stat, viol


def test_box_qp_with_diagonal_hessian_is_clipped_newton_step():
    """min ½Σ d_i x_i² + g_i x_i on a box: x_i = clip(−g_i/d_i, l_i, u_i) (strictly active bounds).  An interior
    point ends inside an active bound by its slack s_i ≤ sᵀλ/λ_i, and it stops once the gap sᵀλ ≤ eps·(1 + |gᵀx| +
    xᵀHx): that bound, with λ_i = |g_i + d_i x_i| known here, is the tolerance (free entries: 1e-9)."""
    rng = np.random.default_rng(1)
    n = 21
    d = rng.uniform(0.05, 2e4, n)          # the LMPC's spread: input weights ~0.1, slack weight 2e4
    g = rng.normal(size=n) * d * 2.0       # unconstrained minima at |x| ~ 2: about half outside [−1, 1]
    g[np.abs(g / d) - 1.0 < 0.05] *= 3.0   # no bound weakly active (degenerate)
    x_l, x_u = -np.ones(n), np.ones(n)
    x = np.empty(n)
    status, iters = solve_qp(np.diag(d), g, np.zeros((0, n)), np.zeros(0), x_l, x_u, 1e-10, 100, x)
    assert status == SOLVED and iters <= 15
    exact = np.clip(-g / d, -1.0, 1.0)
    gap = 1e-10 * (1 + abs(g @ x) + x @ (d * x))
    lam = np.abs(g + d * exact)
    tol = np.where(np.abs(exact) == 1.0, gap / np.maximum(lam, 1e-300), 1e-9)
    assert np.all(np.abs(x - exact) <= tol), np.abs(x - exact) / tol
    assert np.max(np.abs(x - exact)) < 1e-7


def test_equality_like_row_gives_the_projection():
    """min ½‖x − c‖² s.t. aᵀx ≤ β with aᵀc > β: x = c − (aᵀc − β)/‖a‖² · a."""
    rng = np.random.default_rng(2)
    n = 8
    c, a = rng.normal(size=n), rng.normal(size=n)
    beta = a @ c - 1.0
    x = np.empty(n)
    inf = np.full(n, np.inf)
    status, _ = solve_qp(np.eye(n), -c, a[None, :], np.array([beta]), -inf, inf, 1e-10, 100, x)
    assert status == SOLVED
    np.testing.assert_allclose(x, c - (a @ c - beta) / (a @ a) * a, rtol=0, atol=1e-9)


def test_random_qps_meet_kkt_and_agree_with_piqp():
    """300 random strictly convex QPs (2–24 variables, 0–5 rows, some infinite bounds): every feasible one solved in
    ≤ 20 iterations, KKT residuals ≤ 1e-6 of ‖g‖, the objective no worse than PIQP's (eps 1e-11) by 1e-9 relative and
    within 1e-7 of it (PIQP's was the higher one by up to 6e-9 where they differ); every one PIQP calls infeasible
    is reported infeasible."""
    rng = np.random.default_rng(0)
    solved = infeasible = 0
    for _ in range(300):
        n, mg = int(rng.integers(2, 25)), int(rng.integers(0, 6))
        H, g, G, h, x_l, x_u = random_qp(rng, n, mg)
        x = np.empty(n)
        status, iters = solve_qp(H, g, G, h, x_l, x_u, 1e-10, 100, x)
        ref = piqp.DenseSolver()
        ref.settings.eps_abs = ref.settings.eps_rel = 1e-11
        ref.settings.verbose = False
        ref.setup(np.asfortranarray(H), g, None, None, np.asfortranarray(G), np.full(mg, -np.inf), h, x_l, x_u)
        ref_status = ref.solve()
        if ref_status == piqp.PIQP_PRIMAL_INFEASIBLE:
            assert STATUS_NAMES[status] == "primal_infeasible", (n, mg, STATUS_NAMES[status])
            infeasible += 1
            continue
        assert ref_status == piqp.PIQP_SOLVED
        assert status == SOLVED and iters <= 20, (STATUS_NAMES[status], iters)
        stat, viol = kkt(H, g, G, h, x_l, x_u, x)
        assert stat <= 1e-6 * (1 + np.abs(g).max()) and viol <= 1e-9, (stat, viol)
        f = lambda v: 0.5 * v @ H @ v + g @ v   # noqa: E731
        f_ref = f(np.array(ref.result.x))
        assert f(x) <= f_ref + 1e-9 * (1 + abs(f_ref)) and abs(f(x) - f_ref) <= 1e-7 * (1 + abs(f_ref))
        solved += 1
    assert solved > 250 and infeasible >= 2        # both kinds really occurred


def test_infeasible_box_and_row_is_reported_not_solved():
    """x ≥ 1 and x₁ + x₂ ≤ 0 cannot both hold."""
    x = np.empty(2)
    status, _ = solve_qp(np.eye(2), np.zeros(2), np.ones((1, 2)), np.zeros(1), np.ones(2), np.full(2, 5.0),
                         1e-8, 100, x)
    assert STATUS_NAMES[status] == "primal_infeasible"


def test_iteration_limit_is_a_status_and_repeats_are_bit_identical():
    rng = np.random.default_rng(3)
    H, g, G, h, x_l, x_u = random_qp(rng, 21, 1, infinite=0.0)
    qp = DenseQp(21, 1, eps=1e-8, max_iter=2, solver="ipm")
    r = qp.solve(H, g, G, h, x_l, x_u)
    assert not r.success and r.status == "max_iter_reached" and "interior point" in r.message
    qp = DenseQp(21, 1, solver="ipm")
    a, b = qp.solve(H, g, G, h, x_l, x_u), qp.solve(H, g, G, h, x_l, x_u)
    assert a.success and a.x.tobytes() == b.x.tobytes() and a.iterations == b.iterations


def test_unknown_solver_is_refused():
    from kexp.errors import ConfigError
    with pytest.raises(ConfigError, match="valid"):
        DenseQp(3, 1, solver="osqp")


def _cycling_qps():
    """Six LMPC QPs (Duffing and the tight Van der Pol preset, from closed loops of 2026-11-25) on which plain
    Mehrotra cycles: 20 moves and the (21e) slack, which costs 1e4 against ~0.05 for the moves; H as DenseQp hands
    it to the IPM (the rows of the Fortran-ordered H's transpose)."""
    from pathlib import Path
    d = np.load(Path(__file__).parent / "data" / "ipm_cycling_qps.npz")
    return [tuple(d[f"{k}_{i}"] for k in ("H", "g", "G", "h", "x_l", "x_u")) for i in range(6)]


def test_the_safeguard_solves_qps_on_which_plain_mehrotra_cycles():
    """Without the safeguard each QP ends at max_iter: once feasible, its gap rises and falls in a loop (an
    attractor of the iteration, so rounding does not move it); with it each is solved in ≤ 30 iterations, within
    1e-6 of PIQP's solution (eps 1e-10; the slack's 1e4 scales the tolerance: 4e-7 measured) and no worse in
    objective.  DenseQp, which retries with the safeguard after max_iter, reports them solved."""
    for H, g, G, h, x_l, x_u in _cycling_qps():
        x = np.empty(21)
        assert STATUS_NAMES[solve_qp(H, g, G, h, x_l, x_u, 1e-8, 100, x, False)[0]] == "max_iter_reached"
        status, iters = solve_qp(H, g, G, h, x_l, x_u, 1e-8, 100, x, True)
        assert status == SOLVED and iters <= 30, (STATUS_NAMES[status], iters)
        ref = piqp.DenseSolver()
        ref.settings.eps_abs = ref.settings.eps_rel = 1e-10
        ref.settings.verbose = False
        ref.setup(np.asfortranarray(H), g, None, None, G, np.full(1, -np.inf), h, x_l, x_u)
        assert ref.solve() == piqp.PIQP_SOLVED
        x_ref = np.array(ref.result.x)
        assert np.abs(x - x_ref).max() <= 1e-6
        f = lambda v: 0.5 * v @ H @ v + g @ v   # noqa: E731
        assert f(x) <= f(x_ref) + 1e-9 * (1 + abs(f(x_ref)))
        r = DenseQp(21, 1).solve(np.asfortranarray(H.T), g, G, h, x_l, x_u)
        assert r.success and r.status == "solved" and r.iterations == 100 + iters and np.array_equal(r.x, x)


def test_the_safeguard_leaves_qps_solved_without_it_nearly_alone():
    """On 300 random QPs the safeguard, which acts only on a feasible iterate whose gap the corrector would raise,
    gives the plain method's solution to 1e-7 (both solve every feasible one)."""
    rng = np.random.default_rng(5)
    solved = 0
    for _ in range(300):
        n, mg = int(rng.integers(2, 25)), int(rng.integers(0, 6))
        H, g, G, h, x_l, x_u = random_qp(rng, n, mg)
        x, y = np.empty(n), np.empty(n)
        plain, _ = solve_qp(H, g, G, h, x_l, x_u, 1e-10, 100, x, False)
        safe, _ = solve_qp(H, g, G, h, x_l, x_u, 1e-10, 100, y, True)
        assert plain == safe
        if plain == SOLVED:
            solved += 1
            assert np.abs(x - y).max() <= 1e-7 * (1 + np.abs(x).max())
    assert solved >= 250       # measured 295 of 300 (the rest infeasible), so the comparison really ran
