import numpy as np
import pytest
import scipy.linalg as sla

from kexp.data import IntegratorOptions, integrate
from kexp.errors import ConfigError
from kexp.systems import Linear, SlowManifold, VanDerPol


def test_accuracy_against_closed_form_slow_manifold():
    s = SlowManifold(mu=-0.3, lam=-1.0)
    x0 = np.random.default_rng(0).uniform(-1, 1, (40, 2))
    t = np.arange(501) * 0.01
    x = integrate(s, x0, t)
    c = s.lam / (s.lam - 2 * s.mu)
    x1 = x0[:, None, 0] * np.exp(s.mu * t)
    x2 = (x0[:, None, 1] - c * x0[:, None, 0] ** 2) * np.exp(s.lam * t) + c * x0[:, None, 0] ** 2 * np.exp(2 * s.mu * t)
    assert np.max(np.abs(x[..., 0] - x1)) < 1e-9
    assert np.max(np.abs(x[..., 1] - x2)) < 1e-9
    # the tolerance controls the accuracy: a loose one is measurably worse
    loose = integrate(s, x0, t, options=IntegratorOptions(method="RK45", rtol=1e-4, atol=1e-6))
    assert np.max(np.abs(loose[..., 1] - x2)) > 1e-8


def test_sample_and_hold_matches_exact_discretisation():
    s = Linear(A=((0.0, 1.0), (-2.0, -0.3)), B=((0.0,), (1.0,)))
    dt = 0.05
    t = np.arange(41) * dt
    u = np.random.default_rng(1).uniform(-1, 1, (3, 40, 1))
    x0 = np.array([[1.0, 0.0], [0.0, 1.0], [-0.5, 0.3]])
    x = integrate(s, x0, t, u)
    aug = np.zeros((3, 3))
    aug[:2, :2] = np.asarray(s.A)
    aug[:2, 2:] = np.asarray(s.B)
    e = sla.expm(aug * dt)
    ad, bd = e[:2, :2], e[:2, 2:]
    ref = np.empty_like(x)
    ref[:, 0] = x0
    for k in range(40):
        ref[:, k + 1] = ref[:, k] @ ad.T + u[:, k] @ bd.T
    assert np.max(np.abs(x - ref)) < 1e-10


def test_bad_initial_conditions_rejected():
    with pytest.raises(ConfigError, match="NaN"):
        integrate(Linear(), np.array([[np.nan, 0.0]]), np.arange(3) * 0.1)
    with pytest.raises(ConfigError, match="components"):
        integrate(Linear(), np.zeros((1, 3)), np.arange(3) * 0.1)


def test_a_right_hand_side_that_turns_nan_fails_at_once():
    """solve_ivp looped for ever on a NaN first step (a system parameter NaN past its checks, a user's F returning
    NaN at a starting state); the integrator now stops with IntegrationFailure at the first NaN derivative."""
    from kexp.data.integrate import IntegrationFailure, integrate
    s = VanDerPol()
    object.__setattr__(s, "mu", float("nan"))        # past the constructor's check, as a user's own F could be
    with pytest.raises(IntegrationFailure, match=r"right-hand side is NaN/inf at t=0"):
        integrate(s, np.array([[0.5, 0.5]]), np.linspace(0.0, 1.0, 11))
    with pytest.raises(IntegrationFailure, match=r"right-hand side is NaN/inf at t=0"):
        integrate(s, np.array([[0.5, 0.5]]), np.linspace(0.0, 1.0, 11), np.zeros((1, 10, 1)))
