"""The robustness table (kexp-results robustness): conditions read from the CSVs' columns, ratios per initial
condition against the oracle under the same noise and plant, and refusals of ambiguous inputs."""
import csv
from pathlib import Path

import numpy as np
import pytest

from kexp.app.aggregate import ReportError
from kexp.app.results import COLUMNS
from kexp.app.results import table as results_table
from kexp.app.robustness import load, table

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _write(path, costs, *, controller, inputs="projection", noise=0.0, mismatch="", success=None,
           smoothing="none", data_noise=None, estimator=None, per_x0=None):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for i, c in enumerate(costs):
            row = {k: "" for k in COLUMNS}
            ok = True if success is None else success[i]
            row.update(x0_1=str(i / 10), x0_2="0.5", status="completed", success=str(ok),
                       cost="" if np.isnan(c) else repr(float(c)),
                       controller=controller, inputs=inputs, sim_noise=repr(noise), mismatch=mismatch,
                       data_noise=repr(noise if data_noise is None else data_noise), smoothing=smoothing,
                       estimator=estimator or "", sim_noise_per_x0="" if per_x0 is None else str(per_x0))
            w.writerow([row[k] for k in COLUMNS])
    return path


def test_ratios_against_the_oracle_under_the_same_conditions(tmp_path):
    o = np.array([1.0, 2.0, 4.0])
    _write(tmp_path / "vdp_nmpc.csv", o, controller="nmpc_oracle")
    _write(tmp_path / "vdp_nmpc-noise1.csv", 2 * o, controller="nmpc_oracle", noise=0.01)
    _write(tmp_path / "vdp_lmpc.csv", o * [1.1, 1.0, 1.2], controller="lmpc")
    _write(tmp_path / "vdp_lmpc-reg-noise1.csv", 2 * o * [1.5, 1.0, 1.25], controller="lmpc", inputs="regression",
           noise=0.01, success=[True, False, True], smoothing="Savitzky–Golay, window 21, order 3")
    _write(tmp_path / "vdp_lmpc-reg-noise1-raw.csv", 2 * o * 2.0, controller="lmpc", inputs="regression",
           noise=0.01)
    _write(tmp_path / "vdp_lqr-noise1.csv", 2 * o * [1.0, 1.0, 3.0], controller="lqr", noise=0.01)
    _write(tmp_path / "vdp_lmpc-reg-mu1.2.csv", o, controller="lmpc", inputs="regression", mismatch="mu=1.2")
    lines = table(sorted(tmp_path.glob("*.csv"))).splitlines()
    assert lines[2] == "| vdp | known | 0 | nominal | 3/3 | 1.100 / 1.2 | – | – | 3/3 |"
    # noise rows: ratios against the noisy oracle (2·o), not the noise-free one
    assert lines[3] == "| vdp | regressed, data raw | 1 % | nominal | 3/3 | 2.000 / 2 | 3/3 | 1.000 / 3 | 3/3 |"
    assert lines[4] == "| vdp | regressed, data SG 21 | 1 % | nominal | 2/3 | 1.250 / 1.5 | 3/3 | 1.000 / 3 | 3/3 |"
    assert lines[5] == "| vdp | regressed | 0 | μ = 1.2 | 3/3 | no oracle | – | – | – |"
    assert lines[6:] == ["", "J_oracle (J*): the true-model NMPC solved by CasADi + IPOPT for every system."]

    # without an oracle under 1 % noise: against the noise-free one, marked †
    (tmp_path / "vdp_nmpc-noise1.csv").unlink()
    lines = table(sorted(tmp_path.glob("*.csv"))).splitlines()
    assert lines[4] == "| vdp | regressed, data SG 21 | 1 % | nominal | 2/3 | 2.500 / 3 † | 3/3 | 2.000 / 6 † | – |"


