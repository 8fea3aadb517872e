#!/usr/bin/env python
"""Benchmark: the first run of the default ``kexp`` on a fresh install against a warm run (issue 35 item 2).

    python benchmarks/cold_start.py                          # this checkout: 1 fresh start, 3 warm runs
    python benchmarks/cold_start.py --repeat 3 --warm 3      # medians over 3 fresh starts
    python benchmarks/cold_start.py --baseline /work/main    # the same for another source tree, side by side

A "fresh install" here is a copy of the sources (kexp/, conf/, pyproject.toml; no ``__pycache__``, so no numba cache
beside them) run with this interpreter's packages (``PYTHONPATH`` = the copy) and an empty ``KEXP_CACHE_DIR`` (kexp's
model cache and, since kexp.control.jit_cache, numba's cache of kexp's kernels); ``NUMBA_CACHE_DIR`` is unset.  Then:

* first run  — ``kexp logging.rrd=false`` in an empty folder: compiles the kernels and fits the model;
* warm runs  — the same command again (``--warm`` times): what every later run of that install costs ("second run"
  is the first of them: it loads the model from kexp's cache, and before issue 35 it compiled two kernels again);
* compile + first — a second fresh copy and cache, ``python -m kexp.control.warmup`` (``kexp-compile``), then the first
  run (only for trees that have kexp/control/warmup.py).

Wall times are of the whole process (imports included); "controller" is the run's own ``timing.controller_s``
(summary.json), where the kernels compile or load.  Times depend on the machine and its load; nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
KEXP = [sys.executable, "-c", "import sys; from kexp.app.main import main; sys.argv[0] = 'kexp'; main()",
        "logging.rrd=false"]


def fresh_copy(source: Path, into: Path) -> Path:
    into.mkdir(parents=True)
    shutil.copy(source / "pyproject.toml", into / "pyproject.toml")
    for name in ("kexp", "conf"):
        shutil.copytree(source / name, into / name, ignore=shutil.ignore_patterns("__pycache__"))
    return into


def run(cmd: list[str], env: dict, cwd: Path) -> tuple[float, float | None, str]:
    """(wall s, controller_s from the run's summary.json or None, stderr) of one process."""
    cwd.mkdir(parents=True, exist_ok=True)
    before = set(cwd.glob("outputs/*/*/summary.json"))
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"cold_start: {' '.join(cmd[-2:])} failed in {cwd}:\n{proc.stderr[-2000:]}")
    new = sorted(set(cwd.glob("outputs/*/*/summary.json")) - before)
    ctrl = json.loads(new[-1].read_text())["timing"]["controller_s"] if new else None
    return wall, ctrl, proc.stderr


def measure(source: Path, tmp: Path, warm: int) -> dict:
    """One fresh start of ``source``: first run, ``warm`` warm runs, and (if it has one) warm-up + first run."""
    out: dict = {}
    code = fresh_copy(source, tmp / "src")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR", "KEXP_CACHE_DIR")}
    env.update(PYTHONPATH=str(code), KEXP_CACHE_DIR=str(tmp / "cache"))
    out["first"], out["first_ctrl"], err = run(KEXP, env, tmp / "runs")
    out["announced"] = "compiling" in err
    warm_runs = [run(KEXP, env, tmp / "runs") for _ in range(warm)]
    out["warm"] = [w for w, _, _ in warm_runs]
    out["warm_ctrl"] = [c for _, c, _ in warm_runs]
    if (source / "kexp" / "control" / "warmup.py").exists():
        code2 = fresh_copy(source, tmp / "src2")
        env2 = {**env, "PYTHONPATH": str(code2), "KEXP_CACHE_DIR": str(tmp / "cache2")}
        out["compile"], _, _ = run([sys.executable, "-m", "kexp.control.warmup"], env2, tmp / "runs2")
        out["after_compile"], out["after_compile_ctrl"], err2 = run(KEXP, env2, tmp / "runs2")
        out["compiled_after_warmup"] = "compiling" in err2
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=1, help="fresh starts per source tree (medians over them)")
    ap.add_argument("--warm", type=int, default=3, help="warm runs after each fresh start")
    ap.add_argument("--baseline", type=Path, help="another source tree (e.g. the previous code) measured alike")
    args = ap.parse_args()
    trees = [("this", REPO)] + ([("baseline", args.baseline.resolve())] if args.baseline else [])
    rows = []
    for label, source in trees:
        results = []
        for i in range(args.repeat):
            with tempfile.TemporaryDirectory(prefix="kexp-cold-") as tmp:
                results.append(measure(source, Path(tmp), args.warm))
                print(f"{label} #{i + 1}: {json.dumps(results[-1])}", file=sys.stderr, flush=True)
        med = statistics.median

        def pick(key):
            vals = [r[key] for r in results if key in r]
            return med(vals) if vals else None
        warm = med([med(r["warm"]) for r in results])
        warm_ctrl = med([med(r["warm_ctrl"]) for r in results])
        second = med([r["warm"][0] for r in results])
        rows.append((label, source, pick("first"), second, warm, pick("first_ctrl"), warm_ctrl, pick("compile"),
                     pick("after_compile"), all(r["announced"] for r in results)))
    print(f"default `kexp logging.rrd=false`, fresh copy + empty KEXP_CACHE_DIR; {args.repeat} fresh start(s), "
          f"{args.warm} warm run(s) each; medians; seconds")
    print("| code | first run | second run | warm run | first / warm | controller first / warm | announced | kexp-compile | "
          "first run after it |")
    print("|---|---:|---:|---:|---:|---:|---|---:|---:|")

    def f(x):
        return "–" if x is None else f"{x:.1f}"
    for label, source, first, second, warm, fc, wc, comp, after, ann in rows:
        print(f"| {label} ({source}) | {f(first)} | {f(second)} | {f(warm)} | {first / warm:.1f}× | {fc:.2f} / {wc:.2f} | "
              f"{'yes' if ann else 'no'} | {f(comp)} | {f(after)} |")


if __name__ == "__main__":
    main()
