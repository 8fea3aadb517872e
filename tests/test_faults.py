"""Faults end in one line, exit code 2, and destroy nothing already written: a file-size limit (EFBIG, with
RLIMIT_FSIZE in the child; Python ignores SIGXFSZ, so the write raises OSError), a full disk (ENOSPC, on a tiny
tmpfs where this process may mount one), the recording failing after the run, interpolations that do not resolve,
and overrides among Hydra's options."""
import json
import os
import re
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from kexp.app.precheck import precheck
from kexp.recording import read_log

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]
LIMIT = 60_000   # bytes: above model.npz (~8 kB), summary.json (~5 kB) and .hydra's files; run.mcap passes it


def kexp(*argv, fsize=None, env=None):
    """A ``kexp`` process (this checkout's); ``fsize``: its file-size limit in bytes (RLIMIT_FSIZE)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
    return subprocess.run([sys.executable, "-m", "kexp.app.main", *map(str, argv)], capture_output=True, text=True,
                          timeout=300, preexec_fn=limit if fsize else None, env=env)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """The model and CLF cached by a first run, so that the runs under test write only their own files."""
    d = tmp_path_factory.mktemp("cache")
    proc = kexp(*SMALL, "sim.T=0.1", f"cache.dir={d}", f"hydra.run.dir={tmp_path_factory.mktemp('warm') / 'r'}")
    assert proc.returncode == 0, proc.stderr
    return d


def one_error_line(proc) -> str:
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1 and err[0].startswith("kexp: error: "), (proc.returncode, err)
    return err[0]


def assert_log_up_to_stated_time(line: str, out: Path) -> None:
    """The line says "the log up to t = X s (N steps) in …/run.mcap": the log reads back to exactly there."""
    m = re.search(r"the log up to t = (\d+\.\d\d) s \((\d+) steps\) in ([^,;]+)", line)
    assert m and Path(m.group(3)) == out / "run.mcap", line
    steps = read_log(out / "run.mcap").messages("/step")
    assert len(steps) == int(m.group(2)) > 0 and f"{steps[-1]['t']:.2f}" == m.group(1)
    assert [s["k"] for s in steps] == list(range(len(steps)))


@pytest.mark.parametrize("writer", ["sync", "process"])
def test_a_file_size_limit_on_the_log_is_one_line_and_keeps_what_was_written(writer, cache, tmp_path):
    out = tmp_path / "run"
    proc = kexp(*SMALL, "sim.T=5.0", f"logging.writer={writer}", f"cache.dir={cache}", f"hydra.run.dir={out}",
                fsize=LIMIT)
    line = one_error_line(proc)
    assert line.startswith(f"kexp: error: cannot write {out / 'run.mcap'}: File too large (EFBIG); saved: "), line
    assert f"the model in {out / 'model.npz'}" in line
    assert_log_up_to_stated_time(line, out)
    assert (out / "run.mcap").stat().st_size == LIMIT
    from kexp.identify import KoopmanBilinearModel
    assert KoopmanBilinearModel.load(out / "model.npz").k > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "error" and summary["completed"] is False
    assert summary["message"] == line[len("kexp: error: "):] and summary["error_type"] == "OutputError"
    assert sorted(p.name for p in out.iterdir()) == [".hydra", "model.npz", "run.mcap", "summary.json"]


def test_a_recording_that_cannot_be_written_leaves_the_runs_metrics(cache, tmp_path):
    """run.rrd passes the size limit after the run is complete: the run ends with exit code 0, its summary keeps
    every metric (written before the recording) and says why there is no run.rrd; no temporary file stays."""
    out, ref = tmp_path / "run", tmp_path / "ref"
    argv = [*SMALL, "sim.T=1.0", "logging.rrd=true", f"cache.dir={cache}"]
    proc = kexp(*argv, f"hydra.run.dir={out}", fsize=LIMIT)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    warning = [x for x in proc.stdout.splitlines() if x.startswith("warning: no run.rrd: ")]
    assert len(warning) == 1 and f"cannot write {out / 'run.rrd'}" in warning[0], proc.stdout[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["completed"] is True
    assert summary["warnings"] == [warning[0][len("warning: "):]]
    assert summary["files"] == {"model": "model.npz", "mcap": "run.mcap"}
    assert read_log(out / "run.mcap").completed
    assert sorted(p.name for p in out.iterdir()) == [".hydra", "model.npz", "run.mcap", "summary.json"]
    # the metrics are those of the same run without the limit (which renders its recording)
    full = kexp(*argv, f"hydra.run.dir={ref}")
    assert full.returncode == 0, full.stderr[-2000:]
    expected = json.loads((ref / "summary.json").read_text())
    assert expected["files"]["rrd"] == "run.rrd" and (ref / "run.rrd").stat().st_size > LIMIT
    deterministic = lambda m: {k: v for k, v in m.items() if not k.startswith("solve_time")}  # noqa: E731
    assert deterministic(summary["metrics"]) == deterministic(expected["metrics"])


@pytest.fixture
def tiny_disk(tmp_path):
    """A 160 kB tmpfs mounted at a folder (root only; skipped where mounting is not allowed)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=160k", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def test_a_full_disk_is_one_line_and_keeps_what_was_written(cache, tiny_disk):
    out = tiny_disk / "run"
    proc = kexp(*SMALL, "sim.T=20.0", "logging.prediction_every=1", f"cache.dir={cache}", f"hydra.run.dir={out}")
    line = one_error_line(proc)
    assert "No space left on device (ENOSPC)" in line, line
    assert_log_up_to_stated_time(line, out)
    from kexp.identify import KoopmanBilinearModel
    assert KoopmanBilinearModel.load(out / "model.npz").k > 0
    summary = json.loads((out / "summary.json").read_text())   # replaced whole or not at all: valid JSON
    assert summary["completed"] is False and summary["status"] in ("running", "error")


