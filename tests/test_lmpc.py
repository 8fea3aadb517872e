import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla

from kexp.clf import ClfConfig, synthesize_clf
from kexp.control import ExplicitController, Lmpc, LmpcConfig, make_law
from kexp.control.blocking import block_of_step, block_sizes
from kexp.control.condense import block_maps_expm, block_maps_poly, condense
from kexp.control.expm_kernels import expm_frechet, expm_frechet_pade
from kexp.control.kernels import rollout, rollout_poly, rollout_sensitivity
from kexp.control.qp import DenseQp
from kexp.control.zoh_poly import series_expm, zoh_degree, zoh_polynomial
from kexp.data import Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ConfigError
from kexp.identify import identify
from kexp.simulate import SimConfig, closed_loop
from kexp.systems import VanDerPol

ICS = np.random.default_rng(42).uniform(-1, 1, (2, 100)).T  # the design study's initial conditions


@pytest.fixture(scope="module")
def vdp():
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    return s, model, clf, make_law("sontag", clf.lyap, -5.0, 5.0)


def condensed(lam, B, b, dt, z0, U, bos, C, use_c, P, zp=None):
    """The block maps (from the polynomial zp, else the exponential) and one condensing pass (terminal weight 0.7,
    cost scale 0.02, r̂ = 1.5, input diagonal linspace(0.1, 0.3)): its outputs by name, and that diagonal."""
    k, m, nb, Np = lam.shape[0], B.shape[0], U.shape[0], len(bos)
    n, nu = k + 1, U.size
    E, L = np.zeros((nb, n, n)), np.zeros((nb, m, n, n))
    if zp is not None:
        block_maps_poly(zp.coef, zp.norms, zp.rho, lam, B, b, dt, U, E, L)
    else:
        block_maps_expm(lam, B, b, dt, U, E, L)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(bos)) + 1]).astype(np.int64)
    first = np.repeat(starts, m)
    out = dict(Z=np.zeros((Np + 1, k)), S=np.zeros((nu, Np + 1, k)), HS=np.zeros((nu, nu)), q=np.zeros(nu),
               H=np.zeros((nu + 1, nu + 1)), g=np.zeros(nu + 1), rows=np.zeros((Np, nu)), Vbar=np.zeros(Np),
               h_rows=np.zeros(Np))
    terminal = 0.7
    Y = np.zeros((nu + 1, Np + 1, C.shape[0]))
    rdiag = np.linspace(0.1, 0.3, nu)
    condense(E, L, bos, first, z0, U.reshape(-1), C, use_c, 0.02, rdiag, P, terminal, 1.5, True, out["Z"],
             out["S"], Y, out["HS"], out["q"], out["H"], out["g"], out["rows"], out["Vbar"], out["h_rows"],
             np.zeros(n), np.zeros((nu, k)))
    return out, rdiag


def test_rollout_is_the_exact_zero_order_hold(vdp):
    _, model, _, _ = vdp
    rng = np.random.default_rng(0)
    sizes = block_sizes(30, 3, 8)
    bos = block_of_step(sizes)
    U = rng.uniform(-5, 5, (len(sizes), 1))
    z0 = model.lift(np.array([0.4, -0.7]))
    Z = rollout(model.Lambda, model.B, model.b, model.dt, z0, U, bos)
    z = z0.copy()
    for j, blk in enumerate(bos):
        ad, cd = model.step_matrices(U[blk])
        z = ad @ z + cd
        assert np.max(np.abs(Z[j + 1] - z)) < 1e-12 * max(1.0, np.max(np.abs(z)))
    Z2, S = rollout_sensitivity(model.Lambda, model.B, model.b, model.dt, z0, U, bos)
    assert np.array_equal(Z, Z2)
    eps = 1e-6
    for blk in (0, 4, len(sizes) - 1):
        up, um = U.copy(), U.copy()
        up[blk] += eps
        um[blk] -= eps
        fd = (rollout(model.Lambda, model.B, model.b, model.dt, z0, up, bos)
              - rollout(model.Lambda, model.B, model.b, model.dt, z0, um, bos)) / (2 * eps)
        assert np.max(np.abs(fd - S[:, :, blk])) < 1e-6 * max(1.0, np.max(np.abs(fd)))
        assert np.all(S[: np.flatnonzero(bos == blk)[0] + 1, :, blk] == 0)  # causality


