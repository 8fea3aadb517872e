"""Bad input, faults, kills and determinism (issue: reliability)."""
import json
import os
import signal
import sys
import subprocess
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.app.precheck import precheck
from kexp.errors import KexpError
from kexp.recording import diff_logs, read_log

from cli import console_script

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=1.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]

# (override, fragment of the one-line message) — each names the key, the value and what is valid
BAD = [
    ("system.name=nope", "unknown system 'nope'; valid:"),
    ("system.name=no_such_module:Cls", "cannot import module 'no_such_module'"),
    ("controller.kind=mpc", "controller.kind='mpc'; valid:"),
    ("controller.law=foo", "controller.law='foo'; valid:"),
    ("data.dt=0", "data.dt=0.0: the sampling time must be > 0"),
    ("data.dt=20", "data.T=3.0: the duration must be >= dt=20"),
    ("data.pairs=forward", "data.pairs='forward'; valid:"),
    ("data.sampler.kind=disc", "unknown sampler 'disc'; valid:"),
    ("data.sampler.radius=-1", "data.sampler.radius=-1"),
    ("data.filter.mode=cut", "data.filter.mode='cut'; valid:"),
    ("dictionary.degree=0", "dictionary.degree=0: use an int >= 1"),
    ("dictionary.degree=100", "lower the degree"),
    ("identification.method=svd", "identification.method='svd'; valid:"),
    ("controller.lmpc.horizon=0", "lmpc.horizon=0: use an int >= 1"),
    ("controller.lmpc.w=-1", "lmpc weights w=-1"),
    ("controller.lmpc.r=0", "lmpc weights w=1.0, r=0"),
    ("controller.lmpc.state_cost=y", "lmpc.state_cost='y'; valid:"),
    ("controller.u_min=5.0", "controller.u_min=5.0, controller.u_max=5.0: need finite u_min < u_max"),
    ("clf.c_lower=2.0", "clf.c_lower=2.0, clf.c_upper=1.0: need 0 < c_lower < c_upper"),
    ("clf.c_lower=-1.0", "need 0 < c_lower < c_upper"),
    ("clf.gamma=-1", "clf.gamma=-1.0: use a finite number >= 0"),
    ("clf.solver=MOSEK", "clf.solver='MOSEK'; valid:"),
    ("clf.method=magic", "clf.method='magic'; valid:"),
    ("sim.x0=[nan,0.0]", "sim.x0=[nan, 0.0]: give 2 finite numbers"),
    ("sim.x0=[3.0,3.0]", "lies outside the data region"),
    ("sim.x0=[0.1]", "sim.x0=[0.1]: give 2 finite numbers"),
    ("data.T=0.01", "16 training pairs"),
    ("logging.flush_every=0", "logging.flush_every=0.0: use seconds > 0"),
    ("+identification.methd=qr", "identification.methd: unknown key; valid keys:"),  # `+` bypasses the schema
    ("+sim.dt=0", "sim.dt=0: the closed loop steps at the model's sampling time; set data.dt"),
    ("sim.T=inf", "sim: need 0 < dt <= T < inf, got dt=0.01, T=inf"),
    ("sim.T=1e9", "sim.T=1e+09 s at Δ = 0.01 s is 1e+11 control steps, about"),   # not 745 GiB allocated
    ("data.T=1e7", "data: 20 trajectories of data.T=1e+07 s at Δ = 0.01 s are 2e+10 samples"),
    ("sim.diverge_bound=0", "sim.diverge_bound=0.0: use a distance > 0"),
    ("sim.r=-1", "sim.r=-1.0: use a finite number >= 0"),
    ("data.seed=-1", "data.seed=-1: use an int >= 0"),
    ("sim.noise.seed=-1", "noise.seed=-1: use an int >= 0"),
    ("sim.disturbance.seed=-2", "sim.disturbance.seed=-2: use an int >= 0"),
    ("identification.holdout_seed=-1", "identification.holdout_seed=-1: use an int >= 0"),
    ("logging.flush_every=inf", "logging.flush_every=inf: use seconds > 0 (finite)"),
    ("cache.dir=/proc/kexp-no-such", "cache.dir='/proc/kexp-no-such': cannot create it"),
]


