"""An LMPC horizon too large for memory is refused before anything runs (issue 11, item 6), with an estimate that
bounds what the controller really allocates."""
import json
import os
import subprocess
import sys
import textwrap

import pytest

from kexp.control import LmpcConfig
from kexp.control.memory import MEMORY_BUDGET_GB, check_memory, memory_estimate
from kexp.errors import ConfigError
from cli import console_script


def test_cli_refuses_a_horizon_over_the_memory_budget_before_identification(tmp_path):
    # used to identify the model, then die in rollout_sensitivity with MemoryError: Allocation failed
    proc = subprocess.run([console_script("kexp"), "controller.lmpc.horizon=10000000", "logging.progress=false",
                           f"hydra.run.dir={tmp_path}"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    # degree-5 monomials in 2 states: k <= 21; 20 move blocks, 1 input
    assert lines[0].startswith("kexp: error: controller.lmpc.horizon=10000000 with blocks=20 needs about 74.1 GB "
                               "for k=21 dictionary functions and m=1 input(s), over the budget of 4 GB")
    assert not (tmp_path / "model.npz").exists()  # refused before identification
    assert json.loads((tmp_path / "summary.json").read_text())["status"] == "error"


def test_the_budget_is_stated_and_can_be_set(monkeypatch):
    cfg = LmpcConfig(horizon=2000, blocks=None)
    assert memory_estimate(cfg, 21, 1) == 8 * (2 * 2001 * 21 * 2000 + 6 * 2001 ** 2 + 4 * 2001 * 2001 + 2 * 2000)
    monkeypatch.delenv("KEXP_MEMORY_BUDGET_GB", raising=False)
    assert MEMORY_BUDGET_GB == 4.0
    check_memory(cfg, 21, 1)  # 1.67 GB
    monkeypatch.setenv("KEXP_MEMORY_BUDGET_GB", "0.5")
    with pytest.raises(ConfigError, match=r"needs about 1.67 GB .* over the budget of 0.5 GB"):
        check_memory(cfg, 21, 1)
    check_memory(LmpcConfig(horizon=2000, blocks=20), 21, 1)  # blocking: 0.015 GB
    monkeypatch.setenv("KEXP_MEMORY_BUDGET_GB", "lots")
    with pytest.raises(ConfigError, match="KEXP_MEMORY_BUDGET_GB='lots': use a number of gigabytes > 0"):
        check_memory(cfg, 21, 1)


MEASURE = textwrap.dedent("""
    import json, sys
    import numpy as np
    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, LmpcConfig, make_law
    from kexp.control.memory import memory_estimate
    from kexp.data import Circle, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    s = VanDerPol()
    model = identify(s, collect(s, Circle(20, 2.5), DataConfig(T=3.0)), Monomials(2, 3))
    clf = synthesize_clf(model, ClfConfig(grid=11))
    law = make_law("sontag", clf.lyap, -5.0, 5.0)
    x0 = np.array([0.7, -0.5])
    Lmpc(model, clf, law, LmpcConfig(horizon=20, blocks=None), -5.0, 5.0).step(x0, model.lift(x0))  # warm up
    cfg = LmpcConfig(horizon=int(sys.argv[1]), blocks=None)

    def status(key):  # kB
        return int(next(ln for ln in open("/proc/self/status") if ln.startswith(key)).split()[1])

    with open("/proc/self/clear_refs", "w") as f:  # reset the peak (VmHWM) to the current RSS
        f.write("5")
    before = status("VmRSS:")
    Lmpc(model, clf, law, cfg, -5.0, 5.0).step(x0, model.lift(x0))
    grown = (status("VmHWM:") - before) * 1024
    print(json.dumps({"grown": grown, "estimate": memory_estimate(cfg, model.k, model.m)}))
""")


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's /proc peak-RSS reset")
def test_the_estimate_bounds_the_measured_peak():
    """One control step with an 800-step unblocked horizon: the process's peak memory grows by less than the
    estimate, and by more than a third of it (measured: 0.66-0.68 of the estimate at horizons 800-200000)."""
    out = subprocess.run([sys.executable, "-c", MEASURE, "800"], capture_output=True, text=True, timeout=300,
                         check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["estimate"] / 3 < r["grown"] < r["estimate"], r


def test_the_run_size_estimates_bound_what_a_short_run_holds(tmp_path):
    """What check_run_size refuses by: the estimates per data sample and per logged control step (its log read
    back, as the rendering does) bound the peak Python allocations of a short run (tracemalloc), and a run over
    the budget is refused by name."""
    import tracemalloc

    import numpy as np

    from kexp.app.budget import check_run_size, loop_bytes
    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, make_law
    from kexp.data import Circle, DataConfig, collect
    from kexp.data.collect import data_bytes
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.recording.reader import read_log
    from kexp.recording.writer import RunLogger
    from kexp.simulate import SimConfig, closed_loop
    from kexp.systems import VanDerPol
    s = VanDerPol()
    tracemalloc.start()
    data = collect(s, Circle(40, 2.5), DataConfig(T=5.0))
    data_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert data_peak <= data_bytes(40, 500, s.n, s.m)
    model = identify(s, data, Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    ctrl = Lmpc(model, clf, make_law("sontag", clf.lyap, -5.0, 5.0), LmpcConfig(), -5.0, 5.0, prediction_every=20)
    tracemalloc.start()
    with RunLogger(tmp_path / "run.mcap", prediction_every=20) as log:
        closed_loop(s, ctrl, np.array([0.7, -0.5]), SimConfig(T=3.0), model=model, lyap=clf.lyap,
                    on_step=lambda rec, step: log.log_step(rec, step, model))
    back = read_log(tmp_path / "run.mcap")
    loop_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(back.messages("/step")) == 300
    assert loop_peak <= loop_bytes(300, s.n, s.m, model.k)
    with pytest.raises(ConfigError, match=r"sim.T=1e\+06 s at Δ = 0.01 s is 1e\+08 control steps, about 824 GB for"):
        check_run_size(SimConfig(T=1e6), s, 21)
