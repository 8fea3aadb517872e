"""The equilibrium as a fixed point of the fit (kexp/identify/fixed_point.py) and the control model against its
raw fit (kexp/identify/fit_rollout.py): issue 34, "a control model as good as its fit"."""
import numpy as np
import pytest
from kexp.data import Box, Circle, DataConfig, Excitation, collect
from kexp.data.runs import window_samples
from kexp.dictionary import Monomials
from kexp.errors import ConfigError
from kexp.identify import IdentifyConfig, identify
from kexp.identify.edmd import fit_least_squares
from kexp.identify.fit_rollout import raw_fit_error
from kexp.identify.fixed_point import householder_complement, solve_fixed_point
from kexp.identify.regression import fit_bilinear
from kexp.systems import VanDerPol

lstsq = lambda A, B: np.linalg.lstsq(A, B, rcond=None)[0]  # noqa: E731


def test_constrained_solve_is_the_kkt_solution():
    rng = np.random.default_rng(3)
    L, R = rng.normal(size=(40, 6)), rng.normal(size=(40, 4))
    a, b = rng.normal(size=6), rng.normal(size=4)
    X = solve_fixed_point(lstsq, L, R, a, b)
    # independently: the KKT system [[LᵀL, a], [aᵀ, 0]] [X; ν] = [LᵀR; bᵀ]
    kkt = np.block([[L.T @ L, a[:, None]], [a[None, :], np.zeros((1, 1))]])
    ref = np.linalg.solve(kkt, np.vstack([L.T @ R, b[None, :]]))[:6]
    assert np.abs(a @ X - b).max() < 1e-12
    assert np.abs(X - ref).max() < 1e-10 * np.abs(ref).max()
    Q = householder_complement(a)
    assert np.abs(Q.T @ Q - np.eye(5)).max() < 1e-14 and np.abs(a @ Q).max() < 1e-14 * np.linalg.norm(a)


def test_an_empty_constraint_is_the_plain_solve_bit_for_bit():
    rng = np.random.default_rng(4)
    L, R = rng.normal(size=(30, 5)), rng.normal(size=(30, 5))
    assert np.array_equal(solve_fixed_point(lstsq, L, R, np.zeros(5), np.zeros(5)), lstsq(L, R))
    assert np.array_equal(solve_fixed_point(lstsq, L, R, None, None), lstsq(L, R))
    with pytest.raises(ValueError, match="infeasible"):
        solve_fixed_point(lstsq, L, R, np.zeros(5), np.ones(5))


@pytest.fixture(scope="module")
def paper_data():
    """The paper's Van der Pol recipe on 10⁴ pairs (10 circle runs: they never visit x_eq)."""
    return collect(VanDerPol(), Circle(10, 2.5), DataConfig(T=10.0))


def test_the_fixed_fit_drops_no_drift_and_predicts_as_its_fit(paper_data):
    s, d = VanDerPol(), Monomials(2, 5)
    free = identify(s, paper_data, d, IdentifyConfig(fix_equilibrium=False))
    fixed = identify(s, paper_data, d, IdentifyConfig(fix_equilibrium=True))
    # unconstrained: the shift drops ‖ΛΨ(x_eq)‖ ≈ 71 and the control model predicts far worse than its fit
    # (measured 0.90 vs 0.43 RMSE at 1 s on other held-out runs)
    vf = free.report["prediction_vs_fit"]
    assert free.report["drift_at_equilibrium"] > 10
    assert vf["1_s"]["model"] > 1.1 * vf["1_s"]["fit"]     # measured 0.405 vs 0.365 on the 2 held-out runs
    assert any("predicts worse than the fit it comes from" in w for w in free.report["warnings"])
    # constrained: every eigenfunction with λ̃ ≠ 1 vanishes at x_eq, so nothing is dropped; the control model is
    # its fit's eigen-decomposition, equal to the constrained raw rollout up to rounding
    assert fixed.report["drift_at_equilibrium"] < 1e-9 * np.abs(fixed.Lambda).max()
    vx = fixed.report["prediction_vs_fit"]
    assert vx["1_s"]["model"] < vf["1_s"]["model"]
    assert vx["2_s"]["model"] < 1.05 * vx["2_s"]["fit"]
    assert not any("predicts worse" in w for w in fixed.report["warnings"])
    fit = fit_least_squares(paper_data.split(0.2, 0)[0].iter_pairs(20000), d.lift,
                            fixed_point=d.lift(np.zeros((1, 2)))[0])
    phi_eq = d.lift(np.zeros((1, 2)))[0]
    assert np.abs(fit.K @ phi_eq - phi_eq).max() < 1e-12
    assert not np.allclose(fit.raw_K @ phi_eq, phi_eq, atol=1e-6)     # the plain fit moves x_eq