@pytest.mark.parametrize("override,fragment", BAD, ids=[b[0] for b in BAD])
def test_bad_input_is_refused_early_with_one_line(override, fragment, tmp_path):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL + [override])
    with pytest.raises(KexpError) as err:
        run(cfg, tmp_path, echo=lambda *_: None)
    msg = str(err.value)
    assert fragment in msg and "\n" not in msg
    assert not (tmp_path / "model.npz").exists() and not (tmp_path / "run.mcap").exists()  # nothing long started


@pytest.mark.parametrize("argv,fragment", [
    (["system=nope"], "Could not find 'system/nope' Available options in 'system': cart_pendulum data duffing linear"),
    (["+experiment=nope"], "Could not find 'experiment/nope'"),
    (["data.dtt=1"], "data.dtt: Key 'dtt' not in 'DataConfigSchema'; valid keys: ['T', 'dt', "),
    # wrong types fail at composition against the schema (kexp/app/schema.py), with the full key
    (["data.dt=abc"], "data.dt: Value 'abc' of type 'str' could not be converted to Float"),
    (["controller.lmpc.horizon=1.5"], "controller.lmpc.horizon: Value '1.5' of type 'float' could not be converted"),
    (["controller.lmpc.use_21e=maybe"], "controller.lmpc.use_21e: Value 'maybe' is not a valid bool"),
    (["clf.gamma=[1,2]"], "clf.gamma: Value '[1, 2]' of type 'list' could not be converted to Float"),
    (["controller.lmpc.horzion=10"], "controller.lmpc.horzion: Key 'horzion' not in 'LmpcConfigSchema'"),
    # in a sweep, each swept value is checked against the schema before Hydra composes any job
    (["--multirun", "clf.gamma=1,fast"], "clf.gamma: Value 'fast' of type 'str' could not be converted to Float"),
    (["-m", "sim.T=1,2", "data.dtt=1,2"], "data.dtt: Key 'dtt' not in 'DataConfigSchema'"),
    (["sim.x0=[1,"], "no viable alternative"),
    # a sweep's master config (its overrides that are not swept) composed as Hydra composes it, before any job
    (["-m", "system=nope"], "Could not find 'system/nope' Available options in 'system': cart_pendulum data duffing linear"),
    (["-m", "+experiment=nope", "sim.T=1,2"], "Could not find 'experiment/nope'"),
    # a key below a node that this choice leaves null (OmegaConf raised a bare AssertionError: a traceback)
    (["controller=lqr", "controller.lmpc.horizon=20"],
     "controller.lmpc.horizon=20: controller.lmpc is null in this config (this controller is kind 'lqr'), so it "
     "has no keys to set; drop the override, or choose a controller that has controller.lmpc"),
    (["controller=sontag", "sim.T=2", "controller.lmpc.blocks=null"],
     "controller.lmpc.blocks=null: controller.lmpc is null in this config (this controller is kind 'explicit')"),
])
def test_composition_errors_are_one_line_exit_2(argv, fragment, capsys):
    with pytest.raises(SystemExit) as ex:
        precheck(argv)
    assert ex.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("kexp: error: ") and fragment in err[0]


