"""Success over the initial conditions of a sweep (an estimate of the region of attraction), one row of panels per
group of runs.

Runs are grouped as ``kexp-report`` groups them (identical overrides apart from ``sim.x0``) and, within that, by
system: runs of different systems or settings are never drawn in one panel.  A 2-state group gets one panel in
x-space with Ω_r and Ω_r̂ (from the group's first log, their levels in the legend); an n-state group (n > 2) gets one panel per pair of
states, each titled "projection onto (xi, xj)" (level sets are not curves in a projection: Ω_r is not drawn).
Each panel's title states the success rule with the group's T and tol (``sim.T``, ``sim.tol`` from the job's
.hydra/config.yaml or its log's /config).  Runs are named with the words of kexp's sweep lines
(kexp.app.sweep_progress): a completed run is "settled" or "unsettled"; an unsettled one is drawn as "unsettled,
near" when ‖x(T) − x_eq‖ < 10·tol (it was converging: a longer T would likely count it).  Jobs that stopped with an
"error" (or were interrupted, or wrote no summary) are drawn as grey crosses where their x0 is known, and every one
of them is returned in ``failed`` with its reason, never dropped.
"""
from __future__ import annotations

from collections import Counter
from itertools import combinations
from pathlib import Path

import numpy as np

from ..errors import KexpError
from ..recording.reader import read_log
from ..systems.registry import builtin_state_names

MAX_GROUPS = 8       # more groups than this: refuse, listing them (one figure per group is unreadable beyond)
MAX_PAIRS = 6        # n > 4: the first 6 state pairs
NOT_SETTLED = "unsettled, near (‖x(T)‖ < 10·tol)"
KINDS = (("settled", dict(marker="o", color="tab:green")),
         (NOT_SETTLED, dict(marker="^", color="tab:orange")), ("unsettled", dict(marker="o", color="tab:red")),
         ("diverged", dict(marker="x", color="tab:red")), ("error", dict(marker="x", color="0.5")))


class RoaError(KexpError):
    """The sweep cannot be drawn as one region-of-attraction figure (too many groups)."""


def run_kind(row: dict, tol: float | None = None) -> str:
    """How a run is drawn: settled, unsettled near (‖x(T)‖ < 10·tol), unsettled, diverged or error."""
    if row["ok"]:
        if row["success"]:
            return "settled"
        err = row.get("final_error")
        return NOT_SETTLED if tol is not None and err is not None and err < 10 * tol else "unsettled"
    return "diverged" if row["status"] == "diverged" else "error"


def _level(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) else None


def omega_curves(clf: dict) -> list[tuple[np.ndarray, bool, str]]:
    """The closed Ω boundaries of a log's /clf as [(points (k, 2), is Ω_r̂, mathtext label with the level)]: one
    curve labelled "Ω_r = Ω_r̂" when r == r̂ (the same level set), else Ω_r and Ω_r̂ (those with points)."""
    r, rh = _level(clf.get("r")), _level(clf.get("r_hat"))
    b_r = np.asarray(clf.get("boundary_r") or [], float).reshape(-1, 2)
    b_rh = np.asarray(clf.get("boundary_r_hat") or [], float).reshape(-1, 2)
    close = [np.vstack([b, b[:1]]) if b.size else b for b in (b_r, b_rh)]
    if r is not None and rh is not None and np.isclose(r, rh, rtol=1e-9, atol=0.0) and (b_r.size or b_rh.size):
        return [(close[0] if b_r.size else close[1], False, rf"$\Omega_r = \Omega_{{\hat r}}$ (r = {r:.3g})")]
    out = []
    for b, hat, name, sym, lv in ((close[0], False, r"$\Omega_r$", "r", r),
                                  (close[1], True, r"$\Omega_{\hat r}$", r"$\hat r$", rh)):
        if b.size:
            out.append((b, hat, name + ("" if lv is None else f" ({sym} = {lv:.3g})")))
    return out