def test_an_error_after_the_summary_keeps_its_metrics(tmp_path):
    """_error_summary on a completed run's summary adds the error and keeps the metrics and status; on a running
    one it keeps its keys (config hash) besides the error; on none it writes the error alone."""
    from kexp.app.main import _error_summary
    from kexp.errors import KexpError
    done = {"status": "completed", "completed": True, "config_hash": "abc", "metrics": {"cost": 1.5}}
    (tmp_path / "summary.json").write_text(json.dumps(done))
    _error_summary(tmp_path, KexpError("later stage failed"))
    assert json.loads((tmp_path / "summary.json").read_text()) == {
        **done, "error": {"message": "later stage failed", "error_type": "KexpError"}}
    (tmp_path / "summary.json").write_text(json.dumps({"status": "running", "completed": False, "config_hash": "c"}))
    _error_summary(tmp_path, KexpError("boom"))
    assert json.loads((tmp_path / "summary.json").read_text()) == {
        "status": "error", "completed": False, "config_hash": "c", "message": "boom", "error_type": "KexpError"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


def test_a_summary_that_cannot_be_written_stays_as_it_was(tmp_path):
    """write_json under a size limit smaller than the new content: OSError, the previous summary unchanged, no
    temporary file left (a direct write_text left an empty or cut summary.json)."""
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"status": "completed", "metrics": {"cost": 1.5}}))
    before = path.read_bytes()
    script = ("import resource, json, sys; from pathlib import Path; from kexp.app.faults import write_json\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))\n"
              f"try:\n    write_json(Path({str(path)!r}), {{'x': 'y' * 10000}})\n"
              "except OSError as e:\n    print(e.errno)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "27", proc.stderr
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]