def test_cli_exit_code_and_no_traceback(tmp_path):
    proc = subprocess.run([console_script("kexp"), "controller.u_min=9.0", f"hydra.run.dir={tmp_path}"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("kexp: error: controller.u_min=9.0")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "error" and not summary["completed"]


def test_diverging_true_system_ends_with_status_diverged(tmp_path):
    """An unstable linear system with almost no input authority: the run stops when ‖x‖ > diverge_bound, logs up
    to there, and the summary says so."""
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        small = [o for o in SMALL if not o.startswith("controller.")]
        cfg = compose(config_name="config", overrides=small + [
            "system=linear", "system.params.A=[[1.0,0.0],[0.0,2.0]]", "dictionary.degree=1",
            "controller=sontag", "controller.u_min=-0.001", "controller.u_max=0.001", "sim.T=10.0",
            "sim.diverge_bound=50.0", "sim.x0=[0.5,0.5]", "data.sampler.radius=1.0"])
    metrics = run(cfg, tmp_path, echo=lambda *_: None)
    assert metrics["status"] == "diverged" and "left" in metrics["message"]
    assert not metrics["metrics"]["success"]
    log = read_log(tmp_path / "run.mcap")
    assert log.completed and log.one("/summary")["status"] == "diverged"
    steps = log.messages("/step")
    assert 150 < len(steps) < 300  # e^{2t}·0.5 reaches 50 at t ≈ 2.3 s


# the run kills itself (SIGKILL, no clean-up) right after logging this step: 0.99 s after its last flush at 8.00 s
_KILL_AT = 899
_KILLED_RUN = """
import os, signal, sys
from kexp.recording.writer import RunLogger
import kexp.app.main as m
log_step = RunLogger.log_step
def log_step_then_die(self, rec, *args, **kw):
    log_step(self, rec, *args, **kw)
    if rec.k == {k}:
        # the chunk of the last flush is compressed and written on a thread about a millisecond after the flush;
        # the kill must not race that write (the load-dependent part), only cut what is not flushed
        self._w.wait()
        os.kill(os.getpid(), signal.SIGKILL)
RunLogger.log_step = log_step_then_die
sys.argv = ["kexp", *sys.argv[1:]]
m.main()
"""


def test_sigkill_leaves_a_readable_log_up_to_its_last_second(tmp_path):
    """A real run killed with SIGKILL mid-way (it kills itself at a known step, so the progress it had made is
    known exactly, not read from its progress bar while it runs on): the log holds every step up to its last flush
    and nothing after it — at most 1 s of simulated time (logging.flush_every) lost; kexp-render and kexp-diff work
    on it with a warning, summary.json says not completed.  (Killed from outside at the bar's 807th step, a loaded
    machine once left 701 steps: the flush at 8.00 s was handed to the compression thread 7 steps before the
    kill and not yet written.)"""
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", _KILLED_RUN.format(k=_KILL_AT), "sim.T=10.0", "logging.rrd=false",
                           "logging.writer=sync", "logging.progress=false", f"hydra.run.dir={run_dir}"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    log = read_log(run_dir / "run.mcap")
    assert not log.completed and log.warning
    steps = log.messages("/step")
    dt = log.one("/config")["config"]["data"]["dt"]
    assert dt == 0.01 and log.one("/config")["config"]["logging"]["flush_every"] == 1.0
    # every step up to the last flush (t = 8.00 s, the step included) and nothing after
    assert [s["k"] for s in steps] == list(range(801))
    assert steps[-1]["t"] == pytest.approx(8.0, abs=1e-9)
    lost = (_KILL_AT - steps[-1]["k"]) * dt
    assert lost == pytest.approx(0.99) and lost < 1.0
    assert json.loads((run_dir / "summary.json").read_text())["completed"] is False
    r = subprocess.run([console_script("kexp-render"), str(run_dir / "run.mcap"), "-o", str(tmp_path / "cut.rrd")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and (tmp_path / "cut.rrd").exists() and "warning" in r.stderr
    d = subprocess.run([console_script("kexp-diff"), str(run_dir / "run.mcap"), str(run_dir / "run.mcap")],
                       capture_output=True, text=True, timeout=120)
    assert d.returncode == 0 and "warning" in d.stderr


def _run_with_threads(tmp_path: Path, threads: int) -> Path:
    env = dict(os.environ, OPENBLAS_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads),
               MKL_NUM_THREADS=str(threads))
    out = tmp_path / f"t{threads}"
    subprocess.run([console_script("kexp"), *SMALL, "cache.enabled=false", f"hydra.run.dir={out}"], env=env, check=True,
                   capture_output=True, timeout=300)
    return out / "run.mcap"


def test_deterministic_channels_do_not_depend_on_blas_threads(tmp_path):
    a, b = _run_with_threads(tmp_path, 1), _run_with_threads(tmp_path, 2)
    res = diff_logs(a, b)  # exact: every deterministic channel, every field
    assert res.equal, res.report()


@pytest.mark.parametrize("argv,fragment", [
    (["hydra.run.dir={file}"], "hydra.run.dir={file}: '{file}' is not a folder; give a folder you can write"),
    (["hydra.run.dir={file}/run"], "'{file}' is not a folder"),
    (["hydra.run.dir=/proc/kexp-no-such/run"], "cannot create a folder in '/proc'"),
    (["-m", "hydra.sweep.dir={file}", "sim.T=1,2"], "hydra.sweep.dir={file}: '{file}' is not a folder"),
])
def test_a_run_folder_that_cannot_be_made_is_one_line_exit_2(argv, fragment, tmp_path, capsys):
    """Hydra makes the run folder with a traceback (FileExistsError, FileNotFoundError); kexp checks it first,
    creating nothing (a folder made and removed at once: os.access says yes to root even in /proc)."""
    afile = tmp_path / "afile"
    afile.write_text("")
    with pytest.raises(SystemExit) as ex:
        precheck([a.format(file=afile) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert ex.value.code == 2 and len(err) == 1 and fragment.format(file=afile) in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_a_bug_leaves_an_error_summary_not_a_running_one(tmp_path):
    """An unexpected exception keeps its traceback (a bug to report) but summary.json says "error", so
    kexp-report does not count the run as killed."""
    script = ("import sys, kexp.app.main as m\n"
              "def boom(*a, **k): raise RuntimeError('boom')\n"
              f"m.run = boom; sys.argv = ['kexp', 'hydra.run.dir={tmp_path}']; m.main()\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "RuntimeError: boom" in proc.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary == {"status": "error", "completed": False, "message": "internal error: RuntimeError: boom",
                       "error_type": "RuntimeError"}


@pytest.mark.parametrize("module,argv,line", [
    ("kexp.recording.diff", [], "kexp-diff: error: the following arguments are required: a, b (see kexp-diff --help)"),
    ("kexp.recording.render", ["a.mcap", "--bogus"],
     "kexp-render: error: unrecognized arguments: --bogus (see kexp-render --help)"),
    ("kexp.results.report", [], "kexp-report: error: the following arguments are required: sweep_dir (see kexp-report "
                            "--help)"),
    ("kexp.results.cli", ["nope"], "kexp-results: error: argument cmd: invalid choice: 'nope' (choose from "
                                   "'collect', 'table', 'robustness', 'sample', 'compare', 'plants', 'x0') "
                                   "(see kexp-results --help)"),
    ("kexp.analysis.figures", ["paper"], "kexp-figures: error: the following arguments are required: source, "
                                         "-o/--out (see kexp-figures --help)"),
])
def test_a_bad_command_line_is_one_line_exit_2(module, argv, line, capsys):
    """argparse printed its usage line before the error (two lines); kexp's commands print one (kexp.cli.Parser)."""
    import importlib
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as ex:
        main(argv)
    assert ex.value.code == 2 and capsys.readouterr().err.strip().splitlines() == [line]


def test_kexp_diff_refuses_logs_without_a_message(tmp_path, capsys):
    """Two logs cut before their first chunk compared 'equal'; nothing to compare is an error, exit 2."""
    from kexp.recording.diff import main as diff_main
    from kexp.recording.writer import RunLogger
    with RunLogger(tmp_path / "full.mcap") as log:
        log.write("/summary", 0.0, {"status": "completed", "message": "", "metrics": {}, "completed": True})
    cut = tmp_path / "cut.mcap"
    cut.write_bytes((tmp_path / "full.mcap").read_bytes()[:200])
    assert diff_main([str(cut), str(cut)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"kexp-diff: error: {cut} holds no message (cut.mcap is truncated")
