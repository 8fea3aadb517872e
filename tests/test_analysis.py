import csv
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from kexp.analysis.figures import paper_figure, theorem1_figure
from kexp.analysis.theorem1 import estimate_constants, measured_error
from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.app.results import table

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]
RESULTS = Path(__file__).resolve().parents[1] / "results"


@pytest.fixture(scope="module")
def logged_runs(tmp_path_factory):
    out = []
    for preset in ("+experiment=vanderpol", "+experiment=pendulum"):
        d = tmp_path_factory.mktemp(preset.split("=")[1])
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = compose(config_name="config", overrides=[preset, "sim.T=2.0", "logging.rrd=false",
                                                            "logging.progress=false", "clf.grid=21"])
        run(cfg, d, echo=lambda *_: None)
        out.append(d)
    return out


def test_theorem1_bound_is_above_the_measured_error(logged_runs, tmp_path):
    for d in logged_runs:
        png, facts = theorem1_figure(d, tmp_path / "t1.png", horizon=2.0)
        assert png.exists() and png.stat().st_size > 10_000
        assert facts["nu"] > 0 and facts["l_x"] > 0
        assert facts["max_ratio_error_to_bound"] < 1.0, facts


def test_constants_grow_with_the_model_error():
    """A deliberately poor model (degree 2, from 5 short trajectories) has a larger ν than a good one."""
    from kexp.data import Box, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    s = VanDerPol()
    good = identify(s, collect(s, Box(60, -2.5, 2.5), DataConfig(T=5.0)), Monomials(2, 5, include_constant=False))
    poor = identify(s, collect(s, Box(5, -2.5, 2.5), DataConfig(T=2.0)), Monomials(2, 2, include_constant=False))
    cg, cp = estimate_constants(s, good, n_traj=30), estimate_constants(s, poor, n_traj=30)
    assert cp.nu > cg.nu and abs(cp.l_x - cg.l_x) < 0.5 * cg.l_x
    t = np.linspace(0, 1, 11)
    assert np.all(np.diff(cg.bound(t)) > 0) and cg.bound(np.zeros(1))[0] == 0.0
    x = np.zeros((3, 2))
    assert measured_error(good, np.arange(3) * 0.01, x, np.zeros((2, 1))).shape == (3,)


def test_theorem1_constants_of_an_exact_model():
    """On a system whose dictionary spans a Koopman-invariant subspace (ẋ1 = μx1, ẋ2 = λ(x2 − x1²) on
    x1^a x2^b, a + 2b ≤ 2, with G = [0, 1]ᵀ) the model's vector field is the system's: ν is rounding (measured
    4e-12), and l_x lies between ‖∂f/∂x‖ at x1 = 0 (max(|μ|, |λ|)) and at |x1| = 1, the box's edge."""
    from kexp.data import Box, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import SlowManifold
    s = SlowManifold(mu=-0.3, lam=-1.0, inputs="x2")
    model = identify(s, collect(s, Box(20, -1.0, 1.0), DataConfig(T=2.0)), Monomials(2, 2, weights=(1, 2)))
    c = estimate_constants(s, model, n_traj=30)
    assert c.nu < 1e-8
    jac = lambda x1: np.array([[s.mu, 0.0], [-2 * s.lam * x1, s.lam]])  # noqa: E731
    assert np.linalg.norm(jac(0.0), 2) - 1e-6 <= c.l_x <= np.linalg.norm(jac(1.0), 2) + 1e-6


def test_paper_figure_from_a_log(logged_runs, tmp_path):
    png = paper_figure(logged_runs[0] / "run.mcap", tmp_path / "fig.png")
    assert png.stat().st_size > 20_000


