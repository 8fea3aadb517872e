"""Re-running committed results rows (kexp.results.reproduce, kexp-results sample / compare, results/reproduce.sh):
the sampled x0 are the row scripts' full-precision ones, the comparison's verdicts per column and tolerance, the
CLI's exit codes, and the script's sweeps and refusals with kexp stubbed."""
import csv
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kexp.results.aggregate import ReportError
from kexp.results.reproduce import GENERATORS, compare, hydra_list, sample
from kexp.results.cli import main
from kexp.results.csvfiles import COLUMNS

from cli import refused, run_main

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _x0(seed=42, low=-1.0, high=1.0, n=100):
    lo, hi = (np.repeat(np.asarray(b, float), 2) if np.ndim(b) == 0 else np.asarray(b, float) for b in (low, high))
    return np.random.default_rng(seed).uniform(lo[:, None], hi[:, None], (lo.size, n)).T


def _rows(x0s, **kw):
    rows = []
    for i, (a, b) in enumerate(x0s):
        row = dict.fromkeys(COLUMNS, "")
        row.update(x0_1=f"{a:.10g}", x0_2=f"{b:.10g}", status="completed", success="True",
                   cost=f"{1.0 + i:.10g}", settling_time_s="5.53", solve_median_ms="1.0", solve_p99_ms="2.0",
                   max_abs_u="1.25", fallbacks="0", certificate="samples", controller="lmpc", inputs="projection",
                   data_noise="0", smoothing="none", sim_noise="0")
        row.update(kw)
        rows.append(row)
    return rows


def _write(path, rows, header=COLUMNS):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        out = csv.DictWriter(f, header, restval="", extrasaction="ignore")
        out.writeheader()
        out.writerows(rows)
    return path


@pytest.mark.parametrize("gen", [g for g in GENERATORS if np.size(g[1]) <= 2])   # 4 states: test_results_nstates
def test_sample_gives_the_row_scripts_full_precision_x0_evenly_spaced(tmp_path, gen):
    """A CSV holds x0 to 10 digits; sample maps each back to the generator's float, bit for bit, and takes the
    rows 0, 11, 22, …, 99 of 100 for n = 10 (evenly spaced, first and last included)."""
    seed, low, high, n = gen
    full = _x0(seed, low, high, n)
    path = _write(tmp_path / "vanderpol_lmpc.csv", _rows(full))
    got = sample(path, 10)
    idx = np.linspace(0, n - 1, 10).round().astype(int)
    assert got == [tuple(map(float, full[i])) for i in idx]
    assert all(f"{a:.10g}" != repr(a) for a, _ in got)      # the full digits, not the CSV's
    assert np.array_equal(np.array(eval(f"[{hydra_list(got)}]")), full[idx])   # the Hydra list is exact


def test_sample_keeps_a_csvs_own_digits_and_takes_every_row_when_asked_for_more(tmp_path):
    path = _write(tmp_path / "rig_lmpc.csv", _rows([(0.25, -0.5), (1.5, 0.125)]))
    assert sample(path, 10) == [(0.25, -0.5), (1.5, 0.125)]
    assert sample(path, 1) == [(0.25, -0.5)]
    for bad in (0, -3, True, 2.5):
        with pytest.raises(ReportError, match="give a whole number >= 1"):
            sample(path, bad)
    no_x0 = _write(tmp_path / "rig_nmpc.csv", _rows([(0.25, -0.5)], x0_1=""))
    with pytest.raises(ReportError, match="row 2 has no x0"):
        sample(no_x0, 1)


def test_generators_are_the_row_scripts():
    """GENERATORS names the x0 that robustness.sh, regions.sh and regions.sh --map sweep (their x0_list calls), and
    the boxes of plants.sh (x0_box)."""
    text = {s: (RESULTS / s).read_text() for s in ("robustness.sh", "regions.sh", "plants.sh")}
    assert 'gym_pendulum) echo "-0.6,-1.5 0.6,1.5"' in text["plants.sh"]
    assert 'gym_inverted_pendulum) echo "-0.5,-0.6,0,0 0.5,0.6,0,0"' in text["plants.sh"]
    assert "X0=$(x0_list -1 1)" in text["robustness.sh"]
    assert "X0=$(x0_list -2 2)" in text["regions.sh"] and "X0=$(x0_list -2 2 43 300)" in text["regions.sh"]
    assert "${3:-42}" in (RESULTS / "sweep_lib.sh").read_text() and "${4:-100}" in (RESULTS / "sweep_lib.sh").read_text()
    assert set(GENERATORS) == {(42, -1.0, 1.0, 100), (42, -2.0, 2.0, 100), (43, -2.0, 2.0, 300),
                               (42, (-0.6, -1.5), (0.6, 1.5), 100),
                               (42, (-0.5, -0.6, 0.0, 0.0), (0.5, 0.6, 0.0, 0.0), 100)}