def test_the_table_says_which_solver_made_each_systems_oracle(tmp_path):
    o = np.array([1.0, 2.0])
    _write(tmp_path / "vdp_nmpc.csv", o, controller="nmpc_oracle")
    _write(tmp_path / "vdp_lmpc.csv", o, controller="lmpc")
    _write(tmp_path / "pend_nmpc.csv", o, controller="nmpc_sqp")
    _write(tmp_path / "pend_lmpc.csv", 1.5 * o, controller="lmpc")
    lines = table(sorted(tmp_path.glob("*.csv"))).splitlines()
    assert "| pend | known | 0 | nominal | 2/2 | 1.500 / 1.5 | – | – | 2/2 |" in lines   # an SQP oracle is an oracle
    assert lines[-1] == ("J_oracle (J*): the true-model NMPC solved by CasADi + IPOPT (vdp); kexp's compiled SQP "
                         "(pend).")
    assert results_table(sorted(tmp_path.glob("*.csv"))).splitlines()[-1] == lines[-1]
    # a long-horizon oracle row (results/horizon/) is a row of the results table against J_oracle, not J_oracle
    h300 = _write(tmp_path / "vdp_nmpc-h300.csv", 0.9 * o, controller="nmpc_sqp")
    got = results_table(sorted(tmp_path.glob("*.csv"))).splitlines()
    assert got[-1] == lines[-1]
    assert any(r.startswith("| vdp | nmpc-h300 | 2/2 | 1.350 | 1.800 | 0.900 | 0.900 |") for r in got)
    assert results_table([tmp_path / "vdp_nmpc.csv", h300]).splitlines()[-1] == \
        "J_oracle (J*): the true-model NMPC solved by CasADi + IPOPT for every system."


def test_an_oracle_run_without_a_cost_leaves_its_x0_out_of_the_ratios(tmp_path):
    """An oracle run without a cost ('' in the CSV) or with 0 gives no ratio for its x0; the others' median and
    worst stand (they were NaN and inf)."""
    _write(tmp_path / "vdp_nmpc.csv", [1.0, float("nan"), 4.0, 0.0], controller="nmpc_oracle",
           success=[True, False, True, True])
    _write(tmp_path / "vdp_lmpc.csv", [1.1, 2.0, 4.8, 1.0], controller="lmpc")
    assert table(sorted(tmp_path.glob("*.csv"))).splitlines()[2] == \
        "| vdp | known | 0 | nominal | 4/4 | 1.150 / 1.2 | – | – | 3/4 |"


def test_old_csvs_without_columns_count_as_unperturbed(tmp_path):
    p = tmp_path / "vdp_lmpc.csv"
    with open(p, "w") as f:
        f.write("x0_1,x0_2,status,success,cost\n0.1,0.2,completed,True,2.0\n")
    assert list(load([p])) == [("vdp", "lmpc", "projection", 0.0, "none", "", 0.0, "ls", False)]


def test_data_noise_estimator_and_draws_per_x0_are_conditions(tmp_path):
    """Issue 34's rows: raw 3 % data noise with 1 % loop noise drawn per x0, least squares and IV; compared with the
    oracle and LQR whose noise was drawn per x0 as well, never with the shared-draw oracle of the same σ."""
    o = np.array([1.0, 2.0, 4.0])
    _write(tmp_path / "vdp_nmpc-noise1.csv", 10 * o, controller="nmpc_oracle", noise=0.01)       # one shared draw
    _write(tmp_path / "vdp_nmpc-mn1.csv", o, controller="nmpc_oracle", noise=0.01, data_noise=0.0, per_x0=True)
    _write(tmp_path / "vdp_lqr-mn1.csv", 1.5 * o, controller="lqr", noise=0.01, data_noise=0.0, per_x0=True)
    _write(tmp_path / "vdp_lmpc-reg-dn3-mn1.csv", 100 * o, controller="lmpc", inputs="regression", noise=0.01,
           data_noise=0.03, per_x0=True, success=[False] * 3)
    _write(tmp_path / "vdp_lmpc-reg-dn3-mn1-iv.csv", o * [1.0, 1.02, 1.04], controller="lmpc", inputs="regression",
           noise=0.01, data_noise=0.03, per_x0=True, estimator="iv")
    lines = table(sorted(tmp_path.glob("*.csv"))).splitlines()
    assert lines[2:4] == [
        "| vdp | regressed, data raw 3 % | 1 % per x0 | nominal | 0/3 | 100.000 / 100 | 3/3 | 1.500 / 1.5 | 3/3 |",
        "| vdp | regressed, data raw 3 %, IV | 1 % per x0 | nominal | 3/3 | 1.020 / 1.04 | 3/3 | 1.500 / 1.5 | 3/3 |"]
    assert lines[4] == "" and lines[5].startswith("J_oracle (J*)") and len(lines) == 6