def sim_settings(job: Path, log=None) -> dict:
    """The job's sim settings (T, tol): its .hydra/config.yaml, else its log's /config; {} when neither says."""
    import yaml
    try:
        cfg = yaml.safe_load((job / ".hydra" / "config.yaml").read_text()) or {}
    except (OSError, yaml.YAMLError):
        cfg = ((log.one("/config") or {}).get("config") or {}) if log is not None else {}
    sim = cfg.get("sim") if isinstance(cfg, dict) else None
    return {k: _level(sim.get(k)) for k in ("T", "tol")} if isinstance(sim, dict) else {}


def success_rule(sims: list[dict]) -> str:
    """The success rule with the runs' values of T and tol (:func:`sim_settings`; several: joined with '/'; none
    known: the symbols)."""
    def joined(key):
        values = sorted({s[key] for s in sims if s.get(key) is not None})
        return " / ".join(f"{v:g}" for v in values) if values else None
    tol, T = joined("tol"), joined("T")
    return f"settled: ‖x(T) − x_eq‖ < {tol or 'tol'} at {'T' if T is None else f'T = {T} s'}"


def group_rows(rows: list[dict]) -> list[tuple[str, list[dict]]]:
    """Split ``kexp.app.aggregate.aggregate`` rows into groups: the report's group (overrides apart from sim.x0)
    and the system.  Returns [(label, rows)] in the order the groups first appear; a failed job whose system is
    unknown joins its report group when that group has one system."""
    by_label: dict[str, list[dict]] = {}
    for r in rows:
        by_label.setdefault(r.get("group", "(all)"), []).append(r)
    out = []
    for label, members in by_label.items():
        systems = list(dict.fromkeys(r["system"] for r in members if r["system"]))
        if len(systems) <= 1:
            out.append((label if label != "(all)" or not systems else systems[0], members))
            continue
        for s in systems:
            out.append((s if label == "(all)" else f"{s}: {label}", [r for r in members if r["system"] == s]))
        unknown = [r for r in members if not r["system"]]
        if unknown:
            out.append((f"(system unknown): {label}", unknown))
    return out


def fallback_state_names(members: list[dict], n: int) -> list[str]:
    """The state names of runs whose logs do not record them (or that have no log): the built-in system's when
    the runs are of one such system, else x1 … xn."""
    systems = {r["system"] for r in members if r.get("system")}
    names = builtin_state_names(systems.pop(), n) if len(systems) == 1 else None
    return names or [f"x{i + 1}" for i in range(n)]


def _group_meta(members: list[dict]) -> tuple[int, list[str], list, dict]:
    """(n, state names, Ω curves (:func:`omega_curves`), sim settings {T, tol}) of a group: n is the most common
    length of x0 (the state dimension), names and Ω curves come from the first log in the group, T and tol from the
    first job that tells them (the runs of a group share their settings apart from x0); without a log (a sweep with
    ``logging.mcap=false``) a built-in system's names and no Ω curves."""
    lengths = Counter(len(r["x0"]) for r in members if r["x0"])
    n = lengths.most_common(1)[0][0] if lengths else 0
    names = fallback_state_names(members, n)
    curves, sim, read = [], {}, False
    for r in members:
        if not r["path"]:
            continue
        mcap, log = Path(r["path"]) / "run.mcap", None
        if not read and mcap.is_file():
            log, read = read_log(mcap), True
            logged = (log.one("/model") or {}).get("state_names")
            if logged and len(logged) == n:
                names = [str(s) for s in logged]
            curves = omega_curves(log.one("/clf") or {})
        sim = sim or sim_settings(Path(r["path"]), log)
        if read and sim:
            break
    return n, names, curves, sim