def random_plans(model, rng):
    """Five random 20-block one-input plans with |u| ≤ 5 (the polynomial's range), five with |u| ≤ 7 (past it),
    each with a random lifted start in [−2, 2]²."""
    for lo, hi in ((-5, 5), (-7, 7)):
        for _ in range(5):
            yield rng.uniform(lo, hi, (20, 1)), model.lift(rng.uniform(-2, 2, 2))


def test_polynomial_zoh_equals_the_per_step_exponential(vdp):
    """The one-input fast path (the ZOH map as a polynomial in u, its map and derivative once per move block)
    equals the per-step kernel (expm per block, a Van Loan series per step) to rounding, inside and outside the
    polynomial's range |u| ≤ ρ (there it falls back to expm_frechet); measured 2e-14 in range, 4e-14 with
    inputs up to ±7 (five random plans in each range)."""
    _, model, _, _ = vdp
    lam, B, b = (np.ascontiguousarray(a) for a in (model.Lambda, model.B, model.b))
    zp = zoh_polynomial(lam, B, b, model.dt, 5.0)
    assert zp is not None and zp.degree <= 30
    for u in (-5.0, -1.3, 0.0, 2.2, 5.0):
        ref = sla.expm(np.block([[model.Lambda + u * model.B[0], (u * model.b[0])[:, None]],
                                 [np.zeros((1, model.k + 1))]]) * model.dt)
        E = np.einsum("d,drc->rc", (u / zp.rho) ** np.arange(zp.degree + 1), zp.coef)
        assert np.max(np.abs(E - ref)) <= 1e-14 * np.max(np.abs(ref))
    bos = block_of_step(block_sizes(100, 5, 20))
    for U, z0 in random_plans(model, np.random.default_rng(3)):
        out, _ = condensed(lam, B, b, model.dt, z0, U, bos, np.zeros((1, model.k)), False, np.eye(model.k), zp)
        Z0, S0 = rollout_sensitivity(lam, B, b, model.dt, z0, U, bos)
        assert np.max(np.abs(out["Z"] - Z0)) <= 1e-12 * np.max(np.abs(Z0))
        assert np.max(np.abs(out["S"].transpose(1, 2, 0) - S0)) <= 1e-12 * np.max(np.abs(S0))


def test_polynomial_rollout_equals_the_exponential_one(vdp):
    """The prediction of a plan (logged plans, the line search's merit) from the ZOH polynomial equals the
    exponential rollout to rounding, inside the polynomial's range and outside it (inputs up to ±7)."""
    _, model, _, _ = vdp
    lam, B, b = (np.ascontiguousarray(a) for a in (model.Lambda, model.B, model.b))
    zp = zoh_polynomial(lam, B, b, model.dt, 5.0)
    bos = block_of_step(block_sizes(100, 5, 20))
    for U, z0 in random_plans(model, np.random.default_rng(6)):
        Z0 = rollout(lam, B, b, model.dt, z0, U, bos)
        assert np.max(np.abs(rollout_poly(zp.coef, zp.norms, zp.rho, lam, B, b, model.dt, z0, U, bos) - Z0)) <= \
            1e-12 * np.max(np.abs(Z0))


def test_expm_frechet_is_the_van_loan_block():
    rng = np.random.default_rng(4)
    for scale in (0.1, 0.6, 3.0):
        M = rng.standard_normal((9, 9)) * scale / 3
        D = rng.standard_normal((9, 9))
        E, L = np.empty((9, 9)), np.empty((9, 9))
        expm_frechet(M, D, E, L)
        big = sla.expm(np.block([[M, D], [np.zeros((9, 9)), M]]))
        assert np.max(np.abs(E - big[:9, :9])) <= 1e-13 * np.max(np.abs(big[:9, :9]))
        assert np.max(np.abs(L - big[:9, 9:])) <= 1e-13 * np.max(np.abs(big[:9, 9:]))


