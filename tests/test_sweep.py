"""Sweeps (kexp --multirun with the joblib and submitit launchers) and their report (kexp-report)."""
import csv
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from kexp.app import aggregate as agg
from kexp.app import report as rep

QUICK = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.rrd=false"]
# sim.tol=0.5 splits the two initial conditions: measured ‖x(2)‖ = 0.117 from (0.5, 0.5), 1.405 from (1.5, 1.5)
SWEEP_X0 = ["sim.x0=[0.5,0.5],[1.5,1.5]", "sim.tol=0.5"]


def _script(name: str) -> list[str]:
    """The console script installed beside this interpreter (what a user types), else the module."""
    for cand in (Path(sys.executable).parent / name, shutil.which(name)):
        if cand and Path(cand).exists():
            return [str(cand)]
    return [sys.executable, "-m", {"kexp": "kexp.app.main", "kexp-report": "kexp.app.report"}[name]]


def _kexp_multirun(cwd: Path, sweep_dir: Path, *args: str, timeout=180) -> subprocess.CompletedProcess:
    cmd = _script("kexp") + ["--multirun", *args, f"hydra.sweep.dir={sweep_dir}", *QUICK]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, timeout=timeout)


def _summaries(sweep_dir: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(sweep_dir.glob("*/summary.json"))}


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def joblib_sweep(tmp_path_factory):
    """kexp --multirun hydra/launcher=joblib hydra.launcher.n_jobs=2 'sim.x0=[0.5,0.5],[1.5,1.5]' sim.tol=0.5"""
    base = tmp_path_factory.mktemp("joblib")
    sweep = base / "sweep"
    t0 = time.perf_counter()
    proc = _kexp_multirun(base, sweep, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", *SWEEP_X0)
    wall = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-3000:]
    print(f"2-job joblib sweep: {wall:.1f} s")
    (base / "stdout.txt").write_text(proc.stdout)  # beside the sweep folder, for the test of what a job prints
    return sweep


@pytest.mark.slow
def test_joblib_sweep_runs_both_initial_conditions(joblib_sweep):
    assert sorted(p.name for p in joblib_sweep.iterdir() if p.is_dir()) == ["0", "1"]
    runs = _summaries(joblib_sweep)
    assert set(runs) == {"0", "1"}
    assert all(s["completed"] is True and s["status"] == "completed" for s in runs.values())
    assert runs["0"]["x0"] == [0.5, 0.5] and runs["1"]["x0"] == [1.5, 1.5]
    assert yaml.safe_load((joblib_sweep / "0/.hydra/overrides.yaml").read_text())[:2] == ["sim.x0=[0.5,0.5]",
                                                                                         "sim.tol=0.5"]
    m0, m1 = runs["0"]["metrics"], runs["1"]["metrics"]
    # measured: ‖x(2)‖ = 0.117, J = 2.228 from (0.5, 0.5); ‖x(2)‖ = 1.405, J = 6.476 from (1.5, 1.5)
    assert m0["success"] is True and 0.05 < m0["final_error"] < 0.25 and 1.5 < m0["cost"] < 3.0
    assert m1["success"] is False and m1["final_error"] > 1.0 and m1["cost"] > 4.0
    assert m0["max_abs_u"] <= 5.0 and m1["max_abs_u"] <= 5.0
    launcher = yaml.safe_load((joblib_sweep / "multirun.yaml").read_text())["hydra"]["launcher"]
    assert launcher["_target_"].endswith("JoblibLauncher") and launcher["n_jobs"] == 2


@pytest.mark.slow
def test_a_sweep_prints_a_launch_line_a_line_per_job_and_a_closing_line(joblib_sweep):
    """kexp's launch line instead of Hydra's line per job, a [k/N] line per job as it ends (its word, number,
    swept overrides, main numbers), a closing line; nothing else on stdout; no main.log in the job folders."""
    lines = (joblib_sweep.parent / "stdout.txt").read_text().splitlines()
    assert lines[0] == f"kexp: sweep of 2 jobs (2 workers) -> {joblib_sweep}"
    jobs = sorted(lines[1:3], key=lambda ln: ln.split()[2])
    assert sorted(ln[:5] for ln in lines[1:3]) == ["[1/2]", "[2/2]"] and len(lines) == 4, lines
    runs = _summaries(joblib_sweep)
    for num, line in enumerate(jobs):
        m = runs[str(num)]["metrics"]
        word = "settled" if m["success"] else "unsettled"
        assert line[6:].startswith(f"{word:<10} #{num} sim.x0=[{runs[str(num)]['x0'][0]},")   # sim.tol is common
        assert f"J = {m['cost']:.4g}" in line and "sim.tol" not in line
    assert jobs[0].split()[1] == "settled" and jobs[1].split()[1] == "unsettled"
    assert lines[3].startswith("kexp: sweep done in ") and lines[3].endswith(
        f": 2/2 completed (1 settled, 1 unsettled), 0 errors; kexp-report {joblib_sweep}")
    assert not list(joblib_sweep.glob("*/*.log")) and (joblib_sweep / "0" / ".hydra" / "config.yaml").is_file()


