"""Figures from logs and sweeps (matplotlib, Agg backend, PNG):

- ``paper_figure``: open-loop (u = 0) versus closed-loop trajectories, states and input over time and the phase
  portrait, like the paper's Figures 2 and 3;
- ``roa_figure`` (kexp/analysis/roa.py): success over a grid/sample of initial conditions with Ω_r and Ω_r̂ drawn
  in x-space, one row of panels per group of runs, projections onto state pairs for n > 2;
- ``theorem1_figure``: the Theorem 1 bound beside the measured prediction error.

    kexp-figures paper RUN.mcap -o fig.png
    kexp-figures roa SWEEP_DIR -o roa.png
    kexp-figures roa RESULTS.csv [...] --oracle ORACLE.csv -o map.png   (region map: cost ratio to the oracle,
                                                                         kexp/analysis/region_map.py)
    kexp-figures theorem1 RUN_DIR -o thm1.png      (RUN_DIR holds run.mcap and model.npz; or RUN_DIR/run.mcap)

``-o`` names the file to write; its suffix picks the format (.png, .pdf, .svg, ...: matplotlib's), none means .png.
Bad input (a log without steps, CSVs of two systems, an option the kind does not use, ...) is one line on stderr,
``kexp-figures: error: ...``, and exit code 2.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ..app.aggregate import ReportError
from ..app.results import oserror, split_name
from ..cli import Parser
from ..errors import KexpError, SystemDefinitionError
from ..recording.reader import LogError, log_path, read_log
from .roa import _plt, omega_curves, roa_figure  # noqa: F401  (roa_figure: kexp-figures roa; re-exported)


class FigureError(KexpError):
    """The input cannot be drawn (a log without steps) or the figure cannot be written where ``-o`` says."""


def _arr(msgs, key):
    return np.array([m[key] for m in msgs], dtype=float)


def _steps(log, path, least: int = 1) -> list[dict]:
    """The log's /step messages; FigureError when it holds fewer than ``least``."""
    steps = log.messages("/step")
    if not steps:
        raise FigureError(f"{path}: no steps in the log (no /step message): the run stopped, or its file was cut, "
                          "before its first step; pass the log of a run that simulated")
    if len(steps) < least:
        raise FigureError(f"{path}: {len(steps)} step in the log, {least} needed; pass the log of a longer run")
    return steps


def out_path(out: str | Path) -> Path:
    """The file ``-o`` names as it will be written: '.png' added when it has no suffix; FigureError when it is a
    folder, its format is not one matplotlib writes or its folder does not exist."""
    from matplotlib.backend_bases import FigureCanvasBase
    out = Path(out)
    if not out.suffix and not out.is_dir():
        out = out.with_name(out.name + ".png")
    if out.is_dir():
        raise FigureError(f"-o {out}: is a folder; give the file to write, e.g. {out / 'figure.png'}")
    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    if out.suffix[1:].lower() not in formats:
        raise FigureError(f"-o {out}: matplotlib cannot write {out.suffix} files; end the name with one of "
                          f"{', '.join('.' + f for f in formats)}")
    if not out.parent.is_dir():
        raise FigureError(f"-o {out}: {out.parent} " + ("is not a folder" if out.parent.exists() else
                                                         "does not exist") + "; create it or choose another -o")
    return out


def _bounds(ctrl: dict) -> list[tuple[str, list[float]]]:
    """[("u_min", values), ("u_max", values)] of the controller's config, those it holds as numbers."""
    out = []
    for key in ("u_min", "u_max"):
        try:
            v = np.atleast_1d(np.asarray(ctrl.get(key), dtype=float)).ravel()
        except (TypeError, ValueError):
            continue
        if v.size and np.all(np.isfinite(v)):
            out.append((key, sorted(set(v.tolist()))))
    return out