@pytest.mark.parametrize("m", [1, 2, 3])
def test_expm_frechet_pade_is_the_van_loan_block(m):
    """The several-direction Padé kernel of the general path: expm(M) and each Fréchet derivative against the Van
    Loan block exponential, from tiny generators to ‖M‖₁ ~ 700 (a two-input model's reach ~300 at |u| = 5);
    measured ≤ 1.2e-13 where expm_frechet (Taylor) reaches 6.6e-13."""
    rng = np.random.default_rng(5 + m)
    n = 22
    for scale in (0.01, 0.5, 3.0, 40.0, 150.0):
        M = rng.standard_normal((n, n)) * scale / np.sqrt(n)
        D = rng.standard_normal((m, n, n))
        E, L = np.empty((n, n)), np.empty((m, n, n))
        expm_frechet_pade(M, D, E, L)
        for i in range(m):
            big = sla.expm(np.block([[M, D[i]], [np.zeros((n, n)), M]]))
            tol = 1e-14 if scale < 1 else 1e-12
            assert np.max(np.abs(E - big[:n, :n])) <= tol * np.max(np.abs(big[:n, :n]))
            assert np.max(np.abs(L[i] - big[:n, n:])) <= tol * np.max(np.abs(big[:n, n:]))



def _series_tails_hold(D, norm_x, c):
    """Whether the truncation at degree D meets zoh_degree's accuracy on the series' true tails (summed term by
    term here, not bounded): e^{‖X‖}·Σ_{d>D} c^d/d! ≤ 2⁻⁵⁴ and c·e^{‖X‖}·Σ_{d>D} c^{d−1}/(d−1)! ≤ 2⁻⁵⁴·max(1, c·e^{‖X‖})."""
    import math
    term = lambda d: math.exp(d * math.log(c) - math.lgamma(d + 1))  # noqa: E731   c^d/d!
    scale, tail = math.exp(norm_x), 2.0 ** -54
    tail_e = math.fsum(term(d) for d in range(D + 1, D + 300))
    tail_d = math.fsum(term(d - 1) for d in range(D + 1, D + 300))
    return scale * tail_e <= tail and scale * c * tail_d <= tail * max(1.0, c * scale)


def test_zoh_degree_is_the_smallest_that_meets_the_accuracy():
    """zoh_degree bounds the tails in closed form; on the series' summed tails its degree is enough, and no more
    than one above the smallest that is (measured: equal to it on this whole grid, D from 2 to 98)."""
    for norm_x in (0.0, 0.01, 0.5, 2.0):
        for c in (1e-6, 0.01, 0.3, 1.0, 3.0, 10.0, 25.0):
            D = zoh_degree(norm_x, c)
            smallest = next(d for d in range(1, 200) if _series_tails_hold(d, norm_x, c))
            assert D in (smallest, smallest + 1), (norm_x, c, D, smallest)
    assert zoh_degree(0.0, 30.0, max_degree=100) is None and zoh_degree(0.0, 30.0, max_degree=200) is not None


def test_zoh_polynomial_declines_what_it_cannot_do(vdp):
    _, model, _, _ = vdp
    assert zoh_degree(0.1, 50.0) is None                      # the series would need too many terms
    assert zoh_polynomial(model.Lambda, np.repeat(model.B, 2, 0), np.repeat(model.b, 2, 0), model.dt, 5.0) is None
    assert zoh_polynomial(model.Lambda, model.B, model.b, model.dt, 1e4) is None


