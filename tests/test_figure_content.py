"""What the kexp-figures figures show, read from the matplotlib Figure (not its pixels): ``Figure.savefig`` is
patched to keep the figure.  paper: states and input u(t) over time (u with u_min/u_max dashed), labelled axes,
"open loop (u = 0)", Ω_r / Ω_r̂ in mathtext with their levels (one curve when r = r̂); theorem1: the y label and
a title naming the system and the horizon; roa: the success rule with T and tol in the title, runs that were
converging ("not settled by T") told apart from failures."""
import json

import numpy as np
import pytest
from matplotlib.figure import Figure

from kexp.analysis.figures import paper_figure, theorem1_figure
from kexp.analysis.roa import NOT_SETTLED, roa_figure
from kexp.recording import RunLogger

OMEGA_R, OMEGA_RH = r"$\Omega_r$ (r = 5.11)", r"$\Omega_{\hat r}$ ($\hat r$ = 2.44)"


@pytest.fixture
def figures(monkeypatch):
    """The figures the code under test saves, in order (nothing is written)."""
    saved = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: saved.append(fig))
    return saved


def _ellipse(a, b, k=40):
    th = np.linspace(0, 2 * np.pi, k, endpoint=False)
    return np.c_[a * np.cos(th), b * np.sin(th)]


def _log(path, n_steps=50, dt=0.01, config=True, r=5.11, r_hat=2.44, u_sat=False):
    """A Van der Pol log (explicit Euler): /config (u_min/u_max, sim T/tol) when ``config``, /model, /clf,
    /open_loop and /step; the input saturates at u_max for the first steps when ``u_sat``."""
    from kexp.systems import VanDerPol
    s, x = VanDerPol(), np.array([0.5, -0.3])
    with RunLogger(path) as log:
        if config:
            log.log_config({"system": {"name": "vanderpol", "params": {"mu": 1.0}},
                            "controller": {"u_min": -5.0, "u_max": 5.0}, "sim": {"T": 5.0, "tol": 0.01}}, "0")
        log.write("/model", 0.0, {"state_names": ["x1", "x2"], "dt": dt})
        log.write("/clf", 0.0, {"r": r, "r_hat": r_hat, "status": "optimal",
                                "boundary_r": _ellipse(1.0, 1.5), "boundary_r_hat": _ellipse(0.3, 0.4)})
        xo = x.copy()
        for k in range(n_steps):
            log.write("/open_loop", k * dt, {"t": k * dt, "x": xo})
            xo = xo + dt * s.rhs(xo[None], np.zeros((1, 1)))[0]
        for k in range(n_steps):
            u = np.array([5.0 if u_sat and k < 5 else -x[1]])
            log.write("/step", k * dt, {"k": k, "t": k * dt, "x": x, "u": u})
            x = x + dt * s.rhs(x[None], u[None])[0]
    return path


def _legend(ax):
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def _panels(fig):
    """{title: axes} of the figure's visible axes."""
    return {ax.get_title(): ax for ax in fig.axes if ax.get_visible()}


def test_paper_figure_has_the_input_panel_labelled_axes_and_legends(tmp_path, figures):
    paper_figure(_log(tmp_path / "run.mcap", u_sat=True), tmp_path / "p.png")
    (fig,) = figures
    panels = _panels(fig)
    assert set(panels) == {"states over time", "input (closed loop)", "phase portrait"}
    states, inp, phase = panels["states over time"], panels["input (closed loop)"], panels["phase portrait"]
    assert (states.get_xlabel(), states.get_ylabel()) == ("t [s]", "state")
    assert (inp.get_xlabel(), inp.get_ylabel()) == ("t [s]", "u")
    assert _legend(states) == ["x1 closed loop", "x1 open loop (u = 0)", "x2 closed loop", "x2 open loop (u = 0)"]
    # u(t) as steps, saturation visible against the dashed bounds from /config
    (u_line,) = [ln for ln in inp.get_lines() if ln.get_label() == "u"]
    assert u_line.get_drawstyle() == "steps-post" and np.max(u_line.get_ydata()) == 5.0
    bounds = {ln.get_label(): ln for ln in inp.get_lines() if ln.get_label().startswith("u_")}
    assert set(bounds) == {"u_min = -5", "u_max = 5"}
    assert all(ln.get_linestyle() == "--" for ln in bounds.values())
    assert [list(bounds[k].get_ydata()) for k in ("u_min = -5", "u_max = 5")] == [[-5.0, -5.0], [5.0, 5.0]]
    assert _legend(inp) == ["u", "u_min = -5", "u_max = 5"]
    assert _legend(phase) == ["open loop (u = 0)", "closed loop", "x0", OMEGA_R, OMEGA_RH]
    texts = [t for ax in fig.axes for t in _legend(ax)] + [fig.get_suptitle()]
    assert not any("r̂" in t or "Ω" in t for t in texts)  # mathtext only, no combining hat
    assert fig.get_suptitle() == "vanderpol: open loop (u = 0) vs closed loop"


def test_paper_figure_one_omega_curve_when_r_equals_r_hat(tmp_path, figures):
    paper_figure(_log(tmp_path / "run.mcap", r=5.11, r_hat=5.11), tmp_path / "p.png")
    phase = _panels(figures[0])["phase portrait"]
    omegas = [t for t in _legend(phase) if "Omega" in t]
    assert omegas == [r"$\Omega_r = \Omega_{\hat r}$ (r = 5.11)"]


