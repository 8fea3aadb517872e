#!/usr/bin/env python
"""Benchmark: the LMPC's QP on kexp's interior point (kexp.control.ipm), DAQP and PIQP, on the same real QPs.

Captures every one-row QP (``Lmpc.qp_f``) the LMPC solves in closed loop on two problems: the Van der Pol preset
(``kexp +experiment=vanderpol``, built as benchmarks/presets.py builds it; 3 x0 × 5 s) and the benchmark problem
of ``benchmarks/lmpc.py`` (k = 20, horizon 100, 20 blocks, x0 (0.548, 0.817), 2 s).  Each solver
(``DenseQp(solver=…)``) then solves each problem's QPs in their closed-loop order, so DAQP's warm start is the
previous QP's active set as in a run:

- tight loop: one solver runs the whole sequence, ``--reps`` times; per QP the median over the repetitions;
- interleaved: the solvers alternate per QP (ipm, daqp, piqp, ipm, …), ``--reps`` passes.

Times are through ``DenseQp.solve`` (the data check and conversions included).  The table gives the median and p99
over the QPs, the ratio to the IPM's median, and the solutions' agreement: the largest objective excess over the best
of the three (relative to max(1, |f|)), the largest KKT stationarity residual ‖Hx + g + Aᵀλ‖∞ with λ ≥ 0 fitted by
non-negative least squares on the constraints active within 1e-6 (computed here, not by the solvers), the largest
constraint violation, and the largest distance from a bound that DAQP's solution holds active.  One BLAS thread.

    python benchmarks/qp.py [--reps 20] [--problems preset benchmark]
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import nnls  # noqa: E402

from kexp.control.qp import DenseQp  # noqa: E402
from kexp.simulate import SimConfig, closed_loop  # noqa: E402

SOLVERS = ("ipm", "daqp", "piqp")


def _grab(ctrl, qps):
    solve = ctrl.qp_f.solve

    def grab(H, g, G, h_u, x_l, x_u):
        qps.append(tuple(np.array(a) for a in (H, g, G, h_u, x_l, x_u)))
        return solve(H, g, G, h_u, x_l, x_u)
    ctrl.qp_f.solve = grab


def benchmark_qps():
    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, LmpcConfig, make_law
    from kexp.data import Circle, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    ctrl = Lmpc(model, clf, make_law("sontag", clf.lyap, -5.0, 5.0), LmpcConfig(), -5.0, 5.0)
    qps = []
    _grab(ctrl, qps)
    closed_loop(s, ctrl, np.array([0.548, 0.817]), SimConfig(T=2.0), model=model, lyap=clf.lyap)
    return qps


def preset_qps(cache):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from presets import build
    system, model, clf, ctrl = build("vanderpol", cache)
    qps = []
    _grab(ctrl, qps)
    for x0 in np.random.default_rng(42).uniform(-1, 1, (2, 100)).T[:3]:
        ctrl.reset()
        closed_loop(system, ctrl, x0, SimConfig(T=5.0), model=model, lyap=clf.lyap)
    return qps


def kkt(qp, x, tol=1e-6):
    """(stationarity, violation): ‖Hx + g + Aᵀλ‖∞ with λ ≥ 0 on the constraints active within tol (NNLS), and the
    largest violation of Gx ≤ h, x_l ≤ x ≤ x_u."""
    H, g, G, h, xl, xu = qp
    n = len(x)
    rows, viol = [], 0.0
    r = G @ x - h
    viol = max(viol, float(np.max(r, initial=0.0)), float(np.max(xl - x)), float(np.max(x - xu)))
    for i in range(len(h)):
        if r[i] >= -tol * max(1.0, abs(h[i])):
            rows.append(G[i])
    for j in range(n):
        e = np.zeros(n)
        if x[j] <= xl[j] + tol * max(1.0, abs(xl[j])):
            e[j] = -1.0
            rows.append(e)
        elif x[j] >= xu[j] - tol * max(1.0, abs(xu[j])):
            e[j] = 1.0
            rows.append(e)
    grad = H @ x + g
    if not rows:
        return float(np.max(np.abs(grad))), viol
    A = np.array(rows)
    lam, _ = nnls(A.T, -grad)
    return float(np.max(np.abs(grad + A.T @ lam))), viol


def daqp_gap(qp, x, xd, tol=1e-9):
    """The largest distance of x from the bounds (and rows) that DAQP's solution xd holds active (within tol)."""
    H, g, G, h, xl, xu = qp
    gap = 0.0
    for lo_hi, cur, ref in ((xl, x, xd), (xu, x, xd)):
        fin = np.isfinite(lo_hi)
        act = fin & (np.abs(np.where(fin, ref - lo_hi, 1.0)) <= tol * np.maximum(1.0, np.abs(lo_hi)))
        if act.any():
            gap = max(gap, float(np.max(np.abs(cur[act] - lo_hi[act]))))
    act = np.abs(G @ xd - h) <= tol * np.maximum(1.0, np.abs(h))
    if act.any():
        gap = max(gap, float(np.max(np.abs((G @ x - h)[act]))))
    return gap


