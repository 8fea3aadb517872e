"""What kexp-report's pictures and the region map (kexp-figures roa CSVs --oracle) say: axis labels, titles,
legends and bar edges of the matplotlib Figures (captured at savefig), not their pixels.  Inputs are fake sweep
folders and results CSVs, written in a few milliseconds (no kexp runs)."""
import json

import numpy as np
import pytest
import yaml

pytest.importorskip("matplotlib")
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from kexp.analysis.region_map import compare, read_results, region_map  # noqa: E402
from kexp.app import report as rep  # noqa: E402

from test_region_map import _write  # noqa: E402


@pytest.fixture
def saved(monkeypatch):
    """{file name: Figure} of every Figure.savefig call (the file is still written)."""
    figs = {}
    real = Figure.savefig

    def record(self, fname, *args, **kwargs):
        figs[str(getattr(fname, "name", fname)).rsplit("/", 1)[-1]] = self
        return real(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", record)
    return figs


def _job(sweep, i, x0, *, success=None, final_error=None, cost=None, status="completed", system="pendulum",
         T=5.0, tol=0.01, solve_ms=0.25):
    job = sweep / str(i)
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump([f"sim.x0=[{x0[0]},{x0[1]}]", f"sim.T={T}"]))
    (job / ".hydra" / "config.yaml").write_text(yaml.safe_dump({"sim": {"T": T, "tol": tol, "r": 1.0}}))
    summary = {"status": status, "completed": status == "completed", "message": "" if status == "completed"
               else "boom", "system": system, "controller": "lmpc", "x0": list(x0)}
    if status == "completed":
        summary["metrics"] = {"success": success, "final_error": final_error, "cost": cost, "settling_time": None,
                              "max_abs_u": 1.0, "fallbacks": 0, "solve_time_median": solve_ms * 1e-3,
                              "solve_time_p99": 4 * solve_ms * 1e-3}
    (job / "summary.json").write_text(json.dumps(summary))


@pytest.fixture
def sweep(tmp_path):
    """5 pendulum runs (T = 5 s, tol = 0.01): 2 successes, 1 not settled (‖x(T)‖ = 0.05 < 10·tol), 1 failed
    (‖x(T)‖ = 2, a large cost that must not enter the cost histogram), 1 job that ended in an error."""
    s = tmp_path / "sweep"
    _job(s, 0, (0.5, 0.5), success=True, final_error=0.001, cost=1.0, solve_ms=0.23)
    _job(s, 1, (-0.5, 0.5), success=True, final_error=0.002, cost=1.5, solve_ms=0.24)
    _job(s, 2, (1.0, 1.0), success=False, final_error=0.05, cost=3.0, solve_ms=0.245)
    _job(s, 3, (1.5, 1.5), success=False, final_error=2.0, cost=400.0, solve_ms=0.255)
    _job(s, 4, (-1.5, -1.0), status="error")
    return s


def _titles(fig):
    return [ax.get_title() for ax in fig.axes if ax.get_visible()]


def test_report_roa_labels_title_and_legend_counts(sweep, tmp_path, saved):
    rep.report(sweep, tmp_path / "out")
    fig = saved["roa.png"]
    ax = fig.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("theta(0)", "omega(0)")  # pendulum's names, not x1(0), x2(0)
    title = ax.get_title()
    assert "(all)" not in title and "pendulum, lmpc: all 5 runs of the sweep" in title
    assert "settled: ‖x(T) − x_eq‖ < 0.01 at T = 5 s" in title
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == ["settled (2)", "unsettled, near (‖x(T)‖ < 10·tol) (1)", "unsettled (1)",
                      "error (1)"]
    assert "5 runs" in fig._suptitle.get_text()


def test_report_cost_histogram_is_successes_only(sweep, tmp_path, saved):
    rep.report(sweep, tmp_path / "out")
    ax = saved["cost_hist.png"].axes[0]
    assert ax.get_title() == "cost J of the 2 successful runs (of 5)"
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    assert sum(p.get_height() for p in bars) == 2                     # J = 1.0 and 1.5, not the failed 3 and 400
    assert max(p.get_x() + p.get_width() for p in bars) == pytest.approx(1.5)


def test_report_cost_panel_says_when_nothing_succeeded(tmp_path, saved):
    s = tmp_path / "sweep"
    _job(s, 0, (1.5, 1.5), success=False, final_error=2.0, cost=40.0)
    _job(s, 1, (0.5, 0.5), success=False, final_error=0.05, cost=5.0)
    rep.report(s, tmp_path / "out")
    ax = saved["cost_hist.png"].axes[0]
    assert not ax.patches and "0 successful runs (of 2)" in ax.get_title()
    text = " ".join(t.get_text() for t in ax.texts)
    assert "no run succeeded (0 of 2)" in text and "< 0.01 at T = 5 s" in text