def roa_figure(sweep: str | Path, out: str | Path, *, max_groups: int = MAX_GROUPS) -> tuple[Path, dict]:
    """Draw the sweep folder's runs (``kexp.app.aggregate.aggregate``) into the PNG ``out``: one row of panels per
    group, one panel per state pair for n > 2.  Returns (out, facts) with facts = {'groups': [{'label', 'n',
    'runs', 'successes', 'not_settled', 'drawn', 'panels': [panel titles], 'T', 'tol'}], 'failed': [{'job', 'overrides', 'reason'}]}.

    Raises :class:`kexp.app.aggregate.ReportError` if the folder holds no runs and :class:`RoaError` (one line,
    listing the groups) if it holds more than ``max_groups`` groups."""
    from ..app.aggregate import aggregate
    rows = aggregate(sweep)
    groups = group_rows(rows)
    if len(groups) > max_groups:
        listed = "; ".join(f"{label} ({len(m)} runs)" for label, m in groups)
        raise RoaError(f"{sweep}: {len(groups)} groups of runs with different settings, more than {max_groups} to "
                       f"draw in one figure: {listed}; point kexp-figures roa at one group's folder")
    metas = [_group_meta(m) for _, m in groups]
    pair_lists = [list(combinations(range(n), 2))[:MAX_PAIRS] if n > 2 else [(0, 1)] for n, *_ in metas]
    ncols = max(len(p) for p in pair_lists)
    plt = _plt()
    fig, axes = plt.subplots(len(groups), ncols, figsize=(4.6 * ncols, 4.4 * len(groups)), squeeze=False)
    facts: dict = {"groups": [], "failed": [{"job": r["job"], "overrides": r["overrides"], "reason": r["reason"]}
                                            for r in rows if not r["ok"]]}
    for gi, ((label, members), (n, names, curves, sim), pairs) in enumerate(zip(groups, metas, pair_lists)):
        drawable = [r for r in members if r["x0"] and len(r["x0"]) == n and n >= 1]
        successes = sum(bool(r["success"]) for r in members)
        titles = []
        for pi, (i, j) in enumerate(pairs):
            ax = axes[gi, pi]
            for kind, style in KINDS:
                p = np.array([[r["x0"][i], r["x0"][j] if n > 1 else 0.0] for r in drawable
                              if run_kind(r, sim.get("tol")) == kind])
                if p.size:
                    ax.scatter(p[:, 0], p[:, 1], s=30, label=f"{kind} ({len(p)})", **style)
            if n == 2:
                for b, hat, name in curves:
                    ax.plot(b[:, 0], b[:, 1], "k:" if hat else "k-", lw=1, label=name)
            ax.set_xlabel(f"{names[i]}(0)" if n else "x0")
            ax.set_ylabel(f"{names[j]}(0)" if n > 1 else "")
            title = (f"projection onto ({names[i]}, {names[j]}) of {n} states" if n > 2 else
                     "success over initial conditions")
            titles.append(title)
            head = "" if label == "(all)" else (label if len(label) < 60 else label[:57] + "...") + "\n"
            ax.set_title(f"{head}{title} ({successes}/{len(members)})\n{success_rule([sim])}", fontsize=9)
            ax.grid(True, alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7, loc="best", framealpha=0.8)
        for ax in axes[gi, len(pairs):]:
            ax.set_visible(False)
        facts["groups"].append({"label": label, "n": n, "runs": len(members), "successes": successes,
                                "not_settled": sum(run_kind(r, sim.get("tol")) == NOT_SETTLED for r in members),
                                "drawn": len(drawable), "panels": titles, "T": sim.get("T"), "tol": sim.get("tol")})
    notes = []
    if any(n > 2 for n, *_ in metas):
        notes.append("n > 2: projections of x0, Ω_r not drawn")
    if facts["failed"]:
        notes.append(f"{len(facts['failed'])} error(s), grey × where x0 is known")
    not_drawn = sum(g["runs"] - g["drawn"] for g in facts["groups"])
    if not_drawn:
        notes.append(f"{not_drawn} run(s) without a usable x0 not drawn")
    fig.suptitle(f"success over initial conditions: {len(rows)} runs in {len(groups)} group(s)"
                 + (f"\n{'; '.join(notes)}" if notes else ""), fontsize=10)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out, facts


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt
