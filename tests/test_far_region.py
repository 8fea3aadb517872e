"""Far from the origin (issue 13): the working Van der Pol preset's LMPC against the true-model oracle and LQR,
from a fixed sample of initial conditions in [-2, 2]² outside [-1, 1]², all costs computed here."""
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run

pytest.importorskip("casadi")

# from np.random.default_rng(3).uniform(-2, 2, (2, 30)).T, the sample: ICs 0, 15, 20, 21 (measured
# LMPC/oracle 1.0003, 0.9999, 1.0002, 1.0009 with the preset's 20-step horizon, 1.039, 1.034, 1.059, 1.022 with
# 100 steps; LQR/oracle 1.091, 1.141, 1.139, 1.226)
X0 = np.random.default_rng(3).uniform(-2, 2, (2, 30)).T[[0, 15, 20, 21]]


def _costs(tmp_path, overrides):
    out = []
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        for i, x0 in enumerate(X0):
            cfg = compose(config_name="config", overrides=[
                "+experiment=vanderpol", f"sim.x0=[{float(x0[0])!r},{float(x0[1])!r}]", "logging.rrd=false",
                "logging.mcap=false", "logging.progress=false", f"cache.dir={tmp_path / 'cache'}", *overrides])
            d = run(cfg, tmp_path / f"{'_'.join(overrides) or 'lmpc'}{i}", echo=lambda *_: None)
            assert d["metrics"]["success"], (overrides, x0)
            out.append(d["metrics"]["cost"])
    return np.array(out)


def test_lmpc_meets_the_oracle_far_out_and_beats_lqr(tmp_path):
    lmpc = _costs(tmp_path, [])
    oracle = _costs(tmp_path, ["controller=nmpc", "controller.horizon=20"])
    lqr = _costs(tmp_path, ["controller=lqr"])
    ratio, lqr_ratio = lmpc / oracle, lqr / oracle
    assert np.all(ratio <= 1.15), ratio                     # the worst-case bound
    assert np.median(ratio) <= 1.03, ratio                  # the median target; measured 1.0003
    assert np.median(ratio) < np.median(lqr_ratio), (ratio, lqr_ratio)   # measured 1.036 vs 1.140


class _EnergyLaw:
    """u = −bound·sign(x2) (tanh over 1e-3), sampled and held each step like kexp's controllers."""
    name = "energy"

    def __init__(self, bound):
        self.bound = bound

    def reset(self):
        pass

    def step(self, x0, z0):
        from kexp.control.lmpc import ControlStep
        return ControlStep(u=np.array([-self.bound * np.tanh(x0[1] / 1e-3)]), status="explicit", qp_status="none",
                           iterations=0, qp_iterations=0, solve_time=0.0, region="n/a", active="none", binds=False,
                           slack=0.0, fallback=False, reason="")


def test_at_half_a_unit_of_input_no_law_leaves_van_der_pols_cycle():
    """Why no input bound makes LQR fail on Van der Pol where a better controller succeeds (README, "Over the whole
    data region"): with |u| ≤ 0.5 even the law that takes energy out fastest at every instant, u = −0.5·sign(x2)
    (E = |x|²/2, Ė = μ(1 − x1²)x2² + x2·u), is caught on a cycle of amplitude ≈ 1.49 from r = 1 and r = 2 — over a
    cycle the negative damping puts in more than 0.5|x2| takes out; with |u| ≤ 0.75 it is not (the orbit shrinks
    into the set |x1| ≤ 0.75, x2 = 0 where this law stops).  So bounds separate controllers on Van der Pol by speed
    (cost), not by success.  Run by kexp's closed loop on its VanDerPol (the law held over each 0.01 s step), and
    checked against the continuous-time law on the equations written out here (scipy): the same cycle to 0.01."""
    from scipy.integrate import solve_ivp

    from kexp.simulate import SimConfig, closed_loop
    from kexp.systems import VanDerPol

    def late_orbit(bound, r):
        run = closed_loop(VanDerPol(), _EnergyLaw(bound), [r, 0.0], SimConfig(T=60.0, dt=0.01))
        late = run.x[np.arange(len(run.x)) * 0.01 > 40].T
        return np.abs(late[0]).max(), late[1].min(), late[1].max()

    def late_orbit_reference(bound, r):
        def f(_t, x):
            return [x[1], (1 - x[0] ** 2) * x[1] - x[0] - bound * np.tanh(x[1] / 1e-3)]
        sol = solve_ivp(f, [0, 60], [r, 0.0], rtol=1e-8, atol=1e-10, max_step=0.01)
        late = sol.y[:, sol.t > 40]
        return np.abs(late[0]).max(), late[1].min(), late[1].max()

    for r in (1.0, 2.0):
        amp, lo, hi = late_orbit(0.5, r)
        assert 1.4 < amp < 1.6 and lo < -0.5 and hi > 0.5          # still cycling after 40 s (measured 1.4925)
        ref = late_orbit_reference(0.5, r)
        assert np.max(np.abs(np.array([amp, lo, hi]) - ref)) < 0.01, ((amp, lo, hi), ref)
    amp, lo, hi = late_orbit(0.75, 2.0)
    assert amp < 0.75 and max(-lo, hi) < 0.2                       # energy taken out (measured 0.005)
