"""The explicit law h(z) = −K_x·Cz (controller.law=model_lqr): the LQR gain of the identified model's own
linearisation, from the same Riccati solution as the lqr_x CLF."""
import numpy as np
import pytest
import scipy.linalg as sla

from kexp.clf import ClfConfig, synthesize_clf
from kexp.clf.riccati import model_lqr
from kexp.control import ExplicitController, LqrController, ModelLqrGain, make_law
from kexp.data import Box, Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ClfError, ConfigError
from kexp.identify import identify
from kexp.simulate import SimConfig, closed_loop
from kexp.systems import SlowManifold, VanDerPol

from toy import toy_model


@pytest.fixture(scope="module")
def vdp():
    s = VanDerPol()
    model = identify(s, collect(s, Circle(60, 2.5), DataConfig(T=8.0)), Monomials(2, 5, include_constant=False))
    return s, model


def test_gain_is_the_riccati_solution_of_the_model_linearisation(vdp):
    """K_x = R⁻¹BᵀX with X the stabilising solution for (A, B) = (CΛJ, Cbᵀ), computed here independently, to
    1e-10; the same X is the lqr_x CLF's P_x (V = zᵀ(CᵀXC + ε·λmax·I)z)."""
    _, model = vdp
    cfg = ClfConfig(method="lqr_x", q_x=2.0, r_u=0.5)
    J = model.lift_jacobian(model.x_eq[None])[0]
    A, B = model.C @ model.Lambda @ J, model.C @ model.b.T
    X = sla.solve_continuous_are(A, B, 2.0 * np.eye(2), 0.5 * np.eye(1))
    K = B.T @ X / 0.5
    lqr = model_lqr(model, cfg.q_x, cfg.r_u)
    assert np.max(np.abs(lqr.K - K)) <= 1e-10 * np.max(np.abs(K))
    assert lqr.residual() < 1e-10
    assert np.max(np.linalg.eigvals(A - B @ K).real) < 0           # it stabilises the model's linearisation
    clf = synthesize_clf(model, cfg, law="model_lqr", u_min=-5.0, u_max=5.0)
    eps = cfg.eps * np.linalg.eigvalsh(X)[-1]
    assert np.max(np.abs(clf.P - (model.C.T @ X @ model.C + eps * np.eye(model.k)))) < 1e-10 * np.abs(clf.P).max()
    h = make_law("model_lqr", clf.lyap, -5.0, 5.0, model=model, weights=(cfg.q_x, cfg.r_u))
    assert isinstance(h, ModelLqrGain)
    assert np.max(np.abs(h.K - K @ model.C)) <= 1e-10 * np.max(np.abs(K @ model.C))


def test_law_is_the_lqr_law_in_x_and_saturates(vdp):
    """h(Ψ(x)) = clip(−K_x(x − x_eq)): Cz reproduces x (x is in the dictionary), to 1e-10."""
    _, model = vdp
    clf = synthesize_clf(model, ClfConfig(method="lqr_x"), law="model_lqr", u_min=-1.0, u_max=0.5)
    h = make_law("model_lqr", clf.lyap, -1.0, 0.5, model=model)
    Kx = model_lqr(model).K
    x = np.random.default_rng(0).uniform(-2, 2, (200, 2))
    u = h(model.lift(x))
    assert np.max(np.abs(u - np.clip(-(x - model.x_eq) @ Kx.T, -1.0, 0.5))) < 1e-10
    assert u.min() == -1.0 and u.max() == 0.5                   # both bounds are reached on this sample


def test_on_an_invariant_dictionary_the_gain_is_the_true_lqr():
    """Slow manifold (span{x1, x2, x1²} invariant, G = e2): the model's linearisation is the true one, so its LQR
    gain equals LQR on the true linearisation (central differences, 1e-6) and the explicit closed loops agree."""
    s = SlowManifold(mu=-0.3, lam=-1.0, inputs="x2")
    model = identify(s, collect(s, Box(20, -1.0, 1.0), DataConfig(T=2.0)),
                     Monomials(2, 2, weights=(1, 2), include_constant=False))
    clf = synthesize_clf(model, ClfConfig(method="lqr_x"), law="model_lqr")
    true = LqrController(s, -5.0, 5.0)
    assert np.max(np.abs(model_lqr(model).K - true.K)) < 1e-6
    h = make_law("model_lqr", clf.lyap, -5.0, 5.0, model=model)
    a = closed_loop(s, ExplicitController(h, clf), [0.8, -0.6], SimConfig(T=3.0), model=model, lyap=clf.lyap)
    b = closed_loop(s, true, [0.8, -0.6], SimConfig(T=3.0), model=model, lyap=clf.lyap)
    assert abs(a.metrics.cost - b.metrics.cost) < 1e-6 * b.metrics.cost


def test_refusals(vdp):
    _, model = vdp
    clf = synthesize_clf(model, ClfConfig(method="lqr_x"))
    with pytest.raises(ConfigError, match="needs the identified model"):
        make_law("model_lqr", clf.lyap, -5.0, 5.0)
    with pytest.raises(ConfigError, match="takes no law_params"):
        make_law("model_lqr", clf.lyap, -5.0, 5.0, model=model, k=2.0)
    with pytest.raises(ClfError, match="q_x=0.0"):
        model_lqr(model, 0.0, 1.0)
    with pytest.raises(ConfigError, match="shape"):
        ModelLqrGain(clf.lyap, -5.0, 5.0, K=np.ones((1, 3)))
    # a model whose input cannot move an unstable mode: no stabilising Riccati solution
    bad = toy_model(np.diag([1.0, -1.0]), np.zeros((2, 2)))
    with pytest.raises(ClfError, match="not stabilisable"):
        model_lqr(bad)
