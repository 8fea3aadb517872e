"""ProcessRunLogger: the log written by a child process is byte-identical to RunLogger's; errors reach the caller
(at once where RunLogger raises at once, at close for the child's own); an abandoned or orphaned log keeps every
step handed over."""
import pickle
import struct
import warnings
from dataclasses import replace

import numpy as np
import pytest

from kexp.errors import ConfigError
from kexp.recording import read_log
from kexp.recording.process_log import ProcessRunLogger
from kexp.recording.step_frames import pack_steps, unpack_steps
from kexp.recording.steps import step_messages
from kexp.recording.writer import RunLogger


@pytest.fixture(scope="module")
def run(short_lmpc_run):
    """A short LMPC closed loop on Van der Pol (conftest), for logging twice."""
    return short_lmpc_run


def _write(logger, run, steps=None):
    model, clf, result, all_steps = run
    with logger as lg:
        lg.log_config({"a": 1, "nested": {"x": [1.0, 2.5]}}, "h")
        lg.log_model(model)
        lg.log_clf(clf)
        for i, (rec, st) in enumerate(all_steps if steps is None else steps):
            lg.log_step(rec, st, model)
            if i == 37:     # a message among the steps
                lg.write("/timing", rec.t, {"k": -1, "t": rec.t, "solve_time": np.float32(0.5)})
        lg.log_open_loop(np.arange(3) * 0.01, np.ones((3, 2)))
        lg.log_summary(float(result.t[-1]), result.status, "", {"cost": result.metrics.cost}, True)
    return lg.path.read_bytes()


def test_process_log_is_byte_identical(tmp_path, run):
    kw = dict(prediction_every=10, flush_every=0.5)
    sync = _write(RunLogger(tmp_path / "sync.mcap", **kw), run)
    child = _write(ProcessRunLogger(tmp_path / "proc.mcap", **kw), run)
    assert len(sync) > 10_000 and child == sync
    log = read_log(tmp_path / "proc.mcap")
    assert len(log.channels["/step"]) == len(run[3]) and len(log.channels["/prediction"]) > 0


@pytest.mark.parametrize("last,every,between", [(1.99, None, 1), (0.43, None, 157 - 3), (1.99, 7, 27), (None, 1, 197)])
def test_steps_handed_over_between_flushes_are_framed_at_once_to_the_same_bytes(tmp_path, run, last, every, between):
    """Steps handed over between flushes — with the run's last step (``last_step``; 1.99 s is this run's, 0.43 s
    one before its end, after which every step goes over at once) or every ``hand_over_every`` steps — are framed
    by the child into the open chunk at once: the file is RunLogger's, byte for byte, a message among the steps
    included (at step 37).  A synchronous log framing its pending messages at arbitrary steps
    (RunLogger.frame_pending) is unchanged too."""
    kw = dict(prediction_every=10, flush_every=0.5)
    sync = _write(RunLogger(tmp_path / "sync.mcap", **kw), run)
    lg = ProcessRunLogger(tmp_path / "tail.mcap", last_step=last, hand_over_every=every, **kw)
    kinds = []
    real = lg._frame

    def frame(kind, data):
        kinds.append(kind)
        real(kind, data)

    lg._frame = frame
    assert _write(lg, run) == sync
    # hand-overs between flushes (the steps at 0.5, 1 and 1.5 s are the flushes'): the last step's alone; each
    # of the 157 steps from 0.43 s on but those three; every 7 steps since the last hand-over or message (6 before
    # the first flush, the message at step 37 taking 35–37 along, then 7 per half-second, the last one at the last
    # step); every step but the flushes'
    assert len(run[3]) == 200 and kinds.count(b"F") == between

    class Framing(RunLogger):
        def log_step(self, rec, *a):
            super().log_step(rec, *a)
            if rec.k % 3 == 1:
                self.frame_pending()

    assert _write(Framing(tmp_path / "framing.mcap", **kw), run) == sync


