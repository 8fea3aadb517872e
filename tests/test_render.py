"""kexp.recording.render: run.mcap → run.rrd (Rerun 0.41), checked by reading the .rrd back with Rerun's reader."""
import shutil
from pathlib import Path
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pyarrow as pa
import pytest
from hydra import compose, initialize_config_dir
from rerun.chunk import RrdReader

from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.recording.reader import LogError, read_log
from kexp.recording.render import RenderError, RenderWarning, main, render
from kexp.recording.writer import RunLogger

# as tests/test_app.py SMALL (Van der Pol, 2 s), without the .rrd the app would render itself
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
         "logging.prediction_every=10"]


@pytest.fixture(scope="module")
def run_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL)
    run(cfg, out, echo=lambda *_: None)
    path = out / "run.mcap"
    assert path.exists() and not (out / "run.rrd").exists()
    return path


@pytest.fixture(scope="module")
def rendered(run_log, tmp_path_factory):
    rrd = render(run_log, tmp_path_factory.mktemp("rrd") / "run.rrd")
    return rrd, load_rrd(rrd), read_log(run_log)


def load_rrd(path):
    """The recording store of an .rrd as {entity: {"rows": n (temporal), "cols": {name: [values]},
    "static": {name: value}}} (durations as int ns), plus the store entries."""
    reader = RrdReader(path)
    out = defaultdict(lambda: {"rows": 0, "cols": defaultdict(list), "static": {}})
    for chunk in reader.stream().to_chunks():
        rb = chunk.to_record_batch()
        ent = out[chunk.entity_path]
        for name in rb.schema.names:
            if name == "rerun.controls.RowId":
                continue
            col = rb.column(name)
            values = (col.cast(pa.int64()) if pa.types.is_duration(col.type) else col).to_pylist()  # ns
            if chunk.is_static:
                ent["static"][name] = values[-1]
            else:
                ent["cols"][name].extend(values)
        if not chunk.is_static:
            ent["rows"] += chunk.num_rows
    return {"entities": dict(out), "recordings": reader.recordings(), "blueprints": reader.blueprints(),
            "reader": reader}


def scalars(ent):
    return np.array([np.nan if v is None or not v else v[0] for v in ent["cols"]["Scalars:scalars"]], float)


# -- the full render -------------------------------------------------------------------------------------------
def test_rrd_is_written_with_one_recording_named_after_the_config(rendered):
    rrd, data, log = rendered
    assert rrd.exists() and rrd.suffix == ".rrd" and rrd.stat().st_size > 50_000
    (rec,) = data["recordings"]
    assert rec.application_id == "kexp"
    assert rec.recording_id == f"kexp-{log.one('/config')['config_hash']}"
    assert len(data["blueprints"]) == 1


def test_time_series_hold_every_step_on_both_timelines(rendered):
    _, data, log = rendered
    ents = data["entities"]
    steps = log.channels["/step"]
    n_steps = len(steps)
    assert n_steps == 200
    expected = {"/states/x1", "/states/x2", "/input/u1", "/lyapunov/V", "/lyapunov/Vdot", "/constraints/active",
                "/constraints/binds", "/constraints/slack", "/constraints/fallback", "/timing/solve_time_ms",
                "/phase/state"}
    for e in expected:
        assert ents[e]["rows"] == n_steps, e
    x = np.array([m["x"] for _, m in steps])
    np.testing.assert_allclose(scalars(ents["/states/x1"]), x[:, 0])
    np.testing.assert_allclose(scalars(ents["/states/x2"]), x[:, 1])
    np.testing.assert_allclose(scalars(ents["/input/u1"]), [m["u"][0] for _, m in steps])
    np.testing.assert_allclose(scalars(ents["/lyapunov/V"]), [m["V"] for _, m in steps])
    np.testing.assert_allclose(scalars(ents["/lyapunov/Vdot"]), [m["Vdot"] for _, m in steps])
    # sim_time is the log time (duration, ns), step is k
    x1 = ents["/states/x1"]["cols"]
    assert x1["sim_time"] == [t for t, _ in steps]
    assert x1["step"] == [m["k"] for _, m in steps] == list(range(n_steps))
    # constraint activity coded 0/1/2, binds 0/1, solve time in ms
    code = {"none": 0, "21e": 1, "21f": 2}
    np.testing.assert_array_equal(scalars(ents["/constraints/active"]), [code[m["active"]] for _, m in steps])
    assert set(scalars(ents["/constraints/active"])) == {1.0, 2.0}   # this run uses both constraints
    np.testing.assert_array_equal(scalars(ents["/constraints/binds"]), [float(m["binds"]) for _, m in steps])
    np.testing.assert_allclose(scalars(ents["/timing/solve_time_ms"]),
                               [1e3 * m["solve_time"] for m in log.messages("/timing")])
    assert ents["/states/x1"]["static"]["SeriesLines:names"] == ["x1"]
    # r and r̂ drawn as levels over the run
    clf = log.one("/clf")
    np.testing.assert_allclose(scalars(ents["/lyapunov/r"]), [clf["r"]] * 2)
    np.testing.assert_allclose(scalars(ents["/lyapunov/r_hat"]), [clf["r_hat"]] * 2)