def test_results_table_reproduces_the_committed_table():
    csvs = sorted(RESULTS.glob("*.csv"))
    assert csvs, "results/*.csv are committed (results/robustness.sh ROW makes one)"
    committed = (RESULTS / "table.md").read_text().strip()
    assert table(csvs).strip() == committed
    # and the committed numbers say what the README says: both working presets ≥ 95/100
    for name in ("vanderpol_lmpc", "pendulum_lmpc"):
        with open(RESULTS / f"{name}.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == 100 and sum(r["success"] == "True" for r in rows) >= 95


USER_SYSTEM = '''
from dataclasses import dataclass
from typing import ClassVar
from kexp.systems import VanDerPol

@dataclass(frozen=True)
class PolishVdp(VanDerPol):
    name: ClassVar[str] = "polish_vdp"
'''


def test_theorem1_without_the_users_system_module_is_one_line(tmp_path, monkeypatch, capsys):
    """A run of a user's system (system.name=module:Class); kexp-figures theorem1 from a shell where that module
    is not importable: one line that names the module and PYTHONPATH, exit code 2 (was a traceback)."""
    import sys
    from kexp.analysis import figures
    mod_dir = tmp_path / "mods"
    mod_dir.mkdir()
    (mod_dir / "kexp_polish_user_sys.py").write_text(USER_SYSTEM)
    monkeypatch.syspath_prepend(str(mod_dir))
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            *(o for o in SMALL if not o.startswith("controller.")), "controller=sontag",
            "system.name=kexp_polish_user_sys:PolishVdp"])
    run(cfg, tmp_path / "run", echo=lambda *_: None)
    # the figure works while the module is importable ...
    png, _ = theorem1_figure(tmp_path / "run", tmp_path / "ok.png", horizon=1.0)
    assert png.stat().st_size > 10_000
    # ... and fails in one line once it is not
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p != str(mod_dir)])
    monkeypatch.delitem(sys.modules, "kexp_polish_user_sys")
    with pytest.raises(SystemExit) as exc:
        figures.main(["theorem1", str(tmp_path / "run"), "-o", str(tmp_path / "t1.png")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"kexp-figures: error: {tmp_path / 'run'}: cannot rebuild the run's system")
    assert "'kexp_polish_user_sys'" in err[0] and "PYTHONPATH" in err[0]
    assert not (tmp_path / "t1.png").exists()


# a 3-state system (the shipped `linear` with a triple integrator-like A), the cheap Sontag law, tiny settings
LINEAR3 = ["system=linear", "system.params.A=[[0,1,0],[0,0,1],[-1,-2,-2]]", "system.params.B=[[0],[0],[1]]",
           "controller=sontag", "data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=2", "sim.T=2.0",
           "clf.grid=11", "logging.rrd=false", "sim.tol=0.5"]


def _kexp() -> list[str]:
    import shutil
    import sys
    exe = Path(sys.executable).parent / "kexp"
    return [str(exe)] if exe.exists() else [shutil.which("kexp") or "kexp"]


@pytest.fixture(scope="module")
def sweep3(tmp_path_factory):
    """3 jobs of a 3-state sweep: two initial conditions and a 2-component x0 (rejected: an error job)."""
    import subprocess
    sweep = tmp_path_factory.mktemp("linear3") / "sweep"
    proc = subprocess.run(_kexp() + ["--multirun", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                                     f"hydra.sweep.dir={sweep}", *LINEAR3,
                                     "sim.x0=[0.5,0.5,0.5],[0.8,-0.5,0.2],[0.1,0.2]"],
                          capture_output=True, text=True, timeout=300, cwd=sweep.parent)
    assert proc.returncode == 2, proc.stderr[-3000:]   # all 3 jobs ran; the error job makes the exit code 2
    assert proc.stderr.strip().splitlines()[-1] == f"kexp: 1 of 3 jobs stopped with an error; see kexp-report {sweep}"
    return sweep


def test_roa_of_a_3_state_sweep_draws_labelled_projections(sweep3, tmp_path, capsys):
    import json
    from kexp.analysis import figures
    from kexp.analysis.roa import roa_figure
    summaries = {p.parent.name: json.loads(p.read_text()) for p in sweep3.glob("*/summary.json")}
    assert summaries["2"]["status"] == "error" and "give 3 finite numbers" in summaries["2"]["message"]
    successes = sum(bool(s.get("metrics", {}).get("success")) for s in summaries.values())
    png, facts = roa_figure(sweep3, tmp_path / "roa.png")
    assert png.stat().st_size > 20_000
    (g,) = facts["groups"]
    assert g["label"] == "linear" and g["n"] == 3 and g["runs"] == 3 and g["drawn"] == 2
    assert g["successes"] == successes
    assert g["panels"] == [f"projection onto ({a}, {b}) of 3 states" for a, b in (("x1", "x2"), ("x1", "x3"),
                                                                                   ("x2", "x3"))]
    # the error job is listed with its reason, not dropped
    assert [f["job"] for f in facts["failed"]] == ["2"] and "give 3 finite numbers" in facts["failed"][0]["reason"]
    with pytest.raises(SystemExit) as exc:
        figures.main(["roa", str(sweep3), "-o", str(tmp_path / "cli.png")])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"linear: n = 3, success {successes}/3 (1 without a usable x0, not drawn)" in out
    assert "error: 2 sim.x0=[0.1,0.2]: error: sim.x0=[0.1, 0.2]: give 3 finite numbers" in out


def test_paper_figure_of_a_3_state_run_labels_its_projection(sweep3, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt
    titles = []
    real_close = plt.close

    def close_keeping_titles(fig):
        titles.extend(ax.get_title() for ax in fig.axes if ax.get_visible())
        real_close(fig)
    monkeypatch.setattr(plt, "close", close_keeping_titles)
    png = paper_figure(sweep3 / "0" / "run.mcap", tmp_path / "p.png")
    assert png.stat().st_size > 20_000
    assert titles == ["states over time", "input (closed loop)", "phase portrait, projection onto (x1, x2) of 3 states"]


def test_roa_of_a_mixed_folder_draws_one_row_per_group(sweep3, logged_runs, tmp_path):
    """A folder holding a 3-state sweep and two single runs of other systems (Van der Pol, pendulum): three
    groups, each in its own row of panels, never one scatter; too many groups: one line listing them."""
    import shutil
    from kexp.analysis.roa import RoaError, roa_figure
    mixed = tmp_path / "mixed"
    shutil.copytree(sweep3, mixed / "linear3")
    for d in logged_runs:
        shutil.copytree(d, mixed / d.name, ignore=shutil.ignore_patterns("*.npz"))
    png, facts = roa_figure(mixed, tmp_path / "roa.png")
    assert png.stat().st_size > 20_000
    by = {g["label"]: g for g in facts["groups"]}
    assert set(by) == {"vanderpol", "pendulum"} | {g["label"] for g in facts["groups"] if g["n"] == 3}
    assert len(by) == 3
    assert by["vanderpol"]["n"] == 2 and by["vanderpol"]["panels"] == ["success over initial conditions"]
    assert by["vanderpol"]["runs"] == 1 and by["pendulum"]["runs"] == 1
    (lin,) = [g for g in facts["groups"] if g["n"] == 3]
    assert lin["runs"] == 3 and len(lin["panels"]) == 3 and lin["label"].startswith("system=linear")
    assert len(facts["failed"]) == 1
    with pytest.raises(RoaError) as exc:
        roa_figure(mixed, tmp_path / "no.png", max_groups=2)
    msg = str(exc.value)
    assert "\n" not in msg and "3 groups of runs" in msg and "vanderpol (1 runs)" in msg and "pendulum" in msg
    assert not (tmp_path / "no.png").exists()