def test_odd_values_keep_their_bytes(tmp_path, run):
    """numpy scalars that are not Python numbers, float32 vectors and a list z: sent as they are (the float32
    vectors stacked, the list z as a list), the same bytes."""
    model, clf, result, steps = run
    odd = [(replace(rec, V=np.float32(rec.V), binds=np.bool_(rec.binds), u=rec.u.astype(np.float32),
                    z=list(rec.z)), st)
           for rec, st in steps[:120]]
    kind, data = pack_steps([rec for rec, _ in odd])
    back = [rec for rec, _ in unpack_steps(kind, data)]
    assert step_messages(back) == step_messages([rec for rec, _ in odd])
    assert type(back[0].V) is np.float32 and type(back[0].binds) is np.bool_ and back[0].u.dtype == np.float32
    # u, x stacked; z a list; x_meas, w, late, miss all None: ()
    assert [type(c) for c in pickle.loads(data)[1]] == [tuple, tuple, list, tuple, tuple, tuple, tuple]
    kw = dict(prediction_every=10, flush_every=0.5)
    sync = _write(RunLogger(tmp_path / "sync.mcap", **kw), run, odd)
    child = _write(ProcessRunLogger(tmp_path / "proc.mcap", **kw), run, odd)
    assert child == sync


@pytest.mark.parametrize("field,change", [("z", lambda z: np.append(z, 0.5)),        # another length
                                          ("x", lambda x: x.reshape(-1, 1)),          # same length, 2-D
                                          ("x", lambda x: np.stack([x, x])),          # 2-D, another shape
                                          ("u", lambda u: u.astype(np.float32))])     # another dtype
def test_a_column_of_mixed_shapes_or_dtypes_takes_pickle(run, field, change):
    """One record's array of another shape (the 1-D fast path's length and ndim tests included) or dtype among
    the batch's: not stacked, the values as they are, the same messages back."""
    recs = [rec for rec, _ in run[3][:6]]
    odd = recs[:3] + [replace(recs[3], **{field: change(getattr(recs[3], field))})] + recs[4:]
    kind, data = pack_steps(odd)
    columns = pickle.loads(data)[1]
    assert [type(c) is list for c in columns] == [f == field for f in ("u", "x", "z", "x_meas", "w", "late", "miss")]
    back = [rec for rec, _ in unpack_steps(kind, data)]
    assert getattr(back[3], field).shape == getattr(odd[3], field).shape
    assert step_messages(back) == step_messages(odd)


def test_errors_reach_the_caller(tmp_path, run):
    (tmp_path / "a_file").write_text("")
    with pytest.raises(OSError):                        # the file is created at once, in the caller
        ProcessRunLogger(tmp_path / "a_file" / "x.mcap")
    lg = ProcessRunLogger(tmp_path / "ok.mcap")
    with pytest.raises(KeyError):                       # an unknown topic: at once
        lg.write("/nope", 0.0, {})
    payload = {"config": {"a": [1]}, "config_hash": "h"}
    lg.write("/config", 0.0, payload)
    payload["config"]["a"].append(2)                    # encoded at the call: a later change is not logged
    lg.close()
    assert [p["config"] for _, p in read_log(tmp_path / "ok.mcap").channels["/config"]] == [{"a": [1]}]
    neg = ProcessRunLogger(tmp_path / "neg.mcap")
    with pytest.raises(ConfigError, match=r"log time t=-1.0: use a finite number of seconds >= 0"):
        neg.write("/timing", -1.0, {"k": 0, "t": -1.0, "solve_time": 0.0})   # refused in the caller, at once
    neg.close()
    # an error in the child (a step's negative time stamp, which MCAP cannot store) is raised by close(), unchanged
    model, _, _, steps = run
    rec, st = steps[0]
    bad = ProcessRunLogger(tmp_path / "bad.mcap")
    bad.log_step(replace(rec, t=-1.0), st, model)
    with pytest.raises(struct.error):
        bad.close()
    bad.close()                                          # closing again is a no-op


