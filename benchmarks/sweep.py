"""Sweep throughput: a Hydra multirun of the working Van der Pol preset over N initial conditions, and where a
job's time goes.

Runs ``kexp --multirun`` exactly as a user would (joblib launcher, ``--jobs`` workers, MCAP logging on, Rerun
rendering off) after one warm-up run that fills the model and CLF cache, and prints

- the sweep's wall time and runs per second;
- a job's time by phase, median over the jobs (from each run's summary.json ``timing``): setup (config checks),
  model and CLF (cache loads), controller (built; the first job of a worker also loads the compiled kernels),
  log set-up (the header messages and Ω_r's level sets), the closed loop split into control steps, plant
  integration, logging and the rest (lifting, records), finish (the log's last messages, the summary);
- what is outside the jobs: wall × workers − Σ job times (the interpreter and imports of each worker, Hydra's
  composition and launcher, process start).

    python benchmarks/sweep.py [--ics 100] [--jobs 2] [--experiment vanderpol] [--keep DIR]
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PHASES = ["setup_s", "model_s", "clf_s", "controller_s", "log_setup_s", "closed_loop_s", "finish_s"]
LOOP = ["control_s", "integrate_s", "logging_s"]


def load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ics", type=int, default=100)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--experiment", default="vanderpol")
    p.add_argument("--keep", default=None, help="write the sweep here (default: a temporary folder)")
    args = p.parse_args()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="kexp-sweep-"))
    cache = root / "cache"
    ics = np.random.default_rng(42).uniform(-1, 1, (2, args.ics)).T
    x0 = ",".join(f"[{a!r},{b!r}]" for a, b in ics.tolist())
    common = [f"+experiment={args.experiment}", "logging.rrd=false", "logging.mcap=true", f"cache.dir={cache}"]
    print(f"load before: {load()} (1, 5, 15 min)")
    subprocess.run(["kexp", *common, f"hydra.run.dir={root / 'warm'}"], check=True, capture_output=True)
    start = time.perf_counter()
    proc = subprocess.run(["kexp", "--multirun", "hydra/launcher=joblib", f"hydra.launcher.n_jobs={args.jobs}",
                           *common, f"sim.x0={x0}", f"hydra.sweep.dir={root / 'sweep'}"], capture_output=True,
                          text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        sys.exit(f"the sweep failed:\n{proc.stderr[-2000:]}")
    summaries = [json.loads(f.read_text()) for f in sorted((root / "sweep").glob("*/summary.json"))]
    timing = [s["timing"] for s in summaries if "timing" in s]
    if len(timing) != args.ics:
        sys.exit(f"{len(timing)} of {args.ics} jobs wrote a timing")
    job_wall = np.array([s["wall_time_s"] for s in summaries])
    print(f"load after:  {load()}")
    print(f"\n{args.ics} runs of +experiment={args.experiment} on {args.jobs} workers (MCAP on, Rerun off): "
          f"{wall:.1f} s wall, {args.ics / wall:.2f} runs/s; "
          f"successes {sum(s['metrics']['success'] for s in summaries)}/{args.ics}\n")
    rows = [(name, np.array([t[name] for t in timing])) for name in PHASES]
    loop = np.array([t["closed_loop_s"] for t in timing])
    parts = {name: np.array([t["closed_loop"][name] for t in timing]) for name in LOOP}
    rest = loop - sum(parts.values())
    total = float(job_wall.sum())
    outside = wall * args.jobs - total
    print("| phase | median per job [s] | share of Σ jobs |")
    print("|---|---:|---:|")
    for name, v in rows:
        print(f"| {name[:-2]} | {np.median(v):.3f} | {v.sum() / total:.1%} |")
        if name == "closed_loop_s":
            for sub, w in [*parts.items(), ("other (lift, records)", rest)]:
                label = sub[:-2] if sub.endswith("_s") else sub
                print(f"| &nbsp;&nbsp;{label} | {np.median(w):.3f} | {w.sum() / total:.1%} |")
    print(f"| **job total** | {np.median(job_wall):.3f} | 100 % |")
    print(f"\noutside the jobs (workers' start and imports, Hydra, launcher): {outside:.1f} core-s "
          f"= {outside / (wall * args.jobs):.1%} of {wall * args.jobs:.1f} core-s")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
