import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from kexp.app import golden
from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.recording import copy_log, diff_logs, read_log
from kexp.recording.diff import main as diff_main
from kexp.recording.schema import _DUMPS, encode, plain
from kexp.recording.writer import RunLogger
from cli import console_script

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=1.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
         "logging.prediction_every=10", "logging.flush_every=0.25"]


def _run(tmp, overrides=()):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL + list(overrides))
    run(cfg, tmp, echo=lambda *_: None)
    return Path(tmp) / "run.mcap"


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    a = _run(tmp_path_factory.mktemp("a"))
    b = _run(tmp_path_factory.mktemp("b"))
    return a, b


def test_encoder_writes_the_values_the_standard_library_would():
    """encode() uses orjson (8x faster per step); every value it writes must read back exactly as the stdlib
    encoding of plain(payload) does: NaN/inf -> null, float32 as its float64 value, complex -> [re, im], int
    keys -> strings, non-contiguous arrays, unknown objects -> str, an int beyond 64 bits (stdlib fallback)."""
    rng = np.random.default_rng(0)
    wide = rng.normal(size=20000) * 10.0 ** rng.integers(-300, 300, 20000)
    payload = {"wide": wide, "nan": np.array([1.0, np.nan, -np.inf]), "complex": 1 + 2j, "tuple": (1, 2.5),
               "f32": np.float32(0.1), "f32s": np.array([0.1, 1e-8], dtype=np.float32), "f16": np.float16(0.1),
               "keys": {3: "x", "b": [np.float64(np.nan), np.int32(4), np.bool_(True)]},
               "strided": np.arange(6.0).reshape(2, 3)[:, ::2], "big": 2 ** 70, "neg0": -0.0, "tiny": 5e-324,
               "obj": Path("runs/a"), "none": None, "carr": np.array([1 + 1j, 2 - 0.5j])}
    for key, value in payload.items():
        single = {key: value}
        assert json.loads(encode(single)) == json.loads(_DUMPS(plain(single))), key
    assert json.loads(encode(payload)) == json.loads(_DUMPS(plain(payload)))
    back = np.array(json.loads(encode({"w": wide}))["w"])
    assert np.array_equal(back, wide)                      # shortest repr round-trips every float exactly
    assert encode({"b": 1, "a": 2}) == b'{"a":2,"b":1}'     # sorted keys, compact


def test_log_holds_every_step_and_the_run_facts(two_runs):
    log = read_log(two_runs[0])
    steps = log.messages("/step")
    assert len(steps) == 100 and [s["k"] for s in steps] == list(range(100))
    assert set(steps[0]) >= {"x", "z", "u", "V", "Vdot", "region", "active", "binds", "slack", "status",
                             "qp_status", "iterations", "fallback"}
    assert "solve_time" not in steps[0] and len(log.messages("/timing")) == 100
    assert len(log.messages("/prediction")) == 10 and len(log.messages("/prediction")[0]["x_pred"]) == 21
    assert len(log.messages("/open_loop")) == 101
    assert log.completed and not log.truncated
    model = log.one("/model")
    assert model["k"] == 9 and len(model["Lambda"]) == 9
    clf = log.one("/clf")
    assert clf["r"] > clf["r_hat"] > 0 and "verdict" in clf["certificate"]
    # log times are simulation time
    assert [t for t, _ in log.channels["/step"]][:3] == [0, 10_000_000, 20_000_000]


def test_repeated_run_is_identical_on_every_deterministic_channel(two_runs):
    res = diff_logs(*two_runs)
    assert res.equal, res.report()
    la, lb = read_log(two_runs[0]), read_log(two_runs[1])
    for topic in ("/config", "/model", "/clf", "/step", "/prediction", "/open_loop", "/summary"):
        assert [json.dumps(m, sort_keys=True) for m in la.messages(topic)] == \
               [json.dumps(m, sort_keys=True) for m in lb.messages(topic)]
    # the wall-clock channel differs (solve times), and is compared only on request
    assert not diff_logs(*two_runs, include_wall_clock=True).equal


def test_a_changed_input_is_reported_at_its_step_and_field(two_runs, tmp_path):
    changed = tmp_path / "changed.mcap"

    def edit(topic, payload):
        if topic == "/step" and payload["k"] == 57:
            payload["u"][0] += 1e-3
    copy_log(two_runs[0], changed, edit)
    res = diff_logs(two_runs[0], changed)
    assert not res.equal
    f = res.first
    assert (f.channel, f.step, f.field) == ("/step", 57, "u[0]")
    assert abs(f.b - f.a - 1e-3) < 1e-12
    assert res.per_channel["/step"] == (100, 1)
    # within tolerance it is equal
    assert diff_logs(two_runs[0], changed, atol=2e-3).equal