def test_report_histogram_bars_have_white_edges(sweep, tmp_path, saved):
    rep.report(sweep, tmp_path / "out")
    for name in ("cost_hist.png", "solve_time_hist.png"):
        for ax in saved[name].axes:
            bars = [p for p in ax.patches if isinstance(p, Rectangle)]
            assert bars and all(p.get_edgecolor()[:3] == to_rgba("white")[:3] and p.get_linewidth() > 0 for p in bars)
    med, p99 = saved["solve_time_hist.png"].axes
    assert sum(p.get_height() for p in med.patches) == 4 and "(4 runs)" in med.get_title()
    rug = [ln for ln in med.lines if ln.get_marker() == "|"]         # < 10 runs: every value marked too
    assert len(rug) == 1 and len(rug[0].get_xdata()) == 4


_csv = _write   # the region map tests' writer of results CSVs


@pytest.fixture
def maps(tmp_path):
    """pendulum CSVs on a 6 × 6 grid: the oracle succeeds everywhere (J = 1); 'lmpc' is 0.9× the oracle at one
    x0 (a ratio below 1) and fails at (2, 2); 'lqr' costs 1.1× everywhere."""
    g = np.linspace(-2, 2, 6)
    x0s = [(float(a), float(b)) for a in g for b in g]
    n = len(x0s)
    oracle = _csv(tmp_path / "pendulum_nmpc.csv", x0s, [True] * n, [1.0] * n)
    lmpc = _csv(tmp_path / "pendulum_lmpc.csv", x0s, [k != (2.0, 2.0) for k in x0s],
                [0.9 if k == (-2.0, -2.0) else 1.0 for k in x0s])
    lqr = _csv(tmp_path / "pendulum_lqr.csv", x0s, [True] * n, [1.1] * n)
    return oracle, lmpc, lqr


def test_region_map_labels_titles_and_min_ratio(maps, tmp_path, saved):
    oracle, lmpc, lqr = maps
    facts = compare(read_results(lmpc), read_results(oracle))
    assert facts["min_ratio"] == pytest.approx(0.9) and facts["worst_ratio"] == pytest.approx(1.0)
    out, panels = region_map([lmpc, lqr], oracle, tmp_path / "map.png")
    assert [p["min_ratio"] for p in panels] == [pytest.approx(0.9), pytest.approx(1.1)]
    fig = saved["map.png"]
    left, right = fig.axes[:2]
    assert (left.get_xlabel(), left.get_ylabel()) == ("theta(0)", "omega(0)")
    assert right.get_xlabel() == "theta(0)" and right.get_ylabel() == ""       # y-label on the first panel only
    assert right.get_shared_y_axes().joined(left, right)
    assert "J/J_oracle min 0.900, median 1.000, worst 1.000" in left.get_title()
    assert "oracle succeeds everywhere; this controller: 35/36 there" in left.get_title()
    assert "everywhere: 35/36" not in left.get_title()
    assert "clipped to [1, 1.3]" in fig.axes[-1].get_ylabel()                  # the colour bar keeps its note
    fig.canvas.draw()
    legend = left.get_legend()
    assert [t.get_text() for t in legend.get_texts()] == ["no success (1)"]
    assert legend.get_window_extent().y1 <= left.get_window_extent().y0     # below the panel, not over the marks


def test_region_map_unknown_system_keeps_x1_x2(tmp_path, saved):
    x0s = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
    oracle = _csv(tmp_path / "mysys_nmpc.csv", x0s, [True, True, True, False], [1.0, 1.0, 1.0, 1.0])
    mpc = _csv(tmp_path / "mysys_mpc.csv", x0s, [True] * 4, [1.2] * 4)
    region_map([mpc], oracle, tmp_path / "m.png")
    ax = saved["m.png"].axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x1(0)", "x2(0)")
    assert "where the oracle succeeds: 3/3" in ax.get_title() and "min 1.200" in ax.get_title()


def test_region_map_names_a_variant_of_a_built_in_system():
    from kexp.analysis.region_map import state_names
    assert state_names("pendulum-u0.5") == ("theta", "omega")
    assert state_names("vanderpol") == ("x1", "x2") and state_names("mysys") == ("x1", "x2")
