"""The docs' Python API page (docs/guides/python-api.md) runs as written: its python blocks are executed in order in one namespace,
with only the sizes made small (each substitution must hit the page's text exactly as often as stated, so an edit
of the snippet that the test no longer matches fails here instead of going untested)."""
import re
from pathlib import Path

import numpy as np
import pytest

PAGE = Path(__file__).resolve().parents[1] / "docs" / "guides" / "python-api.md"
# the page's text -> small setting, and how many times the text occurs in the section
SMALL = [("Circle(100, 2.5)", "Circle(20, 2.5)", 1),
         ("DataConfig(T=10.0, dt=0.01)", "DataConfig(T=3.0, dt=0.01)", 1),
         ("Monomials(2, 5)", "Monomials(2, 3)", 1),
         ("ClfConfig(gamma=2.0, c_lower=0.01, c_upper=1.0)", "ClfConfig(gamma=2.0, c_lower=0.01, c_upper=1.0, grid=11)",
          1),
         ("LmpcConfig()", "LmpcConfig(horizon=20, blocks=None)", 2),
         ("SimConfig(T=10.0)", "SimConfig(T=1.0)", 2)]


def python_api_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)


def test_the_python_api_section_runs_as_written(tmp_path, monkeypatch, capsys):
    pytest.importorskip("rerun")
    blocks = python_api_blocks()
    assert len(blocks) == 2 and "RunLogger(path)" in blocks[1]
    code = "\n".join(blocks)
    for old, new, count in SMALL:
        assert code.count(old) == count, f"docs/guides/python-api.md: {old!r} occurs {code.count(old)} times, not {count}"
        code = code.replace(old, new)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "docs/guides/python-api.md", "exec"), ns)
    out = capsys.readouterr().out
    assert "logs are equal" in out and "100 control steps logged" in out
    from kexp.recording import read_log
    log = read_log(tmp_path / "a.mcap")
    assert not log.warning and not log.truncated and log.completed
    assert len(log.messages("/step")) == 100 and len(log.messages("/open_loop")) == 101
    assert log.one("/model")["n"] == 2 and len(log.one("/clf")["boundary_r"]) > 0
    summary = log.one("/summary")
    assert summary["status"] == "completed"
    # the logged run is the first block's `run` (deterministic): its steps, and the cost J = ∫ ‖x‖² + r u² dt
    # (x_eq = 0, r = 1: SimConfig's default) computed here from run's samples — trapezoid on x, exact for held u
    run = ns["run"]
    steps = log.messages("/step")
    assert np.array_equal([s["x"] for s in steps], run.x[:100]) and np.array_equal([s["u"] for s in steps], run.u)
    e = np.sum(run.x ** 2, axis=1)
    dt = np.diff(run.t)
    assert len(run.t) == 101 and np.allclose(dt, 0.01, rtol=1e-12)
    cost = float(np.sum(dt * (e[:-1] + e[1:]) / 2) + np.sum(dt * run.u[:, 0] ** 2))
    assert summary["metrics"]["cost"] == pytest.approx(cost, rel=1e-12) and cost > 0.1
    assert callable(ns["logged_closed_loop"])
    assert (tmp_path / "a.png").stat().st_size > 20_000 and (tmp_path / "a.rrd").stat().st_size > 10_000
