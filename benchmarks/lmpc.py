#!/usr/bin/env python
"""Benchmark: per-step solve time and closed-loop cost of kexp's LMPC (SQP, QP on kexp's IPM) against CasADi + IPOPT.

    python benchmarks/lmpc.py                      # 5 ICs, T = 10 s, move blocking (default LmpcConfig)
    python benchmarks/lmpc.py --quick              # 2 ICs, T = 3 s
    python benchmarks/lmpc.py --no-blocking-too    # also the three controllers with blocks=None

Problem: Van der Pol, Monomials(2, 5) (N = 21 functions, k = 20 eigen-coordinates), CLF from ClfConfig(), Sontag
law h on |u| ≤ 5, the LMPC of eq. 21 with LmpcConfig() (horizon 100, 5 free moves / 20 blocks).  Controllers:

* ``rti``       — ``Lmpc(LmpcConfig())``: SQP, one QP per step (real-time iteration, max_iter = 1) on kexp's compiled
                  interior point (``qp_solver='ipm'``, the default);
* ``rti_piqp``  — the same with ``qp_solver='piqp'``: the QP on PIQP, side by side;
* ``sqp``       — ``Lmpc(LmpcConfig(max_iter=20, tol=1e-6))``: SQP iterated to convergence;
* ``ipopt``     — the same problem solved by CasADi + IPOPT (see below).

Each controller runs the closed loop (``kexp.simulate.closed_loop``, the true system, Δ = 0.01) from the same initial
conditions, the first ``--n-ics`` of ``default_rng(42).uniform(-1, 1, (2, 100)).T``; the controllers are interleaved
per IC (IC1: rti, sqp, ipopt; IC2: ...) so machine noise hits all alike.  The step time is ``ControlStep.solve_time``
(wall clock of the whole ``step()`` call, inside the controller).  The first step of every run is left out of the
percentiles and reported on its own (it holds one-time set-up: PIQP's setup on the first call, a cold warm start).

The IPOPT baseline is ``kexp.control.bilinear_nlp.IpoptLmpc``: the same NLP (variables, multiple shooting, cost, slack,
(21e)/(21f) switching, bounds, warm start, IPOPT options tol 1e-10, bound_relax_factor 0, exact Hessian, MUMPS,
``step()``, fallback).  Its step map is the exact zero-order hold of the bilinear model, written symbolically in one
of two equal forms (``discretisation``): 'exact' inlines q = 3 substeps of a 13-term Taylor series with the
input-dependent matrix A_u, and CasADi's exact Hessian and Jacobian then grow with k² · horizon — measured on this
model (k = 20): horizon 5 — build 5 s, 0.6 GB, 650 ms/step; horizon 10 — 11 s, 1.5 GB, 1.5 s/step; horizon 20 —
28 s, 3.5 GB, 3.4 s/step; horizon 100 would need ≈ 17 GB (a build was stopped at 12.7 GB).  'polynomial' (the
default for one input, used here with ``--ipopt poly``) regroups the same map as a polynomial in u with constant
matrix coefficients, z⁺ = Σ_d u^d (C_d z + c_d) (degree 39 = 3 · 13; trailing terms below 1e-18 relative dropped,
degree 8 kept here), so ∂z⁺/∂z is a polynomial in u and CasADi's derivatives stay small.  The script prints the
difference between the two forms on random (z, u) and, unless ``--skip-oracle-check``, solves a short horizon (10
steps, 2 free moves / 5 blocks) with both and prints the differences.  ``--ipopt exact`` benchmarks the 'exact'
form (only feasible for short horizons).

Threads: OMP/OPENBLAS/MKL_NUM_THREADS=1 are set before numpy is imported and ``threadpoolctl.threadpool_limits(1)``
holds for the whole script (numba kernels are serial, CasADi's map is serial, MUMPS is sequential).
OPENBLAS_CORETYPE is left as it is.

``--baseline REV`` adds ``rti_old``: the RTI of kexp.control as committed at git revision REV (e.g. ef2bfbd, before
issue 14), loaded next to today's package (``load_baseline``) and interleaved with it per IC and per repetition.

Output (stdout): a Markdown header, the per-controller table, the speed ratios, the targets of issue 14 (RTI median
≤ 0.4 ms, p99 ≤ 0.8 ms; ≥ 300× faster than IPOPT at the same closed-loop cost within 0.1 %), and a breakdown
of the RTI step over 200 repetitions from one state (rollout and sensitivities vs condensing vs the QP vs the rest),
measured by wrapping those functions in this script, with the step's floating-point work counted from the sizes
(``step_flops``), the achieved GFLOP/s and the lower bound on the step time at the one-thread peak of a large
matrix product measured in the same run (``peak_gflops``).  Progress goes to stderr.
"""
from __future__ import annotations

