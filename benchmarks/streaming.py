#!/usr/bin/env python
"""Benchmark: identification from recorded NPZ files, streamed (kexp.data.streaming.open_runs) and, for
comparison, read into one in-memory Dataset first (read_runs).

    python benchmarks/streaming.py                      # 1e5, 3e5 and 1e6 pairs, both ways
    python benchmarks/streaming.py --sizes 1e5 --modes streamed   # quick run

The data: Van der Pol runs of 20 s at dt = 0.01 (2000 pairs per file) from initial states on a circle of
radius 2, simulated with kexp's collect() and written with write_runs() into a temporary folder, 50 runs at a
time.  Identification: dictionary Monomials(2, 3), IdentifyConfig() (streamed QR, 20 % of the runs held out).

Every measurement runs in a fresh child process (this script with a hidden flag; BLAS pinned to one thread) so
that memory is isolated: first an untraced run gives the wall time (opening the files included) and the peak
RSS above the child's baseline after imports and a small warm-up, then a second run under tracemalloc gives the
peak of the Python/numpy allocations.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PAIRS_PER_RUN = 2000
MIB = 1024.0 ** 2


def write_data(folder: Path, pairs: int) -> int:
    """Van der Pol runs holding ``pairs`` pairs in all, as NPZ files in ``folder``; returns the number of files."""
    from kexp.data import Circle, DataConfig, collect, write_runs
    from kexp.systems import make_system
    vdp = make_system("vanderpol", {})
    n_runs = -(-pairs // PAIRS_PER_RUN)
    done = 0
    while done < n_runs:
        batch = min(50, n_runs - done)
        ds = collect(vdp, Circle(batch, 2.0), DataConfig(T=PAIRS_PER_RUN * 0.01, seed=done))
        write_runs(ds, folder, "npz", prefix=f"batch{done:05d}")
        done += batch
    return n_runs


def child(folder: str, mode: str) -> None:
    import resource
    import tracemalloc

    import numpy as np
    from kexp.data import open_runs, read_runs
    from kexp.dictionary import Monomials
    from kexp.identify import IdentifyConfig, identify
    from kexp.systems import make_system

    vdp = make_system("vanderpol", {})
    load = open_runs if mode == "streamed" else read_runs

    def run(path):
        data = load(path, n=2, m=1, dt=0.01, system_name="vanderpol")
        return data.n_pairs, identify(vdp, data, Monomials(2, 3), IdentifyConfig())

    with tempfile.TemporaryDirectory() as warm:   # warm-up: imports, LAPACK, one small fit
        from kexp.data import Circle, DataConfig, collect, write_runs
        write_runs(collect(vdp, Circle(4, 2.0), DataConfig(T=2.0)), warm, "npz")
        run(warm)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    t0 = time.perf_counter()
    pairs, model = run(folder)
    wall = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0 - base
    tracemalloc.start()
    run(folder)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert np.all(np.isfinite(model.eigenvalues))
    print(json.dumps({"pairs": pairs, "wall": wall, "rss": rss, "peak": peak}))


def measure(folder: Path, mode: str) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, __file__, "--child", str(folder), mode], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", default=["1e5", "3e5", "1e6"], help="numbers of recorded pairs")
    ap.add_argument("--modes", nargs="+", default=["streamed", "in-memory"], choices=["streamed", "in-memory"])
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(*args.child)
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            pairs = int(float(size))
            folder = Path(tmp) / f"p{pairs}"
            files = write_data(folder, pairs)
            for mode in args.modes:
                r = measure(folder, mode)
                rows.append((r["pairs"], files, mode, r["peak"] / MIB, r["rss"] / MIB, r["wall"],
                             r["pairs"] / r["wall"]))
    head = ("pairs", "files", "reading", "tracemalloc peak (MB)", "peak RSS increase (MB)", "wall (s)", "pairs/s")
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---:" if i != 2 else "---" for i in range(len(head))) + "|")
    for p, f, mode, peak, rss, wall, rate in rows:
        print(f"| {p:,} | {f} | {mode} | {peak:.1f} | {rss:.1f} | {wall:.2f} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