def measure(qps, reps):
    n = qps[0][0].shape[0]
    tight = {s: np.zeros((reps, len(qps))) for s in SOLVERS}
    inter = {s: np.zeros((reps, len(qps))) for s in SOLVERS}
    sols = {}
    for s in SOLVERS:                                    # tight loop: one solver, the whole sequence
        qp_obj = DenseQp(n, 1, solver=s)
        qp_obj.solve(*qps[0])
        for rep in range(reps):
            xs = []
            for i, qp in enumerate(qps):
                t = time.perf_counter()
                res = qp_obj.solve(*qp)
                tight[s][rep, i] = time.perf_counter() - t
                assert res.success, (s, i, res.status)
                xs.append(res.x)
        sols[s] = xs
    objs = {s: DenseQp(n, 1, solver=s) for s in SOLVERS}
    for s in SOLVERS:
        objs[s].solve(*qps[0])
    for rep in range(reps):                              # interleaved: the solvers alternate per QP
        for i, qp in enumerate(qps):
            for s in SOLVERS:
                t = time.perf_counter()
                objs[s].solve(*qp)
                inter[s][rep, i] = time.perf_counter() - t
    rows = {}
    for s in SOLVERS:
        excess = stat = viol = gap = 0.0
        for i, qp in enumerate(qps):
            H, g = qp[0], qp[1]
            f = {t: 0.5 * sols[t][i] @ H @ sols[t][i] + g @ sols[t][i] for t in SOLVERS}
            best = min(f.values())
            excess = max(excess, (f[s] - best) / max(1.0, abs(best)))
            st, vi = kkt(qp, sols[s][i])
            stat, viol = max(stat, st), max(viol, vi)
            gap = max(gap, daqp_gap(qp, sols[s][i], sols["daqp"][i]))
        tm, im = np.median(tight[s], axis=0) * 1e6, np.median(inter[s], axis=0) * 1e6
        rows[s] = (np.median(tm), np.percentile(tm, 99), np.median(im), np.percentile(im, 99),
                   excess, stat, viol, gap)
    return rows, {s: np.max(np.abs(np.array(sols[s]) - np.array(sols["daqp"]))) for s in SOLVERS}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--problems", nargs="+", default=["preset", "benchmark"], choices=["preset", "benchmark"])
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "kexp-bench-cache"))
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    print("# The LMPC's QPs: kexp's interior point, DAQP and PIQP side by side\n")
    for prob in args.problems:
        qps = preset_qps(args.cache) if prob == "preset" else benchmark_qps()
        rows, dx = measure(qps, args.reps)
        n = qps[0][0].shape[0]
        print(f"## {prob}: {len(qps)} QPs ({n} variables, 1 row) from closed-loop runs, {args.reps} repetitions\n")
        print("| solver | tight median / p99 (µs) | ratio to ipm | interleaved median / p99 (µs) | objective excess "
              "| stationarity | violation | gap at DAQP's active set | max \\|x − x_daqp\\| |")
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        for s, (tm, tp, im, ip, ex, st, vi, gp) in rows.items():
            print(f"| {s} | {tm:.1f} / {tp:.1f} | {tm / rows['ipm'][0]:.2f} | {im:.1f} / {ip:.1f} | {ex:.1e} | "
                  f"{st:.1e} | {vi:.1e} | {gp:.1e} | {dx[s]:.1e} |")
        print()
    print(f"Load average {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end; {os.cpu_count()} CPUs; "
          "one BLAS thread.")


if __name__ == "__main__":
    main()
