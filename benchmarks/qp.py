#!/usr/bin/env python
"""Benchmark: the LMPC's QP on kexp's interior point (kexp.control.ipm) against PIQP, on the same QPs.

Captures every one-row QP (``Lmpc.qp_f``) the default LMPC solves in a 2-s closed loop of the benchmark problem of
``benchmarks/lmpc.py`` (Van der Pol, k = 20, horizon 100, 20 blocks: 21 variables), then solves every 10th of them
with ``DenseQp(solver='ipm')`` and ``DenseQp(solver='piqp')``, ``--reps`` times each, the two solvers alternating
per QP (so machine noise hits both alike).  Prints the median over the QPs of each QP's median time, in the solver
(``QpResult.solve_time``) and through ``DenseQp.solve`` (guard and conversions included), the iteration counts,
and the largest difference between the two solutions and objectives (and which objective is lower).  One BLAS thread.

    python benchmarks/qp.py [--reps 20]
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from kexp.clf import ClfConfig, synthesize_clf  # noqa: E402
from kexp.control import Lmpc, LmpcConfig, make_law  # noqa: E402
from kexp.control.qp import DenseQp  # noqa: E402
from kexp.data import Circle, DataConfig, collect  # noqa: E402
from kexp.dictionary import Monomials  # noqa: E402
from kexp.identify import identify  # noqa: E402
from kexp.simulate import SimConfig, closed_loop  # noqa: E402
from kexp.systems import VanDerPol  # noqa: E402


def captured_qps():
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    ctrl = Lmpc(model, clf, make_law("sontag", clf.lyap, -5.0, 5.0), LmpcConfig(), -5.0, 5.0)
    qps, solve = [], ctrl.qp_f.solve

    def grab(H, g, G, h_u, x_l, x_u):
        qps.append(tuple(np.array(a) for a in (H, g, G, h_u, x_l, x_u)))
        return solve(H, g, G, h_u, x_l, x_u)
    ctrl.qp_f.solve = grab
    closed_loop(s, ctrl, np.array([0.548, 0.817]), SimConfig(T=2.0), model=model, lyap=clf.lyap)
    return qps


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=20)
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    qps = captured_qps()[::10]
    n = qps[0][0].shape[0]
    solvers = {name: DenseQp(n, 1, solver=name) for name in ("ipm", "piqp")}
    inner = {name: [] for name in solvers}
    outer = {name: [] for name in solvers}
    iters = {name: [] for name in solvers}
    dx = dobj = 0.0
    worse = -np.inf                                   # the largest f_ipm − f_piqp (> 0: ipm's worse)
    for qp in qps:
        H, g = qp[0], qp[1]
        sol = {}
        for name, solver in solvers.items():
            res = solver.solve(*qp)                   # warm: PIQP's set-up on its first call
            a, b = [], []
            for _ in range(args.reps):
                t = time.perf_counter()
                res = solver.solve(*qp)
                b.append(time.perf_counter() - t)
                a.append(res.solve_time)
            assert res.success, (name, res.status)
            inner[name].append(np.median(a))
            outer[name].append(np.median(b))
            iters[name].append(res.iterations)
            sol[name] = res.x
        f = {name: 0.5 * x @ H @ x + g @ x for name, x in sol.items()}
        dx = max(dx, float(np.max(np.abs(sol["ipm"] - sol["piqp"]))))
        dobj = max(dobj, abs(f["ipm"] - f["piqp"]) / max(1.0, abs(f["piqp"])))
        worse = max(worse, f["ipm"] - f["piqp"])
    print(f"# The LMPC's QP ({n} variables, 1 row): kexp's interior point vs PIQP\n")
    print(f"- {len(qps)} QPs captured from a 2-s closed loop of benchmarks/lmpc.py's problem, {args.reps} solves "
          f"each, solvers alternating per QP; load average {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at "
          "the end; one BLAS thread\n")
    print("| solver | in the solver, µs (median) | DenseQp.solve, µs (median) | iterations (median / max) |")
    print("|---|---:|---:|---:|")
    for name in solvers:
        print(f"| {name} | {1e6 * np.median(inner[name]):.1f} | {1e6 * np.median(outer[name]):.1f} | "
              f"{np.median(iters[name]):g} / {max(iters[name])} |")
    print(f"\nPIQP / ipm: {np.median(inner['piqp']) / np.median(inner['ipm']):.2f}× in the solver, "
          f"{np.median(outer['piqp']) / np.median(outer['ipm']):.2f}× through DenseQp.solve.  Largest difference "
          f"of the solutions {dx:.1e}, of the objectives {dobj:.1e} (relative); "
          f"the largest f_ipm − f_piqp {worse:.1e} ({'ipm never worse' if worse <= 1e-12 else 'ipm worse somewhere'}: "
          "an interior point stops short of active bounds, by ~1e-6 here for ipm and up to ~2e-4 for PIQP).")


if __name__ == "__main__":
    main()
