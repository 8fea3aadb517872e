#!/usr/bin/env python
"""Benchmark: recorded CSV files parsed once (issue 35 item 4) — parse time and peak memory of one 10⁶-row CSV, and
identification from a folder of CSV runs, today's code side by side with a revision's (``--baseline REV``).

    python benchmarks/files.py                      # today only
    python benchmarks/files.py --baseline b6d2237   # and the code before the parsed-data cache
    python benchmarks/files.py --rows 200000        # a smaller file

Every measurement runs in a fresh Python process (so each one's peak memory is its own): ``--baseline``'s
``kexp`` is its ``git archive``, put first on that process's path.  Peak memory is the growth of the process's
peak resident set (``ru_maxrss``) over its resident set before the measured call.

* **parse**: one CSV of ``--rows`` rows × 4 columns (t, x1, x2, u1; ``%.17g``): today's ``parse_csv_to_npy`` into an
  empty folder (cold), the same file read through a warm ``ParsedStore`` (hash and memory map only), and the
  strict line-by-line ``kexp.data.parse.read_csv`` of today and of the baseline.
* **identify**: a folder of 10 Van der Pol runs (60 s each, 6000 rows) streamed by ``open_runs`` into ``identify``
  (Monomials(2, 3)): today with a cold and a warm parsed-data folder (with the number of parses), the baseline as it
  was (it parsed each file on every pass).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

WORKER = r'''
import json, resource, sys, time
from pathlib import Path

def rss_kb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])

what, arg, extra = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
import numpy as np
from kexp.data import parse
if what == "identify":
    from kexp.data import open_runs
    from kexp.dictionary import Monomials
    from kexp.identify import IdentifyConfig, identify
    from kexp.systems import make_system
    vdp = make_system("vanderpol", {})
    kw = dict(n=2, m=1, dt=0.01, system_name="vanderpol", x_eq=vdp.equilibrium)
    if extra:
        kw["parsed_dir"] = extra
    before = rss_kb()
    t0 = time.perf_counter()
    model = identify(vdp, open_runs(arg, **kw), Monomials(2, 3), IdentifyConfig())
    took = time.perf_counter() - t0
    try:
        from kexp.data.parsed import counts
        parses = counts()["parsed"]
    except ImportError:
        parses = None
    out = {"seconds": took, "parses": parses, "lambda0": float(np.sort(np.real(np.diag(model.Lambda)))[0])}
else:
    before = rss_kb()
    t0 = time.perf_counter()
    if what == "read_csv":
        _, values, _ = parse.read_csv(arg)
        rows = values.shape[0]
    elif what == "cold":
        from kexp.data.parsed import parse_csv_to_npy
        parse_csv_to_npy(arg, Path(extra) / "out.npy")
        rows = np.load(Path(extra) / "out.npy", mmap_mode="r").shape[0]
    else:   # warm: the entry exists already
        from kexp.data.parsed import ParsedStore
        _, values = ParsedStore(extra).csv(arg)
        rows = values.shape[0]
    took = time.perf_counter() - t0
    out = {"seconds": took, "rows": rows}
out["peak_mb"] = max(0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
print(json.dumps(out))
'''


def extract(rev: str) -> tuple[Path, str]:
    """The kexp package of ``rev`` (``git archive``) in a temporary folder: (folder to put on the path, short sha)."""
    sha = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout.strip()
    base = Path(tempfile.gettempdir()) / f"kexp-files-baseline-{sha}"
    if not (base / "kexp").exists():
        base.mkdir(parents=True, exist_ok=True)
        tar = base / "kexp.tar"
        tar.write_bytes(subprocess.run(["git", "archive", sha, "kexp"], cwd=ROOT, check=True,
                                       capture_output=True).stdout)
        with tarfile.open(tar) as t:
            t.extractall(base, filter="data")
    return base, sha


def measure(root: Path, what: str, arg: Path, extra: str = "") -> dict:
    env = dict(os.environ, PYTHONPATH=str(root), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", WORKER, what, str(arg), extra], env=env, capture_output=True,
                          text=True, cwd=tempfile.gettempdir())
    if proc.returncode != 0:
        raise SystemExit(f"{what} under {root} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def big_csv(path: Path, rows: int) -> None:
    import numpy as np
    rng = np.random.default_rng(0)
    with open(path, "w") as f:
        f.write("t,x1,x2,u1\n")
        for start in range(0, rows, 100_000):
            k = np.arange(start, min(rows, start + 100_000))
            block = np.column_stack([0.01 * k, np.sin(0.01 * k), rng.standard_normal(len(k)), rng.uniform(-1, 1, len(k))])
            np.savetxt(f, block, fmt="%.17g", delimiter=",")


def run_folder(folder: Path) -> None:
    sys.path.insert(0, str(ROOT))
    from kexp.data import Circle, DataConfig, collect, write_runs
    from kexp.systems import make_system
    vdp = make_system("vanderpol", {})
    write_runs(collect(vdp, Circle(10, 2.0), DataConfig(T=60.0)), folder, "csv")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--baseline", metavar="REV", default=None)
    args = ap.parse_args(argv)
    roots = {"today": ROOT}
    if args.baseline:
        base, sha = extract(args.baseline)
        roots[sha] = base
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        csv_path = tmp / "big.csv"
        big_csv(csv_path, args.rows)
        size = csv_path.stat().st_size / 1e6
        print(f"files benchmark, {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()[0]:.2f}; one CSV of "
              f"{args.rows} rows × 4 columns ({size:.0f} MB)\n")
        print("| code | what | seconds | peak memory growth (MB) |\n|---|---|---:|---:|")
        cold = tmp / "cold"
        cold.mkdir()
        r = measure(ROOT, "cold", csv_path, str(cold))
        print(f"| today | parse into the cache (cold) | {r['seconds']:.2f} | {r['peak_mb']:.0f} |")
        store = tmp / "store"
        measure(ROOT, "warm", csv_path, str(store))          # fills the store
        r = measure(ROOT, "warm", csv_path, str(store))
        print(f"| today | the cached entry (warm: hash and memory map) | {r['seconds']:.2f} | {r['peak_mb']:.0f} |")
        for name, root in roots.items():
            r = measure(root, "read_csv", csv_path)
            print(f"| {name} | strict line-by-line read_csv | {r['seconds']:.2f} | {r['peak_mb']:.0f} |")
        folder = tmp / "runs"
        run_folder(folder)
        print("\n| code | identify from a folder of 10 CSV runs | seconds | CSV parses | λ (check) |\n"
              "|---|---|---:|---:|---:|")
        parsed = tmp / "parsed"
        for label, extra in (("cold parsed-data folder", str(parsed)), ("warm parsed-data folder", str(parsed))):
            r = measure(ROOT, "identify", folder, extra)
            print(f"| today | {label} | {r['seconds']:.2f} | {r['parses']} | {r['lambda0']:.6f} |")
        for name, root in roots.items():
            if name != "today":
                r = measure(root, "identify", folder, "")
                print(f"| {name} | every pass parses the files again | {r['seconds']:.2f} | – | {r['lambda0']:.6f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
