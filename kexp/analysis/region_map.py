"""Region maps against the oracle: where each controller succeeds over the initial conditions of a results
sweep, coloured by its cost ratio to the true-model NMPC oracle on the same x0, with the oracle's own success
region outlined.

Input: condensed results CSVs (``kexp-results collect``; committed under ``results/``), one per controller, and
the oracle's CSV over the same initial conditions.  One panel per controller:

- a filled circle per x0 where it succeeded, its colour the cost ratio J / J_oracle (clipped to [1, ``vmax``]);
- a red × where it failed (no success, diverged or a failed job), a grey + where the oracle's cost is unknown
  (the oracle failed there or did not run that x0);
- the oracle's success region outlined: the 0.5 level of its success indicator interpolated over the x0
  (a Delaunay triangulation); when the oracle succeeded from every x0 there is no outline and the title says
  'oracle succeeds everywhere'.

Ratios below 1 (a controller cheaper than the oracle, within the oracle's solver tolerance) share the bottom colour;
each panel's title gives the minimum ratio, so the clipping is never silent.  The axes are labelled with the
system's state names when the file name's system (or the part of it before '-', e.g. ``pendulum`` of
``pendulum-u0.5``) is a built-in one, else x1, x2.

    kexp-figures roa results/regions/vanderpol_lmpc.csv results/regions/vanderpol_lqr.csv \\
        --oracle results/regions/vanderpol_nmpc.csv -o docs/figures/region_vanderpol.png
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..results.aggregate import ReportError
from ..results.csvfiles import read_csv, split_name, x0_columns, x0_key
from ..errors import KexpError
from .roa import _plt

VMAX = 1.3   # ratios above this share the top colour


class RegionMapError(KexpError):
    """The CSVs cannot be drawn as a region map (unreadable, missing columns, no common initial conditions)."""


def read_results(path: str | Path) -> dict[tuple[float, float], dict]:
    """{x0: {'ok': completed, 'success': bool, 'cost': float}} from a results CSV of a 2-state system, checked as
    kexp-results checks it (:func:`kexp.results.csvfiles.read_csv`); RegionMapError names what is wrong with the file,
    or says that a map draws 2 states when the CSV's x0 has another number (x0_1 … x0_n)."""
    try:
        rows = read_csv(path)
    except ReportError as exc:
        raise RegionMapError(str(exc)) from None
    cols = x0_columns(rows[0])
    if len(cols) != 2:
        raise RegionMapError(f"{path}: runs of {len(cols)} states (x0_1 … x0_{len(cols)}); a region map draws the "
                             "plane of a 2-state system's x0: tabulate this one (kexp-results table or plants)")
    out = {}
    for r in rows:
        if "" in x0_key(r, cols) or None in x0_key(r, cols):
            continue  # a failed job without a known x0 cannot be placed
        key = tuple(float(v) for v in x0_key(r, cols))
        cost = float(r["cost"]) if r["cost"] not in ("", None) else float("nan")
        out[key] = {"ok": r["status"] == "completed", "success": r["success"] == "True", "cost": cost}
    return out


def compare(runs: dict, oracle: dict) -> dict:
    """Per controller: successes, where the oracle succeeded and this controller too, and the cost ratios
    (successful runs on x0 where the oracle succeeded): their minimum, median and worst (maximum)."""
    keys = [k for k in runs if k in oracle]
    o_ok = [k for k in keys if oracle[k]["success"]]
    ratios = np.array([runs[k]["cost"] / oracle[k]["cost"] for k in o_ok if runs[k]["success"]])
    return {"runs": len(runs), "common": len(keys), "successes": sum(r["success"] for r in runs.values()),
            "oracle_successes": len(o_ok), "both": int(sum(runs[k]["success"] for k in o_ok)),
            "min_ratio": float(np.min(ratios)) if ratios.size else float("nan"),
            "median_ratio": float(np.median(ratios)) if ratios.size else float("nan"),
            "worst_ratio": float(np.max(ratios)) if ratios.size else float("nan")}


def _system(path: Path) -> str:
    """The system of a results CSV: the CSVs do not record it, their names do (``<system>_<config>.csv``)."""
    try:
        return split_name(path)[0]
    except ReportError as exc:
        raise RegionMapError(str(exc)) from None


def state_names(system: str) -> tuple[str, str]:
    """The first two state names of a results CSV's system: the built-in system's (``pendulum-u0.5``: a variant of
    ``pendulum``, its part before '-'), else ('x1', 'x2') (the CSVs do not record names)."""
    from ..systems.registry import builtin_state_names
    names = builtin_state_names(system)
    return (names[0], names[1]) if names and len(names) >= 2 else ("x1", "x2")