def test_phase_portrait_and_eigenvalues(rendered):
    _, data, log = rendered
    ents = data["entities"]
    steps = log.messages("/step")
    (strip,) = ents["/phase/closed_loop"]["static"]["LineStrips2D:strips"]
    np.testing.assert_allclose(strip, [m["x"] for m in steps], rtol=1e-6)   # stored as float32
    (ol,) = ents["/phase/open_loop"]["static"]["LineStrips2D:strips"]
    assert len(ol) == len(log.messages("/open_loop")) == 201
    np.testing.assert_allclose(ents["/phase/start"]["static"]["Points2D:positions"], [steps[0]["x"]], rtol=1e-6)
    assert ents["/phase/equilibrium"]["static"]["Points2D:positions"] == [[0.0, 0.0]]
    clf = log.one("/clf")
    for key, ent in (("boundary_r", "/phase/omega_r"), ("boundary_r_hat", "/phase/omega_r_hat")):
        (ring,) = ents[ent]["static"]["LineStrips2D:strips"]
        assert len(clf[key]) > 100 and len(ring) == len(clf[key]) + 1   # closed
        np.testing.assert_allclose(ring[0], ring[-1])
        np.testing.assert_allclose(ring[:-1], clf[key], rtol=1e-6)
    # the predicted horizons, at their step times
    preds = log.channels["/prediction"]
    pe = ents["/phase/prediction"]
    assert len(preds) == 20 and pe["rows"] == len(preds)
    assert pe["cols"]["step"] == [m["k"] for _, m in preds] == list(range(0, 200, 10))
    (first,) = pe["cols"]["LineStrips2D:strips"][0]
    np.testing.assert_allclose(first, preds[0][1]["x_pred"], rtol=1e-5, atol=1e-7)
    # eigenvalues in the complex plane, with the axes through 0
    model = log.one("/model")
    pos = np.array(ents["/eigenvalues/lambda"]["static"]["Points2D:positions"])
    np.testing.assert_allclose(pos, np.c_[model["eigenvalues_re"], model["eigenvalues_im"]], rtol=1e-6)
    horizontal, vertical = ents["/eigenvalues/axes"]["static"]["LineStrips2D:strips"]
    assert horizontal[0][1] == horizontal[1][1] == 0 and vertical[0][0] == vertical[1][0] == 0
    assert horizontal[0][0] < pos[:, 0].min() and horizontal[1][0] > max(pos[:, 0].max(), 0)
    assert vertical[0][1] < pos[:, 1].min() and vertical[1][1] > pos[:, 1].max()


def test_summary_document_and_blueprint(rendered):
    _, data, log = rendered
    text = data["entities"]["/summary"]["static"]["TextDocument:text"][0]
    summary, clf = log.one("/summary"), log.one("/clf")
    success = "yes" if summary["metrics"]["success"] else "no"   # 2 s is short of the 1e-2 tolerance: "no"
    assert "| status | completed |" in text and f"| success | {success} |" in text
    assert f"| cost J | {summary['metrics']['cost']:.4g} |" in text
    assert clf["certificate"]["verdict"] in text
    assert data["entities"]["/summary"]["static"]["TextDocument:media_type"] == ["text/markdown"]
    # the default blueprint: time series on one side, phase portrait + eigenvalues on the other, text in tabs
    reader = data["reader"]
    views, containers, bounds = {}, [], []
    for chunk in reader.stream(store=data["blueprints"][0]).to_chunks():
        rb = chunk.to_record_batch()
        cols = {n: rb.column(n).to_pylist()[-1] for n in rb.schema.names if "Blueprint:" in n or "Bounds" in n}
        if "VisualBounds2D:range" in cols:
            bounds.append(cols["VisualBounds2D:range"][0])
        if "ViewBlueprint:display_name" in cols:
            views[cols["ViewBlueprint:display_name"][0]] = (cols["ViewBlueprint:class_identifier"][0],
                                                            cols["ViewBlueprint:space_origin"][0])
        if "ContainerBlueprint:container_kind" in cols:
            containers.append(cols["ContainerBlueprint:container_kind"][0])
    assert views == {
        "states x(t)": ("TimeSeries", "/states"), "input u(t)": ("TimeSeries", "/input"),
        "V(t)": ("TimeSeries", "/lyapunov"), "V̇(t)": ("TimeSeries", "/lyapunov"),
        "constraints (active, binds, slack)": ("TimeSeries", "/constraints"),
        "solve time [ms]": ("TimeSeries", "/timing"),
        "phase portrait x1–x2": ("2D", "/phase"), "eigenvalues (Re, Im)": ("2D", "/eigenvalues"),
        "summary": ("TextDocument", "/summary"), "config": ("TextDocument", "/config")}
    assert len(containers) >= 5
    # the phase portrait is framed on the closed loop and Ω_r (the open loop may run off)
    (frame,) = bounds
    x = np.array([m["x"] for m in log.messages("/step")])
    assert frame["x_range"][0] < x[:, 0].min() and frame["x_range"][1] > x[:, 0].max()
    assert frame["y_range"][0] < x[:, 1].min() and frame["y_range"][1] > x[:, 1].max()


