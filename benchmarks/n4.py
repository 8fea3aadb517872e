#!/usr/bin/env python
"""Four states: the cart-pole of examples/cartpole4.py (a user's own class) through every stage, per dictionary
degree (issue 33, item 6).

For each degree the preset ``+experiment=cartpole4`` is composed as the kexp command composes it (with
``dictionary.degree=D`` and any --set overrides), and the stages run one after the other as a run does them,
each timed (wall clock, one BLAS thread): data (simulated trajectories), identification (EDMD, eigenfunctions,
B and b), the CLF's P (``clf.method``: Riccati or the SDP), the certificate (Proposition 1 and V̇ at the sampled
states), the controller's construction (numba's compiled kernels loaded from its cache: run once before to
compile), then the closed loop on the true cart-pole from --ics initial states (default_rng(0) uniform in
±(0.3 m, 0.2 rad, 0.3 m/s, 0.3 rad/s)) for --T s.  The table gives k, the stage times, the LMPC step's median and
p99 (ControlStep.solve_time, each run's first step left out) against Δ, and the closed-loop successes
(‖x(T)‖ < sim.tol).

    PYTHONPATH=.:examples python benchmarks/n4.py [--degrees 3 4 5] [--ics 3] [--T 8] [--set key=value ...]
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))


def compose(degree: int, extra: list[str]):
    from hydra import compose as hcompose, initialize_config_dir
    from kexp.app.conf import CONF_DIR
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return hcompose(config_name="config", overrides=["+experiment=cartpole4", f"dictionary.degree={degree}",
                                                         *extra])


def stages(degree: int, extra: list[str], ics: np.ndarray, T: float, echo=print) -> dict:
    """Run the stages for one degree; returns the row's numbers."""
    from kexp.app.build import (build_clf, build_controller, build_controller_spec, build_data, build_dictionary,
                                build_identification, build_system)
    from kexp.app.experiment import config_dict
    from kexp.clf.synthesis import clf_from_P, solve_lqr_x, solve_sdp
    from kexp.data import collect
    from kexp.identify import identify
    from kexp.simulate import SimConfig, closed_loop
    cfg = compose(degree, extra)
    cd = config_dict(cfg)
    system = build_system(cd["system"])
    sampler, data_cfg = build_data(cfg["data"])
    ident_cfg = build_identification(cfg["identification"])
    clf_cfg = build_clf(cfg["clf"])
    spec = build_controller_spec(cfg["controller"])
    out: dict = {"degree": degree}
    t = time.perf_counter()
    data = collect(system, sampler, data_cfg)
    out["data_s"] = time.perf_counter() - t
    t = time.perf_counter()
    dictionary = build_dictionary(cfg["dictionary"], system.n, data, system.equilibrium)
    model = identify(system, data, dictionary, ident_cfg)
    out["identify_s"] = time.perf_counter() - t
    out["k"] = model.k
    out["pred_err"] = model.report["prediction_error"]
    t = time.perf_counter()
    P, *_ = (solve_sdp if clf_cfg.method == "sdp" else solve_lqr_x)(model, clf_cfg)
    out["clf_s"] = time.perf_counter() - t
    t = time.perf_counter()
    clf = clf_from_P(model, P, clf_cfg, law=spec.law, u_min=spec.u_min, u_max=spec.u_max,
                     law_params=spec.law_params, progress=echo)
    out["certificate_s"] = time.perf_counter() - t
    out["n_samples"] = clf.certificate.n_samples
    t = time.perf_counter()
    ctrl = build_controller(spec, system, model, clf)
    out["controller_s"] = time.perf_counter() - t
    times, ok, costs = [], 0, []
    sim = SimConfig(T=T, dt=data_cfg.dt, tol=float(cfg["sim"]["tol"]))
    for x0 in ics:
        ctrl.reset()
        t = time.perf_counter()
        res = closed_loop(system, ctrl, x0, sim, model=model, lyap=clf.lyap)
        echo(f"  degree {degree}: x0 = {np.round(x0, 3).tolist()}: {res.status}, ‖x(T)‖ = "
             f"{res.metrics.final_error:.2e}, J = {res.metrics.cost:.4f} ({time.perf_counter() - t:.1f} s)")
        times += [r.solve_time for r in res.records[1:]]
        ok += bool(res.metrics.success)
        costs.append(res.metrics.cost)
    ms = np.array(times) * 1e3
    out.update(step_median_ms=float(np.median(ms)), step_p99_ms=float(np.percentile(ms, 99)), dt_ms=data_cfg.dt * 1e3,
               success=ok, runs=len(ics), cost_median=float(np.median(costs)))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--degrees", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--ics", type=int, default=3)
    ap.add_argument("--T", type=float, default=8.0)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="more overrides of the preset")
    args = ap.parse_args()
    half = np.array([0.3, 0.2, 0.3, 0.3])
    ics = np.random.default_rng(0).uniform(-half, half, (args.ics, 4))
    load0 = os.getloadavg()
    rows = []
    for d in args.degrees:
        print(f"degree {d} ...", file=sys.stderr)
        rows.append(stages(d, args.set, ics, args.T, echo=lambda s: print(s, file=sys.stderr)))
    print("# The 4-state cart-pole (examples/cartpole4.py, +experiment=cartpole4) per dictionary degree")
    print()
    print(f"- {time.strftime('%Y-%m-%d %H:%M:%S %Z')}; {platform.node()}, {os.cpu_count()} CPUs, load average at "
          f"start {load0[0]:.2f}; one BLAS thread; overrides: {' '.join(args.set) or 'none'}")
    print(f"- closed loop: {args.ics} x0 from default_rng(0) in ±{half.tolist()}, {args.T:g} s")
    print()
    print("| degree | k | data [s] | identification [s] | CLF P [s] | certificate [s] (samples) | controller [s] | "
          "step median / p99 [ms] | Δ [ms] | success | median J |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['degree']} | {r['k']} | {r['data_s']:.2f} | {r['identify_s']:.2f} | {r['clf_s']:.3f} | "
              f"{r['certificate_s']:.2f} ({r['n_samples']}) | {r['controller_s']:.2f} | "
              f"{r['step_median_ms']:.2f} / {r['step_p99_ms']:.2f} | {r['dt_ms']:g} | {r['success']}/{r['runs']} | "
              f"{r['cost_median']:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
