#!/usr/bin/env python
"""Per-step time of the working presets' LMPC (issue 13's budget: median RTI step ≤ 0.5 ms).

For each preset (default: ``vanderpol`` and ``pendulum``, both a 20-step horizon with the terminal cost) the script
composes the preset as ``kexp +experiment=<preset>`` would, runs it once through ``kexp.app.experiment.run`` to build
the model, CLF and controller exactly as a run does (model cache in --cache), then runs the closed loop
(``kexp.simulate.closed_loop``, the true system) from the first --ics initial conditions of
``default_rng(42).uniform(-1, 1, (2, 100)).T`` for --T seconds, --repeat times.  The step time is
``ControlStep.solve_time``; the first step of each run is left out.  With ``--baseline REV`` the LMPC of
kexp.control as committed at git revision REV runs on the same model, CLF and settings, interleaved with today's
per x0 and repetition, and the table gives the ratio of the medians and the largest difference of the applied
inputs.  With ``--solvers ipm daqp piqp`` the same controller with each ``qp_solver`` runs interleaved with it
(and the baseline) per x0 and repetition, each with the same ratio and input-difference columns against today's.
One BLAS thread.

    python benchmarks/presets.py [--baseline 4cd09f5] [--solvers daqp] [--presets vanderpol pendulum] [--ics 3]
                                 [--T 5] [--repeat 2]
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lmpc import load_baseline  # noqa: E402


def build(preset: str, cache: str):
    """(system, model, clf, controller) of the preset, built by a short kexp run."""
    from hydra import compose, initialize_config_dir

    import kexp.app.experiment as app
    from kexp.app.conf import CONF_DIR
    overrides = [f"+experiment={preset}", "logging.rrd=false", "logging.progress=false", f"cache.dir={cache}",
                 "sim.T=0.1"]
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    got = {}
    real = app.build_controller

    def capture(spec, system, model, clf, **kw):
        ctrl = real(spec, system, model, clf, **kw)
        got.update(ctrl=ctrl, system=system, model=model, clf=clf)
        return ctrl

    app.build_controller = capture
    try:
        with tempfile.TemporaryDirectory() as out:
            app.run(cfg, out, echo=lambda *a, **k: None)
    finally:
        app.build_controller = real
    return got["system"], got["model"], got["clf"], got["ctrl"]


def old_config(old_mod, cfg):
    """Today's LmpcConfig as the baseline's own class: the fields it has, a QP solver it knows (else its default)."""
    fields = {f.name for f in dataclasses.fields(old_mod.LmpcConfig)}
    kw = {k: v for k, v in dataclasses.asdict(cfg).items() if k in fields}
    if "qp_solver" in kw and kw["qp_solver"] not in getattr(old_mod, "SOLVERS", ()):
        kw.pop("qp_solver")
    return old_mod.LmpcConfig(**kw)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["vanderpol", "pendulum"])
    ap.add_argument("--baseline", metavar="REV", default=None)
    ap.add_argument("--solvers", nargs="*", default=[], help="other qp_solver values to run side by side")
    ap.add_argument("--ics", type=int, default=3)
    ap.add_argument("--T", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "kexp-bench-cache"))
    args = ap.parse_args()
    from kexp.simulate import SimConfig, closed_loop

    load0 = os.getloadavg()
    old_mod, sha = load_baseline(args.baseline) if args.baseline else (None, None)
    print("# Per-step time of the working presets' LMPC")
    print()
    print(f"- date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}; {platform.node()}, {os.cpu_count()} CPUs; load average "
          f"at start {load0[0]:.2f}; one BLAS thread")
    print(f"- {args.ics} x0 (first of default_rng(42).uniform(-1, 1, (2, 100)).T) × {args.T:g} s × {args.repeat} "
          "repetitions; step time ControlStep.solve_time, each run's first step left out"
          + (f"; baseline {sha} interleaved per x0 and repetition" if sha else ""))
    print()
    head = ["preset", "horizon", "steps", "median ms", "p99 ms"]
    if sha:
        head += [f"median ms, {sha}", f"p99 ms, {sha}", "ratio of medians", "max |Δu|"]
    rows, side = [], []
    for preset in args.presets:
        print(f"building {preset} ...", file=sys.stderr)
        system, model, clf, ctrl = build(preset, args.cache)
        ctrls = {"today": ctrl}
        if old_mod is not None:
            ctrls["old"] = old_mod.Lmpc(model, clf, ctrl.law, old_config(old_mod, ctrl.cfg), ctrl.u_min, ctrl.u_max)
        for solver in args.solvers:
            cfg = dataclasses.replace(ctrl.cfg, qp_solver=solver)
            ctrls[solver] = type(ctrl)(model, clf, ctrl.law, cfg, ctrl.u_min, ctrl.u_max)
        times = {key: [] for key in ctrls}
        du = 0.0
        dus = {key: 0.0 for key in ctrls}
        ics = np.random.default_rng(42).uniform(-1, 1, (2, 100)).T[: args.ics]
        for _ in range(args.repeat):
            for x0 in ics:
                runs = {}
                for key, c in ctrls.items():
                    runs[key] = closed_loop(system, c, x0, SimConfig(T=args.T), model=model, lyap=clf.lyap)
                    times[key] += [r.solve_time for r in runs[key].records[1:]]
                if "old" in runs:
                    du = max(du, float(np.max(np.abs(runs["old"].u - runs["today"].u))))
                for key in runs:
                    dus[key] = max(dus[key], float(np.max(np.abs(runs[key].u - runs["today"].u))))
        t = np.array(times["today"]) * 1e3
        row = [preset, str(ctrl.cfg.horizon), str(len(t)), f"{np.median(t):.3f}", f"{np.percentile(t, 99):.3f}"]
        if "old" in times:
            o = np.array(times["old"]) * 1e3
            row += [f"{np.median(o):.3f}", f"{np.percentile(o, 99):.3f}", f"{np.median(o) / np.median(t):.2f}×",
                    f"{du:.1e}"]
        rows.append(row)
        for solver in args.solvers:
            o = np.array(times[solver]) * 1e3
            side.append([preset, f"{ctrl.cfg.qp_solver} (today's)", f"{np.median(t):.3f}",
                         f"{np.percentile(t, 99):.3f}", "1.00×", "0"] if solver == args.solvers[0] else [])
            side.append([preset, solver, f"{np.median(o):.3f}", f"{np.percentile(o, 99):.3f}",
                         f"{np.median(o) / np.median(t):.2f}×", f"{dus[solver]:.1e}"])
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    if side:
        print()
        print("| preset | qp_solver | median ms | p99 ms | median / today's | max |Δu| vs today's |")
        print("|---|---|---:|---:|---:|---:|")
        for row in side:
            if row:
                print("| " + " | ".join(row) + " |")
    print()
    print(f"load average at end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
