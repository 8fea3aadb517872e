#!/usr/bin/env python
"""Benchmark: kexp's streamed EDMD fit vs the usual "lift everything, then lstsq" approach.

    python benchmarks/identify.py                       # full table (sizes 1e5, 1e6, 1e7; 2 and 4 states)
    python benchmarks/identify.py --sizes 1e5 --states 2 --repeat 1   # quick run

Every measured run happens in a fresh child process (this script, started again with a hidden flag) so
that peak memory is isolated; the children pin BLAS to one thread (OMP/OPENBLAS/MKL_NUM_THREADS=1 set in
their environment before numpy is imported).  Per run the child reports

- wall time of the whole fit: data generation + lifting + solve + K (both approaches generate the same
  chunks from the same seed; the streamed fit consumes a generator, the usual approach materialises
  X_all, Y_all, Φ_X, Φ_Y and calls np.linalg.lstsq — that materialisation is what it costs),
- tracemalloc peak (numpy reports its buffers to tracemalloc) during the fit,
- increase of ru_maxrss (peak RSS) over the child's own baseline taken after imports and a tiny warm-up.

The table shows the median time over the repeats and the largest memory figures over the repeats.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

METHOD_LABEL = {"usual": "usual lstsq", "qr": "streamed qr", "gram": "streamed gram"}
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
MIB = 1024.0 ** 2


# ---------------------------------------------------------------------------------------------- data
def system_matrices(n: int):
    """A slightly contracting rotation (2×2 blocks, different angles) and a small cubic term."""
    import numpy as np
    A = np.zeros((n, n))
    for b in range(0, n - 1, 2):
        th = 0.3 + 0.2 * (b // 2)
        A[b:b + 2, b:b + 2] = 0.95 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    if n % 2:
        A[n - 1, n - 1] = 0.9
    return A


def step(A, X):
    """Deterministic smooth map: y = A x − 0.1 x³ (component-wise cube)."""
    return X @ A.T - 0.1 * X ** 3


def chunks(n: int, pairs: int, chunk: int, seed: int):
    """Snapshot pairs created on the fly, chunk by chunk, from a seeded generator (same seed -> same data)."""
    import numpy as np
    rng = np.random.default_rng(seed)
    A = system_matrices(n)
    done = 0
    while done < pairs:
        r = min(chunk, pairs - done)
        X = rng.uniform(-1.0, 1.0, size=(r, n))
        yield X, step(A, X)
        done += r


# ---------------------------------------------------------------------------------------------- child
def blas_threads() -> str:
    """Thread counts reported by the OpenBLAS libraries loaded in this process (best effort)."""
    import ctypes
    try:
        with open("/proc/self/maps") as f:
            libs = sorted({ln.split()[-1] for ln in f if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:
        return "unknown"
    out = []
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                     "openblas_get_num_threads64_", "openblas_get_num_threads"):
            fn = getattr(lib, name, None)
            if fn is not None:
                out.append(f"{os.path.basename(path)}={fn()}")
                break
    return ", ".join(out) or "unknown"


def child(spec: dict) -> dict:
    # Environment (BLAS threads) was set by the parent before this interpreter started.
    import resource
    import tracemalloc

    import numpy as np
    import scipy.linalg  # noqa: F401  (load LAPACK before the baseline)

    from kexp.dictionary import Monomials
    from kexp.identify.edmd import fit_least_squares

    n, deg, pairs, chunk, seed, method = (spec[k] for k in ("n", "degree", "pairs", "chunk", "seed", "method"))
    d = Monomials(n, deg)

    def run(p):
        phases = {}
        if method == "usual":
            t0 = time.perf_counter()
            X_all = np.empty((p, n))
            Y_all = np.empty((p, n))
            i = 0
            for X, Y in chunks(n, p, chunk, seed):
                X_all[i:i + len(X)] = X
                Y_all[i:i + len(X)] = Y
                i += len(X)
            t1 = time.perf_counter()
            PX = d.lift(X_all)
            PY = d.lift(Y_all)
            t2 = time.perf_counter()
            K = np.linalg.lstsq(PX, PY, rcond=None)[0].T
            t3 = time.perf_counter()
            phases = {"generate": t1 - t0, "lift": t2 - t1, "lstsq": t3 - t2}
        else:
            K = fit_least_squares(chunks(n, p, chunk, seed), d.lift, method=method).K
        return np.ascontiguousarray(K), phases

    run(max(d.size * 4, 500))  # warm-up: first-call costs (LAPACK workspace queries, page faults of small arrays)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    K, phases = run(pairs)
    wall = time.perf_counter() - t0
    traced_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if spec.get("k_out"):
        np.save(spec["k_out"], K)
    return {"time": wall, "traced_peak": traced_peak, "rss_base_kib": rss0, "rss_inc_kib": rss1 - rss0,
            "N": d.size, "phases": phases, "threads": blas_threads(),
            "env": {v: os.environ.get(v) for v in THREAD_VARS}}


def run_child(spec: dict, timeout: float) -> dict:
    env = dict(os.environ)
    for v in THREAD_VARS:
        env[v] = "1"
    cmd = [sys.executable, os.path.abspath(__file__), "--_child", json.dumps(spec)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    for line in reversed(p.stdout.splitlines()):
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    tail = (p.stderr.strip().splitlines() or [f"exit code {p.returncode}"])[-1]
    if p.returncode < 0:
        tail = f"killed by signal {-p.returncode} ({tail})"
    return {"error": tail}


# ---------------------------------------------------------------------------------------------- parent
def n_functions(n: int, degree: int) -> int:
    return math.comb(n + degree, degree)


def usual_mem_estimate(n: int, N: int, pairs: int, measured: dict) -> float:
    """Bytes.  Linear extrapolation of the largest measured smaller run if there is one, else a count of
    the arrays: X_all, Y_all, Φ_X, Φ_Y, the (N, M) temporaries of lift, lstsq's Fortran copies of both."""
    best = max((p for p in measured if p < pairs), default=None)
    if best is not None:
        return measured[best] * pairs / best
    return 8.0 * pairs * (2 * n + 5 * N)