def test_series_expm_is_the_van_loan_block_exponential(vdp):
    """series_expm (scaling and squaring on the truncated series) gives the coefficients of expm(X + vY) that the
    (0, d) blocks of the block-bidiagonal Van Loan exponential give, to rounding in absolute terms, and E(v) from
    them equals scipy's expm: on the Van der Pol model (degree 19) and on a random 36×36 case whose a-priori degree,
    50, is past the old limit of 40 (measured 5e-16 and 1.3e-14 relative)."""
    _, model, _, _ = vdp
    rng = np.random.default_rng(8)
    k, n = model.k, model.k + 1
    X = np.zeros((n, n))
    X[:k, :k] = model.Lambda * model.dt
    Y = np.zeros((n, n))
    Y[:k, :k] = model.B[0] * model.dt * 5.0
    Y[:k, k] = model.b[0] * model.dt * 5.0
    for X_, Y_, D, tol in ((X, Y, 19, 1e-14), (rng.normal(size=(36, 36)) * 0.01, rng.normal(size=(36, 36)) * 0.35,
                                                 50, 1e-13)):
        coef = series_expm(X_, Y_, D)
        m = X_.shape[0]
        big = np.kron(np.eye(D + 1), X_) + np.kron(np.eye(D + 1, k=1), Y_)
        ref = sla.expm(big)[:m].reshape(m, D + 1, m).transpose(1, 0, 2)
        assert np.max(np.abs(coef - ref)) <= tol * np.max(np.abs(ref))
        for v in (-1.0, -0.3, 0.05, 1.0):
            E = np.einsum("d,drc->rc", v ** np.arange(D + 1), coef)
            exact = sla.expm(X_ + v * Y_)
            assert np.max(np.abs(E - exact)) <= tol * np.max(np.abs(exact))


def test_zoh_polynomial_refuses_a_series_that_cancels(vdp):
    """A large ρ‖Y‖ makes the series' terms grow to e^{ρ‖Y‖} before they fall: beyond SPREAD_LIMIT (Σ‖Ĉ_d‖ over
    ‖Ĉ_0‖) the polynomial would lose digits, and zoh_polynomial leaves that model to the exponential."""
    _, model, _, _ = vdp
    zp = zoh_polynomial(model.Lambda, model.B, model.b, model.dt, 5.0)
    assert zp is not None and zp.norms.sum() / zp.norms[0] < 10
    # B = cI, Λ = 0: E(u) = e^{cuΔ}I, coefficients (cρΔ)^d/d!, so the norms sum to e^{cρΔ}·‖Ĉ_0‖
    k, dt, rho = 4, 0.01, 5.0
    for c_rho_dt, kept in ((5.0, True), (10.0, False)):      # e^5 = 148 < 1e3 < e^10 = 22026
        B = np.eye(k)[None] * c_rho_dt / (rho * dt)
        got = zoh_polynomial(np.zeros((k, k)), B, np.zeros((1, k)), dt, rho)
        assert (got is not None) == kept
        if kept:
            assert abs(got.norms.sum() / got.norms[0] - np.exp(c_rho_dt)) <= 1e-9 * np.exp(c_rho_dt)


def test_zoh_polynomial_is_computed_once_per_model_and_range(vdp):
    """A sweep worker builds one LMPC per job on the same model: the coefficients come from a memo keyed by the
    inputs' bits, so a changed model or input range gets its own (equal to a fresh computation)."""
    from kexp.control import zoh_poly
    _, model, _, _ = vdp
    first = zoh_polynomial(model.Lambda, model.B, model.b, model.dt, 5.0)
    assert zoh_polynomial(model.Lambda.copy(), model.B.copy(), model.b.copy(), model.dt, 5.0) is first
    other = zoh_polynomial(model.Lambda, model.B, model.b, model.dt, 2.0)
    assert other is not first and other.rho == 2.0
    nudged = model.Lambda.copy()
    nudged[0, 0] += 1e-12
    again = zoh_polynomial(nudged, model.B, model.b, model.dt, 5.0)
    fresh = zoh_poly._coefficients(nudged, model.B, model.b, model.dt, 5.0)
    assert again is not first and np.array_equal(again.coef, fresh.coef)


