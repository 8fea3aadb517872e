"""What the Rerun viewer shows first of a rendered run log (:mod:`kexp.recording.render`): the default blueprint
(its panels and what each shows) and the run's summary document."""
from __future__ import annotations

from typing import Any

from .reader import RunLog


def _fmt(v: Any, spec: str = ".4g") -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return format(v, spec)
    return str(v)


def _realtime_rows(rt: dict | None) -> list[str]:
    """The summary's row for a paced run (sim.realtime): its deadline misses and largest lateness, from /timing."""
    if not rt:
        return []
    late = rt.get("late_max")
    return [f"| real time (sim.realtime) | {rt['misses']} deadline miss(es) in {rt['steps']} steps, largest "
            f"lateness {'—' if late is None else format(late * 1e3, '.3g') + ' ms'} |"]


def summary_markdown(log: RunLog, info: dict) -> str:
    """The summary document: the run's verdict, metrics, CLF, model and log, as a markdown table (``info``: what
    the steps' logging counted, e.g. ``steps``)."""
    cfg = (log.one("/config") or {})
    conf = cfg.get("config") or {}
    summary = log.one("/summary") or {}
    metrics = summary.get("metrics") or {}
    clf = log.one("/clf") or {}
    cert = clf.get("certificate") or {}
    model = log.one("/model") or {}
    system = (conf.get("system") or {}).get("name", "?")
    controller = (conf.get("controller") or {}).get("kind", "?")
    lines = [f"# kexp run: {system}, {controller}", ""]
    if log.warning:
        lines += [f"> **Incomplete log:** {log.warning}", ""]
    status = summary.get("status") or ("did not finish (log truncated)" if log.truncated else "did not finish")
    success = metrics.get("success")
    lines += ["| | |", "|---|---|",
              f"| status | {status} |",
              f"| success | {_fmt(success) if success is not None else '—'} |",
              f"| cost J | {_fmt(metrics.get('cost'))} |",
              f"| ‖x(T) − x_eq‖ | {_fmt(metrics.get('final_error'), '.3e')} |",
              f"| settling time [s] | {_fmt(metrics.get('settling_time'))} |",
              f"| max abs u | {_fmt(metrics.get('max_abs_u'))} |",
              f"| fallbacks | {_fmt(metrics.get('fallbacks'))} |",
              f"| time outside Ω_r [s] | {_fmt(metrics.get('time_outside_omega_r'))} |",
              f"| CLF status | {_fmt(clf.get('status'))} |",
              f"| r, r̂ | {_fmt(clf.get('r'))}, {_fmt(clf.get('r_hat'))} |",
              f"| certificate | {_fmt(cert.get('verdict'))} |",
              f"| model | k = {_fmt(model.get('k'))}, n = {_fmt(model.get('n'))}, m = {_fmt(model.get('m'))}, "
              f"Δ = {_fmt(model.get('dt'))} s |",
              f"| steps logged | {info['steps']} |",
              *_realtime_rows(info.get("realtime")),
              f"| config hash | `{_fmt(cfg.get('config_hash'))}` |",
              f"| log | `{log.path.name}` |"]
    if summary.get("message"):
        lines += ["", f"message: {summary['message']}"]
    return "\n".join(lines) + "\n"


def default_blueprint(rrb, *, has_phase: bool, has_eig: bool, has_timing: bool, phase_bounds=None,
                      has_realtime: bool = False):
    """The viewer's layout (``rrb``: ``rerun.blueprint``): the time series on the left (states, input, V and V̇,
    constraints and solve time, and a paced run's lateness and misses with ``has_realtime``), tabs on the right
    (phase portrait framed by ``phase_bounds`` and eigenvalues where there are any, the summary, the config), the
    time panel on ``sim_time``."""
    left = [rrb.TimeSeriesView(origin="/states", name="states x(t)"),
            rrb.TimeSeriesView(origin="/input", name="input u(t)"),
            rrb.Horizontal(rrb.TimeSeriesView(origin="/lyapunov", contents=["/lyapunov/V", "/lyapunov/r",
                                                                             "/lyapunov/r_hat"], name="V(t)"),
                           rrb.TimeSeriesView(origin="/lyapunov", contents="/lyapunov/Vdot", name="V̇(t)"),
                           name="V / V̇")]
    bottom = [rrb.TimeSeriesView(origin="/constraints", name="constraints (active, binds, slack)")]
    if has_timing and has_realtime:
        bottom += [rrb.TimeSeriesView(origin="/timing", contents="/timing/solve_time_ms", name="solve time [ms]"),
                   rrb.TimeSeriesView(origin="/timing", contents=["/timing/late_ms", "/timing/miss"],
                                      name="lateness [ms] and misses (sim.realtime)")]
    elif has_timing:
        bottom.append(rrb.TimeSeriesView(origin="/timing", name="solve time [ms]"))
    left.append(rrb.Horizontal(*bottom, name="constraints / solve time"))
    right = []
    if has_phase:
        bounds = rrb.VisualBounds2D(x_range=phase_bounds[0], y_range=phase_bounds[1]) if phase_bounds else None
        right.append(rrb.Spatial2DView(origin="/phase", name="phase portrait x1–x2", visual_bounds=bounds))
    if has_eig:
        right.append(rrb.Spatial2DView(origin="/eigenvalues", name="eigenvalues (Re, Im)"))
    tabs = []
    if right:
        tabs.append(rrb.Vertical(*right, row_shares=[3, 2][:len(right)], name="phase / eigenvalues"))
    tabs += [rrb.TextDocumentView(origin="/summary", name="summary"),
             rrb.TextDocumentView(origin="/config", name="config")]
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*left, name="time series"), rrb.Tabs(*tabs, active_tab=0),
                       column_shares=[3, 2]),
        rrb.TimePanel(timeline="sim_time"),
        collapse_panels=False)
