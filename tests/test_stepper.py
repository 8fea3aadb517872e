"""The closed loop's one-step integrator (kexp.simulate.stepper): the same DOP853 step as solve_ivp's, without
its per-call overhead; exact on a linear system; failures raised, not returned."""
import numpy as np
import pytest
import scipy.linalg as sla

from kexp.data import IntegratorOptions, integrate
from kexp.data.integrate import IntegrationFailure
from kexp.simulate.stepper import HeldInputStepper
from kexp.systems import Linear, Pendulum, VanDerPol


@pytest.mark.parametrize("system", [VanDerPol(), Pendulum()], ids=lambda s: s.name)
def test_agrees_with_solve_ivp(system):
    """Both are Hairer's DOP853 with the same tolerances: on 200 random states and inputs they agree far below
    rtol = 1e-10 (measured: to 2.2e-16, the same steps)."""
    opts = IntegratorOptions(batch=1)
    stepper = HeldInputStepper(system, opts)
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(200):
        x, u = rng.uniform(-2, 2, 2), rng.uniform(-5, 5, 1)
        ref = integrate(system, x[None], np.array([0.0, 0.01]), u[None, None], opts)[0, 1]
        worst = max(worst, float(np.max(np.abs(stepper.step(x, u, 0.0, 0.01) - ref))))
    assert worst < 1e-12


@pytest.mark.parametrize("method", ["DOP853", "RK45", "Radau"])
def test_exact_on_a_linear_system(method):
    """x(t+Δ) = e^{AΔ}x + ∫e^{As}ds·Bu on a linear plant, for the fast path (DOP853, RK45) and the fallback."""
    s = Linear(A=((0.0, 1.0), (-2.0, -0.3)), B=((0.0,), (1.0,)))
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2:] = np.asarray(s.A), np.asarray(s.B)
    e = sla.expm(aug * 0.05)
    stepper = HeldInputStepper(s, IntegratorOptions(method=method, batch=1))
    x = np.array([1.0, -0.5])
    for k, u in enumerate(np.random.default_rng(1).uniform(-1, 1, (20, 1))):
        nxt = stepper.step(x, u, 0.05 * k, 0.05 * (k + 1))
        assert np.max(np.abs(nxt - (e[:2, :2] @ x + e[:2, 2:] @ u))) < 1e-10
        x = nxt


def test_blow_up_raises():
    """ẋ = x² from x = 1 leaves the floats before t = 1: IntegrationFailure, with the interval in the message."""
    class Square(Linear):
        def drift(self, x):
            return np.asarray(x, float) ** 2
    stepper = HeldInputStepper(Square(A=((0.0, 0.0), (0.0, 0.0))), IntegratorOptions(batch=1))
    with pytest.raises(IntegrationFailure, match=r"\[0, 2\]"):
        stepper.step(np.array([1.0, 1.0]), np.zeros(1), 0.0, 2.0)


def test_the_systems_own_exception_comes_through_at_once():
    """An error in the user's drift or input matrix is raised unchanged by step() (as solve_ivp would), and the
    integrator stops at its next accepted step instead of running on: here within one step's 12 stages of the
    failing call (without the guard scipy reported "must not return a tuple" after ~35 s of rejected steps)."""
    calls = []

    class Flaky(VanDerPol):
        constant_input_matrix = False      # G is evaluated in every right-hand-side call (where it fails)

        def input_matrix(self, x):
            calls.append(1)
            if len(calls) == 3:
                raise ZeroDivisionError("the rig's model failed")
            return super().input_matrix(x)

    stepper = HeldInputStepper(Flaky(), IntegratorOptions(batch=1))
    with pytest.raises(ZeroDivisionError, match="rig's model failed"):
        stepper.step(np.array([0.5, 0.1]), np.array([0.2]), 0.0, 0.01)
    assert len(calls) == 3        # after the failure the system is not called again
    calls.clear()                 # and the stepper is usable afterwards: the same state as a fresh one
    ref = HeldInputStepper(VanDerPol(), IntegratorOptions(batch=1)).step(np.array([0.5, 0.1]), np.array([0.2]), 0.0,
                                                                       0.01)
    calls.extend([1] * 10)
    assert np.array_equal(stepper.step(np.array([0.5, 0.1]), np.array([0.2]), 0.0, 0.01), ref)


@pytest.mark.parametrize("system", [VanDerPol(), Pendulum(), Linear(A=((0.0, 1.0), (-2.0, -0.3)),
                                                                    B=((0.0, 1.0), (1.0, 0.5)))],
                         ids=["vanderpol", "pendulum", "linear_m2"])
def test_constant_input_matrix_gives_the_same_bits(system):
    """With constant_input_matrix the stepper forms G·u once per step; its steps equal, bit for bit, those of the
    general path that evaluates rhs(x, u) in every call (the same subclass with the declaration switched off)."""
    general = type("General", (type(system),), {"constant_input_matrix": False})
    kw = {} if not isinstance(system, Linear) else {"A": system.A, "B": system.B}
    fast = HeldInputStepper(system, IntegratorOptions(batch=1))
    slow = HeldInputStepper(general(**kw), IntegratorOptions(batch=1))
    assert system.constant_input_matrix and fast._gu is None
    rng = np.random.default_rng(2)
    for _ in range(50):
        x, u = rng.uniform(-2, 2, 2), rng.uniform(-5, 5, system.m)
        assert np.array_equal(fast.step(x, u, 0.0, 0.01), slow.step(x, u, 0.0, 0.01))
    assert fast._gu is not None and slow._gu is None


def test_a_false_constant_declaration_is_refused():
    """check_system evaluates G on probe states: a system that declares constant_input_matrix but whose G varies
    is refused with a message that says which flag to change."""
    from kexp.errors import SystemDefinitionError
    from kexp.systems.base import check_system

    class Varying(VanDerPol):
        def input_matrix(self, x):
            g = super().input_matrix(x)
            g[..., 1, 0] = 1.0 + np.asarray(x)[..., 0] ** 2
            return g

    with pytest.raises(SystemDefinitionError, match="constant_input_matrix = False"):
        check_system(Varying())
    check_system(type("Honest", (Varying,), {"constant_input_matrix": False})())