def paper_figure(mcap: str | Path, out: str | Path) -> Path:
    """The log's closed loop (and open loop: the plant integrated with u = 0) into ``out`` (:func:`out_path`):
    the states and the input u(t) over time, stacked on the left (u with the controller's u_min and u_max, when
    the log's /config holds them), and the phase portrait with Ω_r, Ω_r̂ on the right.  Returns the path written."""
    out = out_path(out)
    log = read_log(mcap)
    steps, ol = _steps(log, mcap), log.messages("/open_loop")
    names = (log.one("/model") or {}).get("state_names") or [f"x{i + 1}" for i in range(len(steps[0]["x"]))]
    t, x = _arr(steps, "t"), _arr(steps, "x")
    u = np.array([np.atleast_1d(np.asarray(m["u"], float)) for m in steps])
    cfg = (log.one("/config") or {}).get("config") or {}
    plt = _plt()
    fig = plt.figure(figsize=(13.5, 6.4))
    gs = fig.add_gridspec(2, 2, width_ratios=[1.3, 1], height_ratios=[1.5, 1])
    ax_x = fig.add_subplot(gs[0, 0])
    ax_u = fig.add_subplot(gs[1, 0], sharex=ax_x)
    ax_p = fig.add_subplot(gs[:, 1])
    for i, nm in enumerate(names):
        line, = ax_x.plot(t, x[:, i], label=f"{nm} closed loop")
        if ol:
            ax_x.plot(_arr(ol, "t"), _arr(ol, "x")[:, i], "--", alpha=0.7, color=line.get_color(),
                      label=f"{nm} open loop (u = 0)")
    ax_x.set_xlabel("t [s]")
    ax_x.set_ylabel("state")
    ax_x.set_title("states over time")
    # the legends outside the axes (a trajectory or Ω_r can cover any corner: the pendulum's open loop does)
    ax_x.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), framealpha=0.85,
                ncol=2 if len(names) > 4 else 1)
    # u_k is held over [t_k, t_k+1): steps from each t_k, the last one drawn to the end of its step
    dt = t[-1] - t[-2] if len(t) > 1 else 0.0
    tt, uu = np.append(t, t[-1] + dt), np.vstack([u, u[-1:]])
    for j in range(u.shape[1]):
        ax_u.plot(tt, uu[:, j], drawstyle="steps-post", label="u" if u.shape[1] == 1 else f"u{j + 1}")
    for key, values in _bounds(cfg.get("controller") or {}):
        for k, v in enumerate(values):
            ax_u.axhline(v, ls="--", lw=1, color="tab:red" if key == "u_max" else "tab:purple",
                         label=f"{key} = {v:g}" if k == 0 else None)
    ax_u.set_xlabel("t [s]")
    ax_u.set_ylabel("u")
    ax_u.set_title("input (closed loop)")
    ax_u.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), framealpha=0.85)
    if x.shape[1] >= 2:  # n > 2: the projection onto the first two states, and the title says so
        if ol:
            xo = _arr(ol, "x")
            ax_p.plot(xo[:, 0], xo[:, 1], "--", color="gray", label="open loop (u = 0)")
        ax_p.plot(x[:, 0], x[:, 1], label="closed loop")
        ax_p.plot(x[0, 0], x[0, 1], "o", label="x0")
        for b, hat, label in omega_curves(log.one("/clf") or {}):
            ax_p.plot(b[:, 0], b[:, 1], "g:" if hat else "g-", lw=1, label=label)
        ax_p.set_xlabel(names[0])
        ax_p.set_ylabel(names[1])
        ax_p.set_title("phase portrait" if x.shape[1] == 2 else
                       f"phase portrait, projection onto ({names[0]}, {names[1]}) of {x.shape[1]} states")
        ax_p.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, framealpha=0.85)
    else:
        ax_p.set_visible(False)
    name = (cfg.get("system") or {}).get("name")  # a log written from Python may have no /config
    head = "open loop (u = 0) vs closed loop"
    fig.suptitle(f"{name}: {head}" if name else head)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def theorem1_figure(run_dir: str | Path, out: str | Path, horizon: float = 2.0) -> tuple[Path, dict]:
    """The bound and the measured error of the model's open-loop prediction under the logged inputs, over the
    first ``horizon`` seconds of the run.  ``run_dir``: the run's folder (run.mcap and model.npz) or its run.mcap."""
    from ..app.build import build_system
    from ..identify import KoopmanBilinearModel
    from .theorem1 import estimate_constants, measured_error
    out = out_path(out)
    run_dir = Path(run_dir)
    if run_dir.is_file() or (run_dir.suffix == ".mcap" and not run_dir.is_dir()):
        if run_dir.suffix != ".mcap":
            raise FigureError(f"{run_dir}: not a run folder nor an .mcap log; pass the run's folder (holding "
                              "run.mcap and model.npz) or its run.mcap")
        run_dir, mcap = run_dir.parent, run_dir
    else:
        mcap = log_path(run_dir)
    log = read_log(mcap)
    model = KoopmanBilinearModel.load(run_dir / "model.npz")
    cfg = (log.one("/config") or {}).get("config") or {}
    try:
        system = build_system(cfg["system"])
    except SystemDefinitionError as exc:  # a user's module (system.name=module:Class) not on PYTHONPATH here
        raise SystemDefinitionError(f"{run_dir}: cannot rebuild the run's system: {exc}") from None
    steps = _steps(log, mcap, least=2)
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
    ax.semilogy(tt[1:], err[1:], label=r"measured $\|x(t) - \hat{x}(t)\|$")
    ax.semilogy(tt[1:], bound[1:], "--", label=f"Theorem 1 bound (ν = {consts.nu:.3g}, l_x = {consts.l_x:.3g})")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$\|x(t) - \hat{x}(t)\|$")
    ax.legend(fontsize=8, loc="best", framealpha=0.85)
    name = (cfg.get("system") or {}).get("name") or "system"
    ax.set_title(f"prediction error vs Theorem 1: {name}, first {tt[-1]:.3g} s", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out, {"nu": consts.nu, "l_x": consts.l_x, "max_ratio_error_to_bound": float(np.max(err[1:] / bound[1:]))}


def main(argv=None) -> None:
    p = Parser(prog="kexp-figures", description="Figures from kexp logs and sweeps.")
    p.add_argument("kind", choices=["paper", "roa", "theorem1"])
    p.add_argument("source", nargs="+", help="run.mcap (paper), a sweep folder or results CSVs (roa), a run folder "
                   "or its run.mcap (theorem1)")
    p.add_argument("-o", "--out", required=True, help="the figure to write (.png; .pdf, .svg, ... by the suffix)")
    p.add_argument("--oracle", help="roa from results CSVs: the oracle's CSV over the same x0 (a region map)")
    args = p.parse_args(argv)
    try:
        _check_sources(args)
        out = out_path(args.out)
    except (FigureError, ReportError) as exc:      # ReportError: a CSV name that is not <system>_<configuration>
        _fail(str(exc))
    source = args.source[0]
    try:
        if args.kind == "paper":
            out = paper_figure(source, out)
        elif args.kind == "roa" and args.oracle:
            from .region_map import region_map
            out, panels = region_map(args.source, args.oracle, out)
            for f in panels:
                print(f"{f['label']}: success {f['successes']}/{f['runs']}, where the oracle succeeds "
                      f"{f['both']}/{f['oracle_successes']}, J/J_oracle min {f['min_ratio']:.3f}, median "
                      f"{f['median_ratio']:.3f}, worst {f['worst_ratio']:.3f}")
        elif args.kind == "roa":
            out, facts = roa_figure(source, out)
            for g in facts["groups"]:
                print(f"{g['label']}: n = {g['n']}, success {g['successes']}/{g['runs']}"
                      + (f" ({g['runs'] - g['drawn']} without a usable x0, not drawn)" if g["drawn"] < g["runs"]
                         else ""))
            for f in facts["failed"][:20]:
                print(f"  error: {f['job']} {f['overrides']}: {f['reason']}")
            if len(facts["failed"]) > 20:
                print(f"  ... and {len(facts['failed']) - 20} more (kexp-report lists them all)")
        else:
            out, facts = theorem1_figure(source, out)
            print(f"ν = {facts['nu']:.4g}, l_x = {facts['l_x']:.4g}, max error/bound = "
                  f"{facts['max_ratio_error_to_bound']:.3g}")
    except (KexpError, LogError, KeyError) as exc:  # e.g. the run's own system module not importable
        _fail(str(exc))
    except OSError as exc:
        _fail(oserror(exc))
    print(f"wrote {out}")
    sys.exit(0)


def _fail(message: str) -> None:
    print(f"kexp-figures: error: {message}", file=sys.stderr)
    sys.exit(2)


def _check_sources(args) -> None:
    """FigureError (one line) when the sources or --oracle do not fit the kind."""
    csvs = [s for s in args.source if s.endswith(".csv")]
    if args.kind != "roa" and args.oracle:
        raise FigureError(f"--oracle is for roa with results CSVs (a region map); {args.kind} does not use it: "
                          "drop it")
    if args.kind == "roa" and csvs:
        if len(csvs) != len(args.source):
            others = [s for s in args.source if not s.endswith(".csv")]
            raise FigureError(f"roa takes one sweep folder, or results CSVs with --oracle, not both: {others[0]} "
                              "is not a .csv")
        if not args.oracle:
            system = split_name(csvs[0])[0]
            raise FigureError(f"--oracle is missing: a region map from results CSVs needs the oracle's CSV over the "
                              f"same x0, e.g. --oracle {Path(csvs[0]).with_name(f'{system}_nmpc.csv')}")
    elif args.kind == "roa" and args.oracle:
        raise FigureError("--oracle is for a region map from results CSVs (kexp-results collect); a sweep folder's "
                          "roa figure does not use it: drop it, or pass the sweep's results CSVs")
    elif len(args.source) != 1:
        raise FigureError(f"{args.kind} takes one source, got {len(args.source)}: "
                          + {"paper": "one run.mcap", "roa": "one sweep folder (or results CSVs with --oracle)",
                             "theorem1": "one run folder"}[args.kind])


if __name__ == "__main__":
    main()
