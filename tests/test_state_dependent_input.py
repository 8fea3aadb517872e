"""An input matrix G that varies with the state.  Every other shipped system has a constant G, so the bilinear model's
input term u·B z (paper: L_G Ψ = BΨ) was only ever fed a constant field.  Here:

- exact recovery where the answer is known: the slow manifold with G = [0, 1 + x1]ᵀ keeps L_G of the weighted
  monomials inside their span, so projection (G known) and regression (G unknown, from forced data) give the exact
  bilinear model, and its forced predictions are the system's;
- the cart pendulum (G = [0, −cos(x1)]ᵀ, L_G leaves any polynomial span) with its working preset, end to end
  against the true-model oracle, with G known and with G regressed;
- two inputs (m = 2), one of them scaled by the state, brought in as a user's own class with Van der Pol's working
  preset."""
import numpy as np
import pytest
from dataclasses import dataclass
from typing import ClassVar

from kexp.app.experiment import run
from kexp.control.oracle import register_symbolic
from kexp.data import Box, DataConfig, Excitation, collect, integrate
from kexp.dictionary import Monomials
from kexp.errors import SystemDefinitionError
from kexp.identify import IdentifyConfig, identify
from kexp.systems import CartPendulum, ControlAffineSystem, SlowManifold, VanDerPol, make_system

from test_app import _compose




# ---------------------------------------------------------------------------------------------------------------
# exact: the slow manifold with G = [0, 1 + x1]ᵀ
@pytest.fixture(scope="module")
def varying():
    s = SlowManifold(mu=-0.3, lam=-1.0, inputs="x2_varying")
    unforced = collect(s, Box(20, -1.0, 1.0), DataConfig(T=2.0))
    forced = collect(s, Box(20, -1.0, 1.0), DataConfig(T=2.0, excitation=Excitation(-1.0, 1.0, 5)))
    return s, unforced, forced


def test_the_varying_input_matrix_is_what_it_says():
    s = SlowManifold(inputs="x2_varying")
    x = np.array([[0.5, -1.0], [-2.0, 3.0]])
    assert np.array_equal(s.input_matrix(x), [[[0.0], [1.5]], [[0.0], [-1.0]]])
    assert s.m == 1 and not s.constant_input_matrix        # the closed loop evaluates G in every rhs call
    assert make_system("slow_manifold", {"inputs": "x2_varying"}) == s
    with pytest.raises(SystemDefinitionError, match="use 'x2', 'both' or 'x2_varying'"):
        SlowManifold(inputs="x1")


@pytest.mark.parametrize("degree", [2, 4])
def test_projection_recovers_the_exact_bilinear_model(varying, degree):
    """L_G x1^a x2^b = b(1 + x1)x1^a x2^(b−1): inside the weighted span, so Assumption 1 holds exactly and
    L_G φ = B φ + b at every state, not only on the data (residual measured 1e-15, identity 4e-13 for |x| ≤ 1.5;
    asserted at 1e-10 and 1e-8)."""
    s, unforced, _ = varying
    model = identify(s, unforced, Monomials(2, degree, weights=(1, 2)))
    assert max(model.report["input_projection_residual"]) < 1e-10
    x = np.random.default_rng(7).uniform(-1.5, 1.5, (50, 2))
    J = model.lift_jacobian(x)
    lg = np.einsum("Mkn,Mn->Mk", J, s.input_matrix(x)[:, :, 0])
    assert np.max(np.abs(lg - (model.lift(x) @ model.B[0].T + model.b[0]))) < 1e-8