def test_default_output_path_and_deterministic_recording_id(run_log, rendered, tmp_path):
    copy = tmp_path / "copy.mcap"
    shutil.copy(run_log, copy)
    out = render(copy)
    assert out == tmp_path / "copy.rrd" and out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy.mcap", "copy.rrd"]   # no temporary left
    assert RrdReader(out).recordings()[0].recording_id == rendered[1]["recordings"][0].recording_id


# -- incomplete and bad input ----------------------------------------------------------------------------------
def test_truncated_log_warns_and_renders_what_is_there(run_log, tmp_path):
    half = tmp_path / "half.mcap"
    half.write_bytes(run_log.read_bytes()[: run_log.stat().st_size // 2])
    log = read_log(half)
    n_steps = len(log.channels.get("/step", []))
    assert log.truncated and 0 < n_steps < 200
    with pytest.warns(RenderWarning, match="truncated"):
        out = render(half)
    assert out.exists() and out.stat().st_size > 10_000
    ents = load_rrd(out)["entities"]
    assert ents["/states/x1"]["rows"] == n_steps
    assert "Incomplete log" in ents["/summary"]["static"]["TextDocument:text"][0]


def test_odd_log_no_phase_portrait_for_n3_and_gaps_stay_gaps(tmp_path):
    """A hand-written log: n = 3 (no phase portrait), a NaN state (logged as null), an unknown activity, no
    /clf, no /summary (unfinished run → warning)."""
    path = tmp_path / "odd.mcap"
    with RunLogger(path) as lg:
        lg.write("/config", 0.0, {"config": {"system": {"name": "made_up"}}, "config_hash": "abc123"})
        lg.write("/model", 0.0, {"eigenvalues_re": [-1.0, 0.5], "eigenvalues_im": [2.0, -2.0], "n": 3, "m": 1,
                                 "state_names": ["a", "b", "c"]})
        for k in range(5):
            x = [float(k), None if k == 2 else 1.0, 2.0]
            lg.write("/step", 0.1 * k, {"k": k, "t": 0.1 * k, "x": x, "u": [0.5], "V": 1.0, "Vdot": -1.0,
                                        "active": "weird" if k == 3 else "none", "binds": False, "slack": 0.0,
                                        "fallback": k == 4})
    with pytest.warns(RenderWarning, match="did not finish"):
        out = render(path)
    data = load_rrd(out)
    ents = data["entities"]
    assert data["recordings"][0].recording_id == "kexp-abc123"
    assert not any(e.startswith("/phase") for e in ents)
    assert {"/states/x1", "/states/x2", "/states/x3", "/eigenvalues/lambda"} <= set(ents)
    assert ents["/states/x1"]["static"]["SeriesLines:names"] == ["x1 (a)"]
    x2 = scalars(ents["/states/x2"])
    assert np.isnan(x2[2]) and np.all(x2[[0, 1, 3, 4]] == 1.0)
    act = scalars(ents["/constraints/active"])
    assert act[0] == 0 and np.isnan(act[3])
    np.testing.assert_array_equal(scalars(ents["/constraints/fallback"]), [0, 0, 0, 0, 1])
    assert "/timing/solve_time_ms" not in ents


def test_predictions_are_cleared_when_a_plan_runs_out(run_log, tmp_path):
    """Every other plan dropped: each remaining plan is shown for prediction_every = 10 steps, then cleared."""
    log = read_log(run_log)
    path = tmp_path / "sparse.mcap"
    with RunLogger(path) as lg:
        for topic, msgs in log.channels.items():
            for i, (t_ns, payload) in enumerate(msgs):
                if topic != "/prediction" or i % 2 == 0:
                    lg.write(topic, t_ns / 1e9, payload)
    pe = load_rrd(render(path))["entities"]["/phase/prediction"]
    assert pe["cols"]["step"] == [k for k0 in range(0, 200, 20) for k in (k0, k0 + 10)]
    assert [len(s) for s in pe["cols"]["LineStrips2D:strips"]] == [1, 0] * 10


def test_missing_or_non_mcap_file_raises(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_text("not a log\n")
    with pytest.raises(LogError, match="not an MCAP file"):
        render(bad)
    with pytest.raises(LogError, match="does not exist"):
        render(tmp_path / "missing.mcap")
    assert not (tmp_path / "bad.rrd").exists()


def test_refuses_to_overwrite_the_log_or_to_write_nothing(run_log, tmp_path, monkeypatch):
    copy = tmp_path / "run.mcap"
    shutil.copy(run_log, copy)
    with pytest.raises(RenderError, match="would overwrite the log"):
        render(copy, copy)
    assert copy.read_bytes() == run_log.read_bytes()
    monkeypatch.setenv("RERUN", "off")   # Rerun disabled: say so instead of returning a path that is not there
    with pytest.raises(RenderError, match="RERUN=off"):
        render(copy)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


# -- command line ----------------------------------------------------------------------------------------------
def test_cli_writes_the_rrd(run_log, tmp_path, capsys):
    out = tmp_path / "sub" / "x.rrd"
    with pytest.raises(SystemExit) as exc:
        main([str(run_log), "-o", str(out)])
    assert exc.value.code == 0 and out.exists()
    cap = capsys.readouterr()
    assert cap.out.startswith(f"wrote {out} (") and cap.err == ""


def test_cli_truncated_log_warns_one_line_and_exits_0(run_log, tmp_path, capsys):
    half = tmp_path / "half.mcap"
    half.write_bytes(run_log.read_bytes()[: run_log.stat().st_size // 2])
    with pytest.raises(SystemExit) as exc:
        main([str(half)])
    assert exc.value.code == 0 and (tmp_path / "half.rrd").exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("kexp-render: warning: half.mcap is truncated")


@pytest.mark.parametrize("name,content,needle", [
    ("bad.mcap", b"hello\n", "is not an MCAP file"),
    ("missing.mcap", None, "does not exist"),
])
def test_cli_bad_input_exits_2_with_one_line(tmp_path, capsys, name, content, needle):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(SystemExit) as exc:
        main([str(path)])
    assert exc.value.code == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert cap.out == "" and len(err) == 1 and err[0].startswith("kexp-render: error: ") and needle in err[0]
    assert not any(tmp_path.glob("*.rrd"))


@pytest.mark.parametrize("output,needle", [
    ("{tmp}/folder", "exists and is not a regular file"),
    ("/dev/null", "output /dev/null exists and is not a regular file"),   # as root, it was replaced by a file
    ("", "output '.' is not a file name"),
])
def test_cli_refuses_an_output_that_is_not_a_file_path(run_log, tmp_path, capsys, output, needle):
    (tmp_path / "folder").mkdir()
    with pytest.raises(SystemExit) as exc:
        main([str(run_log), "-o", output.format(tmp=tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and err[0].startswith("kexp-render: error: ") and needle in err[0]
    assert Path("/dev/null").is_char_device() and sorted(p.name for p in tmp_path.iterdir()) == ["folder"]
    assert not any((tmp_path / "folder").iterdir())


def test_cli_refuses_a_log_without_steps(run_log, tmp_path, capsys):
    """A log cut before its first chunk of steps: nothing to render, exit 2 (was an empty .rrd and exit 0)."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(run_log.read_bytes()[:5000])
    assert not read_log(cut).channels.get("/step")
    with pytest.raises(SystemExit) as exc:
        main([str(cut)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "holds no control step (/step) to render (cut.mcap is " \
        "truncated" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap"]


def test_console_script_exits_2_on_a_non_mcap_file(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_text("not a log\n")
    exe = shutil.which("kexp-render")
    cmd = [exe] if exe else [sys.executable, "-m", "kexp.recording.render"]
    proc = subprocess.run(cmd + [str(bad)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        f"kexp-render: error: {bad} is not an MCAP file (bad magic); pass a run.mcap written by kexp"]
