"""A sweep's jobs as the kexp process sees them (kexp.app.resume, kexp.app.sweeper): the exit code says whether
jobs stopped with an error, ``sweep.resume=true`` re-enters a sweep folder, and the workers end with the kexp
process."""
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from kexp.app import aggregate as agg
from kexp.app import resume
from test_sweep import QUICK, _kexp_multirun, _script

X0 = ["[0.5,0.5]", "[0.4,0.4]", "[0.3,0.3]", "[0.2,0.2]"]
CLOSING = "kexp: {} of {} jobs stopped with an error; see kexp-report {}"


def _files(root: Path) -> dict[str, bytes]:
    """Every file below ``root`` (hidden folders too) and its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _job_lines(stdout: str) -> list[str]:
    return [ln for ln in stdout.splitlines() if ln.startswith("#")]


def _progress(stdout: str) -> dict[str, str]:
    """Job ("#0") -> its word, from the sweep's ``[k/N] word #num …`` lines."""
    return {ln.split()[2]: ln.split()[1] for ln in stdout.splitlines() if ln.startswith("[")}


# -- exit code ----------------------------------------------------------------------------------------------------
def test_a_sweep_whose_job_fails_exits_2_after_all_jobs_with_a_closing_line(tmp_path):
    """Job 1's x0 has 3 components for a 2-state system: it stops with its one-line error, jobs 0 and 2 still
    run (one of them does not settle: a result, not an error), and the sweep exits 2 with one line counting it."""
    sweep = tmp_path / "sweep"
    proc = _kexp_multirun(tmp_path, sweep, f"sim.x0={X0[0]},[0.1,0.2,0.3],[1.5,1.5]", "sim.tol=0.5")
    assert proc.returncode == 2, proc.stderr[-3000:]
    err = proc.stderr.strip().splitlines()
    assert err[-1] == CLOSING.format(1, 3, sweep)
    assert any("give 2 finite numbers (job #1:" in ln for ln in err)
    summaries = {p.parent.name: json.loads(p.read_text()) for p in sweep.glob("*/summary.json")}
    assert summaries["1"]["status"] == "error"
    assert summaries["0"]["completed"] and summaries["2"]["completed"]
    assert summaries["2"]["metrics"]["success"] is False   # did not settle: counted as a result
    assert _progress(proc.stdout) == {"#0": "settled", "#1": "error", "#2": "unsettled"}


def test_a_job_that_raised_is_counted_its_traceback_printed_and_the_sweep_goes_on(capsys):
    """A bug in a job (Hydra's JobReturn with status FAILED) no longer stops the sweep at that batch with exit
    code 1: its traceback is printed, the return is made completed and the job is counted as an error."""
    from hydra.core.utils import JobReturn, JobStatus
    try:
        raise ZeroDivisionError("the bug")
    except ZeroDivisionError as exc:
        failed = JobReturn(overrides=["sim.x0=[0.5,0.5]"], status=JobStatus.FAILED, _return_value=exc)
    tally = resume.Tally(Path("/x"), resume=False)
    resume._tally_launched(tally, [failed], first=7)
    assert tally.launched == [7] and tally.errors == [7]
    assert failed.status == JobStatus.COMPLETED and failed.return_value is None
    err = capsys.readouterr().err
    assert "kexp: internal error in job #7" in err and "ZeroDivisionError: the bug" in err and "Traceback" in err
    assert tally.closing_lines() == ([], [CLOSING.format(1, 1, Path("/x"))])


