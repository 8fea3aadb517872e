"""Noise and mismatch (issue 12 item 4): seeded measurement noise on the data (data.noise), measurement noise in
the closed loop (sim.noise; the log keeps the true x and the measured x_meas), an additive process disturbance on
the input (sim.disturbance), and plant mismatch (sim.plant_params)."""
import numpy as np
import pytest

from kexp.data import Circle, DataConfig, collect
from kexp.data.noise import (DATA_NOISE, DISTURBANCE, MEASUREMENT_NOISE, NoiseConfig, add_measurement_noise,
                             data_rms, noise_rng)
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


# -- the app: closed-loop noise, disturbance, plant mismatch, in the config, the summary and the MCAP log ---------
import json  # noqa: E402
import subprocess  # noqa: E402
from pathlib import Path  # noqa: E402

from hydra import compose, initialize_config_dir  # noqa: E402

from kexp.app.cache import model_key  # noqa: E402
from kexp.app.conf import CONF_DIR  # noqa: E402
from kexp.app.experiment import config_dict, run  # noqa: E402
from kexp.data import IntegratorOptions, integrate  # noqa: E402
from kexp.identify import FORMAT_VERSION, KoopmanBilinearModel  # noqa: E402
from kexp.recording import diff_logs, read_log  # noqa: E402

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]
NOISY = ["sim.noise.std=0.02", "sim.noise.seed=5", "sim.disturbance.std=0.3", "sim.disturbance.seed=7"]


def _cfg(overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=SMALL + list(overrides))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """name -> (out dir, summary): one model (cached) shared by all runs."""
    cache = tmp_path_factory.mktemp("cache")
    out = {}
    for name, ov in {"nominal": [], "noisy": NOISY, "noisy_again": NOISY,
                     "other_seed": ["sim.noise.std=0.02", "sim.noise.seed=6", "sim.disturbance.std=0.3",
                                    "sim.disturbance.seed=7"],
                     "mismatch": ["+sim.plant_params.mu=2.0"]}.items():
        d = tmp_path_factory.mktemp(name)
        out[name] = (d, run(_cfg(ov + [f"cache.dir={cache}"]), d, echo=lambda *_: None))
    return out


def _steps(d: Path):
    return read_log(d / "run.mcap").messages("/step")


