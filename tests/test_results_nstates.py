"""Results rows of plants: CSVs of n states (x0_1 … x0_n, runs known by their full x0), a system without an NMPC
oracle ("n/a"), the plants view against the system's LQR (numbers computed by hand on a tiny example), the
optimal-control check, initial conditions from a box of n states; and the committed tables unchanged, byte for
byte."""
import csv
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from kexp.analysis.region_map import RegionMapError, read_results
from kexp.results import reproduce
from kexp.results.aggregate import ReportError
from kexp.results.cli import main
from kexp.results.csvfiles import COLUMNS, columns

from cli import console_script, refused, run_main

RESULTS = Path(__file__).resolve().parents[1] / "results"
# four x0 of a cart-pole; the first two differ only in x0_3 (one run each: a key of (x0_1, x0_2) merges them)
X = [(0.1, 0.05, 0.0, 0.0), (0.1, 0.05, 0.5, 0.0), (0.3, -0.15, 0.0, 0.0), (0.4, 0.2, 0.0, 0.0)]


def _write(path, runs, n=4, **kw):
    """A results CSV of ``n`` states, one row per (x0, success, cost); success None: a failed job."""
    cols = columns(n)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for x0, ok, cost in runs:
            row = dict.fromkeys(cols, "")
            row.update({f"x0_{i + 1}": v if isinstance(v, str) else f"{v:.10g}" for i, v in enumerate(x0)})
            row.update(status="error" if ok is None else "completed", success="" if ok is None else str(ok),
                       cost="" if cost is None else f"{cost:.10g}", settling_time_s="1.5", solve_median_ms="0.5",
                       solve_p99_ms="1", certificate="", controller="lmpc", inputs="regression")
            row.update(kw)
            w.writerow([row[c] for c in cols])
    return path


def _cart(tmp_path, ocp=True):
    """The tiny example: LQR succeeds from X0, X1 (J 1, 2), fails from X2 and its job failed at X3; the LMPC
    succeeds from X0, X1, X2 (J 1.1, 1.9, 4) and fails from X3; the model's LQR succeeds from X0 and X3 (J 1.5,
    5).  The optimal-control check finds X2 feasible and X3 not (written with other digits than collect's)."""
    paths = [_write(tmp_path / "cart_lqr.csv", zip(X, (True, True, False, None), (1.0, 2.0, 50.0, None)),
                    controller="lqr"),
             _write(tmp_path / "cart_lmpc.csv", zip(X, (True, True, True, False), (1.1, 1.9, 4.0, 80.0))),
             _write(tmp_path / "cart_model-lqr.csv", zip(X, (True, False, False, True), (1.5, 9.0, 60.0, 5.0)))]
    if ocp:
        (tmp_path / "cart_ocp.csv").write_text("x0_1,x0_2,x0_3,x0_4,feasible\n"
                                               "0.30000000000000004,-0.15,0,0,True\n0.4,0.2,0.0,0.0,False\n")
        paths.append(tmp_path / "cart_ocp.csv")
    return paths


def _run(capsys, *argv):
    return run_main(main, capsys, *argv)


def test_the_committed_tables_are_byte_identical(capsys):
    """kexp-results table / robustness print exactly what results/table.md and results/robustness.md hold."""
    csvs = sorted(RESULTS.glob("*.csv"))
    code, out, err = _run(capsys, "table", *csvs)
    assert code == 0 and err == [] and out == (RESULTS / "table.md").read_text()
    code, out, err = _run(capsys, "robustness", *csvs, *sorted((RESULTS / "robustness").glob("*.csv")))
    assert code == 0 and err == [] and out == (RESULTS / "robustness.md").read_text()
    # collect's columns; CSVs collected before issue 34 lack the last two (read as estimator ls, one shared draw)
    old = (RESULTS / "pendulum_lmpc.csv").read_text().splitlines()[0].split(",")
    assert COLUMNS[-2:] == ["estimator", "sim_noise_per_x0"] and old == COLUMNS[:-2]
    new = (RESULTS / "robustness" / "vanderpol_lmpc-reg-dn3-mn1-iv.csv").read_text().splitlines()[0].split(",")
    assert new == COLUMNS