def test_forced_predictions_are_the_system_s(varying):
    """The bilinear model is exact on the invariant span: its prediction of the state under a varying input is the
    integrated system's (measured 7e-13 over 1 s; asserted at 1e-7, the integrator's tolerance).  The model of the
    same system with G frozen at x_eq (inputs=x2) misses by 2e-2 to 4e-2."""
    s, unforced, _ = varying
    model = identify(s, unforced, Monomials(2, 2, weights=(1, 2)))
    frozen = SlowManifold(mu=-0.3, lam=-1.0, inputs="x2")
    frozen_model = identify(frozen, collect(frozen, Box(20, -1.0, 1.0), DataConfig(T=2.0)),
                            Monomials(2, 2, weights=(1, 2)))
    u = np.random.default_rng(7).uniform(-1, 1, (100, 1))
    for x0 in ([0.6, -0.4], [-0.9, 0.8]):
        truth = integrate(s, np.array([x0]), np.arange(101) * 0.01, u[None])[0]
        assert np.max(np.abs(model.predict(np.array(x0), u)[0] - truth)) < 1e-7
        assert np.max(np.abs(frozen_model.predict(np.array(x0), u)[0] - truth)) > 1e-2


def test_regression_recovers_the_exact_model_without_g(varying):
    """G unknown: regressing the held-input map on forced data gives projection's input field (measured 8e-14)."""
    s, _, forced = varying
    model = identify(s, forced, Monomials(2, 2, weights=(1, 2)),
                     IdentifyConfig(inputs="regression", compare_projection=True))
    vp = model.report["input_vs_projection"]
    assert vp["B"] < 1e-6 and vp["b"] < 1e-6 and vp["field_x"] < 1e-6, vp
    assert model.report["input_regression_residual"] < 1e-10


# ---------------------------------------------------------------------------------------------------------------
# the cart pendulum
def test_the_cart_pendulum():
    s = CartPendulum()
    # linearisation: [[0, 1], [g/l, −d]]: a saddle, λ = (−d ± √(d² + 4g/l)) / 2
    h = 1e-6
    A = np.stack([(s.drift(np.eye(2)[i] * h) - s.drift(-np.eye(2)[i] * h)) / (2 * h) for i in range(2)], axis=1)
    assert np.allclose(A, [[0, 1], [1, -0.1]], atol=1e-9)
    assert np.allclose(np.sort(np.linalg.eigvals(A).real), [(-0.1 - np.sqrt(4.01)) / 2, (-0.1 + np.sqrt(4.01)) / 2])
    x = np.array([[0.0, 0.0], [np.pi / 3, 1.0], [np.pi, 0.0]])
    assert np.allclose(s.input_matrix(x)[:, 1, 0], [-1.0, -0.5, 1.0]) and not s.constant_input_matrix
    assert np.allclose(CartPendulum(length=2.0).input_matrix(x)[:, 1, 0], [-0.5, -0.25, 0.5])
    assert s.angle_period == (2 * np.pi, None) and s.state_names == ("theta", "omega")
    for bad, match in (({"length": 0.0}, "length=0.0; use a length > 0"), ({"damping": np.nan}, "damping=nan")):
        with pytest.raises(SystemDefinitionError, match=match):
            CartPendulum(**bad)


SMALL = ["logging.rrd=false", "logging.mcap=false", "logging.progress=false"]
# two of the results' x0 (results/robustness.sh's first 10) where the pendulum is falling away from upright
FAR = [(0.9512, 0.4341), (-0.7437, -0.8069)]


@pytest.fixture(scope="module")
def far_runs(tmp_path_factory):
    """J per controller and x0 (inf for a failed run).  Measured (J): oracle (NMPC, 100 steps) 11.83 and 11.13;
    LMPC 12.19, 11.29 (×1.030, ×1.014); LMPC with G regressed 12.21, 11.41; LMPC with 20 steps 15.08, 13.63
    (×1.27, ×1.22); the 20-step oracle fails on both (J ≈ 92, ‖x(T)‖ ≈ 1.9)."""
    configs = {"oracle": ["controller=nmpc", "controller.horizon=100"], "lmpc": [],
               "lmpc_reg": ["data.excitation={low: -1.0, high: 1.0, hold: 10}", "identification.inputs=regression"],
               "lmpc_20": ["controller.lmpc.horizon=20"], "oracle_20": ["controller=nmpc", "controller.horizon=20"]}
    out, cache = {}, f"cache.dir={tmp_path_factory.mktemp('cache')}"    # one identification per data set
    for name, ov in configs.items():
        for i, x0 in enumerate(FAR):
            r = run(_compose(["+experiment=cart_pendulum", *SMALL, cache, *ov, f"sim.x0=[{x0[0]},{x0[1]}]"]),
                    tmp_path_factory.mktemp(f"{name}{i}"), echo=lambda line: None)
            assert r["status"] == "completed", (name, x0, r["message"])
            out[name, i] = r["metrics"]["cost"] if r["metrics"]["success"] else np.inf
    return out


