"""``kexp system=data``: identification, the CLF and its certificate from recorded runs alone (no F, no G, no class);
the closed loop only on a plant (kexp/app/data_only.py)."""
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import kexp
from cli import console_script
from kexp.app.conf import CONF_DIR
from kexp.app.data_only import STATUS, STOP_LINE
from kexp.app.experiment import run
from kexp.app.sweep_progress import outcome_text, verdict
from kexp.data import Box, DataConfig, collect
from kexp.data.excitation import Excitation
from kexp.data.files import write_runs
from kexp.errors import ConfigError, KexpError
from kexp.identify import KoopmanBilinearModel
from kexp.identify.datasystem import DataSystem
from kexp.identify.model import _ARRAYS
from kexp.systems import make_system

FAST = ["identification.inputs=regression", "dictionary.degree=3", "clf.grid=11", "logging.rrd=false",
        "cache.enabled=false"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """20 forced Van der Pol runs of 3 s as CSV (t, x1, x2, u1): what a rig gives."""
    folder = tmp_path_factory.mktemp("rig") / "runs"
    ds = collect(make_system("vanderpol"), Box(20, -2.5, 2.5),
                 DataConfig(T=3.0, seed=7, excitation=Excitation(low=-1.0, high=1.0, hold=10)))
    write_runs(ds, folder, "csv")
    return folder


def _compose(overrides):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def _data(runs):
    return ["system=data", "data.source.kind=files", f"data.source.path={runs}"]


def test_the_command_identifies_certifies_and_stops_without_a_plant(runs, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run([console_script("kexp"), *_data(runs), *FAST, f"hydra.run.dir={out}"],
                          capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONPATH": os.pathsep.join(
                              [str(Path(kexp.__file__).parents[1]), os.environ.get("PYTHONPATH", "")])})
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == STOP_LINE and lines.count(STOP_LINE) == 1
    assert "Koopman bilinear model of data: k = 9 eigen-coordinates, m = 1 input(s), n = 2 states" in proc.stdout
    assert "inputs: B, b regressed from forced data" in proc.stdout and "certificate:" in proc.stdout
    assert any(line.startswith("result: identified and certified, no closed loop (no plant): k = 9") for line in lines)
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["model.npz", "summary.json"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == STATUS and summary["completed"] is True and "metrics" not in summary
    assert summary["plant"]["kind"] == "none" and summary["model"]["k"] == 9
    assert summary["clf"]["status"] == "optimal" and summary["clf"]["r"] > 0 and summary["clf"]["certificate"]
    # the same model as kexp.fit on the folder (both: DataSystem, the files streamed, B regressed)
    model = KoopmanBilinearModel.load(out / "model.npz")
    fitted = kexp.fit(runs, degree=3)
    assert all(np.array_equal(getattr(model, a), getattr(fitted.model, a)) for a in _ARRAYS)
    assert summary["model"]["prediction_error"] == pytest.approx(fitted.report["prediction_error"], rel=1e-12)
    # kexp-report counts it as completed (what it set out to do), with no success (no closed loop)
    from kexp.app.aggregate import aggregate
    (row,) = aggregate(out)
    assert row["ok"] is True and row["status"] == STATUS and row["success"] is None and row["reason"] == ""


@pytest.mark.parametrize("extra,fragment", [
    ([], "system=data: G is unknown, so B cannot be projected from it: set identification.inputs=regression"),
    (["identification.inputs=regression", "data.source.kind=simulate"], "set data.source.kind=files"),
    (["identification.inputs=regression", "controller=nmpc"], "controller=nmpc (the true-model oracle) needs a "
                                                              "formula"),
    (["identification.inputs=regression", "controller=lqr", "controller.linearisation=formula"],
     "controller.linearisation=formula needs F and G"),
    (["identification.inputs=regression", "data.pairs=euler"], "data.pairs=euler needs F"),
    (["identification.inputs=regression", "identification.compare_projection=true"], "compare_projection needs G"),
    (["identification.inputs=regression", "system.params.equilibrium=[0.0]"], "give 2 finite number(s)"),
    (["identification.inputs=regression", "+system.params.mu=1.0"], "system.params.mu: not a parameter"),
])
def test_what_needs_f_or_g_is_refused_in_one_line_before_any_work(runs, tmp_path, extra, fragment):
    with pytest.raises(ConfigError) as exc:
        run(_compose(_data(runs) + extra), tmp_path, echo=lambda *_: None)
    assert fragment in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "model.npz").exists() and not (tmp_path / "summary.json").exists()


def test_runs_without_inputs_or_without_files_are_refused(tmp_path):
    ds = collect(make_system("vanderpol"), Box(4, -1.0, 1.0), DataConfig(T=1.0))
    write_runs(ds, tmp_path / "free", "npz")
    with pytest.raises(ConfigError, match=r"have no inputs \(run_0000.npz has no u column or array\)"):
        run(_compose(_data(tmp_path / "free") + ["identification.inputs=regression"]), tmp_path / "a",
            echo=lambda *_: None)
    (tmp_path / "empty").mkdir()
    with pytest.raises(KexpError, match="holds no"):
        run(_compose(_data(tmp_path / "empty") + ["identification.inputs=regression"]), tmp_path / "b",
            echo=lambda *_: None)


def test_with_a_plant_the_loop_runs(runs, tmp_path):
    """plant=python (tests/plant_rigs.py's Van der Pol rig): the closed loop runs on it from sim.x0."""
    lines = []
    metrics = run(_compose(_data(runs) + FAST + ["plant=python", "plant.target=plant_rigs:VdpRig",
                                                 "controller=sontag", "sim.T=0.5"]), tmp_path, echo=lines.append)
    assert STOP_LINE not in lines
    assert metrics["status"] == "completed" and metrics["plant"]["kind"] == "python"
    assert metrics["metrics"]["final_error"] < np.hypot(0.7, 0.5)   # h pulls x toward 0 within 0.5 s
    from kexp.data.layout import run_layout   # its log is a recorded run of system 'data': n, m, dt read back
    layout = run_layout(tmp_path / "run.mcap")
    assert (layout.n, layout.m, layout.dt, layout.system) == (2, 1, 0.01, "data")


def test_a_plant_with_other_dimensions_is_refused(tmp_path):
    ds = collect(make_system("slow_manifold", {"inputs": "both"}), Box(4, -1.0, 1.0),
                 DataConfig(T=1.0, excitation=Excitation(low=-1.0, high=1.0, hold=10)))
    write_runs(ds, tmp_path / "two_inputs", "csv")
    with pytest.raises(ConfigError, match=r"has n=2, m=1, the recorded runs n=2, m=2: give runs of this plant"):
        run(_compose(_data(tmp_path / "two_inputs") + FAST + ["plant=python", "plant.target=plant_rigs:VdpRig"]),
            tmp_path / "out", echo=lambda *_: None)


def test_a_sweep_job_line_of_an_identify_only_run():
    summary = {"status": STATUS, "completed": True, "model": {"k": 9}, "clf": {"status": "optimal"}}
    assert verdict(summary) == "identified"
    assert outcome_text(summary) == "k = 9, CLF optimal (no plant: no closed loop)"


def test_the_data_system_has_no_formula():
    s = DataSystem(n_states=2, n_inputs=1)
    assert s.name == "data" and s.state_names == ("x1", "x2") and np.array_equal(s.equilibrium, [0.0, 0.0])
    for call in (s.drift, s.input_matrix):
        with pytest.raises(ConfigError, match="known only from its data: [FG] is unknown") as exc:
            call(np.zeros((1, 2)))
        assert "\n" not in str(exc.value)