def test_lmpc_fast_path_closed_loop_equals_the_per_step_kernel(vdp):
    """The RTI closed loop with the polynomial fast path and with the general per-block kernel (zoh=None,
    block_maps_expm): the same inputs to 1e-9 over 2 s from two ICs, inner region and ring both
    visited."""
    s, model, clf, h = vdp
    for x0 in ICS[:2]:
        runs = []
        for fast in (True, False):
            ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
            if not fast:
                ctrl.zoh = None
            runs.append(closed_loop(s, ctrl, x0, SimConfig(T=2.0), model=model, lyap=clf.lyap))
        assert runs[0].status == runs[1].status == "completed"
        assert np.max(np.abs(runs[0].u - runs[1].u)) <= 1e-9
        assert abs(runs[0].metrics.cost - runs[1].metrics.cost) <= 1e-9 * runs[1].metrics.cost


def with_inputs(model, m, rng):
    """(Λ, B, b) of the model with m inputs: its own B, b and, for m > 1, random extra B_i, b_i of the same size."""
    B = np.concatenate([model.B] + [rng.normal(size=model.B.shape) * np.abs(model.B).max() for _ in range(m - 1)])
    b = np.concatenate([model.b] + [rng.normal(size=model.b.shape) * np.abs(model.b).max() for _ in range(m - 1)])
    return (np.ascontiguousarray(model.Lambda), np.ascontiguousarray(B), np.ascontiguousarray(b))


@pytest.mark.parametrize("m", [1, 2, 3])
def test_per_block_frechet_kernel_equals_the_per_step_kernel(vdp, m):
    """The general path (any m, any input size): map and derivatives once per move block by expm_frechet, then
    matrix-vector products per step, equals the per-step kernel (a Van Loan series every step) to rounding, on the
    Van der Pol model with its B (and, for m > 1, random extra B_i, b_i of the same size), blocked and unblocked,
    inputs up to ±7."""
    _, model, _, _ = vdp
    rng = np.random.default_rng(5)
    lam, B, b = with_inputs(model, m, rng)
    for bos in (block_of_step(block_sizes(100, 5, 20)), block_of_step(block_sizes(30, None, None))):
        nb = int(bos.max()) + 1
        for _ in range(4):
            U = rng.uniform(-7, 7, (nb, m))
            z0 = model.lift(rng.uniform(-2, 2, 2))
            out, _ = condensed(lam, B, b, model.dt, z0, U, bos, np.zeros((1, model.k)), False, np.eye(model.k))
            Z0, S0 = rollout_sensitivity(lam, B, b, model.dt, z0, U, bos)
            assert out["S"].shape == (nb * m, len(bos) + 1, model.k)
            assert np.max(np.abs(out["Z"] - Z0)) <= 1e-12 * np.max(np.abs(Z0))
            assert np.max(np.abs(out["S"].transpose(1, 2, 0) - S0)) <= 1e-12 * np.max(np.abs(S0))


def test_block_sizes():
    s = block_sizes(100, 5, 20)
    assert s.sum() == 100 and len(s) == 20 and np.all(s[:5] == 1) and np.all(np.diff(s) >= 0)
    assert np.all(block_sizes(7, None, None) == 1)
    with pytest.raises(ConfigError, match="horizon"):
        block_sizes(0)


def test_lyapunov_constraints_in_closed_loop(vdp):
    s, model, clf, h = vdp
    ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
    for x0 in ICS[:1]:
        run = closed_loop(s, ctrl, x0, SimConfig(T=10.0), model=model, lyap=clf.lyap)
        assert run.status == "completed" and run.metrics.fallbacks == 0
        for rec in run.records:
            assert -5.0 <= rec.u[0] <= 5.0
            if rec.active == "21f":  # V̇(z, u) ≤ V̇(z, h(z)) at the first step, exactly (linear in u_0)
                _, beta = clf.lyap.lie(rec.z[None])
                rhs = float(beta[0] @ h(rec.z[None])[0])
                assert float(beta[0] @ rec.u) <= rhs + 1e-7 * max(1.0, abs(rhs))
            if rec.active == "21e":  # feasible in every measured step: the slack is zero
                assert rec.slack < 1e-7
        assert {r.active for r in run.records} == {"21e", "21f"}