def test_auto_fixes_the_equilibrium_only_without_a_constant():
    s = VanDerPol()
    data = collect(s, Box(40, -2.5, 2.5), DataConfig(T=10.0, excitation=Excitation(-1.0, 1.0, 10)))
    cfg = dict(inputs="regression")
    auto = identify(s, data, Monomials(2, 5, include_constant=False, center=(0.0, 0.0)), IdentifyConfig(**cfg))
    off = identify(s, data, Monomials(2, 5, include_constant=False, center=(0.0, 0.0)),
                   IdentifyConfig(**cfg, fix_equilibrium=False))
    assert auto.report["fix_equilibrium"] and not off.report["fix_equilibrium"]
    # without the constant, centred at x_eq: the only thing fixed is the regression's intercept at u = 0
    a, o = auto.report["prediction_vs_fit"]["2_s"], off.report["prediction_vs_fit"]["2_s"]
    assert a["fit"] == o["fit"]                      # the raw fit is the same unconstrained regression
    # measured: 2-s error 0.304 (fixed) vs 0.443 (intercept fitted, then dropped by the shift); the raw fit 0.284
    assert a["model"] < 0.8 * o["model"] and a["model"] < 1.15 * a["fit"]
    paper = identify(s, collect(s, Circle(4, 2.5), DataConfig(T=5.0)), Monomials(2, 5))
    assert paper.report["fix_equilibrium"] is False  # the paper's recipe keeps its plain EDMD


def test_the_regressed_fit_keeps_x_eq_at_u_zero():
    s = VanDerPol()
    data = collect(s, Box(10, -2.0, 2.0), DataConfig(T=5.0, excitation=Excitation(-1.0, 1.0, 10)))
    d = Monomials(2, 3, include_constant=False)
    fit = fit_bilinear(data.iter_pairs(5000, with_inputs=True), d.lift, m=1, add_constant=True,
                       fixed_point=np.zeros(d.size))
    assert np.abs(fit.coef[d.size]).max() == 0.0 or np.abs(fit.coef[d.size]).max() < 1e-14   # no intercept
    assert np.abs(fit.raw_coef[d.size]).max() > 1e-8                                         # the plain one has it
    assert np.array_equal(fit.coef[d.size + 1:], fit.coef[d.size + 1:])


def test_raw_fit_error_is_the_rollout_of_k(paper_data):
    d = Monomials(2, 5)
    fit = fit_least_squares(paper_data.iter_pairs(20000), d.lift)
    h = 50
    x0, truth, _ = window_samples(paper_data, h, 300)
    K = fit.raw_K
    pred = np.array([(np.linalg.matrix_power(K, h) @ d.lift(x[None])[0])[d.linear_indices] for x in x0])
    ref = np.linalg.norm(pred - truth) / np.linalg.norm(truth)
    got = raw_fit_error(fit, d, paper_data, h, np.zeros(2), max_forced_windows=300)
    x0all, truthall, _ = window_samples(paper_data, h)
    predall = (d.lift(x0all) @ np.linalg.matrix_power(K, h).T)[:, d.linear_indices]
    assert got == pytest.approx(np.linalg.norm(predall - truthall) / np.linalg.norm(truthall), rel=1e-9)
    assert ref == pytest.approx(got, rel=0.2)    # the subsample of 300 windows tells the same story


def test_fix_equilibrium_is_validated():
    with pytest.raises(ConfigError, match="identification.fix_equilibrium='yes'"):
        IdentifyConfig(fix_equilibrium="yes")
