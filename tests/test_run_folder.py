"""A run folder is never shared and never overwritten (kexp/app/run_folder.py): real ``kexp`` processes started
together, a named folder that holds a run, two sweeps into one sweep folder, and the exclusive creation of each
file.  ``KEXP_PAIRS=50 pytest tests/test_run_folder.py -k pairs`` starts 50 pairs instead of 10."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from kexp.app.run_folder import (RunFolderError, claim_run_folder, completed, holds_run, is_generated, run_files)
from kexp.recording import read_log

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=0.5", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]
STEPS = 50   # sim.T / dt
PAIRS = int(os.environ.get("KEXP_PAIRS", "10"))


def kexp(*argv, cwd=None, wait=True):
    """A ``kexp`` process (this checkout's, via ``python -m``): the CompletedProcess, or the Popen (``wait=False``)."""
    cmd = [sys.executable, "-m", "kexp.app.main", *map(str, argv)]
    if not wait:
        return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A model and CLF cache filled by one run first, so that the runs under test only read it."""
    d = tmp_path_factory.mktemp("cache")
    out = tmp_path_factory.mktemp("warm") / "run"
    proc = kexp(*SMALL, f"cache.dir={d}", f"hydra.run.dir={out}")
    assert proc.returncode == 0, proc.stderr
    return d


def snapshot(folder: Path) -> dict:
    """Every file below ``folder`` (relative path -> bytes)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def files_line(stdout: str) -> Path:
    """The folder a run names in its last line "files: <folder> (…)"."""
    line = [x for x in stdout.splitlines() if x.startswith("files: ")][-1]
    return Path(line[len("files: "):].rsplit(" (", 1)[0])


def assert_complete(folder: Path) -> None:
    """``folder`` holds one whole run: a completed summary, a completed log with every step, its config."""
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["completed"] is True
    log = read_log(folder / "run.mcap")
    assert log.completed and not log.truncated
    assert [m["k"] for m in log.messages("/step")] == list(range(STEPS))
    assert log.one("/config")["config_hash"] == summary["config_hash"]
    assert (folder / ".hydra" / "config.yaml").is_file()


@pytest.mark.parametrize("i", range(PAIRS))
def test_pairs_started_together_never_share_a_folder(i, cache, tmp_path):
    """Two real runs started at once: even pairs with the default folder (outputs/<date>/<time>, one-second
    resolution: the same name whenever both start in the same second), odd pairs with a time stamp that is the same
    for both (the year: the name is always taken), so that the second always takes <name>-1 and says so."""
    extra = [] if i % 2 == 0 else [f"hydra.run.dir={tmp_path}/runs/${{now:%Y}}"]
    procs = [kexp(*SMALL, f"cache.dir={cache}", *extra, cwd=tmp_path, wait=False) for _ in range(2)]
    outs = [p.communicate(timeout=300) + (p.returncode,) for p in procs]
    for out, err, code in outs:
        assert code == 0 and err == "", [(o[-3000:], e) for o, e, _ in outs]
    folders = [files_line(out) for out, _, _ in outs]
    assert folders[0] != folders[1]
    for folder in folders:
        assert_complete(folder)
    notes = [line for out, _, _ in outs for line in out.splitlines() if line.startswith("note: ")]
    if i % 2:
        name = folders[0].parent / str(folders[0].name).split("-")[0]
        assert sorted(folders) == [name, name.with_name(name.name + "-1")]
        assert notes == [f"note: {name} is taken by another run; this run's folder is {name}-1"]
    else:   # the same second: one note; else none
        a, b = sorted(folders)
        same_second = b == a.with_name(a.name + "-1")
        assert len(notes) == same_second and a.parent.parent == tmp_path / "outputs"


def test_a_named_folder_that_holds_a_run_is_refused_and_left_as_it_is(cache, tmp_path):
    out = tmp_path / "mine"
    first = kexp(*SMALL, f"cache.dir={cache}", f"hydra.run.dir={out}")
    assert first.returncode == 0, first.stderr
    before = snapshot(out)
    second = kexp(*SMALL, f"cache.dir={cache}", f"hydra.run.dir={out}", "sim.T=0.3")
    err = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(err) == 1 and second.stdout == ""
    assert err[0] == (f"kexp: error: hydra.run.dir={out} holds a run already (summary.json, model.npz, run.mcap); "
                      "kexp never overwrites a run: give another folder, or leave hydra.run.dir unset for a new "
                      "time-stamped one")
    assert snapshot(out) == before


@pytest.mark.parametrize("name", ["run.mcap", "summary.json", ".hydra"])
def test_a_folder_where_a_file_belongs_is_refused(name, tmp_path):
    """run.mcap or summary.json present as a folder (was IsADirectoryError, a traceback): one line, exit 2, left."""
    out = tmp_path / "run"
    (out / name).mkdir(parents=True)
    (out / name / "keep.txt").write_text("mine")
    proc = kexp(*SMALL, f"hydra.run.dir={out}")
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1 and err[0].startswith("kexp: error: ")
    assert f"holds a run already ({name})" in err[0]
    assert snapshot(out) == {f"{name}/keep.txt": b"mine"}


def test_two_runs_into_one_named_folder_at_once_one_runs(cache, tmp_path):
    """The same hydra.run.dir for two runs started together: one runs, the other is refused in one line (at the
    folder, at its .hydra or at summary.json, whichever it reaches second) and writes nothing."""
    for i in range(3):
        out = tmp_path / f"same{i}"
        procs = [kexp(*SMALL, f"cache.dir={cache}", f"hydra.run.dir={out}", wait=False) for _ in range(2)]
        outs = sorted((p.communicate(timeout=300) + (p.returncode,) for p in procs), key=lambda o: o[2])
        (out0, err0, code0), (_, err1, code1) = outs
        assert (code0, code1) == (0, 2) and err0 == "", (err0, err1)
        err1 = err1.strip().splitlines()
        assert len(err1) == 1 and err1[0].startswith("kexp: error: ") and "holds a run already" in err1[0], err1
        assert files_line(out0) == out
        assert_complete(out)


def test_two_sweeps_into_one_sweep_folder_leave_the_first_sweeps_jobs(cache, tmp_path):
    sweep = tmp_path / "sweep"
    first = kexp("-m", *SMALL, f"cache.dir={cache}", f"hydra.sweep.dir={sweep}", "sim.x0=[0.5,0.5],[0.4,0.4]")
    assert first.returncode == 0, first.stderr
    jobs = {j: snapshot(sweep / j) for j in ("0", "1")}
    second = kexp("-m", *SMALL, f"cache.dir={cache}", f"hydra.sweep.dir={sweep}", "sim.x0=[0.3,0.3],[0.2,0.2]")
    # each job refused (one line each), or the whole sweep before any job (a sweep folder that holds runs)
    assert re.search("holds (a run|runs) already", second.stderr) and "Traceback" not in second.stderr
    assert {j: snapshot(sweep / j) for j in ("0", "1")} == jobs
    assert "sim.x0=[0.5,0.5]" in (sweep / "0" / ".hydra" / "overrides.yaml").read_text()


def test_a_run_with_a_recording_says_how_to_view_it_headless(tmp_path, cache):
    """The last line names the recording and the web viewer for a machine without a display (issue 36)."""
    out = tmp_path / "run"
    proc = kexp(*[a for a in SMALL if a != "logging.rrd=false"], f"cache.dir={cache}", f"hydra.run.dir={out}")
    assert proc.returncode == 0, proc.stderr
    last = proc.stdout.splitlines()[-1]
    assert last.startswith(f"view: rerun {out.resolve() / 'run.rrd'}   (no display: rerun --web-viewer")
    assert (out / "run.rrd").is_file() and files_line(proc.stdout) == out.resolve()
    quiet = kexp(*SMALL, f"cache.dir={cache}", f"hydra.run.dir={tmp_path / 'norrd'}")
    assert quiet.returncode == 0 and "view: " not in quiet.stdout      # no recording: nothing to view


# -- the pieces ---------------------------------------------------------------------------------------------------
def test_holds_run_and_completed(tmp_path):
    assert not holds_run(tmp_path / "missing") and not holds_run(tmp_path) and not completed(tmp_path)
    (tmp_path / "notes.txt").write_text("x")
    assert not holds_run(tmp_path)
    for name in ("summary.json", "model.npz", "run.mcap", "run.rrd", ".hydra"):
        d = tmp_path / name.replace(".", "_")
        d.mkdir()
        (d / name).symlink_to(tmp_path / "nowhere")     # a broken link counts too
        assert holds_run(d), name
    (tmp_path / "summary.json").write_text(json.dumps({"status": "running", "completed": False}))
    assert holds_run(tmp_path) and not completed(tmp_path) and run_files(tmp_path) == ["summary.json"]
    (tmp_path / "summary.json").write_text(json.dumps({"status": "completed", "completed": True}))
    assert completed(tmp_path)
    (tmp_path / "summary.json").write_text("{not json")
    assert not completed(tmp_path)


def test_claim_takes_the_next_free_suffix_and_refuses_a_named_run(tmp_path):
    base = tmp_path / "out" / "12-00-00"
    got = [claim_run_folder(base, generated=True) for _ in range(3)]
    assert [g[0] for g in got] == [base, base.with_name("12-00-00-1"), base.with_name("12-00-00-2")]
    assert got[0][1] is None and got[2][1] == f"note: {base} is taken by another run; this run's folder is {base}-2"
    base.with_name("12-00-00-3").write_text("a file, not a run folder: skipped, left")
    assert claim_run_folder(base, generated=True)[0] == base.with_name("12-00-00-4")
    named = tmp_path / "named"
    assert claim_run_folder(named, generated=False) == (named, None)     # made
    assert claim_run_folder(named, generated=False) == (named, None)     # empty: used
    (named / "run.mcap").write_bytes(b"x")
    with pytest.raises(RunFolderError, match="holds a run already \\(run.mcap\\)"):
        claim_run_folder(named, generated=False)
    assert (named / "run.mcap").read_bytes() == b"x"


@pytest.mark.parametrize("pattern,generated", [
    ("outputs/${now:%Y-%m-%d}/${now:%H-%M-%S}", True), ("runs/${now:%s}", True), ("/tmp/mine", False),
    ("outputs/${hydra.job.name}", False)])
def test_a_time_stamped_pattern_is_generated(pattern, generated):
    assert is_generated(pattern) is generated


def test_the_loggers_create_their_file_exclusively(tmp_path):
    from kexp.recording.process_log import ProcessRunLogger
    from kexp.recording.writer import RunLogger
    for cls in (RunLogger, ProcessRunLogger):
        path = tmp_path / f"{cls.__name__}.mcap"
        path.write_bytes(b"an earlier run's log")
        with pytest.raises(FileExistsError):
            cls(path)
        assert path.read_bytes() == b"an earlier run's log"
        (tmp_path / cls.__name__).mkdir()
        with pytest.raises(FileExistsError):
            cls(tmp_path / cls.__name__)


def test_run_refuses_a_folder_that_holds_a_run(tmp_path):
    from hydra import compose, initialize_config_dir

    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL)
    (tmp_path / "model.npz").write_bytes(b"earlier")
    with pytest.raises(RunFolderError, match="holds a run already \\(model.npz\\)"):
        run(cfg, tmp_path, echo=lambda *_: None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
