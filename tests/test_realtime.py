"""Real-time pacing (sim.realtime): each step held to wall-clock Δ, its lateness and misses recorded and logged.

The pacer's arithmetic is checked exactly on a fake clock; the loop's on the real clock with lower bounds only
(time.sleep sleeps at least what it is asked, so a plant that sleeps 3Δ makes its step at least 2Δ late on any
machine; nothing here assumes a machine fast enough to keep Δ)."""
import time

import numpy as np
import pytest

from kexp.errors import ConfigError, PlantError
from kexp.plants.base import CheckedPlant
from kexp.plants.user import make_user_plant
from kexp.recording.reader import read_log
from kexp.recording.step_frames import pack_steps, unpack_steps
from kexp.recording.steps import timing_messages, timing_payload
from kexp.recording.writer import RunLogger
from kexp.simulate import Pacer, SimConfig, closed_loop
from kexp.systems import VanDerPol

from test_closed_loop import Constant

X0 = np.array([0.5, -0.2])


def rig(target="SleepyRig", dt=0.02, **params):
    system = VanDerPol()
    return system, CheckedPlant(make_user_plant(f"plant_rigs:{target}", {"dt": dt, **params}, system))


class FakeClock:
    """A clock that moves only when slept on or told to (dyadic times: the sums are exact)."""

    def __init__(self):
        self.now = 8.0

    def __call__(self):
        return self.now

    def sleep(self, s):
        assert s > 0
        self.now += s


def test_pacer_rebases_after_a_miss_and_never_catches_up():
    clock = FakeClock()
    p = Pacer(0.25, spin=0.0, clock=clock, sleep=clock.sleep)
    p.start()                                   # step 0 from 8.0, deadline 8.25
    clock.now += 0.125
    assert p.stamp() == (-0.125, False)         # 0.125 s to spare
    p.wait()
    assert clock.now == 8.25                    # step 1 starts Δ after step 0
    clock.now += 0.75                           # step 1 overruns: ends at 9.0, deadline 8.5
    assert p.stamp() == (0.5, True)
    p.wait()
    assert clock.now == 9.0                     # no wait after a miss
    clock.now += 0.125                          # step 2: its deadline is 9.0 + Δ (re-based), not 8.75
    assert p.stamp() == (-0.125, False)
    p.wait()
    assert clock.now == 9.25
    s = p.summary()
    assert (s.steps, s.misses, s.late_max, s.late_max_k, s.late_median, s.wall_s) == (3, 1, 0.5, 1, -0.125, 1.25)


def test_pacer_logging_overrun_counts_against_the_next_step():
    """Time spent after a step's end (the logging callback) is not lost: the next step starts late by it."""
    clock = FakeClock()
    p = Pacer(0.25, spin=0.0, clock=clock, sleep=clock.sleep)
    p.start()
    clock.now += 0.125
    assert p.stamp() == (-0.125, False)
    clock.now += 0.25                           # the callback runs past the deadline (8.25) to 8.375
    p.wait()
    assert clock.now == 8.375
    clock.now += 0.125                          # step 1 ends at 8.5 = its deadline: not a miss
    assert p.stamp() == (0.0, False)
    clock.now += 0.0625                         # its callback: past 8.5 again; step 2 ends at 8.8125 > 8.75
    p.wait()
    clock.now += 0.25
    assert p.stamp() == (0.0625, True)


def test_pacer_refuses_a_bad_dt_and_stamps_only_after_start():
    for dt in (0, -0.01, float("nan"), float("inf"), "0.01"):
        with pytest.raises(ValueError, match="dt="):
            Pacer(dt)
    with pytest.raises(RuntimeError, match="before start"):
        Pacer(0.01).stamp()
    assert Pacer(0.01).summary().steps == 0


def test_off_by_default_no_timing_fields():
    assert SimConfig().realtime is False
    run = closed_loop(VanDerPol(), Constant([0.0]), X0, SimConfig(T=0.05, dt=0.01))
    assert run.realtime is None
    assert all(r.late is None and r.miss is None for r in run.records)
    assert [sorted(timing_payload(r)) for r in run.records] == [["k", "solve_time", "t"]] * 5
    # the /timing bytes as before sim.realtime existed
    assert timing_messages(run.records[:1]) == [b'{"k":0,"solve_time":0.0,"t":0.0}']


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_realtime_must_be_a_bool(value):
    with pytest.raises(ConfigError, match=r"sim.realtime=.*use true or false"):
        SimConfig(realtime=value)


