"""Figures from logs and sweeps (matplotlib, Agg backend, PNG):

- ``paper_figure``: open-loop versus closed-loop trajectories, states over time and the phase portrait, like the
  paper's Figures 2 and 3;
- ``roa_figure`` (kexp/analysis/roa.py): success over a grid/sample of initial conditions with Ω_r and Ω_r̂ drawn
  in x-space, one row of panels per group of runs, projections onto state pairs for n > 2;
- ``theorem1_figure``: the Theorem 1 bound beside the measured prediction error.

    kexp-figures paper RUN.mcap -o fig.png
    kexp-figures roa SWEEP_DIR -o roa.png
    kexp-figures roa RESULTS.csv [...] --oracle ORACLE.csv -o map.png   (region map: cost ratio to the oracle,
                                                                         kexp/analysis/region_map.py)
    kexp-figures theorem1 RUN_DIR -o thm1.png      (RUN_DIR holds run.mcap and model.npz)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..errors import KexpError, SystemDefinitionError
from ..recording.reader import LogError, read_log
from .roa import _plt, roa_figure  # noqa: F401  (roa_figure: kexp-figures roa; re-exported)


def _arr(msgs, key):
    return np.array([m[key] for m in msgs], dtype=float)


def paper_figure(mcap: str | Path, out: str | Path) -> Path:
    log = read_log(mcap)
    steps, ol = log.messages("/step"), log.messages("/open_loop")
    names = (log.one("/model") or {}).get("state_names") or [f"x{i + 1}" for i in range(len(steps[0]["x"]))]
    t, x = _arr(steps, "t"), _arr(steps, "x")
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, nm in enumerate(names):
        ax[0].plot(t, x[:, i], label=f"{nm} closed loop")
        if ol:
            ax[0].plot(_arr(ol, "t"), _arr(ol, "x")[:, i], "--", alpha=0.7, label=f"{nm} open loop")
    ax[0].set_xlabel("t [s]")
    ax[0].set_title("states over time")
    ax[0].legend(fontsize=8)
    if x.shape[1] >= 2:  # n > 2: the projection onto the first two states, and the title says so
        if ol:
            xo = _arr(ol, "x")
            ax[1].plot(xo[:, 0], xo[:, 1], "--", color="gray", label="open loop")
        ax[1].plot(x[:, 0], x[:, 1], label="closed loop")
        ax[1].plot(x[0, 0], x[0, 1], "o", label="x0")
        clf = log.one("/clf") or {}
        for key, style in (("boundary_r", "g-"), ("boundary_r_hat", "g:")):
            b = np.asarray(clf.get(key) or [], float)
            if b.size:
                b = np.vstack([b, b[:1]])
                ax[1].plot(b[:, 0], b[:, 1], style, lw=1, label="Ω_r" if key == "boundary_r" else "Ω_r̂")
        ax[1].set_xlabel(names[0])
        ax[1].set_ylabel(names[1])
        ax[1].set_title("phase portrait" if x.shape[1] == 2 else
                        f"phase portrait, projection onto ({names[0]}, {names[1]}) of {x.shape[1]} states")
        ax[1].legend(fontsize=8)
    else:
        ax[1].set_visible(False)
    cfg = (log.one("/config") or {}).get("config") or {}
    name = (cfg.get("system") or {}).get("name")  # a log written from Python may have no /config
    fig.suptitle(f"{name}: open loop vs closed loop" if name else "open loop vs closed loop")
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def theorem1_figure(run_dir: str | Path, out: str | Path, horizon: float = 2.0) -> tuple[Path, dict]:
    """The bound and the measured error of the model's open-loop prediction under the logged inputs, over the
    first ``horizon`` seconds of the run."""
    from ..app.build import build_system
    from ..identify import KoopmanBilinearModel
    from .theorem1 import estimate_constants, measured_error
    run_dir = Path(run_dir)
    log = read_log(run_dir / "run.mcap")
    model = KoopmanBilinearModel.load(run_dir / "model.npz")
    cfg = (log.one("/config") or {}).get("config") or {}
    try:
        system = build_system(cfg["system"])
    except SystemDefinitionError as exc:  # a user's module (system.name=module:Class) not on PYTHONPATH here
        raise SystemDefinitionError(f"{run_dir}: cannot rebuild the run's system: {exc}") from None
    steps = log.messages("/step")
    t, x, u = _arr(steps, "t"), _arr(steps, "x"), _arr(steps, "u")
    ctrl = cfg.get("controller") or {}
    k = min(len(u) - 1, int(round(horizon / model.dt)))
    consts = estimate_constants(system, model, u_min=ctrl.get("u_min", -5.0), u_max=ctrl.get("u_max", 5.0),
                                horizon=horizon, extra=[(x[0], u[:k])])
    err = measured_error(model, t[: k + 1], x[: k + 1], u[:k])
    tt = t[: len(err)] - t[0]
    bound = consts.bound(tt)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(tt[1:], err[1:], label="measured ‖x(t) − x̂(t)‖")
    ax.semilogy(tt[1:], bound[1:], "--", label=f"Theorem 1 bound (ν = {consts.nu:.3g}, l_x = {consts.l_x:.3g})")
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8)
    ax.set_title("prediction error vs Theorem 1")
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out, {"nu": consts.nu, "l_x": consts.l_x, "max_ratio_error_to_bound": float(np.max(err[1:] / bound[1:]))}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="kexp-figures", description="Figures from kexp logs and sweeps.")
    p.add_argument("kind", choices=["paper", "roa", "theorem1"])
    p.add_argument("source", nargs="+", help="run.mcap (paper), a sweep folder or results CSVs (roa), a run folder "
                   "(theorem1)")
    p.add_argument("-o", "--out", required=True, help="the PNG to write")
    p.add_argument("--oracle", help="roa from results CSVs: the oracle's CSV over the same x0 (a region map)")
    args = p.parse_args(argv)
    csvs = [s for s in args.source if s.endswith(".csv")]
    if args.kind == "roa" and (csvs or args.oracle):
        if len(csvs) != len(args.source) or not args.oracle:
            p.error("a region map takes results CSVs only (kexp-results collect) and --oracle ORACLE.csv")
    elif len(args.source) != 1:
        p.error(f"{args.kind} takes one source, got {len(args.source)}")
    source = args.source[0]
    try:
        if args.kind == "paper":
            out = paper_figure(source, args.out)
        elif args.kind == "roa" and args.oracle:
            from .region_map import region_map
            out, panels = region_map(args.source, args.oracle, args.out)
            for f in panels:
                print(f"{f['label']}: success {f['successes']}/{f['runs']}, where the oracle succeeds "
                      f"{f['both']}/{f['oracle_successes']}, J/J_oracle median {f['median_ratio']:.3f}, worst "
                      f"{f['worst_ratio']:.3f}")
        elif args.kind == "roa":
            out, facts = roa_figure(source, args.out)
            for g in facts["groups"]:
                print(f"{g['label']}: n = {g['n']}, success {g['successes']}/{g['runs']}"
                      + (f" ({g['runs'] - g['drawn']} without a usable x0, not drawn)" if g["drawn"] < g["runs"]
                         else ""))
            for f in facts["failed"][:20]:
                print(f"  failed: {f['job']} {f['overrides']}: {f['reason']}")
            if len(facts["failed"]) > 20:
                print(f"  ... and {len(facts['failed']) - 20} more (kexp-report lists them all)")
        else:
            out, facts = theorem1_figure(source, args.out)
            print(f"ν = {facts['nu']:.4g}, l_x = {facts['l_x']:.4g}, max error/bound = "
                  f"{facts['max_ratio_error_to_bound']:.3g}")
    except (KexpError, LogError, OSError, KeyError) as exc:  # e.g. the run's own system module not importable
        print(f"kexp-figures: error: {exc}", file=sys.stderr)
        sys.exit(2)
    print(f"wrote {out}")
    sys.exit(0)


if __name__ == "__main__":
    main()