def test_a_4_state_system_without_an_oracle_tabulates_with_n_a(tmp_path, capsys):
    code, out, err = _run(capsys, "table", *_cart(tmp_path))        # the ocp file is no row of the table
    assert code == 0 and err == []
    assert out.splitlines()[2:] == [
        "| cart | lmpc | 3/4 | 2.950 | 80.000 | n/a (no oracle) | n/a (no oracle) | 1.50 | 0.50 / 1.00 | – |",
        "| cart | lqr | 2/4 | 2.000 | 50.000 | n/a (no oracle) | n/a (no oracle) | 1.50 | 0.50 / 1.00 "
        "| n/a (linearisation) |",
        "| cart | model-lqr | 2/4 | 7.000 | 60.000 | n/a (no oracle) | n/a (no oracle) | 1.50 | 0.50 / 1.00 | – |"]
    code, out, err = _run(capsys, "robustness", *_cart(tmp_path))
    assert code == 0 and out.splitlines()[2:] == [
        "| cart | regressed | 0 | nominal | 3/4 | n/a (no oracle) | 2/4 | n/a (no oracle) | n/a |"]


def test_with_an_oracle_the_ratios_are_per_full_x0(tmp_path, capsys):
    """An oracle row: J / J_oracle of each run against the oracle's run of the same full x0 (X0 and X1 share
    x0_1, x0_2: the oracle's J 1 and 2 there give the LMPC 1.1 and 0.95)."""
    oracle = _write(tmp_path / "cart_nmpc.csv", zip(X, (True, True, True, True), (1.0, 2.0, 2.0, 4.0)))
    code, out, err = _run(capsys, "table", tmp_path / "cart_lmpc.csv", oracle, *_cart(tmp_path)[:1])
    lmpc = next(line for line in out.splitlines() if "| lmpc |" in line)
    # completed runs (a failure's cost too, as the committed table): 1.1, 0.95, 2.0, 20: median 1.55, worst 20;
    # the LQR's 1, 1, 25 (its job at X3 failed)
    assert code == 0 and lmpc.startswith("| cart | lmpc | 3/4 | 2.950 | 80.000 | 1.550 | 20.000 |")
    assert "| cart | lqr | 2/4 | 2.000 | 50.000 | 1.000 | 25.000 | 1.50 | 0.50 / 1.00 | n/a (true model) |" in out


def test_plants_view_numbers_by_hand(tmp_path, capsys):
    """LMPC: 3/4; where LQR succeeds (X0, X1) 2/2; of LQR's failures (X2, X3) it saves X2: 1 of 2; median J of
    its successes 1.9; J/J_LQR 1.1 and 0.95: median 1.025, worst 1.1; the check finds X2 feasible: 1 of 1.
    model-LQR: 1/2 where LQR succeeds, saves X3 (1 of 2), median J 3.25, J/J_LQR 1.5, X2 not saved: 0 of 1."""
    code, out, err = _run(capsys, "plants", *_cart(tmp_path))
    assert code == 0 and err == []
    assert out.splitlines()[2:] == [
        "| cart | lmpc | 3/4 | 2/2 | 1 of 2 | 1.900 | 1.025 | 1.100 | 1 of 1 | n/a (no formula) |",
        "| cart | lqr | 2/4 | 2/2 | 0 of 2 | 1.500 | 1.000 | 1.000 | 0 of 1 | n/a (no formula) |",
        "| cart | model-lqr | 2/4 | 1/2 | 1 of 2 | 3.250 | 1.500 | 1.500 | 0 of 1 | n/a (no formula) |",
        "",
        "- cart: LQR fails from 2 of 4 x0; LQR failures that could be saved: 1 of 2 (a long-horizon optimal-control "
        "problem stabilises from them, cart_ocp.csv)"]


def test_plants_view_without_the_check_says_not_checked(tmp_path, capsys):
    code, out, err = _run(capsys, "plants", *_cart(tmp_path, ocp=False))
    lines = out.splitlines()
    assert code == 0 and lines[2] == "| cart | lmpc | 3/4 | 2/2 | 1 of 2 | 1.900 | 1.025 | 1.100 | not checked " \
                                     "| n/a (no formula) |"
    assert lines[-1] == ("- cart: LQR fails from 2 of 4 x0; LQR failures that could be saved: not checked "
                         "(no cart_ocp.csv)")
    code, out, err = _run(capsys, "plants", tmp_path / "cart_lmpc.csv")          # no LQR row: nothing against it
    assert code == 0 and out.splitlines()[2:] == [
        "| cart | lmpc | 3/4 | – | – | 1.900 | – | – | – | n/a (no formula) |", "",
        "- cart: no cart_lqr.csv: no LQR reference, the columns against it say –"]


