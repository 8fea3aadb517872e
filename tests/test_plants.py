"""Plants (kexp.plants): kexp's integrator as a plant changes no number, a user's class closes the loop (equal to
the built-in run where it integrates the same system), data come from a plant, and every misuse is one line."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from cli import console_script
from kexp.app.conf import CONF_DIR
from kexp.app.experiment import config_dict, run
from kexp.control.explicit import LqrController
from kexp.data import Box, DataConfig, collect
from kexp.data.excitation import Excitation
from kexp.errors import ConfigError, PlantError
from kexp.plants import CheckedPlant, IntegratorPlant, PlantConfig, PlantSystem, make_plant
from kexp.plants.collect import collect_from_plant
from kexp.recording import read_log
from kexp.recording.diff import diff_logs
from kexp.simulate import SimConfig, closed_loop
from kexp.simulate.stepper import HeldInputStepper
from kexp.systems import VanDerPol

TESTS = str(Path(__file__).parent)
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11"]


def _compose(overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def _rig(name="VdpRig", **params):
    return make_plant(PlantConfig(kind="python", target=f"plant_rigs:{name}", params=params))


def test_the_integrator_plant_takes_the_loops_old_steps():
    """closed_loop's default plant steps x(t_k) → x(t_k+1) exactly as the loop did before plants existed: one
    HeldInputStepper over [kΔ, (k+1)Δ) from the previous state; equal bit for bit."""
    system = VanDerPol()
    ctrl = LqrController(system, -5.0, 5.0)
    cfg = SimConfig(T=3.0, dt=0.01)
    res = closed_loop(system, ctrl, np.array([1.5, -1.0]), cfg)
    stepper, x = HeldInputStepper(system, cfg.integrator), [np.array([1.5, -1.0])]
    t = np.arange(cfg.n_steps + 1) * cfg.dt
    for k in range(cfg.n_steps):
        x.append(stepper.step(x[-1], res.u[k], float(t[k]), float(t[k + 1])))
    assert np.array_equal(res.x, np.array(x))


def test_a_user_plant_closes_the_loop_as_kexps_integrator_does():
    """VdpRig integrates Van der Pol with scipy's solve_ivp (DOP853, rtol 1e-10): the LQR loop on it follows the
    built-in loop to the integrators' tolerance (measured 5.6e-16 over 300 steps here; bound 1e-8, far below the
    tolerance, for other BLAS and libm)."""
    system = VanDerPol()
    cfg = SimConfig(T=3.0, dt=0.01)
    x0 = np.array([1.5, -1.0])
    ref = closed_loop(system, LqrController(system, -5.0, 5.0), x0, cfg)
    got = closed_loop(system, LqrController(system, -5.0, 5.0), x0, cfg, plant=_rig())
    assert got.status == "completed" and got.x.shape == ref.x.shape
    assert np.max(np.abs(got.x - ref.x)) < 1e-8


def test_the_experiment_on_a_user_plant_equals_the_built_in_run(tmp_path):
    """The same config, once on kexp's integrator and once on the user's class (plant=python): the same model
    (from the cache: the plant is not part of the model's key when the data are simulated), the same cost and
    final error to the integrators' tolerance; the summary says which plant ran."""
    base = SMALL + [f"cache.dir={tmp_path / 'cache'}", "logging.rrd=false"]
    a = run(_compose(base), tmp_path / "a", echo=lambda *_: None)
    b = run(_compose(base + ["plant=python", "plant.target=plant_rigs:VdpRig"]), tmp_path / "b",
            echo=lambda *_: None)
    assert any(name.startswith("model-") for name in b["cache"]["hits"])
    assert a["plant"]["kind"] == "integrator" and b["plant"]["kind"] == "python"
    assert b["plant"]["id"] == "plant_rigs:VdpRig"
    assert b["metrics"]["cost"] == pytest.approx(a["metrics"]["cost"], rel=1e-7)
    assert b["metrics"]["final_error"] == pytest.approx(a["metrics"]["final_error"], rel=1e-5, abs=1e-9)
    info = read_log(tmp_path / "b" / "run.mcap").one("/run_info")
    assert info["plant"]["kind"] == "python" and info["plant"]["id"] == "plant_rigs:VdpRig"
    assert read_log(tmp_path / "b" / "run.mcap").one("/summary")["plant"]["kind"] == "python"
    # kexp-diff under the portable policy: every step and prediction agree; the config and the summary say which
    # plant ran, so those differ, and the open loop (one integration of the whole horizon against 200 held steps
    # of the rig: measured 2.1e-10 apart, just past the portable rule's bound) is compared here to 1e-8
    a_log, b_log = read_log(tmp_path / "a" / "run.mcap"), read_log(tmp_path / "b" / "run.mcap")
    d = diff_logs(a_log, b_log, policy="portable")
    assert {ch for ch, (_, n_diff) in d.per_channel.items() if n_diff} <= {"/config", "/summary", "/open_loop"}
    assert d.per_channel["/step"] == (200, 0) and d.per_channel["/prediction"][1] == 0
    ol = [np.array([m["x"] for m in log.messages("/open_loop")]) for log in (a_log, b_log)]
    assert ol[0].shape == ol[1].shape == (201, 2) and np.max(np.abs(ol[0] - ol[1])) < 1e-8


def test_the_default_config_has_no_plant_section_in_its_hash():
    """kexp's integrator is the default: its runs' config (and hash, and cache keys) are as before plants."""
    assert "plant" not in config_dict(_compose([]))
    assert config_dict(_compose(["plant=python", "plant.target=plant_rigs:VdpRig"]))["plant"]["kind"] == "python"


@pytest.mark.parametrize("mode,text", [
    ("raise", "step 5 (t = 0.05 s) raised RuntimeError: the rig's amplifier tripped; check the plant's step(u)"),
    ("nan", "step 5 (t = 0.05 s) returned a non-finite state [nan, 0.0]"),
    ("shape", "step 5 (t = 0.05 s) returned shape (3,); return the next state as 2 numbers")])
def test_a_plant_that_fails_is_one_line_naming_the_step(mode, text):
    plant = _rig("FailingRig", after=5, mode=mode)
    plant.reset(np.array([0.5, 0.0]))
    for _ in range(5):
        plant.step(np.zeros(1))
    with pytest.raises(PlantError) as exc:
        plant.step(np.zeros(1))
    assert str(exc.value).startswith(f"plant 'plant_rigs:FailingRig': {text}") and "\n" not in str(exc.value)


def test_a_failing_plant_ends_the_run_with_exit_2_and_keeps_its_steps(tmp_path):
    """The rig trips at step 30: one line, exit 2, and the log holds steps 0…30 (the 31st decision was logged
    before its plant step failed); summary.json says error."""
    env = {**__import__("os").environ, "PYTHONPATH": TESTS}
    out = tmp_path / "run"
    proc = subprocess.run([console_script("kexp"), f"hydra.run.dir={out}", "logging.rrd=false",
                           f"cache.dir={tmp_path / 'cache'}", *SMALL, "plant=python",
                           "plant.target=plant_rigs:FailingRig", "+plant.params={after: 30}"],
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 2, proc.stderr[-2000:]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("kexp: error:")]
    assert errors == ["kexp: error: plant 'plant_rigs:FailingRig': step 30 (t = 0.3 s) raised RuntimeError: the "
                      "rig's amplifier tripped; check the plant's step(u)"]
    steps = read_log(out / "run.mcap").messages("/step")
    assert [s["k"] for s in steps] == list(range(31))
    assert json.loads((out / "summary.json").read_text())["status"] == "error"


@pytest.mark.parametrize("target,params,text", [
    ("plant_rigs:Nope", {}, "plant 'plant_rigs:Nope': module 'plant_rigs' has no 'Nope'"),
    ("json:JSONDecoder", {}, "plant 'json:JSONDecoder': module 'json' is part of Python's standard library"),
    ("plant_rigs:VdpRig", {"dt": 0.0}, "plant 'plant_rigs:VdpRig': dt=0.0; set dt to the plant's sampling time in s"),
    ("plant_rigs:VdpRig", {"wobble": 1}, "plant 'plant_rigs:VdpRig': plant_rigs:VdpRig(**{'wobble': 1}) raised "
                                         "TypeError"),
    ("plant_rigs:FailingRig", {"mode": 3}, None)])
def test_a_bad_user_plant_is_one_line(target, params, text):
    if text is None:   # built fine: a bad mode only shows when stepped
        assert make_plant(PlantConfig(kind="python", target=target, params=params)).n == 2
        return
    with pytest.raises(PlantError) as exc:
        make_plant(PlantConfig(kind="python", target=target, params=params))
    assert str(exc.value).startswith(text) and "\n" not in str(exc.value)


def test_a_class_without_step_is_refused(tmp_path, monkeypatch):
    (tmp_path / "half_rig.py").write_text("class Half:\n    dt = 0.01\n    n, m = 2, 1\n    def reset(self, x0):\n"
                                          "        pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(PlantError, match=r"^plant 'half_rig:Half': no step\(\); a plant class needs dt, reset\(x0\) "
                                         r"and step\(u\) -> x$"):
        make_plant(PlantConfig(kind="python", target="half_rig:Half"))


@pytest.mark.parametrize("kw,text", [
    ({"kind": "rig"}, "plant.kind='rig'; valid: ('integrator', 'gymnasium', 'python')"),
    ({"kind": "gymnasium"}, "plant.kind=gymnasium needs plant.env_id, e.g. plant.env_id=Pendulum-v1"),
    ({"kind": "python", "target": "rig"}, "plant.kind=python needs plant.target=<module>:<Class>"),
    ({"kind": "python", "target": "a:B", "env_id": "Pendulum-v1"}, "plant.env_id='Pendulum-v1' does not apply to "
                                                                  "plant.kind=python"),
    ({"kind": "integrator", "state": "qpos_qvel"}, "plant.state='qpos_qvel' applies to plant.kind=gymnasium only"),
    ({"kind": "python", "target": "a:B", "equilibrium": [0.0, "x"]}, "plant.equilibrium=")])
def test_plant_config_is_validated(kw, text):
    with pytest.raises(ConfigError) as exc:
        PlantConfig(**kw)
    assert str(exc.value).startswith(text)


def test_data_from_a_plant_equal_simulated_data():
    """data.source.kind=plant on kexp's integrator plant: the same runs as collect() integrates (the same initial
    states and excitation draw), to the integrators' tolerance (measured 5.6e-16; bound 1e-8)."""
    system = VanDerPol()
    cfg = DataConfig(T=1.0, dt=0.01, seed=3, excitation=Excitation(low=-1.0, high=1.0, hold=10))
    sampler = Box(n_traj=6, low=-1.0, high=1.0)
    ref = collect(system, sampler, cfg)
    got = collect_from_plant(IntegratorPlant(system, 0.01), sampler, cfg, system.equilibrium, system.name)
    assert np.array_equal(got.u, ref.u) and got.valid.all()
    assert np.max(np.abs(got.x - ref.x)) < 1e-8
    assert got.report.source == "plant 'vanderpol': 6 runs, 6 of 6 excited (uniform)"


def test_data_from_a_plant_that_fails_keep_the_other_runs():
    """A rig that trips after 40 steps: every run is cut there (the rest masked), the report counts them."""
    system = VanDerPol()
    cfg = DataConfig(T=1.0, dt=0.01, excitation=Excitation(low=-1.0, high=1.0, hold=10))
    ds = collect_from_plant(_rig("FailingRig", after=40), Box(n_traj=4, low=-1.0, high=1.0), cfg,
                            system.equilibrium, "rig")
    assert ds.valid[:, :41].all() and not ds.valid[:, 41:].any()
    assert ds.n_pairs == 4 * 40
    assert "4 cut short by a failed step (first: trajectory 0: plant 'plant_rigs:FailingRig': step 40" in \
        ds.report.source
    with pytest.raises(PlantError, match=r"data\.dt=0\.02 s, but plant 'rig' steps Δ = 0\.01 s: set data\.dt=0\.01"):
        collect_from_plant(_rig(), Box(n_traj=2, low=-1.0, high=1.0), DataConfig(T=1.0, dt=0.02), np.zeros(2), "rig")


@pytest.mark.parametrize("overrides,text", [
    (["system=plant"], "system=plant is the system of an external plant: set plant=gymnasium"),
    (["system=plant", "plant=python", "plant.target=plant_rigs:VdpRig"],
     "plant 'plant_rigs:VdpRig' has no formula to simulate data from: set data.source.kind=plant"),
    (["system=plant", "plant=python", "plant.target=plant_rigs:VdpRig", "data.source.kind=plant"],
     "plant 'plant_rigs:VdpRig': G is unknown, so B cannot be projected from it: set "
     "identification.inputs=regression"),
    (["system=plant", "plant=python", "plant.target=plant_rigs:VdpRig", "data.source.kind=plant",
      "identification.inputs=regression", "controller=nmpc"],
     "controller=nmpc (the true-model oracle) needs a formula (F, G); plant 'plant_rigs:VdpRig' has none"),
    (["plant=python", "plant.target=plant_rigs:VdpRig", "+plant.params={dt: 0.02}"],
     "data.dt=0.01 s, but plant 'plant_rigs:VdpRig' steps Δ = 0.02 s: set data.dt=0.02"),
    (["plant=python", "plant.target=plant_rigs:VdpRig", "+sim.plant_params.mu=2.0"],
     "sim.plant_params applies to kexp's integrator (plant=integrator), not plant.kind=python"),
    (["system=pendulum", "plant=python", "plant.target=plant_rigs:LinearRig"], None)])
def test_what_a_plant_cannot_do_is_refused_before_any_work(tmp_path, overrides, text):
    if text is None:   # LinearRig has n=2, m=1 like the pendulum: the dt is what differs
        text = "data.dt=0.01 s, but plant 'plant_rigs:LinearRig' steps Δ = 0.05 s"
    with pytest.raises((ConfigError, PlantError)) as exc:
        run(_compose([s for s in SMALL if "lmpc" not in s] + overrides), tmp_path / "r", echo=lambda *_: None)
    assert str(exc.value).startswith(text), str(exc.value)
    assert not (tmp_path / "r" / "model.npz").exists()


def test_plant_bounds_narrow_the_controllers():
    """A plant's own input bounds become the controller's where the config is wider, with one line."""
    from kexp.app.build import ControllerSpec, narrow_bounds

    class Boxed:
        m = 1

        def input_bounds(self):
            return np.array([-2.0]), np.array([2.0])

    lines = []
    spec = ControllerSpec(kind="lmpc", law="sontag", law_params={}, u_min=-5.0, u_max=1.5)
    out = narrow_bounds(spec, Boxed(), lines.append)
    assert (out.u_min, out.u_max) == (-2.0, 1.5)
    assert lines == ["input bounds: the plant accepts [-2] … [2]; the controller uses u_min=-2.0, u_max=1.5"]
    with pytest.raises(ConfigError, match="do not overlap the plant's input bounds"):
        narrow_bounds(ControllerSpec(kind="lmpc", law="sontag", law_params={}, u_min=3.0, u_max=5.0), Boxed())


def test_plant_system_has_no_formula():
    s = PlantSystem(plant_id="rig", n_states=3, n_inputs=2, x_eq=(1.0, 0.0, 0.0), names=("a", "b", "c"))
    assert (s.n, s.m, s.name, s.state_names) == (3, 2, "rig", ("a", "b", "c"))
    assert np.array_equal(s.equilibrium, [1.0, 0.0, 0.0])
    with pytest.raises(PlantError, match=r"^plant 'rig' has no formula \(F is unknown\)"):
        s.drift(np.zeros((1, 3)))
    with pytest.raises(PlantError, match="plant.equilibrium has 2 entries; plant 'rig' has n=3"):
        PlantSystem(plant_id="rig", n_states=3, n_inputs=1, x_eq=(0.0, 0.0))


def test_data_from_a_plant_key_the_model_by_the_plant(tmp_path):
    """With data.source.kind=plant, the plant's config (its class and parameters) and identity are part of the
    model's cache key: a rig with another μ is identified anew, the same rig again is a hit."""
    base = [o for o in SMALL if "lmpc" not in o] + [
        "system=plant", "plant=python", "plant.target=plant_rigs:VdpRig", "data.source.kind=plant",
        "identification.inputs=regression", "+data.excitation={low: -1.0, high: 1.0}", "logging.mcap=false",
        "logging.rrd=false", "controller=model_lqr", f"cache.dir={tmp_path / 'cache'}"]
    quiet = dict(echo=lambda *_: None)
    a = run(_compose(base), tmp_path / "a", **quiet)
    b = run(_compose(base + ["+plant.params={mu: 1.5}"]), tmp_path / "b", **quiet)
    c = run(_compose(base), tmp_path / "c", **quiet)
    assert not any(h.startswith("model-") for h in a["cache"]["hits"] + b["cache"]["hits"])
    assert any(h.startswith("model-") for h in c["cache"]["hits"])
    assert a["model"]["eigenvalues"] != b["model"]["eigenvalues"] and c["model"]["eigenvalues"] == \
        a["model"]["eigenvalues"]