def test_abandoned_and_orphaned_logs_keep_their_steps(tmp_path, run):
    """abandon(): every step handed over is in the file (no summary section); the same when the caller's end of
    the pipe closes without a last word (the caller died)."""
    model, clf, result, steps = run
    lg = ProcessRunLogger(tmp_path / "cut.mcap", flush_every=100.0)
    for rec, st in steps[:150]:
        lg.log_step(rec, st, model)
    lg.abandon()
    lg.abandon()
    orphan = ProcessRunLogger(tmp_path / "orphan.mcap", flush_every=0.5)
    for rec, st in steps[:150]:
        orphan.log_step(rec, st, model)
    orphan._hand_over()
    orphan._proc.stdin.close()                           # as when the caller's process is killed
    assert pickle.loads(orphan._proc.stdout.read()[4:]) is None and orphan._proc.wait() == 0
    for name in ("cut.mcap", "orphan.mcap"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            log = read_log(tmp_path / name)
        assert [p["k"] for _, p in log.channels["/step"]] == list(range(150))


def test_steps_are_handed_over_when_a_synchronous_log_flushes(tmp_path, run):
    """A run killed mid-second leaves the child the steps a synchronous log had flushed by then (those up to the
    last flush time, t = 1.0 s here: 101 steps), and the messages written before them; the child, once it has
    answered, is reaped."""
    from kexp.recording import process_log
    model, clf, result, steps = run
    ks = []
    for name, cls in (("sync.mcap", RunLogger), ("orphan.mcap", ProcessRunLogger)):
        kw = {"compress_thread": False} if cls is RunLogger else {}
        lg = cls(tmp_path / name, flush_every=0.5, **kw)
        lg.log_config({"a": 1}, "h")
        for rec, st in steps[:150]:
            lg.log_step(rec, st, model)
        if cls is ProcessRunLogger:
            lg._proc.stdin.close()                       # the caller's process is killed here
            assert pickle.loads(lg._proc.stdout.read()[4:]) is None and lg._proc.wait() == 0
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            log = read_log(tmp_path / name)
        ks.append([p["k"] for _, p in log.channels["/step"]])
        assert len(log.channels["/config"]) == 1
        if cls is RunLogger:
            lg.abandon()
    assert ks[0] == ks[1] == list(range(101))
    lg = ProcessRunLogger(tmp_path / "reaped.mcap")
    lg.close()
    assert lg._proc in process_log._ENDED
    process_log._reap(block=True)
    assert lg._proc not in process_log._ENDED and lg._proc.returncode == 0


def test_a_run_with_the_writer_process_logs_what_a_synchronous_run_does(tmp_path):
    """``logging.writer=process`` end to end: the same log as ``sync`` up to the wall clock (kexp-diff's default
    policy), the same config hash (the writer is not part of the logged config)."""
    from hydra import compose, initialize_config_dir

    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    from kexp.recording import diff_logs
    small = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
             "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.rrd=false",
             "logging.progress=false", f"cache.dir={tmp_path / 'cache'}"]
    from kexp.recording import process_log
    hashes, taken = [], []
    real = ProcessRunLogger.__init__

    def init(self, *a, **kw):         # the run's logger takes the process the run started ahead
        taken.append(process_log._SPARE[0][1] if process_log._SPARE else None)
        real(self, *a, **kw)
        taken.append(self._proc)

    for writer in ("sync", "process"):
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = compose(config_name="config", overrides=small + [f"logging.writer={writer}"])
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(ProcessRunLogger, "__init__", init)
            hashes.append(run(cfg, tmp_path / writer, echo=lambda *_: None)["config_hash"])
    assert hashes[0] == hashes[1]
    assert len(taken) == 2 and taken[0] is not None and taken[0] is taken[1]
    res = diff_logs(tmp_path / "sync" / "run.mcap", tmp_path / "process" / "run.mcap")
    assert res.equal, res.report()
    assert len(read_log(tmp_path / "process" / "run.mcap").channels["/step"]) == 200


def test_ctrl_c_is_the_runs_and_a_dead_child_is_reported(tmp_path, run):
    """The child runs in its own session, so a Ctrl-C at the terminal (SIGINT to the foreground process group)
    reaches only the run, whose handler ends the log.  A child that died is reported by the next hand-over or by
    close(), as a RuntimeError naming the file, not as a hang."""
    import os
    model, clf, result, steps = run
    lg = ProcessRunLogger(tmp_path / "int.mcap")
    assert os.getsid(lg._proc.pid) == lg._proc.pid != os.getsid(0)
    lg.close()
    dead = ProcessRunLogger(tmp_path / "dead.mcap", hand_over_every=20)
    dead._proc.kill()
    dead._proc.wait()
    with pytest.raises(RuntimeError, match="dead.mcap"):
        for rec, st in steps:
            dead.log_step(rec, st, model)
        dead.close()
    dead.abandon()                                       # after the error: a no-op, never raises