def test_infeasible_21e_uses_and_reports_the_slack(vdp):
    """Inside Ω_r̂ with r̂ = V(z_0), at a state where every admissible input (u ∈ [4.99, 5]) raises V, (21e)
    cannot hold: the slack takes the violation and is reported, and the step still succeeds."""
    _, model, clf, h = vdp
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1, 1, 21)), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=1) > 0]
    zs = model.lift(grid)
    a, beta = clf.lyap.lie(zs)
    j = int(np.argmax((a + 4.99 * beta[:, 0]) / clf.lyap.value(zs)))
    assert a[j] + 4.99 * beta[j, 0] > 0
    V0 = float(clf.lyap.value(zs[j]))
    tight = dataclasses.replace(clf, certificate=dataclasses.replace(clf.certificate, r=10 * V0, r_hat=V0))
    with pytest.warns(UserWarning, match="differ from the controller's"):   # on purpose: force a (21e) slack
        ctrl = Lmpc(model, tight, h, LmpcConfig(), 4.99, 5.0)
    st = ctrl.step(grid[j], zs[j])
    assert st.region == "inner" and st.active == "21e"
    assert st.slack > 0 and st.binds and not st.fallback and st.status == "solved"
    # with a generous r̂ the same step has zero slack
    loose = dataclasses.replace(clf, certificate=dataclasses.replace(clf.certificate, r=10 * V0, r_hat=5 * V0))
    st2 = Lmpc(model, loose, h, LmpcConfig(), -5.0, 5.0).step(grid[j], zs[j])
    assert st2.active == "21e" and st2.slack == 0.0


@pytest.mark.parametrize("solver,status", [("ipm", "max_iter_reached"), ("piqp", "PIQP_MAX_ITER_REACHED")])
def test_forced_qp_failure_falls_back_to_h(vdp, solver, status):
    _, model, clf, h = vdp
    ctrl = Lmpc(model, clf, h, LmpcConfig(qp_max_iter=1, qp_solver=solver), -5.0, 5.0)
    x0 = ICS[1]
    z0 = model.lift(x0)
    st = ctrl.step(x0, z0)
    assert st.fallback and st.status == "fallback" and "QP failed" in st.reason
    assert st.qp_status == status
    assert np.array_equal(st.u, h(z0[None])[0])
    # a law on wider bounds than the LMPC's (it warns) falls back within the LMPC's bounds
    wide = make_law("sontag", clf.lyap, -50.0, 50.0)
    with pytest.warns(UserWarning, match="differ from the controller's"):
        tight = Lmpc(model, clf, wide, LmpcConfig(qp_max_iter=1, qp_solver=solver), -0.1, 0.1)
    st = tight.step(x0, z0)
    assert st.fallback and abs(wide(z0[None])[0, 0]) > 0.1 and st.u[0] == np.clip(wide(z0[None])[0, 0], -0.1, 0.1)


@pytest.mark.parametrize("solver", ["ipm", "piqp"])
def test_qp_guard_rejects_bad_input_without_crashing(solver):
    qp = DenseQp(2, 1, solver=solver)
    good = dict(H=np.eye(2), g=np.zeros(2), G=np.ones((1, 2)), h_u=np.ones(1), x_l=-np.ones(2), x_u=np.ones(2))
    bad = dict(good, H=np.array([[np.nan, 0], [0, 1.0]]))
    r = qp.solve(**bad)
    assert not r.success and r.status.startswith("invalid_input") and "H" in r.message
    r = qp.solve(**dict(good, G=np.ones((2, 2))))
    assert not r.success and "G has shape (2, 2)" in r.message
    r = qp.solve(**dict(good, g=np.array([1.0, -1.0])))
    # the unconstrained minimum lies on the bounds (multipliers 0: degenerate): an interior point stops ~sqrt(eps)
    # inside them, measured 4e-5 (PIQP) and 7e-5 (ipm) at eps = 1e-8
    assert r.success and np.allclose(r.x, [-1.0, 1.0], atol=1e-4)