# -- resume -------------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_resume_runs_again_only_the_jobs_without_a_completed_run(tmp_path):
    """4 jobs (joblib, 2 workers); then job 1's summary is corrupted and job 2's deleted.  Without sweep.resume the
    sweep folder is refused (exit 2, nothing changed); with it jobs 0 and 3 are skipped (their files byte-identical),
    1 and 2 run again in their own folders, the old ones moved aside, and the report reads 4 completed jobs."""
    sweep = tmp_path / "sweep"
    launcher = ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"sim.x0={','.join(X0)}"]
    first = _kexp_multirun(tmp_path, sweep, *launcher)
    assert first.returncode == 0, first.stderr[-3000:]
    (sweep / "1" / "summary.json").write_text('{"status": "comple')   # cut mid-write
    old1 = (sweep / "1" / "run.mcap").read_bytes()
    (sweep / "2" / "summary.json").unlink()
    before = _files(sweep)

    again = _kexp_multirun(tmp_path, sweep, *launcher)   # no resume: refused, nothing written
    assert again.returncode == 2
    assert again.stderr.strip().splitlines() == [
        f"kexp: error: hydra.sweep.dir={sweep} holds runs already (4: 0, 1, 2, 3); kexp never overwrites a run: "
        "add sweep.resume=true to skip the completed jobs and run the others, or give another hydra.sweep.dir "
        "(nothing was changed)"]
    assert _files(sweep) == before

    resumed = _kexp_multirun(tmp_path, sweep, *launcher, "sweep.resume=true")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    lines = _job_lines(resumed.stdout)
    assert [ln.split(" (")[0] for ln in lines if "sweep.resume" in ln] == [
        "#0 skipped", "#1 runs again", "#2 runs again", "#3 skipped"]
    assert sorted(_progress(resumed.stdout)) == ["#1", "#2"]   # k counts the skipped: [3/4], [4/4]
    assert sorted(ln[:5] for ln in resumed.stdout.splitlines() if ln.startswith("[")) == ["[3/4]", "[4/4]"]
    assert "kexp: sweep.resume: 2 of 4 jobs were complete and skipped, 2 launched" in resumed.stdout
    after = _files(sweep)
    for job in ("0", "3"):   # skipped: byte-identical, .hydra included
        assert {k: v for k, v in after.items() if k.startswith(job + "/")} == {
            k: v for k, v in before.items() if k.startswith(job + "/")}
    for job, x0 in (("1", [0.4, 0.4]), ("2", [0.3, 0.3])):   # each in its own folder, under its own number
        s = json.loads((sweep / job / "summary.json").read_text())
        assert s["completed"] is True and s["x0"] == x0
        assert yaml.safe_load((sweep / job / ".hydra" / "overrides.yaml").read_text())[0] == f"sim.x0={X0[int(job)]}"
        assert "sweep.resume=true" not in (sweep / job / ".hydra" / "overrides.yaml").read_text()
    assert (sweep / ".1.replaced-1" / "summary.json").read_text() == '{"status": "comple'
    assert (sweep / ".1.replaced-1" / "run.mcap").read_bytes() == old1
    aside2 = sweep / ".2.replaced-1"
    assert not (aside2 / "summary.json").exists() and (aside2 / "run.mcap").exists()
    rows = agg.aggregate(sweep)
    assert len(rows) == 4 and all(r["status"] == "completed" for r in rows)

    # a changed config resumed into the same folder: every job's folder holds another config's run, refused
    snapshot = _files(sweep)
    changed = _kexp_multirun(tmp_path, sweep, *launcher, "sweep.resume=true", "clf.gamma=1.5")
    assert changed.returncode == 2
    err = changed.stderr.strip().splitlines()
    assert sum("holds the run of another config" in ln for ln in err) == 4
    assert err[-1] == CLOSING.format(4, 4, sweep)
    assert {k: v for k, v in _files(sweep).items() if k != "multirun.yaml"} == {
        k: v for k, v in snapshot.items() if k != "multirun.yaml"}


def test_resume_is_not_part_of_the_config_hash():
    from hydra import compose, initialize_config_dir

    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import config_dict, config_hash
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        a = compose(config_name="config", overrides=QUICK)
        b = compose(config_name="config", overrides=[*QUICK, "sweep.resume=true"])
    assert b.sweep.resume is True and a.sweep.resume is False
    assert "sweep" not in config_dict(b)
    assert config_hash(config_dict(a)) == config_hash(config_dict(b))


def test_classify_a_job_folder(tmp_path):
    job = tmp_path / "0"
    assert resume.classify(job, "abc") == ("launch", "")
    job.mkdir()
    assert resume.classify(job, "abc") == ("launch", "")   # an empty folder holds no run
    (job / "summary.json").write_text(json.dumps({"status": "completed", "completed": True, "config_hash": "abc"}))
    assert resume.classify(job, "abc")[0] == "skip"
    assert resume.classify(job, "abd")[0] == "refuse"
    (job / "summary.json").write_text(json.dumps({"status": "diverged", "completed": True, "config_hash": "abc"}))
    assert resume.classify(job, "abc")[0] == "skip"   # a result, not an error
    (job / "summary.json").write_text(json.dumps({"status": "running", "completed": False, "config_hash": "abc"}))
    assert resume.classify(job, "abc") == ("replace", "an incomplete run (status 'running')")
    (job / "summary.json").write_text(json.dumps({"status": "error", "completed": False, "message": "x"}))
    assert resume.classify(job, "abc") == ("replace", "a run that stopped with an error")
    (job / "summary.json").unlink()
    (job / "run.mcap").write_bytes(b"")
    assert resume.classify(job, "abc") == ("replace", "a run without a readable summary.json")
    aside = resume.move_aside(job)
    assert aside == tmp_path / ".0.replaced-1" and (aside / "run.mcap").exists() and not job.exists()


