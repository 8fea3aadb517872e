"""Success over the initial conditions of a sweep (an estimate of the region of attraction), one row of panels per
group of runs.

Runs are grouped as ``kexp-report`` groups them (identical overrides apart from ``sim.x0``) and, within that, by
system: runs of different systems or settings are never drawn in one panel.  A 2-state group gets one panel in
x-space with Ω_r and Ω_r̂ (from the group's first log); an n-state group (n > 2) gets one panel per pair of
states, each titled "projection onto (xi, xj)" (level sets are not curves in a projection: Ω_r is not drawn).
Jobs that failed (error, interrupted, no summary) are drawn as grey crosses where their x0 is known, and every one
of them is returned in ``failed`` with its reason, never dropped.
"""
from __future__ import annotations

from collections import Counter
from itertools import combinations
from pathlib import Path

import numpy as np

from ..errors import KexpError
from ..recording.reader import read_log

MAX_GROUPS = 8       # more groups than this: refuse, listing them (one figure per group is unreadable beyond)
MAX_PAIRS = 6        # n > 4: the first 6 state pairs
KINDS = (("success", dict(marker="o", color="tab:green")), ("no success", dict(marker="o", color="tab:red")),
         ("diverged", dict(marker="x", color="tab:red")), ("failed job", dict(marker="x", color="0.5")))


class RoaError(KexpError):
    """The sweep cannot be drawn as one region-of-attraction figure (too many groups)."""


def _kind(row: dict) -> str:
    if row["ok"]:
        return "success" if row["success"] else "no success"
    return "diverged" if row["status"] == "diverged" else "failed job"


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


def _group_meta(members: list[dict]) -> tuple[int, list[str], np.ndarray, np.ndarray]:
    """(n, state names, boundary_r, boundary_r_hat) of a group: n is the most common length of x0 (the state
    dimension), names and Ω boundaries come from the first log in the group."""
    lengths = Counter(len(r["x0"]) for r in members if r["x0"])
    n = lengths.most_common(1)[0][0] if lengths else 0
    names = [f"x{i + 1}" for i in range(n)]
    b_r = b_rh = np.zeros((0, 2))
    for r in members:
        mcap = Path(r["path"]) / "run.mcap" if r["path"] else None
        if mcap is None or not mcap.is_file():
            continue
        log = read_log(mcap)
        logged = (log.one("/model") or {}).get("state_names")
        if logged and len(logged) == n:
            names = [str(s) for s in logged]
        clf = log.one("/clf") or {}
        b_r = np.asarray(clf.get("boundary_r") or [], float).reshape(-1, 2)
        b_rh = np.asarray(clf.get("boundary_r_hat") or [], float).reshape(-1, 2)
        break
    return n, names, b_r, b_rh


def roa_figure(sweep: str | Path, out: str | Path, *, max_groups: int = MAX_GROUPS) -> tuple[Path, dict]:
    """Draw the sweep folder's runs (``kexp.app.aggregate.aggregate``) into the PNG ``out``: one row of panels per
    group, one panel per state pair for n > 2.  Returns (out, facts) with facts = {'groups': [{'label', 'n',
    'runs', 'successes', 'drawn', 'panels': [panel titles]}], 'failed': [{'job', 'overrides', 'reason'}]}.

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
    for gi, ((label, members), (n, names, b_r, b_rh), pairs) in enumerate(zip(groups, metas, pair_lists)):
        drawable = [r for r in members if r["x0"] and len(r["x0"]) == n and n >= 1]
        successes = sum(bool(r["success"]) for r in members)
        titles = []
        for pi, (i, j) in enumerate(pairs):
            ax = axes[gi, pi]
            for kind, style in KINDS:
                p = np.array([[r["x0"][i], r["x0"][j] if n > 1 else 0.0] for r in drawable if _kind(r) == kind])
                if p.size:
                    ax.scatter(p[:, 0], p[:, 1], s=30, label=f"{kind} ({len(p)})", **style)
            if n == 2:
                for b, style, name in ((b_r, "k-", "Ω_r"), (b_rh, "k:", "Ω_r̂")):
                    if b.size:
                        b = np.vstack([b, b[:1]])
                        ax.plot(b[:, 0], b[:, 1], style, lw=1, label=name)
            ax.set_xlabel(f"{names[i]}(0)" if n else "x0")
            ax.set_ylabel(f"{names[j]}(0)" if n > 1 else "")
            title = (f"projection onto ({names[i]}, {names[j]}) of {n} states" if n > 2 else
                     "success over initial conditions")
            titles.append(title)
            head = "" if label == "(all)" else (label if len(label) < 60 else label[:57] + "...") + "\n"
            ax.set_title(f"{head}{title} ({successes}/{len(members)})", fontsize=9)
            ax.grid(True, alpha=0.3)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
        for ax in axes[gi, len(pairs):]:
            ax.set_visible(False)
        facts["groups"].append({"label": label, "n": n, "runs": len(members), "successes": successes,
                                "drawn": len(drawable), "panels": titles})
    notes = []
    if any(n > 2 for n, *_ in metas):
        notes.append("n > 2: projections of x0, Ω_r not drawn")
    if facts["failed"]:
        notes.append(f"{len(facts['failed'])} failed job(s), grey × where x0 is known")
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