def test_refusals(tmp_path):
    _write(tmp_path / "a_lmpc.csv", [1.0], controller="lmpc")
    _write(tmp_path / "a_lmpc-again.csv", [1.0], controller="lmpc")
    with pytest.raises(ReportError, match="hold the same runs' conditions"):
        load(sorted(tmp_path.glob("*.csv")))
    mixed = _write(tmp_path / "b_lmpc.csv", [1.0], controller="lmpc")
    with open(mixed, "a", newline="") as f:
        row = dict.fromkeys(COLUMNS, "")
        row.update(x0_1="9", x0_2="9", status="completed", success="True", cost="1.0", controller="lmpc",
                   inputs="regression", sim_noise="0.0")
        csv.writer(f).writerow([row[k] for k in COLUMNS])
    with pytest.raises(ReportError, match="different conditions"):
        load([mixed])


def test_committed_robustness_table_is_generated_from_the_committed_csvs():
    committed = RESULTS / "robustness.md"
    assert committed.is_file(), ("results/robustness.md is committed: kexp-results robustness results/*.csv "
                                 "results/robustness/*.csv > results/robustness.md")
    csvs = sorted(RESULTS.glob("*.csv")) + sorted((RESULTS / "robustness").glob("*.csv"))
    assert table(csvs).strip() == committed.read_text().strip()


def test_the_docs_include_the_committed_robustness_table():
    """Its one source is the generator's file: docs/results.md includes it (tests/test_docs.py renders it)."""
    committed = RESULTS / "robustness.md"
    assert committed.is_file(), ("results/robustness.md is committed: kexp-results robustness results/*.csv "
                                 "results/robustness/*.csv > results/robustness.md")
    page = (RESULTS.parent / "docs" / "results.md").read_text()
    assert '\n--8<-- "results/robustness.md"\n' in page


def _stubbed_results(tmp_path, collected=None):
    """A copy of results/ (scripts only) under tmp_path/repo and an environment whose kexp and kexp-results are
    stubs appending their arguments to tmp_path/calls; with ``collected`` (a CSV path), `kexp-results collect DIR
    ROW -o DEST` also copies that file to DEST/ROW.csv: (the copy's root, the environment)."""
    import os
    import shutil
    root = tmp_path / "repo"
    shutil.copytree(RESULTS, root / "results", ignore=shutil.ignore_patterns("*.csv", "*.md"))
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name in ("kexp", "kexp-results"):
        body = f'#!/bin/sh\nprintf "%s\\n" {name} "$@" >> "{tmp_path}/calls"\n'
        if name == "kexp-results" and collected is not None:
            body += f'[ "$1" = collect ] && cp "{collected}" "$5/$3.csv"\n'
        (bin_dir / name).write_text(body)
        (bin_dir / name).chmod(0o755)
    return root, {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}


@pytest.mark.parametrize("script, row, dest, lo", [("robustness.sh", "vanderpol_lmpc-reg-noise1", "results/robustness", -1),
                                                   ("regions.sh", "pendulum-u1_nmpc", "results/regions", -2)])
