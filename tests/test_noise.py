"""Noise and mismatch (issue 12 item 4): seeded measurement noise on the data (data.noise), measurement noise in
the closed loop (sim.noise; the log keeps the true x and the measured x_meas), an additive process disturbance on
the input (sim.disturbance), and plant mismatch (sim.plant_params)."""
import numpy as np
import pytest

from kexp.data import Circle, DataConfig, collect
from kexp.data.noise import NoiseConfig, add_measurement_noise, data_rms
from kexp.errors import ConfigError
from kexp.systems import make_system


@pytest.fixture(scope="module")
def clean():
    # 40 trajectories × 301 samples × 2 states = 24 080 noise samples per state
    return collect(make_system("vanderpol"), Circle(n_traj=40, radius=2.5), DataConfig(T=3.0))


@pytest.mark.parametrize("std,relative", [(0.01, True), (0.03, True), (0.05, False)])
def test_data_noise_has_the_requested_sigma(clean, std, relative):
    noisy = add_measurement_noise(clean, std, relative, seed=0)
    rms = data_rms(clean)
    want = std * rms if relative else np.full(2, std)
    e = (noisy.x - clean.x).reshape(-1, 2)
    assert e.shape[0] >= 10_000
    # sampling error of a std estimate over 24 080 samples: ≈ 0.46 %; allow 3 %
    np.testing.assert_allclose(e.std(axis=0), want, rtol=0.03)
    np.testing.assert_allclose(e.mean(axis=0), 0.0, atol=4 * want.max() / np.sqrt(e.shape[0]))
    np.testing.assert_allclose(noisy.report.noise_std, want, rtol=1e-12)    # the report says the σ used
    assert any("measurement noise σ per state" in line for line in noisy.report.lines())
    assert noisy.x.flags.writeable is False and np.array_equal(noisy.valid, clean.valid)


def test_data_rms_is_about_the_equilibrium(clean):
    rms = data_rms(clean)
    np.testing.assert_allclose(rms, np.sqrt(np.mean(clean.x.reshape(-1, 2) ** 2, axis=0)))
    np.testing.assert_allclose(data_rms(clean, [1.0, 0.0])[0],
                               np.sqrt(np.mean((clean.x[..., 0] - 1.0) ** 2)))


def test_data_noise_is_reproducible_from_its_seed(clean):
    a = add_measurement_noise(clean, 0.01, seed=3)
    b = add_measurement_noise(clean, 0.01, seed=3)
    c = add_measurement_noise(clean, 0.01, seed=4)
    assert np.array_equal(a.x, b.x)
    assert not np.array_equal(a.x, c.x)
    assert np.abs(a.x - c.x).max() > 0.01     # not just rounding: another draw
    assert add_measurement_noise(clean, 0.0) is clean


@pytest.mark.parametrize("kwargs,match", [
    ({"std": -0.01}, r"noise\.std=-0\.01: use a finite number >= 0"),
    ({"std": float("nan")}, r"noise\.std=nan"),
    ({"std": [0.01, -1]}, r"noise\.std=\(0\.01, -1\)"),
    ({"seed": 1.5}, r"noise\.seed=1\.5: expected an integer"),
    ({"relative": "yes"}, r"noise\.relative='yes'"),
])
def test_noise_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        NoiseConfig(**kwargs)


def test_noise_per_state_needs_one_value_per_state(clean):
    with pytest.raises(ConfigError, match=r"give one number or 2"):
        add_measurement_noise(clean, [0.1, 0.1, 0.1])
    per_state = add_measurement_noise(clean, [0.0, 0.02], relative=False, seed=1)
    assert np.array_equal(per_state.x[..., 0], clean.x[..., 0])
    assert per_state.report.noise_std == (0.0, 0.02)