import os

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
for _v in THREAD_VARS:
    os.environ[_v] = "1"

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from dataclasses import replace  # noqa: E402

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_info, threadpool_limits  # noqa: E402

_THREAD_LIMITS = threadpool_limits(1)  # kept alive for the whole script

TARGET_MEDIAN_MS = 0.4      # issue 14 item 1 (the earlier targets were 2 ms, 10 ms, 50x, 1 %)
TARGET_P99_MS = 0.8
TARGET_SPEEDUP = 300.0
TARGET_COST_TOL = 0.001
SUCCESS_TOL = 1e-2          # SimConfig's default: ‖x(T) − x_eq‖ < 1e-2


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------------- IPOPT baseline
def polynomial_vs_oracle_step(model, n: int = 500) -> tuple[float, int, int]:
    """Max relative difference (‖·‖∞ / ‖exact‖∞) between IpoptLmpc's two symbolic forms of the exact step,
    'polynomial' and 'exact', on random z (standard normal, k) and u ∈ [−5, 5]; also the terms kept and the full
    degree of the polynomial."""
    from kexp.control.bilinear_nlp import _step_order, bilinear_step_function, polynomial_terms, step_polynomial

    q, p, umax = _step_order(model, -5.0, 5.0, None)
    C = step_polynomial(model.Lambda, model.B, model.b, model.dt, q, p)
    poly = bilinear_step_function(model, -5.0, 5.0, "polynomial")
    ref = bilinear_step_function(model, -5.0, 5.0, "exact")
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(n):
        z = rng.standard_normal(model.k)
        u = rng.uniform(-5.0, 5.0, 1)
        a = np.asarray(ref(z, u), float).ravel()
        c = np.asarray(poly(z, u), float).ravel()
        worst = max(worst, float(np.max(np.abs(a - c)) / np.max(np.abs(a))))
    return worst, polynomial_terms(C, umax), C.shape[0] - 1


def oracle_check(model, clf, law, ics):
    """IpoptLmpc with the polynomial form vs the exact (nested Taylor) form on a short horizon, cold start."""
    from kexp.control import LmpcConfig
    from kexp.control.bilinear_nlp import IpoptLmpc

    cfg = LmpcConfig(horizon=10, free_moves=2, blocks=5)
    t0 = time.perf_counter()
    ship = IpoptLmpc(model, clf, law, cfg, -5.0, 5.0, discretisation="exact")
    t_ship = time.perf_counter() - t0
    t0 = time.perf_counter()
    poly = IpoptLmpc(model, clf, law, cfg, -5.0, 5.0, discretisation="polynomial")
    t_poly = time.perf_counter() - t0
    rows = []
    for i, x0 in enumerate(ics):
        z0 = model.lift(x0)
        out = []
        for c in (ship, poly):
            c.reset()
            st = c.step(x0, z0)
            out.append((st, c.last_plan.copy(), c.last_objective))
        (s1, p1, o1), (s2, p2, o2) = out
        rows.append([f"IC{i + 1}", s1.region, s1.active, f"{np.max(np.abs(p1 - p2)):.1e}",
                     f"{abs(o1 - o2) / max(abs(o1), 1e-300):.1e}", f"{s1.iterations} / {s2.iterations}",
                     f"{s1.solve_time * 1e3:.0f} / {s2.solve_time * 1e3:.1f}"])
    return rows, t_ship, t_poly


# ---------------------------------------------------------------------------------------------------- baseline
BASELINE_FILES = ("blocking.py", "expm_kernels.py", "kernels.py", "ipm.py", "qp.py", "zoh_poly.py", "condense.py",
                  "memory.py", "checks.py", "lmpc.py")
# not yet written at older revisions (a file that is missing where it was needed fails at the import)
OPTIONAL_BASELINE_FILES = ("expm_kernels.py", "ipm.py", "zoh_poly.py", "condense.py", "memory.py", "checks.py")


def load_baseline(rev: str):
    """kexp.control's LMPC as committed at git revision ``rev`` (the files BASELINE_FILES, read with ``git show``),
    imported as a package of its own next to today's, so that old and new controllers run side by side in one
    process.  ``from ..errors`` becomes ``from kexp.errors`` (unchanged module)."""
    import importlib
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parent.parent
    sha = subprocess.run(["git", "rev-parse", "--short", rev], cwd=root, check=True, capture_output=True,
                         text=True).stdout.strip()
    name = f"kexp_baseline_{sha}"
    base = Path(tempfile.gettempdir()) / name
    pkg = base / name
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    for f in BASELINE_FILES:
        got = subprocess.run(["git", "show", f"{sha}:kexp/control/{f}"], cwd=root, capture_output=True, text=True)
        if got.returncode != 0:
            if f in OPTIONAL_BASELINE_FILES:
                continue               # not yet written at that revision
            got.check_returncode()
        text = got.stdout
        (pkg / f).write_text(text.replace("from ..errors import", "from kexp.errors import"))
    sys.path.insert(0, str(base))
    return importlib.import_module(f"{name}.lmpc"), sha