def test_sqp_converges_and_rti_is_close(vdp):
    _, model, clf, h = vdp
    x0 = np.array([0.6, -0.4])
    z0 = model.lift(x0)
    full = Lmpc(model, clf, h, LmpcConfig(max_iter=30, tol=1e-7), -5.0, 5.0)
    st = full.step(x0, z0)
    # Gauss-Newton SQP: linear convergence, measured ~15× per iteration: 8 iterations to 1e-7
    assert st.status == "solved" and 1 < st.iterations <= 12
    # a second SQP started from the converged plan stops at once: a fixed point
    plan = lambda c, step: np.vstack([step.u[None], c._useq[:-1]])  # noqa: E731   the plan: warm-start shift undone
    again = Lmpc(model, clf, h, LmpcConfig(max_iter=30, tol=1e-7), -5.0, 5.0)
    again._useq = plan(full, st)
    st2 = again.step(x0, z0)
    assert st2.iterations <= 2 and abs(st2.u[0] - st.u[0]) < 1e-6
    # the real-time iteration (one QP from a cold start): here its first input is the SQP's (both at u_max) but
    # its plan is not yet converged (measured 25 % from the SQP's, relative 2-norm)
    rti_ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
    rti = rti_ctrl.step(x0, z0)
    # (on the bound to rounding: DAQP's active bound comes back as the QP's variable plus its shift, 1 ulp off)
    assert rti.iterations == 1 and abs(rti.u[0] - 5.0) <= 1e-12 and abs(st.u[0] - 5.0) <= 1e-12
    assert np.linalg.norm(plan(rti_ctrl, rti) - plan(full, st)) > 0.1 * np.linalg.norm(plan(full, st))
    # near the origin, where the input is inside its bounds and the model nearly linear, one QP is nearly the SQP's
    # answer: measured |Δu0| = 1.6e-3 on u0 = -2.05 and the plans 0.7 % apart
    x1 = np.array([0.1, 0.05])
    z1 = model.lift(x1)
    sqp_ctrl, rti_ctrl = (Lmpc(model, clf, h, c, -5.0, 5.0) for c in (LmpcConfig(max_iter=30, tol=1e-7), LmpcConfig()))
    sqp, rti = sqp_ctrl.step(x1, z1), rti_ctrl.step(x1, z1)
    assert sqp.status == rti.status == "solved" and sqp.iterations > 1 and abs(sqp.u[0]) < 4.0
    assert abs(rti.u[0] - sqp.u[0]) < 5e-3
    assert np.linalg.norm(plan(rti_ctrl, rti) - plan(sqp_ctrl, sqp)) < 0.02 * np.linalg.norm(plan(sqp_ctrl, sqp))


