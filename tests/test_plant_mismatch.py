"""Plant mismatch (sim.plant_params) and the true-model baselines: the LQR (and the NMPC oracle, built by the same
call) know the plant the closed loop runs on, not the nominal system the data and the model come from."""
import numpy as np
import scipy.linalg as sla
from hydra import compose, initialize_config_dir

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.recording import read_log

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "sim.T=1.0", "clf.grid=11",
         "logging.rrd=false", "logging.progress=false", "controller=lqr"]


def _vdp_lqr_gain(mu: float, q: float = 1.0, r: float = 1.0) -> np.ndarray:
    """K (1, 2) of the LQR on Van der Pol's linearisation at 0 (ẋ1 = x2, ẋ2 = −x1 + μ x2 + u), Q = q I, R = r,
    from scipy's Riccati solver on the matrices written out here (not kexp's linearise)."""
    A = np.array([[0.0, 1.0], [-1.0, mu]])
    B = np.array([[0.0], [1.0]])
    X = sla.solve_continuous_are(A, B, q * np.eye(2), r * np.eye(1))
    return B.T @ X / r


def test_the_lqr_baseline_is_the_mismatched_plants(tmp_path):
    """A run with +sim.plant_params.mu=2.0 and controller=lqr: every logged input is the saturated LQR of the
    plant (μ = 2) at the logged state, to rounding; the nominal (μ = 1) LQR's inputs differ by more than 0.1."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL + ["+sim.plant_params.mu=2.0", "cache.enabled=false"])
    summary = run(cfg, tmp_path, echo=lambda *_: None)
    assert summary["plant"]["mismatch"] == {"mu": {"nominal": 1.0, "plant": 2.0}}
    steps = read_log(tmp_path / "run.mcap").messages("/step")
    assert len(steps) == 100
    x = np.array([s["x_meas"] for s in steps])
    u = np.array([s["u"] for s in steps])
    K_plant, K_nominal = _vdp_lqr_gain(2.0), _vdp_lqr_gain(1.0)
    # K_plant ≈ [0.414, 4.414], K_nominal ≈ [0.414, 2.682]: the gains differ in the rate's coefficient
    assert abs(K_plant[0, 1] - K_nominal[0, 1]) > 1.5
    np.testing.assert_allclose(u, np.clip(-x @ K_plant.T, -5.0, 5.0), rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(u - np.clip(-x @ K_nominal.T, -5.0, 5.0))) > 0.1