def test_plants_view_refusals_are_one_line(tmp_path, capsys):
    paths = _cart(tmp_path)
    paths[-1].write_text("x0_1,x0_2,x0_3,x0_4,feasible\n0.3,-0.15,0,0,yes\n")
    refused(main, "kexp-results", capsys, f"{paths[-1]}, line 2: column feasible holds 'yes'", "plants", *paths)
    paths[-1].write_text("x0_1,x0_2,feasible\n")
    refused(main, "kexp-results", capsys, "an optimal-control check with no rows", "plants", *paths)
    paths[-1].write_text("x0_1,x0_2,ok\n0,0,True\n")
    refused(main, "kexp-results", capsys, "missing columns feasible", "plants", *paths)
    refused(main, "kexp-results", capsys, "an optimal-control check of cart without any results CSV",
            "plants", paths[-1])


def test_x0_columns_must_be_numbered_without_a_gap(tmp_path, capsys):
    p = tmp_path / "cart_lmpc.csv"
    p.write_text("x0_1,x0_3,status,success,cost\n0,0,completed,True,1\n")
    refused(main, "kexp-results", capsys, f"{p}: column x0_3 without x0_2", "table", p)
    p.write_text("status,success,cost\ncompleted,True,1\n")
    refused(main, "kexp-results", capsys, "missing columns x0_1, x0_2, … (one per state)", "table", p)
    _write(p, [((0.1, "nan", 0.0, 0.0), True, 1.0)])
    refused(main, "kexp-results", capsys, "line 2: column x0_2 holds 'nan'", "plants", p)


def _sweep(root, x0s):
    """A sweep folder as kexp writes it: one completed job per x0 (None: a job that failed before its summary,
    its x0 only in the overrides)."""
    for i, x0 in enumerate(x0s):
        job = root / str(i)
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- sim.x0=[{','.join(map(str, x0))}]\n")
        if i == len(x0s) - 1:
            continue
        (job / "summary.json").write_text(json.dumps({
            "status": "completed", "completed": True, "system": "cart", "controller": "lmpc", "x0": list(x0),
            "metrics": {"success": True, "cost": 1.0 + i, "settling_time": 3.0, "max_abs_u": 1.0, "fallbacks": 0,
                        "solve_time_median": 0.001, "solve_time_p99": 0.002}}))
    return root