# ---------------------------------------------------------------------------------------------------- flops
def step_flops(ctrl, qp_iterations: float, active: str, degrees=None) -> dict[str, float]:
    """Floating-point operations (multiply and add counted apart) of one RTI step of ``ctrl`` (an Lmpc with the
    one-input polynomial ZOH), from the algorithm's sizes: k, n = k+1, the polynomial's degree per block
    (``degrees``, the cut of kexp.control.kernels.poly_degree; default the full degree D), the block sizes,
    horizon Np, nu inputs, the step each column's block starts (f_c), and the QP's iterations.  Lower-order terms
    (vector updates of the QP, bookkeeping) are left out, so this is a lower bound on the work.
      map + derivative per block   E and dE/du by one Horner pass: 4·D_b·n²
      per step                     E·[z;1] and L·[z;1] on k rows: 4·k·n; sensitivities A·s_c on the started
                                   columns: 2·k²·(b+1)
      condensing                   H: one dot product per pair c ≤ d over the steps both are non-zero,
                                   Σ_{c≤d} 2·k·(Np − f_d); g: Σ_c 2·k·(Np − f_c) + 2·nu²; (21e) rows and V:
                                   Np·2·k² + Σ_c 2·k·(Np − f_c)
      QP (dense IPM, per iter.)    the reduced KKT matrix H + ρI + Gᵀ W G (one row), its Cholesky n_x³/3, two
                                   triangular solves 4·n_x², products with G and Gᵀ 4·n_x
    """
    k, n = ctrl.k, ctrl.k + 1
    Np, nu, nb = ctrl.cfg.horizon, ctrl.nu, ctrl.nb
    degrees = np.full(nb, ctrl.zoh.degree) if degrees is None else np.asarray(degrees)
    first = np.asarray(ctrl._first)
    nx, p = nu + 1, 1
    after = Np - first                       # steps at which each column is non-zero
    gram = sum(2 * k * after[d] * (d + 1) for d in range(nu))        # pairs c ≤ d: the later column's steps
    parts = {
        "map + derivative per block": float(np.sum(4 * degrees * n * n)),
        "per-step propagation": sum(4 * k * n + 2 * k * k * (int(b) + 1) for b in ctrl.bos),
        "condensing": gram + float(np.sum(2 * k * after)) + 2 * nu * nu
        + ((Np * 2 * k * k + float(np.sum(2 * k * after))) if active == "21e" else 0),
        "QP": qp_iterations * (p * nx * nx + nx ** 3 / 3 + 4 * nx * nx + 4 * p * nx),
    }
    parts["total"] = sum(parts.values())
    return parts


def peak_gflops(n: int = 2000, reps: int = 5) -> float:
    """The best rate of an n×n float64 matrix product on this thread (BLAS, one thread): the machine's practical
    peak, measured in the same run."""
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    a @ b
    best = np.inf
    for _ in range(reps):
        t = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t)
    return 2.0 * n ** 3 / best / 1e9


# ---------------------------------------------------------------------------------------------------- statistics
def fmt_ms(v: float) -> str:
    if not np.isfinite(v):
        return "–"
    return f"{v:.3f}" if v < 10 else (f"{v:.1f}" if v < 1000 else f"{v:.0f}")


def md_table(headers, rows) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def summarise(runs):
    """runs: list of RunResult (one per IC) → dict of statistics (times in ms)."""
    rest = np.array([r.solve_time for run in runs for r in run.records[1:]]) * 1e3
    first = np.array([run.records[0].solve_time for run in runs if run.records]) * 1e3
    iters = np.array([r.iterations for run in runs for r in run.records])
    pct = (lambda q: float(np.percentile(rest, q))) if rest.size else (lambda q: float("nan"))
    return dict(
        steps=int(sum(len(run.records) for run in runs)), timed=int(rest.size),
        median=pct(50), p95=pct(95), p99=pct(99), max=float(rest.max()) if rest.size else float("nan"),
        first_first=float(first[0]) if first.size else float("nan"),
        first_median=float(np.median(first)) if first.size else float("nan"),
        success=int(sum(run.metrics.success for run in runs)), n=len(runs),
        completed=int(sum(run.status == "completed" for run in runs)),
        costs=np.array([run.metrics.cost for run in runs]),
        fallbacks=int(sum(run.metrics.fallbacks for run in runs)),
        iters_median=float(np.median(iters)) if iters.size else float("nan"),
        iters_max=int(iters.max()) if iters.size else 0,
        total_s=float(sum(r.solve_time for run in runs for r in run.records)))


