#!/usr/bin/env python
"""Benchmark: the true-model oracle by kexp's compiled SQP (``controller.solver=sqp``) against CasADi + IPOPT
(``controller.solver=ipopt``, the previous code's oracle), side by side in one process.

    python benchmarks/oracle.py                     # 4 systems × 5 ICs, the tables' horizon, 1 s and 3 s; 2 s loops
    python benchmarks/oracle.py --ics 10 --T 3      # more
    python benchmarks/oracle.py --baseline b6d2237  # the IPOPT oracle as committed at a revision (its whole kexp)

Problem: each system of the results tables (Van der Pol, pendulum, Duffing, cart pendulum; library defaults,
|u| ≤ 5, Δ = 0.01, q = r = 1, LQR terminal cost, RK4 with 4 substeps), at the initial conditions of its committed
oracle runs (the first ``--ics`` rows of ``results/<system>_nmpc.csv``: the ICs the tables' J* were measured at).

* **objective**: each IC solved cold (zero initial inputs) by both; the largest |J_sqp − J_ipopt| over the ICs,
  absolute and relative to J_ipopt (target: within 1e-6 of IPOPT's converged objective on every IC).
* **step time**: a closed loop of ``--T`` seconds from each IC for each oracle, the two loops stepped alternately
  (SQP step k, IPOPT step k, …) so machine load hits both alike; ``ControlStep.solve_time`` of every step but the
  first (the cold one); medians and p99 over all ICs; the ratio of medians (target ≥ 10×).  The plant is the
  same RK4 map of the true F and G.  ``J loop`` is the largest relative difference of the two closed loops' costs.
* horizons: the results tables' (``oracle_horizon`` in ``results/sweep_lib.sh``: 20 steps, 100 for the cart
  pendulum), 1 s (100 steps) and, for Van der Pol, the long-horizon option: 3 s (300 steps, unblocked).

Threads: OMP/OPENBLAS/MKL_NUM_THREADS=1 before numpy is imported (MUMPS and DAQP are sequential anyway).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
import time
import warnings
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
warnings.simplefilter("ignore", FutureWarning)     # casadi's notice about numpy functions on casadi values

from kexp.control.oracle import NmpcOracle  # noqa: E402
from kexp.control.sqp_oracle import SqpOracle  # noqa: E402
from kexp.systems import library  # noqa: E402

TABLES_HORIZON = {"cart_pendulum": 100}          # results/sweep_lib.sh oracle_horizon: 20 steps, else these
SYSTEMS = {"vanderpol": "VanDerPol", "pendulum": "Pendulum", "duffing": "Duffing", "cart_pendulum": "CartPendulum"}


def load_baseline(rev: str):
    """The kexp package as committed at ``rev`` (``git archive``), renamed kexp_baseline_<sha> so that it imports
    beside today's (its relative imports are unchanged; absolute ``kexp`` imports are renamed)."""
    import importlib
    sha = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout.strip()
    name = f"kexp_baseline_{sha}"
    base = Path(tempfile.gettempdir()) / f"{name}-src"
    if not (base / name).exists():
        base.mkdir(parents=True, exist_ok=True)
        tar = subprocess.run(["git", "archive", sha, "kexp"], cwd=ROOT, check=True, capture_output=True).stdout
        tmp = base / "kexp.tar"
        tmp.write_bytes(tar)
        with tarfile.open(tmp) as t:
            t.extractall(base, filter="data")
        for py in (base / "kexp").rglob("*.py"):
            text = py.read_text()
            py.write_text(text.replace("from kexp.", f"from {name}.").replace("import kexp.", f"import {name}."))
        (base / "kexp").rename(base / name)
    sys.path.insert(0, str(base))
    return importlib.import_module(f"{name}.control.oracle"), importlib.import_module(f"{name}.systems.library"), sha


def ics_of(system: str, k: int) -> np.ndarray:
    rows = np.genfromtxt(ROOT / "results" / f"{system}_nmpc.csv", delimiter=",", names=True, dtype=None,
                         encoding="utf-8")
    return np.array([[r["x0_1"], r["x0_2"]] for r in rows[:k]], float)