def test_the_working_preset_on_the_cart_pendulum_is_near_the_oracle(far_runs):
    """G known (projected) or regressed from forced data: within 6 % of the 100-step oracle where the pendulum
    falls away (measured 1.4–3.2 %; the margin covers other BLAS kernels' rounding through 1000 steps)."""
    for i in range(len(FAR)):
        J = far_runs["oracle", i]
        assert np.isfinite(J)
        assert far_runs["lmpc", i] < 1.06 * J
        assert far_runs["lmpc_reg", i] < 1.06 * J


def test_the_preset_s_horizon_and_the_oracle_s_are_needed(far_runs):
    """Why the preset keeps the paper's 100 steps and the oracle of results/sweep_lib.sh has 100 here: with 20
    steps the LMPC costs > 15 % more (measured 22–27 %) and the oracle fails (measured on both x0)."""
    for i in range(len(FAR)):
        assert far_runs["lmpc_20", i] > 1.15 * far_runs["oracle", i]
        assert far_runs["oracle_20", i] == np.inf


# ---------------------------------------------------------------------------------------------------------------
# two inputs, one scaled by the state
@dataclass(frozen=True)
class TwoInputVanDerPol(ControlAffineSystem):
    """Van der Pol with u1 acting on ẋ1 and u2 on ẋ2 through the gain 1 + x1²/2."""

    name: ClassVar[str] = "two_input_vanderpol"
    n: ClassVar[int] = 2
    m: ClassVar[int] = 2

    def drift(self, x):
        return VanDerPol().drift(x)

    def input_matrix(self, x):
        x = np.asarray(x, dtype=float)
        g = np.zeros(x.shape[:-1] + (2, 2))
        g[..., 0, 0] = 1.0
        g[..., 1, 1] = 1.0 + 0.5 * x[..., 0] ** 2
        return g


def _two_input_symbolic(system, x):
    import casadi as ca
    return (ca.vertcat(x[1], (1 - x[0] ** 2) * x[1] - x[0]),
            ca.vertcat(ca.horzcat(1, 0), ca.horzcat(0, 1 + 0.5 * x[0] ** 2)))


register_symbolic(TwoInputVanDerPol, _two_input_symbolic)


def test_two_inputs_by_config_alone(tmp_path):
    """m = 2 with Van der Pol's working preset, unchanged: the LMPC is within 2 % of the oracle (measured 0.09 % and
    0.17 %) and at or below LQR on the true linearisation (measured 0.9 % and 1.6 % above the oracle)."""
    cache = f"cache.dir={tmp_path / 'cache'}"
    base = ["+experiment=vanderpol", f"system.name={__name__}:TwoInputVanDerPol", *SMALL, cache]
    for i, x0 in enumerate([(0.548, 0.817), (0.395, 0.938)]):
        J = {}
        for name, ov in (("lmpc", []), ("lqr", ["controller=lqr"]),
                         ("oracle", ["controller=nmpc", "controller.horizon=20"])):
            r = run(_compose([*base, *ov, f"sim.x0=[{x0[0]},{x0[1]}]"]), tmp_path / f"{name}{i}",
                    echo=lambda line: None)
            assert r["status"] == "completed" and r["metrics"]["success"], (name, x0, r["message"])
            J[name] = r["metrics"]["cost"]
            if name == "lmpc":
                assert len(r["model"]["input_projection_residual"]) == 2      # one B per input
        assert J["lmpc"] < 1.02 * J["oracle"] and J["lmpc"] <= J["lqr"], J