@pytest.fixture
def committed(tmp_path):
    rows = _rows(_x0()[:5])
    rows[4].update(success="False", cost="9.5", settling_time_s="inf")
    return _write(tmp_path / "old" / "vanderpol_lmpc.csv", rows), rows


def _new(tmp_path, rows, **changes):
    """A re-run's CSV: ``rows`` with changes {row index: {column: value}}."""
    new = [dict(r) for r in rows]
    for i, kw in changes.items():
        new[int(i)].update(kw)
    return _write(tmp_path / "new" / "vanderpol_lmpc.csv", new)


def test_identical_reruns_agree_and_solve_times_are_not_compared(tmp_path, committed):
    path, rows = committed
    c = compare(path, _new(tmp_path, rows, **{"0": {"solve_median_ms": "7.5", "solve_p99_ms": "99"}}))
    assert c.agrees and len(c.runs) == 5 and c.worst_cost_rel == 0.0 and c.skipped == ()
    assert c.report().startswith(f"{path}: 5/5 re-run x0 agree") and len(c.report().splitlines()) == 1


@pytest.mark.parametrize("column, new, agrees", [
    ("cost", f"{1.0 * (1 + 9e-7):.10g}", True), ("cost", f"{1.0 * (1 + 2e-6):.10g}", False),
    ("max_abs_u", f"{1.25 * (1 - 9e-7):.10g}", True), ("max_abs_u", f"{1.25 * (1 - 2e-6):.10g}", False),
    ("settling_time_s", "5.54", True), ("settling_time_s", "5.52", True), ("settling_time_s", "5.55", False),
    ("settling_time_s", "inf", False), ("success", "False", False), ("status", "diverged", False),
    ("fallbacks", "1", False), ("certificate", "fails", False), ("sim_noise", "0.01", False),
    ("inputs", "regression", False), ("max_abs_u", "", False)])
def test_each_column_by_its_rule(tmp_path, committed, column, new, agrees):
    """Discrete columns exactly; cost and max |u| to rtol 1e-6 of the committed value, and missing only where
    the committed one is; settling time to one step (0.01 s), inf only equal to inf."""
    path, rows = committed
    c = compare(path, _new(tmp_path, rows, **{"0": {column: new}}))
    assert c.agrees is agrees
    assert [r.agrees for r in c.runs[1:]] == [True] * 4
    if not agrees:
        assert c.runs[0].fields == ((column, rows[0][column], new),)
        assert f"{column} {rows[0][column]} -> {new}" in c.report()


def test_worst_cost_difference_tolerance_and_a_failed_runs_infinite_settling_time(tmp_path, committed):
    path, rows = committed
    new = _new(tmp_path, rows, **{"2": {"cost": f"{3.0 * (1 + 4e-5):.10g}"}})
    assert not compare(path, new).agrees
    loose = compare(path, new, rtol=1e-4)
    assert loose.agrees and math.isclose(loose.worst_cost_rel, 4e-5, rel_tol=1e-6)
    assert compare(path, _new(tmp_path, rows)).runs[4].agrees           # inf == inf, the failed run's 9.5


def test_a_rerun_of_a_few_x0_and_old_csvs_without_the_condition_columns(tmp_path, committed):
    path, rows = committed
    old_header = COLUMNS[:COLUMNS.index("controller")]
    old = _write(tmp_path / "older" / "vanderpol_lmpc.csv", rows, old_header)
    c = compare(old, _write(tmp_path / "new" / "vanderpol_lmpc.csv", [dict(rows[1]), dict(rows[3])]))
    assert c.agrees and [r.x0 for r in c.runs] == [(rows[i]["x0_1"], rows[i]["x0_2"]) for i in (1, 3)]
    assert set(c.skipped) == {"controller", "inputs", "data_noise", "smoothing", "sim_noise", "mismatch"}
    assert "not compared (only in one CSV)" in c.report()


def test_refusals(tmp_path, committed):
    path, rows = committed
    stranger = _write(tmp_path / "new" / "vanderpol_lmpc.csv", _rows([(0.5, 0.5)]))
    with pytest.raises(ReportError, match=r"x0 \(0.5, 0.5\) is not a run of"):
        compare(path, stranger)
    other = _write(tmp_path / "new" / "pendulum_lmpc.csv", rows)
    with pytest.raises(ReportError, match="rows of two names"):
        compare(path, other)
    for bad in (float("nan"), -1e-6, float("inf"), True):
        with pytest.raises(ReportError, match="--rtol"):
            compare(path, path, bad)


def test_report_lists_at_most_ten_runs(tmp_path):
    rows = _rows(_x0()[:14])
    path = _write(tmp_path / "old" / "vanderpol_lmpc.csv", rows)
    c = compare(path, _new(tmp_path, rows, **{str(i): {"success": "False"} for i in range(14)}))
    lines = c.report().splitlines()
    assert lines[0].startswith(f"{path}: 0/14") and len(lines) == 12 and lines[-1] == "  … and 4 more runs that disagree"