# ---------------------------------------------------------------------------------------------------- breakdown
class Snapshot:
    """Wraps an Lmpc for one closed loop and keeps (x, z, warm start) before each step."""

    def __init__(self, ctrl):
        self.ctrl, self.name, self.seen = ctrl, ctrl.name, []

    def reset(self):
        self.ctrl.reset()

    def step(self, x0, z0):
        self.seen.append((np.array(x0, float), np.array(z0, float), self.ctrl._useq.copy()))
        return self.ctrl.step(x0, z0)


def breakdown(ctrls, z0, warm, reps: int):
    """Time the parts of each ``ctrl.step`` over ``reps`` repetitions from z0 with the same warm start each time,
    the controllers alternating every repetition (so machine noise hits all alike).  Returns, per controller,
    (rows, the last ControlStep, the median step time in s)."""
    import contextlib

    accs, infos, totals = [], [], []
    with contextlib.ExitStack() as undo:
        for ctrl in ctrls:
            mod = sys.modules[type(ctrl).__module__]
            acc = dict(rs=0.0, maps=0.0, cond=0.0, qp_data=0.0, qp=0.0, solver=0.0, rollout=0.0)
            accs.append(acc)

            def timed(fn, key, acc=acc):
                def wrapper(*a, **kw):
                    t = time.perf_counter()
                    try:
                        return fn(*a, **kw)
                    finally:
                        acc[key] += time.perf_counter() - t
                return wrapper

            for qp_name in ("qp", "qp_e", "qp_f"):             # the baseline's one QP, or today's two
                qp = getattr(ctrl, qp_name, None)
                if qp is None:
                    continue
                orig_solve = qp.solve

                def solve(*a, acc=acc, orig_solve=orig_solve, **kw):
                    t = time.perf_counter()
                    try:
                        res = orig_solve(*a, **kw)
                    finally:
                        acc["qp"] += time.perf_counter() - t
                    acc["solver"] += res.solve_time
                    return res

                qp.solve = solve
                undo.callback(delattr, qp, "solve")
            if hasattr(type(ctrl), "_condense"):              # today's: block maps, then the condensing kernel
                ctrl._maps = timed(ctrl._maps, "maps")
                ctrl._condense = timed(ctrl._condense, "cond")
                undo.callback(delattr, ctrl, "_maps")
                undo.callback(delattr, ctrl, "_condense")
            elif hasattr(type(ctrl), "_sensitivity"):         # issue 14's first round: the rollout and sensitivities
                ctrl._sensitivity = timed(ctrl._sensitivity, "rs")
                undo.callback(delattr, ctrl, "_sensitivity")
            else:                                             # the baseline: its module's kernel
                orig_rs = mod.rollout_sensitivity
                setattr(mod, "rollout_sensitivity", timed(orig_rs, "rs"))
                undo.callback(setattr, mod, "rollout_sensitivity", orig_rs)
            orig_rollout = mod.rollout
            setattr(mod, "rollout", timed(orig_rollout, "rollout"))
            undo.callback(setattr, mod, "rollout", orig_rollout)
            ctrl._qp_data = timed(ctrl._qp_data, "qp_data")
            undo.callback(delattr, ctrl, "_qp_data")
            infos.append(None)
            totals.append([])
        for _ in range(5):                                      # warm-up, not counted
            for ctrl in ctrls:
                ctrl._useq = warm.copy()
                ctrl.step(None, z0)
        for acc in accs:
            for key in acc:
                acc[key] = 0.0
        for _ in range(reps):
            for i, ctrl in enumerate(ctrls):
                ctrl._useq = warm.copy()
                st = ctrl.step(None, z0)
                totals[i].append(st.solve_time)
                infos[i] = st
    out = []
    for acc, info, tt in zip(accs, infos, totals):
        total = float(np.sum(tt))
        acc["rs"] += acc["maps"] + acc["cond"]
        parts = [("rollout and sensitivities (numba; today: block maps, then one kernel that also forms H, g and the "
                  "(21e) rows)", acc["rs"]),
                 ("condensing in numpy (rest of _qp_data: H, g, G, h_u)", acc["qp_data"] - acc["rs"]),
                 ("DenseQp.solve: the solver (PIQP update + solve, or kexp's IPM)", acc["solver"]),
                 ("DenseQp.solve: guard + array conversion", acc["qp"] - acc["solver"]),
                 ("exact rollout of the applied plan (21e check)", acc["rollout"]),
                 ("rest (V, h(z), L_BV, bookkeeping, warm-start shift)",
                  total - acc["qp_data"] - acc["qp"] - acc["rollout"])]
        rows = [[name, f"{v / reps * 1e3:.3f}", f"{100 * v / total:.1f} %"] for name, v in parts]
        rows.append(["**total step** (mean; median {:.3f}, p99 {:.3f})".format(
            np.median(tt) * 1e3, np.percentile(tt, 99) * 1e3), f"{total / reps * 1e3:.3f}", "100 %"])
        out.append((rows, info, float(np.median(tt)), {k: v / reps for k, v in acc.items()}))
    return out