def test_paced_run_holds_every_step_to_dt_and_changes_no_number():
    dt, n = 0.02, 50
    seen = []
    start = time.perf_counter()
    run = closed_loop(VanDerPol(), Constant([0.3]), X0, SimConfig(T=n * dt, dt=dt, realtime=True),
                      on_step=lambda rec, step: seen.append(rec))
    wall = time.perf_counter() - start
    assert wall >= n * dt                                   # the last step, too, held to its deadline
    assert run.realtime.steps == n and run.realtime.wall_s >= n * dt and run.realtime.dt == dt
    assert len(run.records) == n and [r.k for r in run.records] == list(range(n))
    assert all(isinstance(r.late, float) and r.miss is (r.late > 0) for r in run.records)
    assert seen == list(run.records) and all(a is b for a, b in zip(seen, run.records))  # the logged records
    assert run.realtime.misses == sum(r.miss for r in run.records)
    assert run.realtime.late_max == max(r.late for r in run.records)
    assert run.records[run.realtime.late_max_k].late == run.realtime.late_max
    plain = closed_loop(VanDerPol(), Constant([0.3]), X0, SimConfig(T=n * dt, dt=dt))
    assert np.array_equal(plain.x, run.x) and np.array_equal(plain.u, run.u)


def test_overrunning_steps_are_misses_and_nothing_is_lost():
    dt, n = 0.02, 30
    system, plant = rig(dt=dt, overrun=3 * dt, at=(10, 20))
    start = time.perf_counter()
    run = closed_loop(system, Constant([0.3]), X0, SimConfig(T=n * dt, dt=dt, realtime=True), plant=plant)
    wall = time.perf_counter() - start
    assert run.status == "completed" and len(run.records) == n and run.x.shape == (n + 1, 2)
    for k in (10, 20):
        assert run.records[k].miss is True and run.records[k].late >= 2 * dt
    assert run.realtime.misses >= 2 and run.realtime.late_max >= 2 * dt
    # re-based, not caught up: each miss adds its lateness to the run's wall-clock time
    assert wall >= (n + 2 * 2) * dt and run.realtime.wall_s >= (n + 2 * 2) * dt
    _, fast = rig(target="VdpRig", dt=dt)
    plain = closed_loop(system, Constant([0.3]), X0, SimConfig(T=n * dt, dt=dt), plant=fast)
    assert np.array_equal(plain.x, run.x)


def test_a_plant_error_on_a_paced_step_still_hands_its_record_over():
    dt = 0.01
    logged = {}
    for realtime in (False, True):
        system, plant = rig(target="FailingRig", dt=dt, after=5)
        seen = logged[realtime] = []
        with pytest.raises(PlantError, match="amplifier tripped"):
            closed_loop(system, Constant([0.3]), X0, SimConfig(T=0.2, dt=dt, realtime=realtime), plant=plant,
                        on_step=lambda rec, step: seen.append(rec))
    assert [r.k for r in logged[True]] == [r.k for r in logged[False]] == list(range(6))
    assert all(isinstance(r.late, float) for r in logged[True])
    assert all(np.array_equal(a.x, b.x) for a, b in zip(logged[True], logged[False]))


def test_paced_log_has_late_and_miss_per_step_and_the_same_steps(tmp_path):
    dt, n = 0.02, 8
    logs = {rt: read_log(_paced_log(tmp_path / f"rt{rt}.mcap", dt, n, realtime=rt)) for rt in (False, True)}
    timing = [m for _, m in logs[True].channels["/timing"]]
    assert [m["k"] for m in timing] == list(range(n))
    assert all(set(m) == {"k", "t", "solve_time", "late", "miss"} for m in timing)
    assert timing[3]["miss"] is True and timing[3]["late"] >= 2 * dt
    assert all(m["miss"] is (m["late"] > 0) for m in timing)
    assert all(set(m) == {"k", "t", "solve_time"} for _, m in logs[False].channels["/timing"])
    assert logs[True].channels["/step"] == logs[False].channels["/step"]      # pacing changes no logged number


def test_the_log_writer_process_hands_late_and_miss_over(tmp_path):
    from kexp.recording.process_log import ProcessRunLogger
    system, plant = rig(dt=0.01, overrun=0.03, at=(2,))
    run = closed_loop(system, Constant([0.3]), X0, SimConfig(T=0.3, dt=0.01, realtime=True), plant=plant)
    back = [r for r, _ in unpack_steps(*pack_steps(list(run.records)))]
    assert timing_messages(back) == timing_messages(run.records)
    assert [r.late for r in back] == [r.late for r in run.records] and back[2].miss is True
    files = []
    for kind in (RunLogger, ProcessRunLogger):
        with kind(tmp_path / f"{kind.__name__}.mcap", flush_every=0.1) as logger:
            for rec in run.records:
                logger.log_step(rec)
        files.append((tmp_path / f"{kind.__name__}.mcap").read_bytes())
    assert files[0] == files[1]
    assert [m["late"] for m in read_log(tmp_path / "ProcessRunLogger.mcap").messages("/timing")] == \
        [r.late for r in run.records]


def _paced_log(path, dt=0.02, n=8, at=(3,), realtime=True):
    system, plant = rig(dt=dt, overrun=3 * dt, at=at)
    with RunLogger(path) as logger:
        run = closed_loop(system, Constant([0.3]), X0, SimConfig(T=n * dt, dt=dt, realtime=realtime), plant=plant,
                          on_step=lambda rec, step: logger.log_step(rec, step))
        logger.log_summary(float(run.t[-1]), run.status, run.message, run.metrics.to_dict(), completed=True)
    return path