def run(system_key, ics, horizon, cfg, T, ipopt_cls, ipopt_lib):
    sys_new = getattr(library, SYSTEMS[system_key])()
    sys_old = getattr(ipopt_lib, SYSTEMS[system_key])()
    sqp = SqpOracle(sys_new, cfg, -5, 5, horizon_steps=horizon, dt=0.01)
    ipo = ipopt_cls(sys_old, cfg, -5, 5, horizon_steps=horizon, dt=0.01)
    dj_abs = dj_rel = 0.0
    for x0 in ics:
        sqp.reset()
        ipo.reset()
        a, b = sqp.step(x0), ipo.step(x0)
        if a.status != "solved" or b.status != "solved":
            print(f"  {system_key} x0={x0}: sqp {a.qp_status}, ipopt {b.qp_status}", file=sys.stderr)
        d = abs(sqp.last_objective - ipo.last_objective)
        dj_abs, dj_rel = max(dj_abs, d), max(dj_rel, d / ipo.last_objective)
    ts, ti, iters, jl = [], [], [], 0.0
    steps = int(round(T / 0.01))
    for x0 in ics:
        sqp.reset()
        ipo.reset()
        xs, xi, js, ji = x0.copy(), x0.copy(), 0.0, 0.0
        for k in range(steps):
            a, b = sqp.step(xs), ipo.step(xi)
            if k:
                ts.append(a.solve_time)
                ti.append(b.solve_time)
                iters.append(a.iterations)
            for x, u, acc in ((xs, a.u, "s"), (xi, b.u, "i")):
                c = 0.01 * (float(x @ x) + float(u @ u))
                js, ji = (js + c, ji) if acc == "s" else (js, ji + c)
            xs = sqp.simulate(xs, np.repeat(a.u[None], sqp.nb, 0))[1]
            xi = sqp.simulate(xi, np.repeat(b.u[None], sqp.nb, 0))[1]
        jl = max(jl, abs(js - ji) / ji)
    ts, ti = np.array(ts) * 1e3, np.array(ti) * 1e3
    return dict(dj_abs=dj_abs, dj_rel=dj_rel, s_med=np.median(ts), s_p99=np.percentile(ts, 99),
                i_med=np.median(ti), i_p99=np.percentile(ti, 99), ratio=np.median(ti) / np.median(ts),
                iters=np.median(iters), jl=jl)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ics", type=int, default=5, help="ICs per system (the first rows of results/<system>_nmpc.csv)")
    ap.add_argument("--T", type=float, default=2.0, help="closed-loop seconds per IC")
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=list(SYSTEMS))
    ap.add_argument("--no-long", action="store_true", help="skip the 3-s horizon row")
    ap.add_argument("--baseline", metavar="REV", default=None, help="IPOPT oracle from this git revision's kexp")
    args = ap.parse_args(argv)
    if args.baseline:
        old_oracle, old_lib, sha = load_baseline(args.baseline)
        ipopt_cls, ipopt_lib, label = old_oracle.NmpcOracle, old_lib, f"IPOPT @ {sha}"
    else:
        ipopt_cls, ipopt_lib, label = NmpcOracle, library, "IPOPT (today's NmpcOracle)"
    print(f"oracle benchmark: kexp SQP vs {label}; {args.ics} ICs per system, {args.T:g} s loops, "
          f"{time.strftime('%Y-%m-%d %H:%M')}\n")
    print("| system | horizon | max abs. ΔJ (SQP − IPOPT) | max rel. ΔJ | SQP median / p99 ms | IPOPT median / p99 ms "
          "| IPOPT / SQP | SQP iterations (median) | closed-loop J rel. diff |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    ratios = []
    for key in args.systems:
        ics = ics_of(key, args.ics)
        horizons = sorted({TABLES_HORIZON.get(key, 20), 100} | ({300} if key == "vanderpol" and not args.no_long
                                                                  else set()))
        for horizon in horizons:
            r = run(key, ics, horizon, None, args.T, ipopt_cls, ipopt_lib)
            ratios.append(r["ratio"])
            h = f"{horizon} steps" + (" (tables)" if horizon == TABLES_HORIZON.get(key, 20) else "")
            print(f"| {key} | {h} | {r['dj_abs']:.1e} | {r['dj_rel']:.1e} | {r['s_med']:.2f} / {r['s_p99']:.2f} | "
                  f"{r['i_med']:.2f} / {r['i_p99']:.2f} | **{r['ratio']:.1f}×** | {r['iters']:.0f} | {r['jl']:.1e} |",
                  flush=True)
    print(f"\ntargets: ≥ 10× per step (min ratio {min(ratios):.1f}×); objective within 1e-6 of IPOPT's on every IC")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
