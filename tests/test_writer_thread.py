"""RunLogger's writer thread (background=True): the same bytes as a synchronous log, errors raised in the
caller's thread, and a run that stops with an exception keeps its steps."""
import warnings

import pytest

from kexp.recording import read_log
from kexp.recording.writer import RunLogger


@pytest.fixture(scope="module")
def run(short_lmpc_run):
    """A short LMPC closed loop on Van der Pol (conftest), for logging twice."""
    return short_lmpc_run


def _write(path, run, background):
    model, clf, result, steps = run
    with RunLogger(path, prediction_every=10, flush_every=0.5, background=background) as lg:
        lg.log_config({"a": 1}, "h")
        lg.log_model(model)
        lg.log_clf(clf)
        for rec, st in steps:
            lg.log_step(rec, st, model)
        lg.log_summary(float(result.t[-1]), result.status, "", {"cost": result.metrics.cost}, True)
    return path.read_bytes()


def test_background_log_is_byte_identical(tmp_path, run):
    sync = _write(tmp_path / "sync.mcap", run, False)
    threaded = _write(tmp_path / "thread.mcap", run, True)
    assert len(sync) > 10_000 and threaded == sync


def test_an_error_on_the_writer_thread_is_raised_in_the_callers_thread(tmp_path, run):
    """A step MCAP cannot store (a negative time stamp; write() refuses one at once) fails on the writer thread;
    the next write or close raises that error, unchanged, and the file is closed."""
    import struct
    from dataclasses import replace
    model, _, _, steps = run
    lg = RunLogger(tmp_path / "bad.mcap", background=True)
    lg.log_step(replace(steps[0][0], t=-1.0), steps[0][1], model)
    with pytest.raises(struct.error):
        for k in range(1, 1000):   # the thread reports it at the latest on close
            lg.write("/timing", 0.01 * k, {"k": k, "t": 0.01 * k, "solve_time": 0.0})
        lg.close()
    lg.close()                      # closing again is a no-op
    assert lg._f.closed
    with pytest.raises(KeyError):   # an unknown topic fails at once, in the caller's thread
        RunLogger(tmp_path / "b.mcap", background=True).write("/nope", 0.0, {})


def test_abandon_keeps_every_queued_step(tmp_path, run):
    """A run that raised: abandon() writes what was queued and the open chunk; the log reads back (truncated, no
    summary section) with every step given before."""
    model, clf, result, steps = run
    lg = RunLogger(tmp_path / "cut.mcap", flush_every=100.0, background=True)
    for rec, st in steps[:150]:
        lg.log_step(rec, st, model)
    lg.abandon()
    lg.abandon()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log = read_log(tmp_path / "cut.mcap")
    assert [p["k"] for _, p in log.channels["/step"]] == list(range(150))