def test_row_scripts_run_one_sweep_per_row_and_refuse_bad_names(tmp_path, script, row, dest, lo):
    """results/robustness.sh and regions.sh (through results/sweep_lib.sh), with kexp and kexp-results replaced by
    stubs that record their arguments: one 100-IC multirun per row from default_rng(42) over [lo, -lo]², then
    one collect into the row's folder; a row name they cannot parse stops with exit code 2 before any sweep."""
    import subprocess
    root, env = _stubbed_results(tmp_path)
    proc = subprocess.run(["bash", str(root / "results" / script), row], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    calls = (tmp_path / "calls").read_text().split("kexp")
    kexp_args = next(c for c in calls if "--multirun" in c).split("\n")
    x0 = next(a for a in kexp_args if a.startswith("sim.x0="))[len("sim.x0="):]
    ics = np.array(eval(f"[{x0}]"))
    assert np.array_equal(ics, np.random.default_rng(42).uniform(lo, -lo, (2, 100)).T)
    assert any(a.startswith("hydra.sweep.dir=sweeps/") and a.endswith(row) for a in kexp_args)
    collect = next(c for c in calls if c.startswith("-results\ncollect")).split("\n")
    assert collect[3:6] == [row, "-o", dest]
    (tmp_path / "calls").unlink()
    bad = subprocess.run(["bash", str(root / "results" / script), "vanderpol_foo"], env=env, capture_output=True,
                         text=True)
    assert bad.returncode == 2 and "unknown controller" in bad.stderr and not (tmp_path / "calls").exists()


def test_region_map_rows_add_300_x0_and_merge_them_with_the_rows_100(tmp_path):
    """results/regions.sh --map ROW (kexp and kexp-results stubbed): refuses (exit 2, no sweep) while the row's
    100-x0 CSV is missing; else one multirun over default_rng(43).uniform(-2, 2, (2, 300)).T, collected into
    results/regions/map/300/, and results/regions/map/ROW.csv = the row's 100 lines then the 300 (one header);
    a collect that writes nothing merges nothing (an earlier sweep's CSV is removed first)."""
    import subprocess
    header = "x0_1,x0_2,status,success,cost\n"
    collected = tmp_path / "collected.csv"
    collected.write_text(header + "1.5,-1.5,completed,True,3.0\n-1.9,0.3,completed,False,9.0\n")
    root, env = _stubbed_results(tmp_path, collected)
    script = ["bash", str(root / "results" / "regions.sh"), "--map", "vanderpol_lmpc"]
    missing = subprocess.run(script, env=env, capture_output=True, text=True)
    assert missing.returncode == 2 and "run results/regions.sh vanderpol_lmpc first" in missing.stderr
    assert not (tmp_path / "calls").exists()
    (root / "results" / "regions" / "map" / "300").mkdir(parents=True)
    (root / "results" / "regions" / "vanderpol_lmpc.csv").write_text(header + "0.1,0.2,completed,True,1.0\n")
    stale = root / "results" / "regions" / "map" / "300" / "vanderpol_lmpc.csv"
    stale.write_text(header + "0.0,0.0,completed,True,7.0\n")      # an earlier sweep's
    proc = subprocess.run(script, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    kexp_args = next(c for c in (tmp_path / "calls").read_text().split("kexp") if "--multirun" in c).split("\n")
    x0 = next(a for a in kexp_args if a.startswith("sim.x0="))[len("sim.x0="):]
    assert np.array_equal(np.array(eval(f"[{x0}]")), np.random.default_rng(43).uniform(-2, 2, (2, 300)).T)
    assert (root / "results" / "regions" / "map" / "vanderpol_lmpc.csv").read_text() == (
        header + "0.1,0.2,completed,True,1.0\n1.5,-1.5,completed,True,3.0\n-1.9,0.3,completed,False,9.0\n")
    stale.write_text(header + "0.0,0.0,completed,True,7.0\n")
    merged = root / "results" / "regions" / "map" / "vanderpol_lmpc.csv"
    merged.unlink()
    _, no_collect = _stubbed_results(tmp_path / "again")
    assert subprocess.run(script, env=no_collect, capture_output=True, text=True).returncode == 0
    assert not stale.exists() and not merged.exists()


def test_a_configuration_that_is_no_controller_kind_is_no_row(tmp_path):
    """pendulum_paper-lmpc.csv collected in today's columns says controller lmpc, as pendulum_lmpc.csv does: the
    file name's configuration (paper-lmpc: the paper's preset) keeps it out of the table instead of a refusal as
    a duplicate."""
    import shutil
    for name in ("pendulum_lmpc.csv", "pendulum_paper-lmpc.csv"):
        shutil.copyfile(RESULTS / "pendulum_lmpc.csv", tmp_path / name)
    rows = load(sorted(tmp_path.glob("*.csv")))
    assert [key[:2] for key in rows] == [("pendulum", "lmpc")]
    assert next(iter(rows.values()))[0] == "pendulum_lmpc.csv"


@pytest.mark.parametrize("row, horizon", [("cart_pendulum_nmpc", "100"), ("cart_pendulum_nmpc-reg", "100"),
                                          ("vanderpol_nmpc", "20"), ("pendulum_nmpc-noise1", "20")])
def test_the_oracle_s_horizon_per_system(row, horizon):
    """results/sweep_lib.sh's oracle_horizon: the NMPC oracle looks 100 steps ahead on the cart pendulum, where 20
    fail from 10 of the results' 100 x0 (README, "A state-dependent input matrix"), and 20 elsewhere."""
    import subprocess
    proc = subprocess.run(["bash", str(RESULTS / "robustness.sh"), "--overrides", row], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    ov = proc.stdout.split("\n")
    assert "controller=nmpc" in ov and f"controller.horizon={horizon}" in ov
    assert ov[0] == f"+experiment={row.rsplit('_', 1)[0]}"