def test_the_child_runs_the_callers_kexp_found_through_sys_path(tmp_path):
    """A caller that found kexp by changing ``sys.path`` (a copy here, first on its path; the installed kexp is
    also importable): the writer process is started on the caller's ``sys.path``, so it runs the same copy — and
    checks that it does, so that two versions never write one log."""
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    import kexp
    copy = tmp_path / "elsewhere"
    shutil.copytree(Path(kexp.__file__).parent, copy / "kexp", ignore=shutil.ignore_patterns("__pycache__"))
    script = (f"import sys; sys.path.insert(0, {str(copy)!r})\n"
              "import kexp\n"
              f"assert kexp.__file__.startswith({str(copy)!r}), kexp.__file__\n"
              "from kexp.recording.process_log import ProcessRunLogger\n"
              f"with ProcessRunLogger({str(tmp_path / 'run.mcap')!r}) as lg:\n"
              "    lg.write('/config', 0.0, {'config': {'a': 1}, 'config_hash': 'h'})\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert read_log(tmp_path / "run.mcap").one("/config") == {"config": {"a": 1}, "config_hash": "h"}

    # the check itself: a child that imported kexp from elsewhere says so, and the log is not written by it
    lg = ProcessRunLogger(tmp_path / "other.mcap")
    lg._frames.clear()
    lg._frame(b"O", pickle.dumps((str(lg.path), 1.0, 0, str(copy / "kexp" / "recording" / "process_log.py"))))
    lg._push()
    with pytest.raises(RuntimeError, match="two copies of kexp"):
        lg.close()


def test_a_prestarted_writer_process_takes_the_next_log(tmp_path, run):
    """prestart() starts the writer process ahead (the app does, before identification): the next logger takes it
    and writes the same bytes as RunLogger; an unused one ends at the next prestart or at exit; a dead one is
    replaced, not used."""
    import subprocess
    import sys

    from kexp.recording import process_log

    process_log.prestart()
    spare = process_log._SPARE[0][1]
    process_log.prestart()                               # one waits at most
    assert len(process_log._SPARE) == 1 and process_log._SPARE[0][1] is spare
    lg = ProcessRunLogger(tmp_path / "p.mcap", prediction_every=3)
    assert lg._proc is spare and not process_log._SPARE
    assert _write(lg, run) == _write(RunLogger(tmp_path / "s.mcap", prediction_every=3), run)

    process_log.prestart()
    dead = process_log._SPARE[0][1]
    dead.kill()
    dead.wait()
    lg = ProcessRunLogger(tmp_path / "d.mcap")           # the dead one is not used: a new process writes the log
    assert lg._proc is not dead
    lg.write("/config", 0.0, {"config": {}, "config_hash": "h"})
    lg.close()
    assert read_log(tmp_path / "d.mcap").one("/config") == {"config": {}, "config_hash": "h"}

    process_log.prestart()
    unused = process_log._SPARE[0][1]
    process_log._drop_spare()                            # it ends without writing, and is reaped
    assert unused.returncode == 0 and not process_log._SPARE and unused not in process_log._ENDED
    import os
    import signal
    import time
    process_log.prestart()                               # a forked copy of the caller holds the pipe too:
    held = process_log._SPARE[0][1]
    pid = os.fork()
    if pid == 0:
        time.sleep(30)
        os._exit(0)
    try:
        t0 = time.perf_counter()
        process_log._drop_spare()                        # the last word ends it, not end-of-file
        assert held.returncode == 0 and time.perf_counter() - t0 < 10
    finally:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
    script = ("from kexp.recording.process_log import prestart, _SPARE\nprestart()\n"
              "print(_SPARE[0][1].pid, flush=True)\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    pid = int(proc.stdout)
    with pytest.raises(ProcessLookupError):              # ended and reaped at the caller's exit
        os.kill(pid, 0)