def test_iterate_only_where_a_constraint_binds(vdp):
    """iterate_when='binding': a step whose first QP has no bound and no Lyapunov row active stops after it (the
    real-time iteration's input, exactly); a step with one active iterates exactly like 'always'.  With r̂ = r
    (the working presets) from ICS[0]: the first ~0.2 s saturate at u = -5 and iterate, the rest do not."""
    s, model, _, _ = vdp
    clf = synthesize_clf(model, ClfConfig(rhat_floor=1.0))
    h = make_law("sontag", clf.lyap, -5.0, 5.0)
    cfg = LmpcConfig(max_iter=10, tol=1e-7, iterate_when="binding")
    run = closed_loop(s, Lmpc(model, clf, h, cfg, -5.0, 5.0), ICS[0], SimConfig(T=3.0), model=model,
                      lyap=clf.lyap)
    its = np.array([r.iterations for r in run.records])
    assert run.status == "completed" and its.max() > 1 and np.sum(its == 1) > 200
    # step by step: a step that iterated had its input at the bound or a Lyapunov constraint binding (measured:
    # 18 steps iterate, all of them so); none that stopped after one QP had its input at the bound
    assert all(abs(r.u[0]) > 4.9 or r.binds for r in run.records if r.iterations > 1)
    assert not any(abs(r.u[0]) > 4.9 for r in run.records if r.iterations == 1)
    # replayed from a cold start: 'binding' gives RTI's input where it stopped after one QP, and exactly
    # the 'always' SQP's input (and iteration count) where it went on
    seen = {True: 0, False: 0}
    for rec in run.records[:60:3] + run.records[100::40]:
        ctrls = [Lmpc(model, clf, h, c, -5.0, 5.0) for c in
                 (cfg, dataclasses.replace(cfg, iterate_when="always"), dataclasses.replace(cfg, max_iter=1))]
        o, a, r = (c.step(rec.x, rec.z) for c in ctrls)
        if o.iterations == 1:
            assert np.array_equal(o.u, r.u)
        else:
            assert np.array_equal(o.u, a.u) and o.iterations == a.iterations
        seen[o.iterations > 1] += 1
    assert seen[True] > 0 and seen[False] > 0
    with pytest.raises(ConfigError, match="iterate_when"):
        LmpcConfig(iterate_when="sometimes")


def test_vanderpol_closed_loop_success_on_fixed_sample(vdp):
    """Issue target: ≥ 95 % of ICs in [-1, 1]² reach ‖x(10)‖ < 1e-2 with |u| ≤ 5; here the first 10 of the
    design study's 100 ICs (measured: 10/10, median cost 4.57)."""
    s, model, clf, h = vdp
    ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0)
    results = [closed_loop(s, ctrl, x0, model=model, lyap=clf.lyap) for x0 in ICS[:10]]
    assert sum(r.metrics.success for r in results) == 10
    assert max(r.metrics.max_abs_u for r in results) <= 5.0
    assert all(r.metrics.fallbacks == 0 for r in results)


def test_explicit_sontag_is_slower_than_lmpc(vdp):
    """Measured: Sontag with the SDP's P converges but slowly near 0 (‖x(10)‖ = 0.019 from (0.5, −0.3): not
    inside the success radius 1e-2), where the LMPC on the same V and h settles (‖x(10)‖ = 2.6e-4, at 6.6 s).
    Slower, not costlier: the LMPC's J (2.65) is above Sontag's (1.68) here."""
    s, model, clf, h = vdp
    x0 = np.array([0.5, -0.3])
    run = closed_loop(s, ExplicitController(h, clf), x0, model=model, lyap=clf.lyap)
    err = np.linalg.norm(run.x, axis=1)
    assert run.status == "completed" and err[-1] < 0.5 * err[0]
    assert np.all(np.diff([r.V for r in run.records]) < 0)  # V decreases at every sample
    lmpc = closed_loop(s, Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0), x0, model=model, lyap=clf.lyap)
    assert lmpc.metrics.success and not run.metrics.success
    assert np.linalg.norm(lmpc.x[-1]) < 1e-3 and err[-1] > 1e-2
    assert lmpc.metrics.settling_time < 8.0 and run.metrics.settling_time == np.inf


@pytest.mark.parametrize("norm", [0.0, 1e-3, 0.3, 0.5, 2.0, 40.0])
def test_expm_small_matches_scipy(norm):
    """The kernel's expm (scaling and squaring, Taylor degree from the norm, Paterson–Stockmeyer) to rounding,
    from a zero matrix to one that needs 7 squarings."""
    import scipy.linalg as sla
    from kexp.control.expm_kernels import expm_small
    rng = np.random.default_rng(3)
    M = rng.standard_normal((21, 21))
    M *= norm / max(np.max(np.abs(M).sum(axis=1)), 1e-300)
    ref = sla.expm(M)
    # measured ≤ 6e-15 relative at the norms of the LMPC (≤ 0.5); squaring amplifies rounding at norm 40
    assert np.max(np.abs(expm_small(M) - ref)) <= (1e-14 if norm <= 2 else 1e-12) * np.max(np.abs(ref))
