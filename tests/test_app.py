import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.errors import ConfigError
from kexp.identify import KoopmanBilinearModel

# every option of every config group (presets apart: test_presets_*), read from conf/ so that a new one is tested
GROUPS = {d.name: sorted(f.stem for f in d.glob("*.yaml")) for d in sorted(Path(CONF_DIR).iterdir())
          if d.is_dir() and d.name != "experiment"}
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11"]


def _compose(overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


# an option that needs more keys to build: what a user adds on the command line (tests/plant_rigs.py)
NEEDS = {("plant", "python"): ["plant.target=plant_rigs:VdpRig"],
         ("plant", "gymnasium"): ["plant.env_id=Pendulum-v1", "data.dt=0.05"],
         ("system", "plant"): ["plant=python", "plant.target=plant_rigs:VdpRig"]}


@pytest.mark.parametrize("group,option", [(g, o) for g, opts in GROUPS.items() for o in opts])
def test_every_config_option_composes_and_builds(group, option, tmp_path):
    from kexp.app.build import (build_clf, build_data, build_dictionary, build_identification, build_sim,
                                build_system)
    from kexp.app.build import build_controller_spec, build_external_plant, build_logging, build_plant_config
    if (group, option) == ("system", "data"):   # a system known from recorded runs: one run (t, x1, x2, u1)
        (tmp_path / "run.csv").write_text("t,x1,x2,u1\n0,1,0,0.5\n0.01,1,0.01,\n")
    cfg = _compose([f"{group}={option}", *NEEDS.get((group, option), []),
                    *(["data.source.kind=files", f"data.source.path={tmp_path}"] if option == "data" else [])])
    plant_cfg = build_plant_config(cfg.plant)
    if (group, option) == ("system", "data"):
        from kexp.app.data_only import build_data_system
        system = build_data_system(cfg.system, build_data(cfg.data)[1])
        assert (system.n, system.m) == (2, 1)
    elif plant_cfg.external:
        plant, system = build_external_plant(plant_cfg, cfg.system, cfg.sim)
        plant.close()
    else:
        system = build_system(cfg.system)
    build_data(cfg.data)
    build_identification(cfg.identification)
    build_dictionary(cfg.dictionary, system.n)
    build_clf(cfg.clf)
    build_sim(cfg.sim, system, 0.01)
    build_logging(cfg.logging)
    assert build_controller_spec(cfg.controller).kind in ("lmpc", "explicit", "lqr", "nmpc")


def test_the_option_list_is_conf_s():
    """The parametrisation above reads conf/: the groups and options a user sees (README) are all there."""
    assert GROUPS["system"] == ["cart_pendulum", "data", "duffing", "linear", "pendulum", "plant", "slow_manifold",
                                "vanderpol"]
    assert GROUPS["plant"] == ["gymnasium", "integrator", "python"]
    assert GROUPS["controller"] == ["lie_gain", "lmpc", "lqr", "model_lqr", "nmpc", "sontag"]
    assert {"data", "dictionary", "identification", "clf", "sim", "plant", "logging", "cache"} <= set(GROUPS)


def test_default_job_end_to_end_small(tmp_path):
    cfg = _compose(SMALL)
    lines = []
    metrics = run(cfg, tmp_path, echo=lines.append)
    assert metrics["status"] == "completed" and metrics["model"]["k"] == 9
    assert (tmp_path / "model.npz").exists()
    summary = json.loads((tmp_path / "summary.json").read_text())
    # degree 3 from 20 short trajectories: measured 29.9 % held-out 1-s error
    assert summary["model"]["k"] == 9 and summary["model"]["prediction_error"]["1_s"] < 0.4
    assert KoopmanBilinearModel.load(tmp_path / "model.npz").k == 9
    assert any("Koopman bilinear model of vanderpol" in line for line in lines)
    assert any(line.startswith("result: ") for line in lines)
    m = summary["metrics"]
    assert m["max_abs_u"] <= 5.0 and m["fallbacks"] == 0
    # 2 s from (0.7, -0.5): measured ‖x(2)‖ = 0.27 (halved at least)
    assert m["final_error"] < 0.5 * (0.7 ** 2 + 0.5 ** 2) ** 0.5


def test_unknown_key_is_named(tmp_path):
    cfg = _compose(SMALL + ["+identification.methd=qr"])
    with pytest.raises(ConfigError, match=r"identification\.methd: unknown key"):
        run(cfg, tmp_path, echo=lambda *_: None)


@pytest.mark.parametrize("preset,needle", [
    ("controller:\n  lmpc:\n    horizn: 10\n", "controller.lmpc.horizn: Key 'horizn' not in 'LmpcConfigSchema'; valid keys:"),
    ("clf:\n  gamma: fast\n", "clf.gamma: Value 'fast' of type 'str' could not be converted to Float"),
    ("sim:\n  open_loop: sometimes\n", "sim.open_loop: Value 'sometimes' is not a valid bool"),
])
def test_a_users_preset_is_checked_against_the_schema_at_composition(tmp_path, preset, needle):
    """A misspelled key or a wrong type in a preset file fails when Hydra composes it, with the full key named."""
    import shutil
    from hydra.errors import HydraException
    from kexp.app.precheck import composition_error_line
    conf = tmp_path / "conf"
    shutil.copytree(CONF_DIR, conf)
    (conf / "experiment" / "mine.yaml").write_text("# @package _global_\n" + preset)
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        with pytest.raises(HydraException) as err:
            compose(config_name="config", overrides=["+experiment=mine"])
    line = composition_error_line(err.value)
    assert needle in line and "\n" not in line


def test_schema_defaults_are_the_stages_defaults():
    """The schema is derived from the stages' dataclasses: a key left out of a YAML file gets the stage's default."""
    from kexp.app.schema import filled, register
    from kexp.clf import ClfConfig
    from kexp.control import LmpcConfig
    from kexp.identify import IdentifyConfig
    cfg = filled(register())
    assert cfg.controller.lmpc.horizon == LmpcConfig().horizon == 100
    assert cfg.clf.rhat_floor == ClfConfig().rhat_floor == 0.05
    assert cfg.identification.rcond == IdentifyConfig().rcond == 1e-13
    assert cfg.data.integrator.rtol == 1e-10 and cfg.logging.prediction_every == 20
    # the logging schema is hand-written: its defaults must be the ones conf/logging/default.yaml states
    yaml_logging = OmegaConf.load(Path(CONF_DIR) / "logging" / "default.yaml")
    for key, value in yaml_logging.items():
        assert cfg.logging[key] == value, key


def test_cli_bad_input_exits_2_with_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "kexp.app.main", "data.dt=-0.1", f"hydra.run.dir={tmp_path}"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    err = proc.stderr.strip().splitlines()
    assert err == ["kexp: error: data.dt=-0.1: the sampling time must be > 0"]
    # the run folder keeps Hydra's config record but no empty main.log (hydra/job_logging: none)
    assert (tmp_path / ".hydra" / "config.yaml").is_file() and (tmp_path / ".hydra" / "overrides.yaml").is_file()
    assert not list(tmp_path.glob("*.log")) and (tmp_path / "summary.json").is_file()


@pytest.mark.parametrize("override,needle", [
    ("controller.u_min=6.0", "controller.u_min=6.0, controller.u_max=5.0"),
    ("sim.x0=[0.1]", "sim.x0=[0.1]: give 2 finite numbers"),
    ("clf.c_lower=2.0", "need 0 < c_lower < c_upper"),
    ("controller.lmpc.horizon=0", "lmpc.horizon=0"),
    ("+controller.lmpc.foo=1", "controller.lmpc.foo: unknown key"),
    ("controller.kind=mpc", "controller.kind='mpc'"),
    ("logging.prediction_every=-1", "logging.prediction_every=-1"),
    ("logging.writer=thread", "logging.writer='thread'; valid: sync"),
])
def test_bad_controller_settings_are_named(tmp_path, override, needle):
    cfg = _compose(SMALL + [override])
    with pytest.raises(ConfigError, match=re.escape(needle)):
        run(cfg, tmp_path, echo=lambda *_: None)


def test_a_sweep_job_draws_no_progress_bar_on_a_terminal(tmp_path, monkeypatch):
    """logging.progress=auto draws the bar when stderr is a terminal; a sweep job (auto_progress=False) does not:
    parallel jobs share the terminal and their bars would overwrite each other."""
    import io

    class Terminal(io.StringIO):
        def isatty(self):
            return True
    cfg = _compose([*(o for o in SMALL if not o.startswith("controller.")), "controller=sontag", "sim.T=0.5",
                    "logging.rrd=false", "logging.mcap=false"])
    assert cfg.logging.progress == "auto"
    for auto, expect_bar in ((None, True), (False, False)):
        err = Terminal()
        monkeypatch.setattr(sys, "stderr", err)
        run(cfg, tmp_path / str(auto), echo=lambda *_: None, auto_progress=auto)
        assert ("closed loop [" in err.getvalue()) is expect_bar, err.getvalue()[-300:]


@pytest.mark.parametrize("preset, base, bound", [("pendulum_tight", "pendulum", 1.0),
                                                 ("vanderpol_tight", "vanderpol", 0.75)])
def test_tight_bound_presets_are_the_working_presets_with_the_bound(preset, base, bound):
    """+experiment=<system>_tight composes to exactly +experiment=<system> with |u| ≤ bound (the rows
    <system>-uN of results/regions.sh)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from kexp.app.conf import CONF_DIR
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        tight = compose(config_name="config", overrides=[f"+experiment={preset}"])
        ref = compose(config_name="config", overrides=[f"+experiment={base}", f"controller.u_min={-bound}",
                                                       f"controller.u_max={bound}"])
    assert OmegaConf.to_container(tight) == OmegaConf.to_container(ref)
    assert tight.controller.u_max == bound and tight.controller.u_min == -bound