# -- workers end with the kexp process ----------------------------------------------------------------------------
def _group(pgid: int) -> list[tuple[int, str]]:
    """(pid, command) of the live processes (not zombies) in process group ``pgid``."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()   # after "pid (comm) ": state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] != "Z":
            out.append((int(d.name), cmd))
    return out


LAUNCHERS = {"joblib": (["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"], "loky"),
             "submitit_local": (["hydra/launcher=submitit_local", "hydra.launcher.timeout_min=5"], "submitit")}


@pytest.mark.slow
@pytest.mark.parametrize("launcher,sig", [("joblib", signal.SIGKILL), ("joblib", signal.SIGTERM),
                                          ("submitit_local", signal.SIGKILL)])
def test_workers_end_when_the_kexp_process_is_killed(tmp_path, launcher, sig):
    """A sweep in its own process group; once a job runs (its summary says "running"), the kexp process is killed:
    its loky workers and the resource trackers (joblib), its jobs and their submitit helpers (children of the kexp
    process's children) end too (they stayed, ~240 MB each, for the whole sweep's work and idle afterwards)."""
    if launcher == "submitit_local":
        pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    args, marker = LAUNCHERS[launcher]
    sweep = tmp_path / "sweep"
    cmd = _script("kexp") + ["--multirun", *args, f"sim.x0={','.join(X0[:2])}", f"hydra.sweep.dir={sweep}", *QUICK,
                             "sim.T=1000.0"]   # minutes: no job ends by itself within the test
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    pgid = proc.pid
    try:
        deadline = time.monotonic() + 300
        while not list(sweep.glob("*/summary.json")):
            assert proc.poll() is None, "the sweep ended before a job started"
            assert time.monotonic() < deadline, "no job started within 300 s"
            time.sleep(0.2)
        workers = [p for p in _group(pgid) if p[0] != proc.pid]
        assert any(marker in c for _, c in workers), workers   # the workers exist, in the sweep's group
        os.kill(proc.pid, sig)
        proc.wait(timeout=60)
        deadline = time.monotonic() + 60
        while _group(pgid) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert _group(pgid) == []
    finally:
        for pid, _ in _group(pgid):   # whatever is left of this test's own process group
            os.kill(pid, signal.SIGKILL)
    summaries = [json.loads(p.read_text()) for p in sweep.glob("*/summary.json")]
    assert summaries and all(s["status"] == "running" for s in summaries)   # killed mid-run: kexp-report says so


def test_a_job_whose_kexp_process_is_gone_does_not_start(tmp_path):
    """watch_parent in a fresh process, with the kexp process named as this test's process (its host, pid and start
    time): alive, the job is watched and goes on; the same pid with another start time (the pid reused: the kexp
    process is gone) ends it at once with one line, exit code 3; another host's process is not watched."""
    import socket
    import sys

    from kexp.app.sweeper import PARENT_ENV, _proc_stat
    start = _proc_stat(os.getpid())[1]
    code = "from kexp.app.sweeper import watch_parent; print(watch_parent())"

    def job(value):
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                              env={**os.environ, PARENT_ENV: value})
    host = socket.gethostname()
    alive = job(f"{host}:{os.getpid()}:{start}")
    assert (alive.returncode, alive.stdout.strip()) == (0, "True"), alive.stderr
    gone = job(f"{host}:{os.getpid()}:{int(start) + 1}")
    assert gone.returncode == 3 and gone.stdout == ""
    assert gone.stderr.strip() == f"kexp: the sweep's kexp process (pid {os.getpid()}) is gone: this job does not start"
    elsewhere = job(f"{host}-other-node:{os.getpid()}:{int(start) + 1}")
    assert (elsewhere.returncode, elsewhere.stdout.strip()) == (0, "False"), elsewhere.stderr
