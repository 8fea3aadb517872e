"""Far from the origin (issue 13): the working Van der Pol preset's LMPC against the true-model oracle and LQR,
from a fixed sample of initial conditions in [-2, 2]² outside [-1, 1]², all costs computed here."""
import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from kexp.app.main import CONF_DIR, run

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