def test_paper_figure_without_config_has_no_bound_lines(tmp_path, figures):
    paper_figure(_log(tmp_path / "run.mcap", config=False), tmp_path / "p.png")
    (fig,) = figures
    inp = _panels(fig)["input (closed loop)"]
    assert _legend(inp) == ["u"] and len(inp.get_lines()) == 1
    assert fig.get_suptitle() == "open loop (u = 0) vs closed loop"


def test_theorem1_figure_labels_the_error_and_names_system_and_horizon(tmp_path, figures):
    from kexp.data import Box, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    s = VanDerPol()
    model = identify(s, collect(s, Box(5, -2.5, 2.5), DataConfig(T=2.0)), Monomials(2, 2, include_constant=False))
    model.save(tmp_path / "model.npz")
    _log(tmp_path / "run.mcap", 60, dt=model.dt)
    theorem1_figure(tmp_path, tmp_path / "t.png", horizon=0.3)
    (ax,) = figures[0].axes
    assert ax.get_ylabel() == r"$\|x(t) - \hat{x}(t)\|$" and ax.get_xlabel() == "t [s]"
    assert ax.get_title() == "prediction error vs Theorem 1: vanderpol, first 0.3 s"
    assert _legend(ax)[0] == r"measured $\|x(t) - \hat{x}(t)\|$"


def _sweep(root, jobs, config="hydra", *, log=True, system="vanderpol"):
    """A sweep folder as kexp writes it: per job .hydra/overrides.yaml, summary.json and (``config``) the sim
    settings in .hydra/config.yaml ("hydra"), only in job 0's run.mcap ("log") or nowhere (None); job 0 has a
    run.mcap (its /clf) unless config is None or not ``log`` (a sweep with logging.mcap=false)."""
    for i, (x0, success, final_error) in enumerate(jobs):
        job = root / str(i)
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- sim.x0=[{x0[0]},{x0[1]}]\n")
        if config == "hydra":
            (job / ".hydra" / "config.yaml").write_text("sim:\n  T: 5.0\n  tol: 0.01\n  r: 1.0\n")
        if i == 0 and config is not None and log:
            _log(job / "run.mcap", 5)
        (job / "summary.json").write_text(json.dumps({
            "status": "completed", "completed": True, "system": system, "controller": "lmpc", "x0": x0,
            "metrics": {"success": success, "final_error": final_error, "cost": 1.0, "settling_time": None,
                        "max_abs_u": 1.0, "fallbacks": 0, "solve_time_median": 0.001, "solve_time_p99": 0.002}}))
    return root


JOBS = [([0.5, 0.5], False, 0.058), ([-0.5, 0.5], False, 1.99), ([1.5, 1.5], False, 2.01), ([0.1, 0.1], True, 0.004)]


@pytest.mark.parametrize("config", ["hydra", "log"])
def test_roa_title_has_the_rule_and_not_settled_runs_are_told_apart(tmp_path, figures, config):
    _, facts = roa_figure(_sweep(tmp_path / "sweep", JOBS, config), tmp_path / "roa.png")
    (ax,) = [a for a in figures[0].axes if a.get_visible()]
    assert "settled: ‖x(T) − x_eq‖ < 0.01 at T = 5 s" in ax.get_title()
    assert _legend(ax) == ["settled (1)", f"{NOT_SETTLED} (1)", "unsettled (2)", OMEGA_R, OMEGA_RH]
    assert NOT_SETTLED == "unsettled, near (‖x(T)‖ < 10·tol)"
    (g,) = facts["groups"]
    assert (g["T"], g["tol"], g["not_settled"], g["successes"]) == (5.0, 0.01, 1, 1)


def test_roa_of_a_sweep_without_logs_names_a_built_in_system_s_states(tmp_path, figures):
    """Row sweeps run with logging.mcap=false: no Ω curves to draw, but the pendulum's axes are still theta and
    omega (kexp.systems' names), not x1 and x2."""
    roa_figure(_sweep(tmp_path / "sweep", JOBS, "hydra", log=False, system="pendulum"), tmp_path / "roa.png")
    (ax,) = [a for a in figures[0].axes if a.get_visible()]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("theta(0)", "omega(0)")
    assert _legend(ax) == ["settled (1)", f"{NOT_SETTLED} (1)", "unsettled (2)"]



def test_not_settled_is_within_ten_times_tol():
    """A completed run that missed tol is drawn as 'unsettled, near' only while ‖x(T)‖ < 10·tol, unsettled from
    there; without tol it is unsettled; a run that did not complete is diverged or an error."""
    from kexp.analysis.roa import run_kind
    done = lambda err: {"ok": True, "success": False, "final_error": err, "status": "completed"}  # noqa: E731
    assert run_kind(done(0.0999), 0.01) == NOT_SETTLED and run_kind(done(0.1001), 0.01) == "unsettled"
    assert run_kind(done(0.05), None) == "unsettled" and run_kind({**done(0.0), "success": True}, 0.01) == "settled"
    assert run_kind({"ok": False, "success": False, "status": "diverged"}, 0.01) == "diverged"
    assert run_kind({"ok": False, "success": False, "status": "error"}, 0.01) == "error"


def test_roa_without_t_and_tol_says_so_and_does_not_guess(tmp_path, figures):
    _, facts = roa_figure(_sweep(tmp_path / "sweep", JOBS, None), tmp_path / "roa.png")
    (ax,) = [a for a in figures[0].axes if a.get_visible()]
    assert ax.get_title().endswith("settled: ‖x(T) − x_eq‖ < tol at T")
    assert _legend(ax) == ["settled (1)", "unsettled (3)"]
    assert facts["groups"][0]["not_settled"] == 0