@pytest.mark.slow
def test_report_over_joblib_sweep(joblib_sweep, tmp_path):
    out = tmp_path / "report"
    proc = subprocess.run(_script("kexp-report") + [str(joblib_sweep), "-o", str(out)], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "2 runs: 2 completed, 0 errors; settled 1/2 (50 %)" in proc.stdout
    rows = _csv_rows(out / "report.csv")
    assert len(rows) == 2
    by_x0 = {tuple(json.loads(r["x0"])): r for r in rows}
    assert set(by_x0) == {(0.5, 0.5), (1.5, 1.5)}
    runs = _summaries(joblib_sweep)
    for job, s in runs.items():
        r = by_x0[tuple(s["x0"])]
        assert r["job"] == job and r["status"] == "completed" and r["reason"] == ""
        assert r["overrides"] == f"sim.x0=[{s['x0'][0]},{s['x0'][1]}]"  # only the swept key labels the row
        assert r["system"] == "vanderpol" and r["controller"] == s["controller"]
        assert r["success"] == ("true" if s["metrics"]["success"] else "false")
        assert float(r["cost"]) == pytest.approx(s["metrics"]["cost"], rel=1e-12)
        assert float(r["solve_median_ms"]) == pytest.approx(s["metrics"]["solve_time_median"] * 1e3, rel=1e-12)
        assert float(r["solve_p99_ms"]) == pytest.approx(s["metrics"]["solve_time_p99"] * 1e3, rel=1e-12)
        assert r["certificate_verdict"] == s["clf"]["certificate"]["verdict"]
        assert r["certificate"] in ("global", "samples", "fails")
    assert by_x0[(0.5, 0.5)]["success"] == "true" and by_x0[(1.5, 1.5)]["success"] == "false"
    assert float(by_x0[(0.5, 0.5)]["settling_time_s"]) < 2.0 and by_x0[(1.5, 1.5)]["settling_time_s"] == "inf"
    summary = _csv_rows(out / "report_summary.csv")
    assert len(summary) == 1 and summary[0]["group"] == "(all)" and summary[0]["runs"] == "2"
    assert float(summary[0]["success_rate"]) == 0.5
    costs = sorted(s["metrics"]["cost"] for s in runs.values())
    assert float(summary[0]["cost_worst"]) == pytest.approx(costs[1])
    assert float(summary[0]["cost_median"]) == pytest.approx(sum(costs) / 2)
    md = (out / "report.md").read_text()
    assert "**2 runs**: 2 completed, 0 errors; settled 1/2 (50 %)" in md
    assert "| (all) | 2 | 0 | 1/2 (50 %) |" in md
    assert "## Runs that stopped with an error (0)" in md and "| [1.5, 1.5] | completed | no |" in md
    _check_pictures(out, md)


def _check_pictures(out: Path, md: str):
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert rep.NO_MATPLOTLIB in md and not list(out.glob("*.png"))
        return
    for name in rep.PICTURES.values():
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"]({name})" in md


def test_pictures_are_optional_without_matplotlib(joblib_sweep, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib → ImportError
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(SystemExit) as exc:
        rep.main([str(joblib_sweep), "-o", str(tmp_path)])
    assert exc.value.code == 0
    assert capsys.readouterr().err.strip() == f"kexp-report: {rep.NO_MATPLOTLIB}"
    assert rep.NO_MATPLOTLIB in (tmp_path / "report.md").read_text() and not list(tmp_path.glob("*.png"))


def test_job_without_summary_is_counted_as_an_error(joblib_sweep, tmp_path, capsys):
    sweep = tmp_path / "sweep"
    shutil.copytree(joblib_sweep, sweep, ignore=shutil.ignore_patterns("*.mcap", "*.npz", "report*", "*.png"))
    (sweep / "1" / "summary.json").unlink()  # as a job that crashed before its run started
    rows = agg.aggregate(sweep)
    assert [r["job"] for r in rows] == ["0", "1"]
    assert rows[0]["ok"] and rows[0]["success"] is True
    bad = rows[1]
    assert not bad["ok"] and bad["status"] == "missing" and bad["success"] is None and bad["cost"] is None
    assert bad["reason"].startswith("no summary.json") and bad["x0"] == [1.5, 1.5]  # x0 from overrides.yaml
    with pytest.raises(SystemExit) as exc:
        rep.main([str(sweep)])
    assert exc.value.code == 0
    stdout = capsys.readouterr().out
    assert "2 runs: 1 completed, 1 error; settled 1/2 (50 %)" in stdout
    assert "error: 1 sim.x0=[1.5,1.5]: no summary.json" in stdout
    md = (sweep / "report.md").read_text()
    assert "## Runs that stopped with an error (1)" in md and "- `1` sim.x0=[1.5,1.5]: no summary.json" in md
    assert "| (all) | 2 | 1 | 1/2 (50 %) |" in md
    rows_csv = _csv_rows(sweep / "report.csv")
    assert [r["status"] for r in rows_csv] == ["completed", "missing"]

    # a run killed mid-way leaves the 'running' summary that run() writes first
    (sweep / "1" / "summary.json").write_text(json.dumps({"status": "running", "completed": False,
                                                          "config_hash": "x"}))
    bad = agg.aggregate(sweep)[1]
    assert not bad["ok"] and bad["status"] == "interrupted" and "status 'running'" in bad["reason"]
    # a diverged run completed its summary but is a failure, with the simulator's message
    s = json.loads((sweep / "0" / "summary.json").read_text())
    s.update(status="diverged", message="state left ‖x‖ ≤ 1e+06 at t=1.230")
    s["metrics"]["success"] = False
    (sweep / "1" / "summary.json").write_text(json.dumps(s))
    bad = agg.aggregate(sweep)[1]
    assert not bad["ok"] and bad["status"] == "diverged" and bad["reason"] == "status 'diverged': " + s["message"]
    assert agg.summarize(agg.aggregate(sweep))[0]["errors"] == 1


def test_jobs_the_sweep_never_started_are_listed(joblib_sweep, tmp_path):
    sweep = tmp_path / "sweep"
    shutil.copytree(joblib_sweep, sweep, ignore=shutil.ignore_patterns("*.mcap", "*.npz", "report*", "*.png"))
    # as if the sweep had planned a third initial condition and stopped before launching it
    mr = sweep / "multirun.yaml"
    mr.write_text(mr.read_text().replace("sim.x0=[0.5,0.5],[1.5,1.5]", "sim.x0=[0.5,0.5],[1.5,1.5],[0.0,-1.0]"))
    rows = agg.aggregate(sweep)
    assert len(rows) == 3 and [r["ok"] for r in rows] == [True, True, False]
    assert rows[2]["status"] == "not started" and rows[2]["x0"] == [0.0, -1.0]
    assert rows[2]["job"] == "(not started #2)" and rows[2]["reason"].startswith("not started")
    summary = agg.summarize(rows)[0]
    assert (summary["runs"], summary["completed"], summary["errors"], summary["successes"]) == (3, 2, 1, 1)
    assert summary["success_rate"] == 1 / 3          # of the runs planned, not of those that completed


def test_report_errors_exit_2_with_one_line(tmp_path, capsys):
    for folder, needle in [(tmp_path / "nope", "no such folder"), (tmp_path, "holds no runs")]:
        with pytest.raises(SystemExit) as exc:
            rep.main([str(folder)])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"kexp-report: error: {folder}: ") and needle in err[0]
    proc = subprocess.run(_script("kexp-report") + [str(tmp_path / "nope")], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and proc.stderr.strip() == f"kexp-report: error: {tmp_path / 'nope'}: no such folder"


@pytest.mark.slow
def test_report_output_and_input_errors_exit_2_with_one_line(joblib_sweep, tmp_path, capsys):
    """-o a file, -o where no folder can be made (tracebacks before), a run.mcap given for the sweep folder."""
    afile = tmp_path / "afile"
    afile.write_text("")
    for argv, line in [
        ([str(joblib_sweep), "-o", str(afile)], f"kexp-report: error: -o {afile} is a file; give a folder"),
        ([str(joblib_sweep), "-o", "/proc/kexp-no-such/out"],
         "kexp-report: error: cannot write the report: /proc/kexp-no-such: No such file or directory; give a "
         "folder you can write with -o"),
        ([str(joblib_sweep / "0" / "run.mcap")],
         f"kexp-report: error: {joblib_sweep / '0' / 'run.mcap'} is a file; give the sweep folder (e.g. "
         "multirun/<date>/<time>)")]:
        with pytest.raises(SystemExit) as exc:
            rep.main(argv)
        assert exc.value.code == 2 and capsys.readouterr().err.strip().splitlines() == [line]
    assert afile.read_text() == ""


@pytest.mark.slow
def test_submitit_local_sweep(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    sweep = tmp_path / "sweep"
    proc = _kexp_multirun(tmp_path, sweep, "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=5",
                          "sim.x0=[0.5,0.5]", "clf.gamma=1,2", timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = _summaries(sweep)
    assert set(runs) == {"0", "1"} and all(s["completed"] and s["status"] == "completed" for s in runs.values())
    assert (sweep / ".submitit").is_dir()
    launcher = yaml.safe_load((sweep / "multirun.yaml").read_text())["hydra"]["launcher"]
    assert launcher["_target_"].endswith("LocalLauncher")
    res = rep.report(sweep, tmp_path / "report", pictures=False)
    groups = {g["group"]: g for g in res["groups"]}
    assert set(groups) == {"clf.gamma=1", "clf.gamma=2"}
    assert all(g["runs"] == 1 and g["completed"] == 1 for g in groups.values())
    assert [r["overrides"] for r in res["rows"]] == ["clf.gamma=1", "clf.gamma=2"]
    # the two CLF decay rates give two different controllers: the costs differ (measured 1.81 vs 2.23 at sim.tol
    # default, x0 = (0.5, 0.5))
    c1, c2 = (groups[k]["cost_median"] for k in ("clf.gamma=1", "clf.gamma=2"))
    assert 1.0 < c1 < 3.0 and 1.0 < c2 < 3.0 and abs(c1 - c2) > 0.1


def test_a_broken_job_does_not_stop_the_sweep(tmp_path):
    """Job 0 has a 3-component x0 for a 2-state system: it is rejected with its one-line reason in its folder,
    job 1 still runs, the report counts the broken one, and the sweep exits 2 after both with a closing line."""
    sweep = tmp_path / "sweep"
    proc = _kexp_multirun(tmp_path, sweep, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                          "sim.x0=[0.1,0.2,0.3],[0.5,0.5]", "sim.tol=0.5")
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines()[-1] == f"kexp: 1 of 2 jobs stopped with an error; see kexp-report {sweep}"
    runs = _summaries(sweep)
    assert runs["0"]["status"] == "error" and "sim.x0=[0.1, 0.2, 0.3]: give 2 finite numbers" in runs["0"]["message"]
    assert runs["1"]["status"] == "completed" and runs["1"]["completed"]
    assert "kexp: error: sim.x0=[0.1, 0.2, 0.3]" in proc.stderr
    assert f"give 2 finite numbers (job #0: {sweep / '0'})" in proc.stderr  # which job, in the same line
    assert sorted(ln.split()[1:3] for ln in proc.stdout.splitlines() if ln.startswith("[")) == [
        ["error", "#0"], ["settled", "#1"]]
    rows = agg.aggregate(sweep)
    assert sorted(r["status"] for r in rows) == ["completed", "error"]


def test_a_job_inside_a_joblib_sweep_logs_the_same_as_a_single_run(joblib_sweep, tmp_path):
    """Determinism: job 0 of the sweep and a plain run with the same overrides have identical deterministic
    channels, except the config's own record of the Hydra run mode."""
    from kexp.recording import diff_logs, read_log
    single = tmp_path / "single"
    proc = subprocess.run(_script("kexp") + ["sim.x0=[0.5,0.5]", "sim.tol=0.5", *QUICK, f"hydra.run.dir={single}"],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-2000:]
    a, b = read_log(joblib_sweep / "0" / "run.mcap"), read_log(single / "run.mcap")
    res = diff_logs(a, b)
    assert res.equal, res.report()