# -- interpolations and options: precheck ---------------------------------------------------------------------------
@pytest.mark.parametrize("argv,line", [
    (["sim.T=${oc.env:KEXP_TEST_UNSET}"], "kexp: error: sim.T=${oc.env:KEXP_TEST_UNSET}: Environment variable "
     "'KEXP_TEST_UNSET' not found; set the variable, or give a default: ${oc.env:NAME,value}"),
    (["sim.T=${nope.x}"], "kexp: error: sim.T=${nope.x}: Interpolation key 'nope.x' not found; interpolate a key "
     "that exists, or give a value"),
    (["sim.x0=[0.1,${nope.x}]"], "kexp: error: sim.x0[1]=${nope.x}: Interpolation key 'nope.x' not found; "
     "interpolate a key that exists, or give a value"),
    (["-cn", "config", "controller.lmpc.horizon=abc"], "kexp: error: controller.lmpc.horizon: Value 'abc' of type "
     "'str' could not be converted to Integer (error merging override controller.lmpc.horizon=abc)"),
    (["--config-name=config", "sim.T=${nope.x}"], "kexp: error: sim.T=${nope.x}: Interpolation key 'nope.x' not "
     "found; interpolate a key that exists, or give a value"),
    (["-m", "controller.lmpc.horizon=abc"], "kexp: error: controller.lmpc.horizon: Value 'abc' of type 'str' could "
     "not be converted to Integer (sweep value controller.lmpc.horizon='abc' does not fit the config schema)"),
    (["-cn", "nope", "sim.T=1"], "kexp: error: Cannot find primary config 'nope'."),
    (["sim.T=1", "-m", "sim.T=2"], "kexp: error: unrecognized arguments: sim.T=2; give the options (-m, -cn NAME, …) "
     "before or after all the overrides (see kexp --help)"),
])
def test_interpolations_and_options_are_checked_in_one_line(argv, line, capsys, monkeypatch):
    monkeypatch.delenv("KEXP_TEST_UNSET", raising=False)
    with pytest.raises(SystemExit) as ex:
        precheck(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert ex.value.code == 2 and len(err) == 1 and err[0].startswith(line), err


def test_config_dir_overrides_are_checked(tmp_path, capsys, monkeypatch):
    """--config-dir D with a preset of D that interpolates an unset variable, and a bad value beside it."""
    monkeypatch.delenv("KEXP_TEST_UNSET", raising=False)
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "mine.yaml").write_text("# @package _global_\nsim:\n  T: ${oc.env:KEXP_TEST_UNSET}\n")
    for argv, fragment in (
            (["--config-dir", str(tmp_path), "+experiment=mine"], "sim.T=${oc.env:KEXP_TEST_UNSET}: Environment"),
            (["--config-dir", str(tmp_path), "sim.T=1", "controller.lmpc.horizon=abc"], "controller.lmpc.horizon")):
        with pytest.raises(SystemExit) as ex:
            precheck(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert ex.value.code == 2 and len(err) == 1 and fragment in err[0], err
    monkeypatch.setenv("KEXP_TEST_UNSET", "2.0")
    precheck(["--config-dir", str(tmp_path), "+experiment=mine"])   # set: composes, nothing printed
    assert capsys.readouterr().err == ""


def test_an_unset_variable_in_a_users_preset_is_one_line_from_the_command(tmp_path):
    (tmp_path / "experiment").mkdir()
    (tmp_path / "experiment" / "mine.yaml").write_text("# @package _global_\nsim:\n  T: ${oc.env:KEXP_TEST_UNSET}\n")
    env = {k: v for k, v in os.environ.items() if k != "KEXP_TEST_UNSET"}
    proc = kexp("--config-dir", tmp_path, "+experiment=mine", f"hydra.run.dir={tmp_path / 'run'}", env=env)
    assert one_error_line(proc).startswith("kexp: error: sim.T=${oc.env:KEXP_TEST_UNSET}: Environment variable")
    assert not (tmp_path / "run").exists()


def test_an_unresolved_interpolation_in_a_sweep_job_is_one_line(tmp_path):
    """Past the precheck (a sweep composes its jobs later): the run's own conversion says it in one line."""
    from hydra import compose, initialize_config_dir

    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    from kexp.errors import ConfigError
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL + ["sim.T=${nope.x}"])
    with pytest.raises(ConfigError) as exc:
        run(cfg, tmp_path, echo=lambda *_: None)
    assert str(exc.value) == ("sim.T=${nope.x}: Interpolation key 'nope.x' not found; interpolate a key that "
                              "exists, or give a value")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, sweep", [
    (["sim.T=1"], False), (["-m", "sim.T=1,2"], True), (["--multirun", "sim.T=1,2"], True),
    (["--multir", "sim.T=1,2"], True),   # argparse's abbreviation: Hydra runs a sweep, so its workers are watched
    (["--help"], False),
])
def test_precheck_says_whether_the_command_line_runs_a_sweep_as_hydra_reads_it(argv, sweep, capsys):
    assert precheck(argv) is sweep