def test_closed_loop_measurement_noise_has_the_requested_sigma(runs):
    d, summary = runs["noisy"]
    # the data's RMS per state about x_eq = 0, computed here from the data the run collected (its seeded config)
    from kexp.app.build import build_data
    data = collect(make_system("vanderpol"), *build_data(_cfg(NOISY).data))
    rms = np.sqrt(np.mean(data.x[data.valid] ** 2, axis=0))
    np.testing.assert_allclose(summary["noise"]["data_rms"], rms, rtol=1e-12)
    sigma = 0.02 * rms                                # relative: a fraction of the data's RMS per state
    np.testing.assert_allclose(summary["noise"]["sim_noise_std"], sigma, rtol=1e-12)
    steps = _steps(d)
    x = np.array([s["x"] for s in steps])
    v = np.array([s["x_meas"] for s in steps]) - x
    assert len(steps) == 200
    # exactly the seeded draws: the measurement noise's stream of seed 5, n numbers per step
    np.testing.assert_allclose(v, sigma * noise_rng(5, MEASUREMENT_NOISE).standard_normal((200, 2)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(v.std(axis=0), sigma, rtol=0.2)     # 200 samples: sampling error ≈ 5 %
    # the controller saw x_meas: z (and V) in the log are of the measured state
    model = KoopmanBilinearModel.load(d / "model.npz")
    np.testing.assert_allclose(np.array([s["z"] for s in steps[:20]]),
                               model.lift(np.array([s["x_meas"] for s in steps[:20]])), rtol=1e-12, atol=1e-12)
    assert not np.allclose(np.array([s["z"] for s in steps[:20]]), model.lift(x[:20]), atol=1e-6)


def test_disturbance_is_added_to_the_input_and_the_true_x_is_the_plant_under_u_plus_w(runs):
    d, summary = runs["noisy"]
    steps = _steps(d)
    w = np.array([s["w"] for s in steps])
    np.testing.assert_allclose(w, 0.3 * noise_rng(7, DISTURBANCE).standard_normal((200, 1)), atol=1e-12)
    assert summary["noise"]["disturbance_std"] == [0.3]
    system = make_system("vanderpol")
    opts = IntegratorOptions(batch=1)
    for k in (0, 50, 150):      # x is the TRUE state: x_{k+1} = plant flow from x_k under u_k + w_k (not x_meas)
        s0, s1 = steps[k], steps[k + 1]
        u = np.array(s0["u"]) + w[k]
        nxt = integrate(system, np.array([s0["x"]]), np.array([s0["t"], s1["t"]]), u[None, None], opts)[0, 1]
        np.testing.assert_allclose(s1["x"], nxt, rtol=1e-12, atol=1e-12)
    nominal = _steps(runs["nominal"][0])
    assert all(s["x_meas"] == s["x"] and s["w"] == [0.0] for s in nominal)


def test_same_seeds_give_identical_steps_and_another_seed_differs(runs):
    a, b, c = (runs[n][0] / "run.mcap" for n in ("noisy", "noisy_again", "other_seed"))
    res = diff_logs(a, b)       # exact on every deterministic channel
    assert res.equal, res.report()
    assert [p for _, p in read_log(a).channels["/step"]] == [p for _, p in read_log(b).channels["/step"]]
    res = diff_logs(a, c)
    assert not res.equal and res.first.channel in ("/config", "/step")
    assert _steps(runs["noisy"][0])[0]["x_meas"] != _steps(runs["other_seed"][0])[0]["x_meas"]


def test_plant_mismatch_runs_the_changed_plant(runs):
    d, summary = runs["mismatch"]
    nd, nominal = runs["nominal"]
    plant = {"kind": "integrator", "id": "vanderpol", "versions": {}}   # kexp's integrator (kexp.plants)
    assert summary["plant"] == {"params": {"mu": 2.0}, "mismatch": {"mu": {"nominal": 1.0, "plant": 2.0}}, **plant}
    assert nominal["plant"] == {"params": {"mu": 1.0}, "mismatch": {}, **plant}
    # the data and the model are the nominal system's: the mismatch run loads the nominal run's model
    assert summary["cache"]["hits"] and summary["cache"]["hits"][0].startswith("model-")
    assert KoopmanBilinearModel.load(d / "model.npz") == KoopmanBilinearModel.load(nd / "model.npz")
    ol = np.array([p["x"] for p in read_log(d / "run.mcap").messages("/open_loop")])
    x0, t = np.array(summary["x0"]), np.arange(len(ol)) * 0.01
    want = integrate(make_system("vanderpol", {"mu": 2.0}), x0[None], t, None, IntegratorOptions())[0]
    other = integrate(make_system("vanderpol"), x0[None], t, None, IntegratorOptions())[0]
    np.testing.assert_allclose(ol, want, rtol=1e-12, atol=1e-12)
    assert np.abs(ol - other).max() > 0.05
    xs, xn = np.array([s["x"] for s in _steps(d)]), np.array([s["x"] for s in _steps(nd)])
    assert np.array_equal(xs[0], xn[0]) and np.abs(xs - xn).max() > 1e-3
    log_summary = read_log(d / "run.mcap").one("/summary")
    assert log_summary["plant"]["mismatch"] == {"mu": {"nominal": 1.0, "plant": 2.0}}
    cfg = read_log(d / "run.mcap").one("/config")["config"]
    assert cfg["sim"]["plant_params"] == {"mu": 2.0} and cfg["sim"]["noise"]["std"] == 0.0


def test_data_noise_is_in_the_model_cache_key_and_the_sim_settings_are_not():
    base = model_key(config_dict(_cfg([])), FORMAT_VERSION)
    for ov in (["data.noise.std=0.01"], ["data.noise.std=0.01", "data.noise.seed=1"],
               ["data.noise.std=0.01", "data.noise.relative=false"]):
        assert model_key(config_dict(_cfg(ov)), FORMAT_VERSION) != base, ov
    assert len({model_key(config_dict(_cfg(["data.noise.std=0.01", f"data.noise.seed={s}"])), FORMAT_VERSION)
                for s in range(3)}) == 3
    for ov in (NOISY, ["+sim.plant_params.mu=2.0"]):
        assert model_key(config_dict(_cfg(ov)), FORMAT_VERSION) == base, ov


def test_data_noise_in_the_run_changes_the_model_and_is_reported(tmp_path):
    summary = run(_cfg(["data.noise.std=0.03", "sim.T=0.1", "cache.enabled=false"]), tmp_path / "noisy",
                  echo=lambda *_: None)
    clean = run(_cfg(["sim.T=0.1", "cache.enabled=false"]), tmp_path / "clean", echo=lambda *_: None)
    rms = np.array(summary["noise"]["data_rms"])
    assert clean["noise"]["data_noise_std"] is None and clean["noise"]["data_rms"] == summary["noise"]["data_rms"]
    np.testing.assert_allclose(summary["noise"]["data_noise_std"], 0.03 * rms, rtol=1e-12)
    model = KoopmanBilinearModel.load(tmp_path / "noisy" / "model.npz")
    assert any("measurement noise σ per state" in line for line in model.report["data"])
    saved = json.loads((tmp_path / "noisy" / "summary.json").read_text())
    assert saved["noise"]["data_noise_std"] == summary["noise"]["data_noise_std"]
    # the noise reached the model: its 1 s free response from (0.5, -0.5) moves by 0.35 (measured) against the
    # clean data's model (1.4 in size); 0.05 is far above rounding and far below that
    clean_model = KoopmanBilinearModel.load(tmp_path / "clean" / "model.npz")
    x0, u = np.array([0.5, -0.5]), np.zeros((100, 1))
    assert np.abs(model.predict(x0, u)[0] - clean_model.predict(x0, u)[0]).max() > 0.05


BAD = [
    ("sim.noise.std=-0.1", "sim.noise.std=-0.1: use a finite number >= 0"),
    ("data.noise.std=-1", "data.noise.std=-1: use a finite number >= 0"),
    ("sim.disturbance.std=-2", "sim.disturbance.std=-2: use a finite number >= 0"),
    ("data.noise.std=[0.1,0.1,0.1]", "data.noise.std=[0.1, 0.1, 0.1]: give one number or 2 (one per state)"),
    ("sim.disturbance.std=[0.1,0.1]", "give one number or 1 (one per input)"),
    ("+sim.plant_params.nu=1.0", "sim.plant_params.nu: not a parameter of system 'vanderpol'; valid: ['mu']"),
]


@pytest.mark.parametrize("override,message", BAD)
def test_bad_noise_and_plant_settings_fail_before_any_work(override, message, tmp_path):
    with pytest.raises(ConfigError) as exc:
        run(_cfg([override]), tmp_path, echo=lambda *_: None)
    assert message in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "model.npz").exists()


def test_bad_plant_param_at_the_cli_is_one_line_and_exit_2(tmp_path):
    import sys   # the running interpreter, not whatever `python` is first on PATH
    proc = subprocess.run([sys.executable, "-m", "kexp.app.main", *SMALL, "+sim.plant_params.damping=0.1",
                           f"hydra.run.dir={tmp_path}"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("kexp: error: sim.plant_params.damping: not a parameter of system 'vanderpol'; "
                                   "valid: ['mu']")


def test_the_recording_draws_the_measured_state_and_the_disturbance_only_when_present(runs, tmp_path):
    from kexp.recording.render import render
    from test_render import load_rrd, scalars
    ents = load_rrd(render(runs["noisy"][0] / "run.mcap", tmp_path / "noisy.rrd"))["entities"]
    steps = _steps(runs["noisy"][0])
    np.testing.assert_allclose(scalars(ents["/states/x2_meas"]), [s["x_meas"][1] for s in steps])
    np.testing.assert_allclose(scalars(ents["/input/w1"]), [s["w"][0] for s in steps])
    plain = load_rrd(render(runs["nominal"][0] / "run.mcap", tmp_path / "nominal.rrd"))["entities"]
    assert "/states/x1" in plain and not {"/states/x1_meas", "/input/w1"} & set(plain)


def test_closed_loop_gives_the_controller_only_the_measured_state():
    """closed_loop alone (no app): the controller's input is x + v, the plant integrates the true x under u + w."""
    from kexp.control import LqrController
    from kexp.simulate import Disturbance, SimConfig, closed_loop

    class Spy:
        name = "spy"

        def __init__(self):
            self.inner, self.seen = LqrController(make_system("vanderpol"), -5, 5), []

        def reset(self):
            self.inner.reset()

        def step(self, x, z):
            self.seen.append(np.array(x))
            return self.inner.step(x, z)

    spy = Spy()
    cfg = SimConfig(T=0.5, noise=NoiseConfig(std=[0.05, 0.0], relative=False, seed=2),
                    disturbance=Disturbance(std=0.1, seed=3))
    res = closed_loop(make_system("vanderpol", {"mu": 1.3}), spy, [0.7, -0.5], cfg)
    seen, x = np.array(spy.seen), res.x[:-1]
    np.testing.assert_array_equal(seen, [r.x_meas for r in res.records])
    np.testing.assert_array_equal(x, [r.x for r in res.records])
    np.testing.assert_allclose(seen - x, np.array([0.05, 0.0]) * noise_rng(2, MEASUREMENT_NOISE).standard_normal(
        (50, 2)), atol=1e-15)
    assert np.array_equal(seen[:, 1], x[:, 1])                   # σ = 0 for x2: measured exactly
    with pytest.raises(ConfigError, match=r"noise\.relative=true needs the data's RMS per state: pass it"):
        closed_loop(make_system("vanderpol"), spy, [0.7, -0.5], SimConfig(T=0.1, noise=NoiseConfig(std=0.01)))


def test_data_noise_applies_to_recorded_data_too(tmp_path):
    from kexp.data import write_runs
    clean = collect(make_system("vanderpol"), Circle(n_traj=20, radius=2.5), DataConfig(T=3.0))
    write_runs(clean, tmp_path / "runs", "npz")
    summary = run(_cfg(["data.source.kind=files", f"data.source.path={tmp_path / 'runs'}", "data.noise.std=0.02",
                        "data.noise.seed=4", "sim.T=0.1", "cache.enabled=false"]), tmp_path / "out",
                  echo=lambda *_: None)
    rms = np.sqrt(np.mean(clean.x[clean.valid] ** 2, axis=0))      # from the data themselves (x_eq = 0)
    np.testing.assert_allclose(summary["noise"]["data_rms"], rms, rtol=1e-12)
    np.testing.assert_allclose(summary["noise"]["data_noise_std"], 0.02 * rms, rtol=1e-12)