def test_collect_writes_as_many_x0_columns_as_the_runs_have_states(tmp_path, capsys):
    sweep = _sweep(tmp_path / "s4", [(0.5, 0.1, 0.0, 0.0), (-0.5, 0.2, 0.0, 0.25), (0.1, 0.1, 0.0, 0.0)])
    code, out, err = _run(capsys, "collect", sweep, "cart_lmpc", "-o", tmp_path)
    with open(tmp_path / "cart_lmpc.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert code == 0 and rows[0] == columns(4) == ["x0_1", "x0_2", "x0_3", "x0_4", *COLUMNS[2:]]
    assert [r[:6] for r in rows[1:]] == [["-0.5", "0.2", "0", "0.25", "completed", "True"],
                                          ["0.1", "0.1", "0", "0", "missing", ""],
                                          ["0.5", "0.1", "0", "0", "completed", "True"]]
    two = _sweep(tmp_path / "s2", [(0.5, 0.5), (-0.5, 0.2)])
    code, out, err = _run(capsys, "collect", two, "vdp_lmpc", "-o", tmp_path)
    assert code == 0 and (tmp_path / "vdp_lmpc.csv").read_text().splitlines()[0] == ",".join(COLUMNS)
    mixed = _sweep(tmp_path / "mixed", [(0.5, 0.5), (0.1, 0.1, 0.0, 0.0), (0.0, 0.0)])
    refused(main, "kexp-results", capsys, "runs with x0 of 2 and 4 states; one system", "collect", mixed,
            "cart_lqr", "-o", tmp_path)
    assert not (tmp_path / "cart_lqr.csv").exists()


def test_generated_x0_of_a_box_and_the_2_state_draws_unchanged():
    for seed, low, high, n in (g for g in reproduce.GENERATORS if np.ndim(g[1]) == 0):   # the 2-state rows
        old = [tuple(map(float, x)) for x in np.random.default_rng(seed).uniform(low, high, (2, n)).T]
        assert reproduce.generated_x0(seed, low, high, n) == old
        assert reproduce.generated_x0(seed, [low, low], [high, high], n) == old
    box = np.array(reproduce.generated_x0(7, [-0.5, -0.2, 0.0, 0.0], [0.5, 0.2, 0.0, 0.0], 200))
    assert box.shape == (200, 4) and np.all(box[:, 2:] == 0.0)
    assert np.all(np.abs(box[:, 0]) <= 0.5) and np.all(np.abs(box[:, 1]) <= 0.2)
    assert box[:, 0].max() > 0.45 and box[:, 1].min() < -0.18          # the box is filled, not a corner of it
    for args, msg in (((1, [0.0, 1.0], [1.0], 3), "one bound per state"), ((1, [2.0], [1.0], 3), "low 2 > high 1"),
                      ((1, [0.0], [1.0], 0), "give a whole number >= 1"), ((1, [0.0], [np.inf], 3), "finite")):
        with pytest.raises(ReportError, match=msg):
            reproduce.generated_x0(*args)


def test_x0_box_prints_the_hydra_list(tmp_path):
    """results/sweep_lib.sh x0_box: a box's x0 as one Hydra list; '-1,-1' '1,1' is x0_list -1 1."""
    env = dict(os.environ, PATH=f"{Path(console_script('kexp-results')).parent}{os.pathsep}{os.environ['PATH']}")

    def sh(cmd):
        return subprocess.run(["bash", "-c", f"source {RESULTS / 'sweep_lib.sh'}; {cmd}"], capture_output=True,
                              text=True, env=env, timeout=120)
    got = sh("x0_box '-1,-1' '1,1'; x0_list -1 1; x0_box '-0.5,-0.2,0,0' '0.5,0.2,0,0' 3 5")
    two, old, four = got.stdout.splitlines()
    assert got.returncode == 0 and two == old == reproduce.hydra_list(reproduce.generated_x0(42, -1.0, 1.0, 100))
    assert np.array_equal(np.array(eval(f"[{four}]")),
                          np.array(reproduce.generated_x0(3, [-0.5, -0.2, 0, 0], [0.5, 0.2, 0, 0], 5)))
    bad = sh("x0_box '0,a' '1,1'")
    assert bad.returncode == 2 and bad.stdout == "" and bad.stderr.strip() == (
        "kexp-results: error: low '0,a': give finite numbers, one per state, separated by commas (e.g. -0.5,-0.2,0,0)")


def test_sample_and_compare_of_4_state_rows(tmp_path, monkeypatch):
    box = ((5, (-0.5, -0.2, 0.0, 0.0), (0.5, 0.2, 0.0, 0.0), 6),)
    full = reproduce.generated_x0(*box[0])
    path = _write(tmp_path / "cart_lmpc.csv", [(x, True, 1.0 + i) for i, x in enumerate(full)])
    assert reproduce.sample(path, 2) == [tuple(float(f"{v:.10g}") for v in full[i]) for i in (0, 5)]
    monkeypatch.setattr(reproduce, "GENERATORS", reproduce.GENERATORS + box)
    assert reproduce.sample(path, 2) == [full[0], full[5]]                  # the box's full precision
    (tmp_path / "new").mkdir()
    new = _write(tmp_path / "new" / "cart_lmpc.csv", [(full[1], True, 2.0), (full[2], False, 3.0)])
    c = reproduce.compare(path, new)
    assert not c.agrees and [r.agrees for r in c.runs] == [True, False]
    assert f"  x0 ({', '.join(f'{v:.10g}' for v in full[2])}): success True -> False" in c.report()


def test_a_region_map_of_4_states_is_one_line(tmp_path):
    p = _write(tmp_path / "cart_lmpc.csv", [(X[0], True, 1.0)])
    with pytest.raises(RegionMapError, match="runs of 4 states"):
        read_results(p)
    two = _write(tmp_path / "vdp_lmpc.csv", [((0.5, 0.25), True, 1.0), ((0.5, 0.5), False, 2.0)], n=2)
    assert list(read_results(two)) == [(0.5, 0.25), (0.5, 0.5)]