def test_cli_sample_and_compare_exit_codes(tmp_path, committed, capsys):
    path, rows = committed
    code, out, _ = run_main(main, capsys, "sample", path, 2)
    assert code == 0 and np.array_equal(np.array(eval(f"[{out.strip()}]")), _x0()[[0, 4]])
    code, out, _ = run_main(main, capsys, "compare", path, _new(tmp_path, rows))
    assert code == 0 and "5/5 re-run x0 agree" in out
    code, out, _ = run_main(main, capsys, "compare", path, _new(tmp_path, rows, **{"1": {"success": "False"}}))
    assert code == 1 and "4/5 re-run x0 agree" in out and "success True -> False" in out
    refused(main, "kexp-results", capsys, "--rtol nan", "compare", path, path, "--rtol", "nan")
    refused(main, "kexp-results", capsys, "sample size 0", "sample", path, 0)
    refused(main, "kexp-results", capsys, "No such file", "compare", path, tmp_path / "vanderpol_lmpc.csv")


def _stubbed_repo(tmp_path, collected_rows):
    """results/'s scripts in tmp_path/repo with a committed results/vanderpol_lmpc.csv; kexp a stub recording its
    arguments; kexp-results the real one but for ``collect``, which writes ``collected_rows`` to DEST/ROW.csv."""
    root = tmp_path / "repo"
    shutil.copytree(RESULTS, root / "results", ignore=shutil.ignore_patterns("*.csv", "*.md"))
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "kexp").write_text(f'#!/bin/sh\nprintf "%s\\n" "$@" > "{tmp_path}/kexp_args"\n')
    collected = _write(tmp_path / "collected.csv", collected_rows)
    (bin_dir / "kexp-results").write_text(
        f'#!/bin/sh\nif [ "$1" = collect ]; then mkdir -p "$5" && cp "{collected}" "$5/$3.csv"; exit 0; fi\n'
        f'exec "{sys.executable}" -c "import sys; from kexp.results.cli import main; main(sys.argv[1:])" "$@"\n')
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    return root, {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}


def test_reproduce_script_reruns_the_sample_with_the_rows_overrides(tmp_path):
    rows = _rows(_x0())
    idx = np.linspace(0, 99, 3).round().astype(int)
    root, env = _stubbed_repo(tmp_path, [rows[i] for i in idx])
    _write(root / "results" / "vanderpol_lmpc-reg-noise1.csv", rows)
    script = ["bash", str(root / "results" / "reproduce.sh"), "--sample", "3"]
    proc = subprocess.run(script + ["results/vanderpol_lmpc-reg-noise1.csv"], env=env, capture_output=True,
                          text=True, cwd=root)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert "3/3 re-run x0 agree" in proc.stdout and "== all 1 rows reproduced (3 x0 each)" in proc.stdout
    args = (tmp_path / "kexp_args").read_text().splitlines()
    x0 = next(a for a in args if a.startswith("sim.x0="))[len("sim.x0="):]
    assert np.array_equal(np.array(eval(f"[{x0}]")), _x0()[idx])
    assert {"+experiment=vanderpol", "identification.inputs=regression", "data.noise.std=0.01",
            "data.smooth.window=7"} <= set(args)
    assert "hydra.sweep.dir=sweeps/reproduce/sweeps/vanderpol_lmpc-reg-noise1" in args


def test_reproduce_script_fails_a_row_that_disagrees_and_refuses_bad_arguments(tmp_path):
    rows = _rows(_x0())
    rerun = [dict(rows[0], success="False")]
    root, env = _stubbed_repo(tmp_path, rerun)
    _write(root / "results" / "regions" / "pendulum-u1_nmpc.csv", rows)
    run = lambda *a: subprocess.run(["bash", str(root / "results" / "reproduce.sh"), *a], env=env,  # noqa: E731
                                    capture_output=True, text=True, cwd=root)
    proc = run("--sample", "1", "results/regions/pendulum-u1_nmpc.csv")
    assert proc.returncode == 1 and "success True -> False" in proc.stdout
    assert "not reproduced (1 of 1)" in proc.stdout
    args = (tmp_path / "kexp_args").read_text().splitlines()
    assert {"+experiment=pendulum", "controller=nmpc", "controller.u_min=-1", "controller.u_max=1"} <= set(args)
    (tmp_path / "kexp_args").unlink()
    _write(root / "results" / "vanderpol_foo.csv", rows)
    for argv, msg in ((("results/nope.csv",), "no such file"), (("--sample", "0", "results/vanderpol_foo.csv"),
                      "--sample 0"), (("results/vanderpol_foo.csv",), "unknown controller"), ((), "usage"),
                      (("--bogus", "x.csv"), "unknown option")):
        bad = run(*argv)
        assert bad.returncode == 2 and msg in bad.stderr, (argv, bad.stderr)
    assert not (tmp_path / "kexp_args").exists()      # no sweep started
