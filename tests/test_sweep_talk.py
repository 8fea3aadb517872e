"""Sweeps that talk (kexp.app.sweep_progress): one launch line, a [k/N] line with an ETA per job as it ends, a
closing line; one word per outcome (settled, unsettled, error, identified)."""
import io
import json
import os
import subprocess
from pathlib import Path

from kexp.app import sweep_progress as sp
from test_cli_help import script

# controller=lqr, 2 s horizon, a small data set: the 3 jobs take ~3 s in all
TINY = ["controller=lqr", "sim.T=2.0", "data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "clf.grid=11",
        "logging.rrd=false", "sim.tol=0.5"]


def test_a_sweep_of_three_tiny_jobs_talks(tmp_path):
    """Job 0 settles (‖x(2)‖ = 0.32 < tol 0.5, measured), job 1 does not (1.04), job 2 stops with an error
    (3 numbers for 2 states): every line on stdout is kexp's, the exit code 2 counts the error."""
    sweep = tmp_path / "sweep"
    proc = subprocess.run([*script("kexp"), "-m", "sim.x0=[0.5,0.5],[1.5,1.5],[0.123456789,0.2,0.3]", *TINY,
                           f"hydra.sweep.dir={sweep}"], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert len(lines) == 5, lines
    assert lines[0] == f"kexp: sweep of 3 jobs (1 worker) -> {sweep}"
    assert [ln[:5] for ln in lines[1:4]] == ["[1/3]", "[2/3]", "[3/3]"]
    by_job = {ln.split()[2]: ln for ln in lines[1:4]}
    assert by_job["#0"][6:].startswith("settled    #0 sim.x0=[0.5,0.5]: ‖x(T)‖ = ")
    assert by_job["#1"][6:].startswith("unsettled  #1 sim.x0=[1.5,1.5]: ‖x(T)‖ = ")
    # the float to 4 significant digits in the overrides; the job's own error message after it
    assert by_job["#2"][6:].startswith("error      #2 sim.x0=[0.1235,0.2,0.3]: sim.x0=[0.123456789, 0.2, 0.3]: "
                                       "give 2 finite numbers; ")
    assert all(" ETA " in ln for ln in lines[1:3]) and lines[3].endswith(" in all")
    assert lines[4].startswith("kexp: sweep done in ") and lines[4].endswith(
        f": 2/3 completed (1 settled, 1 unsettled), 1 error; kexp-report {sweep}")
    assert proc.stderr.strip().splitlines()[-1] == f"kexp: 1 of 3 jobs stopped with an error; see kexp-report {sweep}"
    assert "#0 : " not in proc.stdout + proc.stderr and "Launching" not in proc.stdout + proc.stderr   # Hydra's
    report = subprocess.run([*script("kexp-report"), str(sweep), "-o", str(tmp_path / "report")],
                            capture_output=True, text=True, timeout=120)
    assert report.returncode == 0, report.stderr
    assert "3 runs: 2 completed, 1 error; settled 1/3 (33 %)" in report.stdout
    assert "error: 2 sim.x0=[0.123456789,0.2,0.3]: " in report.stdout


def test_words():
    done = {"status": "completed", "completed": True}
    assert sp.verdict({**done, "metrics": {"success": True}}) == "settled"
    assert sp.verdict({**done, "status": "diverged", "metrics": {"success": False}}) == "unsettled"
    assert sp.verdict({**done, "metrics": {"success": True}, "error": {"message": "x"}, "status": "error"}) == "error"
    assert sp.verdict({"status": "running", "completed": False}) == "error" and sp.verdict(None) == "error"
    assert sp.verdict({**done, "model": {"k": 9}}) == "identified"
    assert not sp.ended({"status": "running", "completed": False}) and sp.ended({"status": "error"})


def test_overrides_are_shortened():
    assert sp.round_floats("sim.x0=[0.123456789,-1.99999999e-05,3] clf.gamma=2") == \
        "sim.x0=[0.1235,-2e-05,3] clf.gamma=2"
    assert sp.round_floats("controller=lqr2 a.b_1=0.25") == "controller=lqr2 a.b_1=0.25"
    jobs = [["sim.x0=[0.5,0.5]", "sim.tol=0.5"], ["sim.x0=[1.5,1.5]", "sim.tol=0.5"]]
    assert sp.varying_keys(jobs) == {"sim.x0"} and sp.varying_keys(jobs[:1]) is None
    assert sp.shorten(jobs[1], {"sim.x0"}) == "sim.x0=[1.5,1.5]" and sp.shorten(jobs[1], None) == \
        "sim.x0=[1.5,1.5] sim.tol=0.5"
    assert sp.shorten(["k=" + "x" * 100], None, width=20) == "k=" + "x" * 17 + "…"
    assert [sp.duration(s) for s in (0.4, 59.6, 200, 7500)] == ["0 s", "1 min 00 s", "3 min 20 s", "2 h 05 min"]


def _job(sweep: Path, num: int, overrides, summary, mtime):
    folder = sweep / str(num)
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    if summary is not None:
        (folder / "summary.json").write_text(json.dumps(summary))
        os.utime(folder / "summary.json", (mtime, mtime))
    return folder


def test_lines_come_in_the_order_jobs_end_with_an_eta(tmp_path):
    """Jobs 2 then 0 end (by their summaries' times), 1 wrote none: [1/3] #2, [2/3] #0, ETA from the pace so far;
    the launcher's return adds #1 as an error; a finished run already there before the sweep is not a line."""
    sweep = tmp_path / "sweep"
    jobs = [[f"sim.x0=[{x},0.5]", "sim.T=5"] for x in (0.1, 0.2, 0.3)]
    _job(tmp_path / "old", 0, jobs[0], {"status": "completed", "completed": True, "metrics": {}}, 1)
    now = [100.0]
    out = io.StringIO()
    p = sp.Progress(sweep, jobs, workers=2, out=out, clock=lambda: now[0])
    p.started = 100.0
    assert p.launch_line() == f"kexp: sweep of 3 jobs (2 workers) -> {sweep}"
    metrics = {"success": False, "final_error": 1.5, "cost": 6.4759, "settling_time": None}
    _job(sweep, 0, jobs[0], {"status": "completed", "completed": True, "metrics": metrics}, 2000)
    _job(sweep, 2, jobs[2], {"status": "error", "completed": False, "message": "boom"}, 1000)
    _job(sweep, 1, jobs[1], {"status": "running", "completed": False}, 500)
    now[0] = 110.0
    p.scan()
    p.scan()   # a second look prints nothing new
    assert out.getvalue().splitlines() == [
        "[1/3] error      #2 sim.x0=[0.3,0.5]: boom; ETA 20 s",
        "[2/3] unsettled  #0 sim.x0=[0.1,0.5]: ‖x(T)‖ = 1.50e+00, J = 6.476, settling inf; ETA 5 s"]
    now[0] = 112.0
    p.finish([(0, sweep / "0"), (1, sweep / "1"), (2, sweep / "2")])
    assert out.getvalue().splitlines()[2] == "[3/3] error      #1 sim.x0=[0.2,0.5]: no final summary (status running); 12 s in all"
    assert p.closing_line() == f"kexp: sweep done in 12 s: 1/3 completed (1 unsettled), 2 errors; kexp-report {sweep}"


def test_workers():
    assert sp.workers_of({"_target_": "hydra._internal.core_plugins.basic_launcher.BasicLauncher"}) == 1
    assert sp.workers_of({"_target_": "x.JoblibLauncher", "n_jobs": 3}) == 3
    assert sp.workers_of({"_target_": "x.JoblibLauncher", "n_jobs": -1}) == (os.cpu_count() or 1)
    assert sp.workers_of({"_target_": "x.LocalLauncher"}) is None