def fmt_size(p: int) -> str:
    e = int(round(math.log10(p)))
    return f"1e{e}" if 10 ** e == p else f"{p:,}"


def parse_sizes(s: str) -> list[int]:
    return [int(float(v)) for v in s.split(",") if v.strip()]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="1e5,1e6,1e7", help="comma-separated numbers of pairs (default 1e5,1e6,1e7)")
    ap.add_argument("--states", default="2,4", help="comma-separated state dimensions (default 2,4)")
    ap.add_argument("--degree", type=int, default=5, help="monomial degree (default 5)")
    ap.add_argument("--methods", default="usual,qr,gram", help="subset of usual,qr,gram (default all)")
    ap.add_argument("--repeat", type=int, default=None,
                    help="runs per case (default: 3 for sizes <= 1e6, 1 above)")
    ap.add_argument("--chunk", type=int, default=20000, help="rows per streamed chunk (default 20000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-usual-gb", type=float, default=8.0,
                    help="skip usual-approach cases estimated to need more memory (default 8)")
    ap.add_argument("--max-streamed-s", type=float, default=240.0,
                    help="skip streamed cases estimated to take longer per run (default 240)")
    ap.add_argument("--budget-s", type=float, default=900.0,
                    help="skip cases that would push the total run time past this (default 900)")
    ap.add_argument("--_child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args._child is not None:
        print("RESULT " + json.dumps(child(json.loads(args._child))), flush=True)
        return

    t_start = time.perf_counter()
    sizes = sorted(parse_sizes(args.sizes))
    states = [int(v) for v in args.states.split(",") if v.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHOD_LABEL]
    if bad:
        ap.error(f"unknown methods {bad}; valid: usual, qr, gram")
    methods = [m for m in ("usual", "qr", "gram") if m in methods]

    import platform
    print("# kexp EDMD identification benchmark: streamed fit vs usual lstsq\n")
    print(f"- started {time.strftime('%Y-%m-%d %H:%M:%S')}, Python {platform.python_version()}, "
          f"{os.cpu_count()} CPUs ({platform.processor() or platform.machine()})")
    print("- every run in a fresh child process with OMP_NUM_THREADS=OPENBLAS_NUM_THREADS=MKL_NUM_THREADS=1 "
          "(single-threaded BLAS)")
    print(f"- data: pairs (x, y), x ~ U[-1,1]^n, y = 0.95·rotation·x − 0.1·x³, seed {args.seed}, "
          f"generated in chunks of {args.chunk}; dictionary Monomials(n, {args.degree})")
    print("- time = median wall time of generate + lift + fit + K; memory = largest over the repeats; "
          "peak RSS increase is over the child's baseline after imports and a warm-up")
    print("- usual lstsq = X_all, Y_all, Φ_X = lift(X_all), Φ_Y = lift(Y_all), "
          "np.linalg.lstsq(Φ_X, Φ_Y, rcond=None)[0].T; streamed = kexp.identify.edmd.fit_least_squares "
          "on a chunk generator\n", flush=True)

    rows, notes, results = [], [], {}
    usual_mem = {}         # n -> {pairs: measured peak bytes (max of traced and RSS)}
    per_pair_time = {}     # (n, method) -> {pairs: seconds per run}
    threads_seen = set()
    kdir = tempfile.mkdtemp(prefix="kexp-bench-")

    for n in states:
        N = n_functions(n, args.degree)
        usual_mem.setdefault(n, {})
        for pairs in sizes:
            reps = args.repeat if args.repeat is not None else (3 if pairs <= 10 ** 6 else 1)
            K_usual = None
            for method in methods:
                label = METHOD_LABEL[method]
                key = (n, pairs, method)
                skip = None
                # time estimate from the largest smaller measured size (linear in pairs)
                tdone = per_pair_time.get((n, method), {})
                ref = max((p for p in tdone if p < pairs), default=None)
                t_est = tdone[ref] * pairs / ref if ref else None
                if method == "usual":
                    mem = usual_mem_estimate(n, N, pairs, usual_mem[n])
                    if mem > args.max_usual_gb * 1e9:
                        skip = f"skipped: needs {mem / 1e9:.0f} GB"
                        notes.append(f"n={n}, {fmt_size(pairs)} pairs, usual lstsq: estimated peak memory "
                                     f"{mem / 1e9:.1f} GB > {args.max_usual_gb:g} GB limit")
                elif t_est is not None and t_est > args.max_streamed_s:
                    skip = f"skipped: needs ~{t_est:.0f} s"
                    notes.append(f"n={n}, {fmt_size(pairs)} pairs, {label}: estimated {t_est:.0f} s per run "
                                 f"(from {fmt_size(ref)} pairs: {tdone[ref]:.1f} s) > {args.max_streamed_s:.0f} s")
                if skip is None and t_est is not None:
                    elapsed = time.perf_counter() - t_start
                    need = reps * (t_est + 2.0)
                    if elapsed + need > args.budget_s:
                        skip = "skipped: run-time budget"
                        notes.append(f"n={n}, {fmt_size(pairs)} pairs, {label}: estimated {need:.0f} s "
                                     f"({reps} run(s)) after {elapsed:.0f} s elapsed would exceed the "
                                     f"{args.budget_s:.0f} s budget")
                if skip is not None:
                    print(f"  n={n} pairs={fmt_size(pairs)} {label}: {skip}", flush=True)
                    rows.append((n, N, pairs, label, skip))
                    continue

                runs = []
                for r in range(reps):
                    k_out = os.path.join(kdir, f"K_{n}_{pairs}_{method}.npy") if r == 0 else None
                    spec = {"n": n, "degree": args.degree, "pairs": pairs, "chunk": args.chunk,
                            "seed": args.seed, "method": method, "k_out": k_out}
                    timeout = max(600.0, 5 * t_est) if t_est else 1800.0
                    res = run_child(spec, timeout)
                    if "error" in res:
                        runs = [res]
                        break
                    runs.append(res)
                    threads_seen.add(res["threads"])
                if "error" in runs[0]:
                    msg = f"failed: {runs[0]['error']}"
                    print(f"  n={n} pairs={fmt_size(pairs)} {label}: {msg}", flush=True)
                    rows.append((n, N, pairs, label, msg))
                    notes.append(f"n={n}, {fmt_size(pairs)} pairs, {label}: {msg}")
                    continue

                import numpy as np
                t_med = statistics.median(r["time"] for r in runs)
                traced = max(r["traced_peak"] for r in runs) / MIB
                rss = max(r["rss_inc_kib"] for r in runs) / 1024.0
                K = np.load(os.path.join(kdir, f"K_{n}_{pairs}_{method}.npy"))
                if method == "usual":
                    K_usual = K
                    usual_mem[n][pairs] = max(traced, rss) * MIB
                    dK = "—"
                    ph = {k: statistics.median(r["phases"][k] for r in runs) for k in runs[0]["phases"]}
                    results[(n, pairs, "phases")] = ph
                else:
                    dK = f"{np.max(np.abs(K - K_usual)):.1e}" if K_usual is not None else "— (no usual)"
                per_pair_time.setdefault((n, method), {})[pairs] = t_med
                results[key] = {"time": t_med, "traced": traced, "rss": rss}
                cells = (f"{t_med:.3f}", f"{pairs / t_med:,.0f}", f"{traced:,.1f}", f"{rss:,.1f}", dK)
                rows.append((n, N, pairs, label, cells))
                print(f"  n={n} pairs={fmt_size(pairs)} {label}: {t_med:.2f} s "
                      f"(runs {', '.join('%.2f' % r['time'] for r in runs)}), traced {traced:.1f} MiB, "
                      f"RSS +{rss:.1f} MiB, max|ΔK| {dK}", flush=True)

    # ------------------------------------------------------------------------------------- table
    print()
    head = ["states", "degree", "N", "pairs", "method", "median time [s]", "pairs/s",
            "peak traced memory [MiB]", "peak RSS increase [MiB]", "max\\|ΔK\\| vs usual"]
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join(["---:"] * 4 + [":---"] + ["---:"] * 5) + "|")
    for n, N, pairs, label, cells in rows:
        if isinstance(cells, str):
            cells = (cells, "", "", "", "")
        print("| " + " | ".join([str(n), str(args.degree), str(N), fmt_size(pairs), label, *cells]) + " |")

    # ------------------------------------------------------------------------------------- ratios at 1e6
    P = 10 ** 6
    ratio_lines = []
    for n in states:
        u = results.get((n, P, "usual"))
        for method in ("qr", "gram"):
            s = results.get((n, P, method))
            if u is None or s is None:
                continue
            rt, rr, rtime = u["traced"] / s["traced"], u["rss"] / max(s["rss"], 1e-9), u["time"] / s["time"]
            verdict = ""
            if method == "qr":
                ok_mem, ok_time = min(rt, rr) >= 10, rtime >= 1.0
                verdict = ("memory " + ("met" if ok_mem else "NOT met") + ", time "
                           + ("met" if ok_time else f"NOT met (streamed qr takes {1 / rtime:.2f}× the usual time)"))
            ratio_lines.append(f"| {n} | {METHOD_LABEL[method]} | {rt:.1f}× | {rr:.1f}× | {rtime:.2f}× | {verdict} |")
    if ratio_lines:
        print(f"\nRatios usual/streamed at {fmt_size(P)} pairs (memory: larger is better for streamed; "
              "time: > 1 means streamed is faster):\n")
        print("| states | method | traced memory ratio | RSS increase ratio | time ratio "
              "| target for streamed qr: ≥10× less peak memory, no slower |")
        print("|---:|:---|---:|---:|---:|:---|")
        for line in ratio_lines:
            print(line)

    phase_lines = [(n, p, results[(n, p, "phases")]) for n in states for p in sizes if (n, p, "phases") in results]
    if phase_lines:
        print("\nUsual approach, median time by phase [s]:\n")
        print("| states | pairs | generate | lift | lstsq |")
        print("|---:|---:|---:|---:|---:|")
        for n, p, ph in phase_lines:
            print(f"| {n} | {fmt_size(p)} | {ph['generate']:.3f} | {ph['lift']:.3f} | {ph['lstsq']:.3f} |")

    print("\nNote: tracemalloc sees numpy's array buffers but not buffers that C code mallocs directly "
          "(e.g. the copies np.linalg.lstsq makes for LAPACK, LAPACK workspaces), so the RSS column is the "
          "fuller picture for the usual approach.")
    if notes:
        print("\nSkipped / failed:\n")
        for line in notes:
            print(f"- {line}")
    print(f"\nBLAS threads reported inside the children: {'; '.join(sorted(threads_seen)) or 'n/a'}")
    total = time.perf_counter() - t_start
    print(f"Total run time: {total:.0f} s ({total / 60:.1f} min), finished {time.strftime('%Y-%m-%d %H:%M:%S')}")
    for f in os.listdir(kdir):
        os.remove(os.path.join(kdir, f))
    os.rmdir(kdir)


if __name__ == "__main__":
    main()
