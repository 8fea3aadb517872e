"""results/plants_ocp.py: the numerical linearisation through a plant's step equals Pendulum-v1's known one, and the
long-horizon search saves an x0 the saturated LQR loses (by a fall and a swing back), never costs more than a
succeeding LQR, and writes its CSV."""
from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gymnasium")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def ocp():
    spec = importlib.util.spec_from_file_location("plants_ocp", ROOT / "results" / "plants_ocp.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def pendulum(ocp):
    from kexp.plants.gymnasium import make_gymnasium_plant
    cfg, x_eq, T, tol, r = ocp.experiment_settings("gym_pendulum")
    plant = make_gymnasium_plant(cfg)
    yield ocp.Shooter(plant, np.zeros(2) if x_eq is None else x_eq, r), T, tol
    plant.close()


def test_linearisation_is_pendulum_v1s(pendulum):
    """θ̇' = θ̇ + (15 sin θ + 3u)Δ, θ' = θ + θ̇'Δ (gymnasium's source, g = 10, l = m = 1) at (0, 0): A and B exactly
    known.  Central differences of a smooth step: error O(h²) ≈ 1e-10 plus rounding (float32 u: 1e-7 relative)."""
    sh, _, _ = pendulum
    A, B = sh.linearise()
    d = 0.05
    np.testing.assert_allclose(A, [[1 + 15 * d * d, d], [15 * d, 1.0]], atol=1e-8)
    np.testing.assert_allclose(B, [[3 * d * d], [3 * d]], rtol=1e-6)


def test_saves_what_the_lqr_loses(pendulum, ocp):
    """From θ = −0.557 (past the static hold limit asin 0.4 = 0.41) the saturated LQR falls and ends 5 rad off; the
    search brings the pendulum back to upright, which costs a fall and a swing (J > 100)."""
    sh, T, tol = pendulum
    x0 = np.array([-0.557, 0.045])
    x, _ = sh.rollout(x0, np.zeros((0, 1)), int(round(T / sh.dt)))
    assert np.linalg.norm(x[-1]) > 1.0
    ok, err, cost, _ = ocp.solve(sh, x0, T, tol, 4.0, 3, 60)
    assert ok and err < tol
    assert 100 < cost < 130


def test_never_costlier_than_a_succeeding_lqr(pendulum, ocp):
    sh, T, tol = pendulum
    x0 = np.array([0.2, 0.3])
    x, u = sh.rollout(x0, np.zeros((0, 1)), int(round(T / sh.dt)))
    lqr_cost = sh.cost(x, u)
    ok, err, cost, _ = ocp.solve(sh, x0, T, tol, 4.0, 3, 60)
    assert ok and cost <= lqr_cost


def test_writes_the_csv(ocp, tmp_path):
    src = tmp_path / "x0.csv"
    src.write_text("x0_1,x0_2\n0.1,0.0\n")
    assert ocp.main(["gym_pendulum", "--x0-csv", str(src), "-o", str(tmp_path)]) == 0
    rows = list(csv.DictReader(open(tmp_path / "gym_pendulum_ocp.csv")))
    assert list(rows[0]) == ["x0_1", "x0_2", "feasible", "final_error", "cost"]
    assert rows[0]["feasible"] == "True" and float(rows[0]["final_error"]) < 1e-2