def _label(path: Path) -> str:
    """'system: configuration' of a results CSV (cart_pendulum_lmpc.csv -> 'cart_pendulum: lmpc')."""
    return ": ".join(split_name(path))


def region_map(csvs: list[str | Path], oracle: str | Path, out: str | Path, *, vmax: float = VMAX
               ) -> tuple[Path, list[dict]]:
    """Draw one panel per CSV in ``csvs`` against the oracle's CSV into the PNG ``out``.  Returns (out, facts),
    one dict of :func:`compare` (plus 'label') per panel.  RegionMapError if a file is unreadable or shares no
    initial condition with the oracle."""
    oracle = Path(oracle)
    ref = read_results(oracle)
    system = _system(oracle)
    panels = []
    for p in map(Path, csvs):
        runs = read_results(p)
        if _system(p) != system:
            raise RegionMapError(f"{p} holds runs of {_system(p)}, the oracle's {oracle} of {system} (the system is "
                                 "the file name's part before '_'); compare a system's CSVs with its own oracle")
        facts = compare(runs, ref)
        if facts["common"] == 0:
            raise RegionMapError(f"{p}: no initial condition in common with the oracle's {oracle}: run both over "
                                 "the same sim.x0")
        panels.append((p, runs, {"label": _label(p), **facts}))
    plt = _plt()
    from matplotlib.tri import Triangulation
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels) + 1.0, 5.6), squeeze=False, sharey=True,
                             layout="constrained")
    xname, yname = state_names(system)
    pts = np.array(list(ref))
    o_succ = np.array([ref[k]["success"] for k in ref], float)
    try:
        tri = Triangulation(pts[:, 0], pts[:, 1]) if len(pts) >= 3 else None
    except (RuntimeError, ValueError):   # x0 on one line (qhull: singular input): no region to outline
        tri = None
    sc = None
    for pi, (ax, (p, runs, facts)) in enumerate(zip(axes[0], panels)):
        keys = list(runs)
        x = np.array(keys)
        good = [k for k in keys if runs[k]["success"] and k in ref and ref[k]["success"]]
        unknown = [k for k in keys if runs[k]["success"] and not (k in ref and ref[k]["success"])]
        bad = [k for k in keys if not runs[k]["success"]]
        if good:
            g = np.array(good)
            ratio = np.array([runs[k]["cost"] / ref[k]["cost"] for k in good])
            sc = ax.scatter(g[:, 0], g[:, 1], c=np.clip(ratio, 1.0, vmax), cmap="viridis", vmin=1.0, vmax=vmax,
                            s=22, edgecolors="none")
        if unknown:
            u = np.array(unknown)
            ax.scatter(u[:, 0], u[:, 1], marker="+", color="0.4", s=30, label=f"no oracle cost ({len(u)})")
        if bad:
            b = np.array(bad)
            ax.scatter(b[:, 0], b[:, 1], marker="x", color="tab:red", s=30, label=f"no success ({len(b)})")
        if tri is not None and 0 < o_succ.sum() < len(o_succ):
            ax.tricontour(tri, o_succ, levels=[0.5], colors="k", linewidths=1.2)
            ax.plot([], [], "k-", lw=1.2, label="oracle's success region")
        where = (f"oracle succeeds everywhere; this controller: {facts['both']}/{facts['oracle_successes']} there"
                 if o_succ.all() else f"where the oracle succeeds: {facts['both']}/{facts['oracle_successes']}")
        ax.set_title(f"{facts['label']}: {facts['successes']}/{facts['runs']} succeed\n{where}\n"
                     f"J/J_oracle min {facts['min_ratio']:.3f}, median {facts['median_ratio']:.3f}, "
                     f"worst {facts['worst_ratio']:.3f}", fontsize=8)
        ax.set_xlabel(f"{xname}(0)")
        if pi == 0:   # sharey: the first panel's label names the rows of all
            ax.set_ylabel(f"{yname}(0)")
        ax.set_aspect("equal", adjustable="box")
        if x.size:
            for i, setter in ((0, ax.set_xlim), (1, ax.set_ylim)):
                pad = 0.05 * (np.ptp(x[:, i]) + 1e-9)
                setter(x[:, i].min() - pad, x[:, i].max() + pad)
        if ax.get_legend_handles_labels()[0]:   # below the panel: never over the marks or the outline
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncols=2, frameon=False)
    if sc is not None:
        bar = fig.colorbar(sc, ax=axes[0].tolist(), shrink=0.85)
        bar.set_label(f"J / J_oracle (clipped to [1, {vmax:g}])")
    fig.suptitle(f"success and cost against the true-model oracle ({_label(oracle)}, {len(ref)} x0)", fontsize=10)
    out = Path(out)
    fig.savefig(out, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return out, [f for *_, f in panels]
