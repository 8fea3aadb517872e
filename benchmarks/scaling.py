#!/usr/bin/env python
"""How the LMPC's step time grows with the model size k, the horizon and the number of inputs (issue 14).

Models (identified from data like any run, EDMD on monomials, CLF by the Riccati of the model's linearisation,
h = the model's LQR gain, |u| ≤ 5):

* k = 20: Van der Pol, 2 states, degree 5 (the paper's size), one input;
* k = 34: a 3-state system, degree 4: Van der Pol driven through a first-order lag (ẋ1 = x2,
  ẋ2 = μ(1 − x1²)x2 − x1 + x3, ẋ3 = −2x3 + u), one input;
* k = 55: the same 3-state system, degree 5, one input;
* k = 20, m = 2: the slow-manifold system with both states actuated (2 states, degree 5, two inputs: the
  LMPC's general path, a matrix exponential per block and a Van Loan series per step, not the one-input
  polynomial).

For each model and horizon Np ∈ {50, 100, 200} (move blocking: 5 free moves, 20 blocks — the QP has 20·m + 1
variables whatever the horizon), the RTI LMPC runs the closed loop on the true system from 3 initial conditions
(default_rng(0), within ±0.8 of x_eq) for --T seconds, and the whole grid is measured --repeats times, cells
interleaved and the order rotated each pass (a shared VM's speed drifts by tens of per cent within a minute); the
table gives the median over the passes of each pass's median step time and the p99 of all the passes' step times
(``ControlStep.solve_time``, the first step of each run left out), the memory a step holds
(``kexp.control.memory.memory_estimate``, the model the memory budget uses), and the growth exponents fitted by least
squares on log-log axes: time ∝ k^a at Np = 100 (one input; over the models that form a block's map the same way,
and over all) and time ∝ Np^b per model.  The table says which
way each model forms the ZOH map of a block: the polynomial in u (:mod:`kexp.control.zoh_poly`, one input, when
its degree stays ≤ 40 on |u| ≤ 5) or the matrix exponential and its Fréchet derivatives.  A plot of the medians
goes to --plot (default docs/figures/lmpc_scaling.png).  One BLAS thread.

    python benchmarks/scaling.py [--T 3] [--repeats 3] [--plot docs/figures/lmpc_scaling.png]
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import ClassVar  # noqa: E402

import numpy as np  # noqa: E402

from kexp.clf import ClfConfig, synthesize_clf  # noqa: E402
from kexp.control import make_law  # noqa: E402
from kexp.control.lmpc import Lmpc, LmpcConfig  # noqa: E402
from kexp.control.memory import memory_estimate  # noqa: E402
from kexp.data import Box, DataConfig, collect  # noqa: E402
from kexp.dictionary import Monomials  # noqa: E402
from kexp.identify import identify  # noqa: E402
from kexp.simulate import SimConfig, closed_loop  # noqa: E402
from kexp.systems import SlowManifold, VanDerPol  # noqa: E402
from kexp.systems.base import ControlAffineSystem  # noqa: E402

HORIZONS = (50, 100, 200)


@dataclass(frozen=True)
class LaggedVanDerPol(ControlAffineSystem):
    """Van der Pol driven through a first-order lag: a 3-state system with one input (a user's own system)."""

    mu: float = 1.0
    name: ClassVar[str] = "lagged_vanderpol"
    n: ClassVar[int] = 3
    m: ClassVar[int] = 1
    constant_input_matrix: ClassVar[bool] = True

    def drift(self, x):
        x = np.asarray(x, dtype=float)
        x1, x2, x3 = x[..., 0], x[..., 1], x[..., 2]
        return np.stack([x2, self.mu * (1.0 - x1 ** 2) * x2 - x1 + x3, -2.0 * x3], axis=-1)

    def input_matrix(self, x):
        x = np.asarray(x)
        g = np.zeros(x.shape[:-1] + (3, 1))
        g[..., 2, 0] = 1.0
        return g


def build(system, degree: int, n_traj: int):
    """Model, CLF and law of ``system`` from unforced data over the box ±1.5."""
    n = system.n
    data = collect(system, Box(n_traj, (-1.5,) * n, (1.5,) * n), DataConfig(T=5.0))
    model = identify(system, data, Monomials(n, degree))
    cfg = ClfConfig(method="lqr_x", grid=11 if n == 3 else 41)
    clf = synthesize_clf(model, cfg)
    law = make_law("model_lqr", clf.lyap, -5.0, 5.0, model=model, weights=(cfg.q_x, cfg.r_u))
    return model, clf, law


def measure(system, model, clf, law, horizon: int, T: float) -> dict:
    """One pass over a cell: 3 closed-loop runs; the step times [ms] (first step of each run left out)."""
    cfg = LmpcConfig(horizon=horizon, terminal=1.0)
    ctrl = Lmpc(model, clf, law, cfg, -5.0, 5.0)
    rng = np.random.default_rng(0)
    times = []
    for _ in range(3):
        x0 = system.equilibrium + rng.uniform(-0.8, 0.8, system.n)
        run = closed_loop(system, ctrl, x0, SimConfig(T=T), model=model, lyap=clf.lyap)
        times += [r.solve_time for r in run.records[1:]]
    path = f"polynomial, degree {ctrl.zoh.degree}" if ctrl.zoh is not None else "expm + Fréchet per block"
    return {"times": np.array(times) * 1e3, "mem": memory_estimate(cfg, model.k, model.m), "nu": ctrl.nu,
            "path": path}


def summarise(passes: list[dict]) -> dict:
    """The median over the passes of each pass's median, the p99 of all the passes' step times."""
    pooled = np.concatenate([p["times"] for p in passes])
    return {**passes[0], "median": float(np.median([np.median(p["times"]) for p in passes])),
            "p99": float(np.percentile(pooled, 99)), "spread": (min(np.median(p["times"]) for p in passes),
                                                             max(np.median(p["times"]) for p in passes))}


def slope(x, y) -> float:
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--T", type=float, default=3.0, help="simulated seconds per run (3 runs per cell)")
    ap.add_argument("--repeats", type=int, default=3, help="passes over the whole grid, interleaved")
    ap.add_argument("--plot", default="docs/figures/lmpc_scaling.png", help="the PNG ('' for none)")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    cases = [("Van der Pol, 2 states, degree 5", VanDerPol(), 5, 100),
             ("lagged Van der Pol, 3 states, degree 4", LaggedVanDerPol(), 4, 200),
             ("lagged Van der Pol, 3 states, degree 5", LaggedVanDerPol(), 5, 300),
             ("slow manifold, 2 states, degree 5, both actuated", SlowManifold(inputs="both"), 5, 100)]
    built = {}
    for label, system, degree, n_traj in cases:
        t0 = time.perf_counter()
        built[label] = (system, *build(system, degree, n_traj))
        model = built[label][1]
        print(f"[{label}: k = {model.k}, m = {model.m}, built in {time.perf_counter() - t0:.1f} s]", flush=True)
    cells = [(label, horizon) for label, *_ in cases for horizon in HORIZONS]
    passes: dict = {cell: [] for cell in cells}
    for rep in range(args.repeats):
        t0 = time.perf_counter()
        shift = rep * len(cells) // max(args.repeats, 1)
        for label, horizon in cells[shift:] + cells[:shift]:
            system, model, clf, law = built[label]
            passes[(label, horizon)].append(measure(system, model, clf, law, horizon, args.T))
        print(f"[pass {rep + 1}/{args.repeats} in {time.perf_counter() - t0:.1f} s]", flush=True)
    results = {(label, h): (built[label][1].k, built[label][1].m, summarise(passes[(label, h)]))
               for label, h in cells}
    print(f"\n- date {time.strftime('%Y-%m-%d %H:%M')}; {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs; load average {load0[0]:.2f} at the start, {os.getloadavg()[0]:.2f} at the end; "
          f"one BLAS thread; RTI, 5 free moves / 20 blocks, {args.T:g} s × 3 runs per cell and pass, "
          f"{args.repeats} passes\n")
    print("| model | k | m | ZOH map per block | horizon | QP variables | step median [ms] | p99 [ms] | "
          "passes' medians [ms] | memory of a step [kB] |")
    print("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|")
    for (label, horizon), (k, m, r) in results.items():
        print(f"| {label} | {k} | {m} | {r['path']} | {horizon} | {r['nu'] + 1} | {r['median']:.3f} | "
              f"{r['p99']:.3f} | {r['spread'][0]:.3f}–{r['spread'][1]:.3f} | {r['mem'] / 1e3:.0f} |")
    print()
    one = [(k, r["median"], r["path"]) for (label, h), (k, m, r) in results.items() if h == 100 and m == 1]
    poly = [(k, t) for k, t, path in one if path.startswith("polynomial")]
    if len(poly) >= 2:   # fit only like with like: the two ways of forming a block's map differ by a lot
        print(f"- growth with k at horizon 100 (one input, the models on the polynomial path: k = "
              f"{', '.join(str(k) for k, _ in poly)}): time ∝ k^{slope(*zip(*poly)):.2f}")
    print(f"- growth with k at horizon 100 (one input, all models: k = {', '.join(str(k) for k, _, _ in one)}): "
          f"time ∝ k^{slope(*zip(*[(k, t) for k, t, _ in one])):.2f}")
    for label, *_ in cases:
        hs = [(h, results[(label, h)][2]["median"]) for h in HORIZONS]
        print(f"- growth with the horizon, {label}: time ∝ Np^{slope(*zip(*hs)):.2f}")
    if args.plot:
        from kexp.analysis.roa import _plt
        plt = _plt()
        fig, ax = plt.subplots(figsize=(6, 4))
        for label, *_ in cases:
            k, m, _r = results[(label, HORIZONS[0])]
            ax.loglog(HORIZONS, [results[(label, h)][2]["median"] for h in HORIZONS], "o-",
                      label=f"k = {k}, m = {m} ({label.split(',')[0]})")
        ax.set_xlabel("horizon Np (steps)")
        ax.set_ylabel("step time, median (ms)")
        ax.set_xticks(HORIZONS, [str(h) for h in HORIZONS])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title("LMPC step (RTI, 20 move blocks)")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"\nplot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
