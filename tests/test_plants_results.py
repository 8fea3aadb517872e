"""The worked examples' committed rows (results/plants/, made by results/plants.sh from the presets
gym_pendulum and gym_inverted_pendulum): results/plants.md is what kexp-results prints from them, and the rows hold
the issue's targets — the LMPC, learned only from the environment's own excited runs, succeeds from ≥ 95 % of the
x0 where the LQR on the plant's numerical linearisation succeeds, at median cost ≤ 1.05× that LQR's there — and say
where they do not (the LQR failures a long-horizon optimal-control problem saves, which the LMPC does not)."""
import csv
from pathlib import Path

import numpy as np
import pytest

from kexp.app.results import main
from test_results_cli import run_main

PLANTS = Path(__file__).resolve().parents[1] / "results" / "plants"
SYSTEMS = ("gym_pendulum", "gym_inverted_pendulum")


def _rows(name):
    with open(PLANTS / f"{name}.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    xs = [k for k in rows[0] if k.startswith("x0_")]
    return {tuple(r[k] for k in xs): r for r in rows}


def test_results_plants_md_is_what_kexp_results_prints(capsys):
    csvs = sorted(PLANTS.glob("*.csv"))
    code, plants, err = run_main(main, capsys, "plants", *csvs)
    assert code == 0 and err == []
    code, table, err = run_main(main, capsys, "table", *csvs)
    assert code == 0 and err == []
    assert plants + "\n" + table == (PLANTS.parent / "plants.md").read_text()


@pytest.mark.parametrize("system", SYSTEMS)
def test_the_lmpc_holds_the_targets_where_the_lqr_succeeds(system):
    lmpc, lqr = _rows(f"{system}_lmpc"), _rows(f"{system}_lqr")
    assert len(lmpc) == len(lqr) == 100 and set(lmpc) == set(lqr)
    ok = [x for x in lqr if lqr[x]["success"] == "True"]
    both = [x for x in ok if lmpc[x]["success"] == "True"]
    assert len(both) >= 0.95 * len(ok)
    ratio = np.median([float(lmpc[x]["cost"]) / float(lqr[x]["cost"]) for x in both])
    assert ratio <= 1.05
    assert lmpc[both[0]]["inputs"] == "regression"      # learned from the environment's own excited data


def test_the_gap_is_what_the_readme_says():
    """The LQR's failures that the optimal-control check saves (results/plants_ocp.py), and how many the LMPC
    saves: Pendulum-v1 1 of 1 savable, InvertedPendulum-v5 10 of 12; the LMPC saves none of them."""
    for system, savable in (("gym_pendulum", 1), ("gym_inverted_pendulum", 10)):
        lmpc, lqr, ocp = _rows(f"{system}_lmpc"), _rows(f"{system}_lqr"), _rows(f"{system}_ocp")
        failed = [x for x in lqr if lqr[x]["success"] != "True"]
        can = [x for x in failed if ocp[x]["feasible"] == "True"]
        assert len(can) == savable
        assert sum(lmpc[x]["success"] == "True" for x in can) == 0


@pytest.mark.parametrize("preset,x0,cost", [("gym_pendulum", [0.3, 0.0], 1.3224),
                                            ("gym_inverted_pendulum", [0.0, 0.3, 0.0, 0.0], 1.6817)])
def test_the_presets_run_as_the_readme_says(tmp_path, preset, x0, cost):
    """`kexp +experiment=gym_pendulum` / `gym_inverted_pendulum` as the README shows them: data from the
    environment, B regressed, the LMPC succeeds with no fallback at the README's J (a least-squares model of the
    env's data, cond(Φ_X) ~1e3–1e4: J to 1e-3 relative across BLAS kernels)."""
    from hydra import compose, initialize_config_dir
    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"+experiment={preset}", "logging.rrd=false",
                                                        f"cache.dir={tmp_path / 'cache'}"])
    summary = run(cfg, tmp_path / "run", echo=lambda *_: None)
    assert summary["x0"] == x0 and summary["plant"]["kind"] == "gymnasium"
    assert summary["metrics"]["success"] and summary["metrics"]["fallbacks"] == 0
    assert summary["metrics"]["cost"] == pytest.approx(cost, rel=1e-3)


def test_a_run_mostly_on_its_fallback_says_so(tmp_path):
    """An LMPC whose QP cannot finish (one interior-point iteration; DAQP, the default, warm-started from the last
    active set, finishes in one) falls back to h at every step: the run ends as
    h's run and says so in one warning line, also kept in summary.json (before plants, degree-5 models of
    Pendulum-v1 did this silently: only 'fallbacks 200' in the result line)."""
    from hydra import compose, initialize_config_dir
    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=["+experiment=gym_pendulum", "logging.mcap=false",
                                                        "logging.rrd=false", "controller.lmpc.qp_max_iter=1",
                                                            "controller.lmpc.qp_solver=ipm",   # DAQP finishes warm
                                                        f"cache.dir={tmp_path / 'cache'}"])
    lines = []
    summary = run(cfg, tmp_path / "run", echo=lines.append)
    steps = 200
    assert summary["metrics"]["fallbacks"] == steps
    warning = ("the controller fell back to its explicit law h at 200 of 200 steps (100 %): its QP failed or was "
               "infeasible there, so this run measured h more than the MPC")
    assert [ln for ln in lines if ln.startswith("warning: the controller fell back")][0].startswith(f"warning: {warning}")
    assert summary["warnings"][0].startswith(warning)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        ok = compose(config_name="config", overrides=["+experiment=gym_pendulum", "logging.mcap=false",
                                                       "logging.rrd=false", f"cache.dir={tmp_path / 'cache'}"])
    lines = []
    assert "warnings" not in run(ok, tmp_path / "ok", echo=lines.append)
    assert not any("fell back" in ln for ln in lines)