def _views(data):
    views = {}
    for chunk in data["reader"].stream(store=data["blueprints"][0]).to_chunks():
        rb = chunk.to_record_batch()
        cols = {n: rb.column(n).to_pylist()[-1] for n in rb.schema.names if "Blueprint:" in n}
        if "ViewBlueprint:display_name" in cols:
            views[cols["ViewBlueprint:display_name"][0]] = cols["ViewBlueprint:space_origin"][0]
    return views


def test_rerun_shows_lateness_and_misses_of_a_paced_run_only(tmp_path):
    from kexp.recording.render import render
    from test_render import load_rrd, scalars
    paced = read_log(_paced_log(tmp_path / "paced.mcap"))
    data = load_rrd(render(paced.path, tmp_path / "paced.rrd"))
    ents, timing = data["entities"], paced.messages("/timing")
    assert ents["/timing/late_ms"]["rows"] == ents["/timing/miss"]["rows"] == 8
    np.testing.assert_allclose(scalars(ents["/timing/late_ms"]), [1e3 * m["late"] for m in timing])
    np.testing.assert_array_equal(scalars(ents["/timing/miss"]), [float(m["miss"]) for m in timing])
    assert scalars(ents["/timing/miss"])[3] == 1.0
    misses = sum(m["miss"] for m in timing)
    text = ents["/summary"]["static"]["TextDocument:text"][0]
    assert (f"| real time (sim.realtime) | {misses} deadline miss(es) in 8 steps, largest lateness "
            f"{max(m['late'] for m in timing) * 1e3:.3g} ms |") in text
    assert _views(data)["lateness [ms] and misses (sim.realtime)"] == "/timing"
    plain = load_rrd(render(_paced_log(tmp_path / "plain.mcap", realtime=False), tmp_path / "plain.rrd"))
    assert "/timing/late_ms" not in plain["entities"] and "/timing/miss" not in plain["entities"]
    assert "real time" not in plain["entities"]["/summary"]["static"]["TextDocument:text"][0]
    assert _views(plain)["solve time [ms]"] == "/timing" and len(_views(plain)) == len(_views(data)) - 1


def test_the_app_paces_a_user_plant_and_logs_its_misses(tmp_path):
    """kexp sim.realtime=true plant=python plant.target=plant_rigs:SleepyRig: every step in /timing with its
    lateness, the overrunning step a miss, the run complete."""
    from hydra import compose, initialize_config_dir
    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    dt = 0.01
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            "data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
            "controller.lmpc.blocks=null", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
            "cache.enabled=false", "sim.T=0.5", "sim.realtime=true", "sim.open_loop=false", "plant=python",
            "plant.target=plant_rigs:SleepyRig", f"+plant.params.overrun={3 * dt}", "+plant.params.at=[5]"])
    metrics = run(cfg, tmp_path, echo=lambda *_: None)
    assert metrics["status"] == "completed"
    log = read_log(tmp_path / "run.mcap")
    assert log.one("/config")["config"]["sim"]["realtime"] is True
    timing = log.messages("/timing")
    assert [m["k"] for m in timing] == [m["k"] for m in log.messages("/step")] == list(range(50))
    assert all(isinstance(m["late"], float) and m["miss"] is (m["late"] > 0) for m in timing)
    assert timing[5]["miss"] is True and timing[5]["late"] >= 2 * dt


def test_cli_refuses_a_realtime_that_is_not_a_bool_in_one_line(tmp_path):
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-m", "kexp.app.main", "sim.realtime=maybe", f"hydra.run.dir={tmp_path}"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("kexp: error: sim.realtime: Value 'maybe' is not a valid bool")


def test_the_app_summarises_a_paced_run(tmp_path):
    """(with the experiment.py change) summary.json and /run_info's timing have the run's realtime block; an
    unpaced config keeps its hash (no sim.realtime in the logged config)."""
    from hydra import compose, initialize_config_dir
    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import config_dict, config_hash, run
    dt = 0.01
    small = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
             "controller.lmpc.blocks=null", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
             "cache.enabled=false", "sim.T=0.3", "sim.open_loop=false"]
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        plain = compose(config_name="config", overrides=small)
        off = compose(config_name="config", overrides=small + ["sim.realtime=false"])
        cfg = compose(config_name="config", overrides=small + [
            "sim.realtime=true", "plant=python", "plant.target=plant_rigs:SleepyRig",
            f"+plant.params.overrun={3 * dt}", "+plant.params.at=[4]"])
    assert "realtime" not in config_dict(plain)["sim"] and config_hash(config_dict(off)) == config_hash(
        config_dict(plain))
    lines = []
    metrics = run(cfg, tmp_path, echo=lines.append)
    rt = metrics["realtime"]
    assert rt["steps"] == 30 and rt["misses"] >= 1 and rt["late_max"] >= 2 * dt and rt["wall_s"] >= 32 * dt
    assert read_log(tmp_path / "run.mcap").one("/run_info")["timing"]["realtime"] == rt
    (line,) = [s for s in lines if s.startswith("real time: ")]
    assert f"deadline miss(es) in 30 steps of Δ = 10 ms" in line