# ---------------------------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-ics", type=int, default=5, help="number of initial conditions (default 5)")
    ap.add_argument("--T", type=float, default=10.0, help="simulated time per run in s (default 10)")
    ap.add_argument("--quick", action="store_true", help="2 ICs, T = 3 s")
    ap.add_argument("--no-blocking-too", action="store_true", help="also the three controllers with blocks=None")
    ap.add_argument("--ipopt", choices=("poly", "exact"), default="poly",
                    help="IpoptLmpc's step map: the polynomial form (default) or the nested Taylor form "
                         "(needs ≈ 17 GB and ≈ 17 s/step at horizon 100 on this model)")
    ap.add_argument("--skip-oracle-check", action="store_true", help="skip the short-horizon check of the "
                                                                     "polynomial form against the exact form")
    ap.add_argument("--breakdown-reps", type=int, default=200)
    ap.add_argument("--baseline", metavar="REV", default=None,
                    help="also run the RTI of kexp.control as committed at git revision REV (e.g. ef2bfbd, before "
                         "issue 14), interleaved with today's, in this process (load_baseline)")
    args = ap.parse_args(argv)
    if args.quick:
        args.n_ics, args.T = 2, 3.0

    wall0 = time.perf_counter()
    load0 = os.getloadavg()
    import casadi
    import numba
    import piqp
    import scipy

    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, LmpcConfig, make_law
    from kexp.control.kernels import poly_degree
    from kexp.control.bilinear_nlp import IpoptLmpc
    from kexp.data import Circle, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.simulate import SimConfig, closed_loop
    from kexp.systems import VanDerPol

    log("identifying the model and synthesising the CLF ...")
    t0 = time.perf_counter()
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    h = make_law("sontag", clf.lyap, -5.0, 5.0)
    t_setup = time.perf_counter() - t0
    ics = np.random.default_rng(42).uniform(-1, 1, (2, 100)).T[: args.n_ics]
    sim = SimConfig(T=args.T)

    base = LmpcConfig()
    variants = [("blocked", base)]
    if args.no_blocking_too:
        variants.append(("no blocking", replace(base, free_moves=None, blocks=None)))

    def pr(line: str = "") -> None:
        print(line, flush=True)
    pr("# LMPC per-step solve time and closed-loop cost: kexp's SQP (QP on its IPM, or on PIQP) vs CasADi + IPOPT")
    pr("")
    pr(f"- date: {time.strftime('%Y-%m-%d %H:%M:%S %Z')}; host: {platform.node()}, {os.cpu_count()} CPUs, "
       f"{platform.processor() or platform.machine()}; load average at start {load0[0]:.2f} / {load0[1]:.2f}")
    pr(f"- Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
       f"numba {numba.__version__}, piqp {piqp.__version__}, casadi {casadi.__version__}")
    blas = sorted({f"{i.get('internal_api')}={i.get('num_threads')}" for i in threadpool_info()})
    pr(f"- threads: {', '.join(f'{v}=1' for v in THREAD_VARS)} set before numpy was imported; "
       f"threadpoolctl.threadpool_limits(1) for the whole script (now: {', '.join(blas) or 'no pools'}); "
       f"OPENBLAS_CORETYPE={os.environ.get('OPENBLAS_CORETYPE', 'unset')} (untouched)")
    pr(f"- problem: VanDerPol, Monomials(2, 5) (N = {model.dictionary.size}), k = {model.k}, Δ = {model.dt}; "
       f"ClfConfig() (r = {clf.r:.4g}, r̂ = {clf.r_hat:.4g}); Sontag h, |u| ≤ 5; "
       f"set-up (data, identification, CLF) {t_setup:.1f} s")
    pr(f"- LMPC: LmpcConfig() — horizon {base.horizon}, {base.free_moves} free moves / {base.blocks} blocks, "
       f"w = {base.w}, r = {base.r}, slack weight {base.slack_weight:g}")
    pr(f"- closed loop: {args.n_ics} ICs (first {args.n_ics} of default_rng(42).uniform(-1, 1, (2, 100)).T), "
       f"T = {args.T:g} s ({sim.n_steps} steps), controllers interleaved per IC; success: ‖x(T)‖ < {SUCCESS_TOL:g}")
    pr("- step time: ControlStep.solve_time (wall clock of the whole step() call); percentiles over all steps of "
       "all runs except the first step of each run, which is shown separately (first run's / median over runs)")

    if args.ipopt == "poly":
        err, keep, deg = polynomial_vs_oracle_step(model)
        pr(f"- IPOPT baseline: kexp.control.bilinear_nlp.IpoptLmpc, discretisation='polynomial' (its step map as a "
           f"polynomial in u, {keep} of {deg + 1} terms kept; max relative difference to the 'exact' form on 500 "
           f"random (z, u): {err:.1e}); tol 1e-10, bound_relax_factor 0, exact Hessian.  The 'exact' form needs "
           f"≈ 17 GB and ≈ 17 s/step at horizon 100 on this model (module docstring)")
    else:
        pr("- IPOPT baseline: kexp.control.bilinear_nlp.IpoptLmpc, discretisation='exact'")
    pr("")

    if args.ipopt == "poly" and not args.skip_oracle_check:
        log("checking IpoptLmpc's polynomial form against its exact form (horizon 10) ...")
        rows, t_ship, t_poly = oracle_check(model, clf, h, ics[:3])
        pr("## Check: IpoptLmpc, polynomial vs exact form (horizon 10, 2 free moves / 5 blocks, cold start)")
        pr("")
        pr(md_table(["IC", "region", "active", "max |ΔU|", "rel. Δ objective", "IPOPT iterations (exact / poly)",
                     "step ms (exact / poly)"], rows))
        pr(f"\nbuild time: exact {t_ship:.1f} s, poly {t_poly:.1f} s")
        pr("")

    # ------------------------------------------------------------------ controllers
    old_lmpc = None
    if args.baseline:
        old_lmpc, old_sha = load_baseline(args.baseline)
    kinds = ("rti_old", "rti_piqp", "rti", "sqp", "ipopt") if old_lmpc else ("rti_piqp", "rti", "sqp", "ipopt")

    def make(kind, cfg):
        if kind == "rti_old":
            return old_lmpc.Lmpc(model, clf, h, cfg, -5.0, 5.0)
        if kind == "rti":
            return Lmpc(model, clf, h, cfg, -5.0, 5.0)
        if kind == "rti_piqp":
            return Lmpc(model, clf, h, replace(cfg, qp_solver="piqp"), -5.0, 5.0)
        if kind == "sqp":
            return Lmpc(model, clf, h, replace(cfg, max_iter=20, tol=1e-6), -5.0, 5.0)
        return IpoptLmpc(model, clf, h, cfg, -5.0, 5.0,
                         discretisation="polynomial" if args.ipopt == "poly" else "exact")

    labels = {"rti_old": f"SQP/PIQP, RTI, before issue 14 ({old_sha if old_lmpc else ''})",
              "rti_piqp": "SQP, RTI, QP on PIQP (qp_solver='piqp')",
              "rti": "SQP, RTI (max_iter=1), QP on kexp's IPM (the default)",
              "sqp": "SQP, converged (max_iter=20, tol=1e-6)",
              "ipopt": "CasADi + IPOPT" + (" (poly form)" if args.ipopt == "poly" else "")}
    ctrls, build = {}, {}
    for vname, cfg in variants:
        for kind in kinds:
            log(f"building {kind} ({vname}) ...")
            t0 = time.perf_counter()
            ctrls[(vname, kind)] = make(kind, cfg)
            build[(vname, kind)] = time.perf_counter() - t0
    runs = {key: [] for key in ctrls}
    for i, x0 in enumerate(ics):
        for key, c in ctrls.items():
            t0 = time.perf_counter()
            run = closed_loop(s, c, x0, sim, model=model, lyap=clf.lyap)
            runs[key].append(run)
            st = np.array([r.solve_time for r in run.records[1:]]) * 1e3
            log(f"IC{i + 1} {key[1]:5s} ({key[0]}): {run.status}, {len(run.records)} steps, median "
                f"{np.median(st):.3f} ms, max {st.max():.1f} ms, J = {run.metrics.cost:.6f}, "
                f"|x(T)| = {run.metrics.final_error:.1e}, fallbacks {run.metrics.fallbacks}, "
                f"{time.perf_counter() - t0:.1f} s")

    # ------------------------------------------------------------------ tables
    for vname, cfg in variants:
        stats = {kind: summarise(runs[(vname, kind)]) for kind in kinds}
        Jref = stats["ipopt"]["costs"]
        pr(f"## Per-step solve time and closed-loop cost — {vname}"
           + ("" if vname == "blocked" else " (free_moves=None, blocks=None)"))
        pr("")
        rows = []
        for kind in kinds:
            st = stats[kind]
            ratio = st["costs"] / Jref
            rows.append([labels[kind], f"{st['steps']} ({st['timed']})", fmt_ms(st["median"]), fmt_ms(st["p95"]),
                         fmt_ms(st["p99"]), fmt_ms(st["max"]),
                         f"{fmt_ms(st['first_first'])} / {fmt_ms(st['first_median'])}",
                         f"{st['iters_median']:g} / {st['iters_max']}",
                         f"{st['success']}/{st['n']}" + ("" if st["completed"] == st["n"]
                                                         else f" ({st['n'] - st['completed']} diverged)"),
                         f"{np.median(st['costs']):.6f}", f"{np.median(ratio):.6f}", f"{np.max(ratio):.6f}",
                         st["fallbacks"], f"{build[(vname, kind)]:.1f}"])
        pr(md_table(["controller", "steps (timed)", "median ms", "p95 ms", "p99 ms", "max ms", "first step ms",
                     "iters med / max", "success", "median J", "J/J_ipopt median", "J/J_ipopt max", "fallbacks",
                     "build s"], rows))
        pr("")
        per_ic = [[f"IC{i + 1}", f"({x0[0]:+.3f}, {x0[1]:+.3f})"]
                  + [f"{runs[(vname, kind)][i].metrics.cost:.6f}" for kind in kinds]
                  + [f"{runs[(vname, kind)][i].metrics.cost / Jref[i]:.6f}" for kind in kinds[:-1]]
                  for i, x0 in enumerate(ics)]
        pr(md_table(["IC", "x0"] + [f"J {kd}" for kd in kinds] + [f"J_{kd}/J_ipopt" for kd in kinds[:-1]],
                    per_ic))
        if old_lmpc:
            du = max(float(np.max(np.abs(a.u - b.u))) for a, b in zip(runs[(vname, "rti_old")], runs[(vname, "rti")]))
            pr(f"\nRTI before vs after issue 14: max |Δu| over all closed-loop steps {du:.1e}; median step "
               f"{stats['rti_old']['median']:.3f} → {stats['rti']['median']:.3f} ms "
               f"(**{stats['rti_old']['median'] / stats['rti']['median']:.2f}×**), p99 {stats['rti_old']['p99']:.3f} "
               f"→ {stats['rti']['p99']:.3f} ms ({stats['rti_old']['p99'] / stats['rti']['p99']:.2f}×)")
        pr("")
        sp_rti = stats["ipopt"]["median"] / stats["rti"]["median"]
        sp_sqp = stats["ipopt"]["median"] / stats["sqp"]["median"]
        pr(f"Speed ratio of the median step time: IPOPT / RTI = **{sp_rti:.0f}×**, "
           f"IPOPT / converged SQP = **{sp_sqp:.1f}×** (converged SQP / RTI = "
           f"{stats['sqp']['median'] / stats['rti']['median']:.1f}×).  Total solver time over all runs: "
           + ", ".join(f"{kind} {stats[kind]['total_s']:.1f} s" for kind in kinds) + ".")
        pr("")
        if vname == "blocked":
            st = stats["rti"]
            dev = float(np.max(np.abs(st["costs"] / Jref - 1.0)))
            checks = [
                (f"RTI median step ≤ {TARGET_MEDIAN_MS:g} ms", st["median"] <= TARGET_MEDIAN_MS,
                 f"{st['median']:.3f} ms ({st['median'] / TARGET_MEDIAN_MS:.2f} × target)"),
                (f"RTI p99 step ≤ {TARGET_P99_MS:g} ms", st["p99"] <= TARGET_P99_MS,
                 f"{st['p99']:.3f} ms ({st['p99'] / TARGET_P99_MS:.2f} × target)"),
                (f"RTI ≥ {TARGET_SPEEDUP:g}× faster than IPOPT (median step)", sp_rti >= TARGET_SPEEDUP,
                 f"{sp_rti:.0f}×"),
                (f"RTI closed-loop cost within {100 * TARGET_COST_TOL:g} % of IPOPT (every IC)",
                 dev <= TARGET_COST_TOL,
                 f"max |J_rti/J_ipopt − 1| = {100 * dev:.3f} %"),
            ]
            pr("## Targets (the issue's, blocked LmpcConfig())")
            pr("")
            pr(md_table(["target", "met", "measured"], [[n, "**yes**" if ok else "**NO**", m] for n, ok, m in checks]))
            both = checks[2][1] and checks[3][1]
            pr(f"\n≥ {TARGET_SPEEDUP:g}× faster than IPOPT at the same closed-loop cost (within "
               f"{100 * TARGET_COST_TOL:g} %): "
               f"**{'met' if both else 'NOT met'}**")
            pr("")

    # ------------------------------------------------------------------ breakdown
    log("breakdown of the RTI step ...")
    snap = Snapshot(Lmpc(model, clf, h, base, -5.0, 5.0))
    closed_loop(s, snap, ics[0], sim, model=model, lyap=clf.lyap)
    recs = snap.seen
    Vs = np.array([float(clf.lyap.value(z)) for _, z, _ in recs])
    picks = []
    ring_or_out = np.flatnonzero(Vs[1:] > clf.r_hat) + 1
    inner = np.flatnonzero(Vs[1:] <= clf.r_hat) + 1
    if ring_or_out.size:
        picks.append(int(ring_or_out[len(ring_or_out) // 2]))
    if inner.size:
        picks.append(int(inner[min(len(inner) - 1, 50)]))
    pr(f"## Breakdown of the RTI step ({args.breakdown_reps} repetitions from one state, same warm start each "
       "time, after 5 warm-up steps)")
    pr("")
    pr("States from the RTI closed loop of IC1, with the warm start the controller had there.  The parts are "
       "timed by wrapping, in this script, the rollout-and-sensitivity calls (Lmpc._maps and Lmpc._condense; "
       "in a baseline Lmpc._sensitivity or its module's rollout_sensitivity), the module's rollout, DenseQp.solve and Lmpc._qp_data; 'the solver' "
       "is QpResult.solve_time (wall clock around PIQP's update()/solve() or kexp's compiled IPM).  Times are means per step"
       + (f"; the baseline ({old_sha}) and today's controller alternate every repetition." if old_lmpc else "."))
    pr("")
    peak = peak_gflops()
    pr(f"Machine limit: the best of 5 products of 2000×2000 float64 matrices on this thread (numpy/OpenBLAS, one "
       f"thread), measured now: **{peak:.1f} GFLOP/s** (load average {os.getloadavg()[0]:.2f}).")
    pr("")
    for j in picks:
        x, z, warm = recs[j]
        ctrls = [Lmpc(model, clf, h, base, -5.0, 5.0)]
        if old_lmpc:
            ctrls.insert(0, old_lmpc.Lmpc(model, clf, h, base, -5.0, 5.0))
        res = breakdown(ctrls, z, warm, args.breakdown_reps)
        rows, info, med, acc = res[-1]
        pr(f"### step {j} (t = {j * sim.dt:.2f} s), x = ({x[0]:+.4f}, {x[1]:+.4f}), region {info.region}, "
           f"constraint {info.active}, QP iterations {info.qp_iterations}")
        pr("")
        if old_lmpc:
            rows_old, _, med_old, _ = res[0]
            table = [[r_new[0], r_old[1], r_new[1], f"{float(r_old[1]) / max(float(r_new[1]), 1e-12):.2f}×",
                      r_new[2]] for r_old, r_new in zip(rows_old, rows)]
            pr(md_table(["part", f"ms / step, {old_sha}", "ms / step, today", "ratio", "share today"], table))
            pr(f"\nMedian step {med_old * 1e3:.3f} → {med * 1e3:.3f} ms (**{med_old / med:.2f}×**).")
        else:
            pr(md_table(["part", "ms / step", "share"], rows))
        pr("")
        if ctrls[-1].zoh is not None:
            cur = ctrls[-1]
            ubar = cur._blocks_from_steps(warm)[:, 0]
            degrees = [poly_degree(cur.zoh.norms, u / cur.zoh.rho, cur.zoh.degree) for u in ubar]
            fl = step_flops(cur, info.qp_iterations, info.active, degrees)
            frows = []
            times = {"map + derivative per block": acc["maps"], "per-step propagation": None, "condensing": None,
                     "QP": acc["solver"], "total": med}
            for name, f in fl.items():
                t = times.get(name)
                frows.append([name, f"{f / 1e6:.3f}", f"{f / peak / 1e6:.4f}",
                              "–" if t is None else f"{t * 1e3:.3f}",
                              "–" if t is None else f"{f / t / 1e9:.2f}"])
            kern = fl["per-step propagation"] + fl["condensing"]
            frows.insert(3, ["(both: the condensing kernel)", f"{kern / 1e6:.3f}", f"{kern / peak / 1e6:.4f}",
                             f"{acc['cond'] * 1e3:.3f}", f"{kern / max(acc['cond'], 1e-12) / 1e9:.2f}"])
            pr(md_table(["work (step_flops)", "MFLOP", f"lower bound ms at {peak:.1f} GFLOP/s", "measured ms",
                         "achieved GFLOP/s"], frows))
            pr(f"\nThe step does {fl['total'] / 1e6:.2f} MFLOP; at the measured peak that is ≥ "
               f"{fl['total'] / peak / 1e6:.4f} ms, so the median step ({med * 1e3:.3f} ms) is "
               f"{med / (fl['total'] / peak / 1e9):.0f}× the floating-point limit (total row: the median step; "
               "other rows: mean times of the part).")
            pr("")

    wall = time.perf_counter() - wall0
    load1 = os.getloadavg()
    pr(f"Total run time {wall:.0f} s ({wall / 60:.1f} min); load average at end {load1[0]:.2f} / {load1[1]:.2f}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