def test_truncated_log_still_reads_and_diffs_with_a_warning(two_runs, tmp_path):
    data = two_runs[0].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    log = read_log(cut)
    assert log.truncated and "truncated" in log.warning and not log.completed
    assert 0 < len(log.messages("/step")) < 100
    res = diff_logs(two_runs[0], cut)
    assert not res.equal and res.first.field == "message count"
    assert res.warnings == (f"b ({cut}): {log.warning}",)    # which of the two, by its path


@pytest.mark.parametrize("flag,value", [("--rtol", "inf"), ("--atol", "inf"), ("--atol", "nan"), ("--rtol", "-1")])
def test_cli_refuses_a_tolerance_that_is_not_finite_and_nonnegative(two_runs, capsys, flag, value):
    """--rtol inf gave a 'first divergence' at 0.0 != 0.0 (inf·0 = nan): no verdict can come from it."""
    assert diff_main([str(two_runs[0]), str(two_runs[1]), flag, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"kexp-diff: error: tolerances must be finite and >= 0, got "
                   f"rtol={float(value) if flag == '--rtol' else 0.0}, atol={float(value) if flag == '--atol' else 0.0}"]


def test_cli_exit_codes(two_runs, tmp_path, capsys):
    assert diff_main([str(two_runs[0]), str(two_runs[1])]) == 0
    changed = tmp_path / "c.mcap"
    copy_log(two_runs[0], changed, lambda t, p: p.update(V=p["V"] * 2) if t == "/step" and p["k"] == 3 else None)
    assert diff_main([str(two_runs[0]), str(changed)]) == 1
    out = capsys.readouterr().out
    assert "channel /step, step 3" in out and "field V" in out
    bogus = tmp_path / "bogus.mcap"
    bogus.write_text("not mcap")
    assert diff_main([str(two_runs[0]), str(bogus)]) == 2
    proc = subprocess.run([console_script("kexp-diff"), str(two_runs[0]), str(tmp_path / "no.mcap")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.strip().startswith("kexp-diff: error:")


@pytest.mark.parametrize("name", sorted(golden.GOLDEN))
def test_golden_recording(name, tmp_path):
    """Re-run each paper experiment's golden config and diff against the committed recording under the portable
    policy (what holds on any CPU, BLAS kernel and thread count; README "Golden recordings"); regenerate with
    `python -m kexp.app.golden`."""
    committed = golden.RECORDINGS / f"{name}.mcap"
    assert committed.exists(), "run `python -m kexp.app.golden` and commit recordings/"
    new = golden.record(name, tmp_path / f"{name}.mcap")
    res = diff_logs(committed, new, policy="portable")
    assert res.equal, res.report()
    assert len(read_log(committed).messages("/step")) == 200


@pytest.mark.parametrize("kwargs,fragment", [
    ({"flush_every": 0}, "logging.flush_every=0: use seconds > 0 (finite)"),
    ({"flush_every": float("inf")}, "logging.flush_every=inf: use seconds > 0 (finite)"),
    ({"flush_every": "a"}, "logging.flush_every='a': expected a number"),
    ({"prediction_every": -1}, "logging.prediction_every=-1: use an int >= 0 (0: never)"),
    ({"prediction_every": 2.5}, "logging.prediction_every=2.5: expected an integer"),
])
def test_logger_settings_are_refused_at_construction(tmp_path, kwargs, fragment):
    from kexp.errors import ConfigError
    with pytest.raises(ConfigError) as err:
        RunLogger(tmp_path / "a.mcap", **kwargs)
    assert str(err.value) == fragment and not (tmp_path / "a.mcap").exists()


@pytest.mark.parametrize("t,payload,fragment", [
    (float("nan"), {}, "log time t=nan"), (float("inf"), {}, "log time t=inf"), (-1.0, {}, "log time t=-1.0"),
    ("0", {}, "log time t='0'"), (True, {}, "log time t=True"), (0.0, [1, 2], "payload list: a log message is a dict"),
])
def test_a_message_log_cannot_store_is_refused_in_the_call(tmp_path, t, payload, fragment):
    """Was struct.error or OverflowError at the flush, or (a list) a log read_log could not read back."""
    from kexp.errors import ConfigError
    with RunLogger(tmp_path / "a.mcap") as log:
        with pytest.raises(ConfigError, match=re.escape(fragment)):
            log.write("/summary", t, payload)
    assert read_log(tmp_path / "a.mcap").channels == {}
