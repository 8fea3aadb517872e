"""Resources of a sweep worker over many jobs: native threads and resident memory after job 1, 50, 100, 150, 200.

A joblib sweep's worker runs job after job in one process; whatever a job leaves behind (a thread, a buffer)
accumulates over the sweep.  This benchmark runs N jobs' worth of a worker's work in this one process, as a loky
worker does: each job's config composed by Hydra (the small Van der Pol run of tests/test_sweep.py, its own
``sim.x0``), then :func:`kexp.app.experiment.run` into its own folder with the MCAP log and the Rerun recording
(``logging.rrd=true``, the default), echo and progress as in a sweep job.  After the jobs named by ``--at`` it
reads the process's thread count (``/proc/self/task``: the native threads too, which ``threading`` does not
see) and ``VmRSS``, and prints a table and the ratio last/first.

    python benchmarks/sweep_resources.py [--jobs 200] [--at 1,50,100,150,200] [--rrd true] [--keep DIR]

Before the fix every job left 4 native threads (Rerun's ``ChunkBatcher`` and ``RecordingStream`` of the data and
the blueprint stream) and ~2.5 MB behind; run it with ``PYTHONPATH`` on another checkout to compare.
"""
import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

QUICK = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=2.0", "clf.grid=11", "logging.progress=false"]


def threads() -> int:
    """This process's threads, native ones included."""
    return len(os.listdir("/proc/self/task"))


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def thread_names() -> dict[str, int]:
    names: dict[str, int] = {}
    for t in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{t}/comm") as f:
                name = f.read().strip()
        except OSError:
            continue
        names[name] = names.get(name, 0) + 1
    return names


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--jobs", type=int, default=200)
    p.add_argument("--at", default="1,50,100,150,200", help="jobs after which to measure")
    p.add_argument("--rrd", default="true", choices=["true", "false"], help="logging.rrd")
    p.add_argument("--keep", default=None, help="write the job folders here (default: a temporary folder)")
    args = p.parse_args()
    at = sorted({int(a) for a in args.at.split(",") if 0 < int(a) <= args.jobs} | {args.jobs})
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="kexp-resources-"))

    import numpy as np
    from hydra import compose, initialize_config_dir

    import kexp
    from kexp.app.conf import CONF_DIR
    from kexp.app.experiment import run
    from kexp.app.main import _warnings_only

    x0s = np.random.default_rng(0).uniform(-1, 1, (args.jobs, 2)).tolist()
    rows = []
    start = time.perf_counter()
    before = (threads(), rss_mb())
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        for job in range(1, args.jobs + 1):
            a, b = x0s[job - 1]
            cfg = compose(config_name="config", overrides=[*QUICK, f"logging.rrd={args.rrd}",
                                                           f"cache.dir={root / 'cache'}", f"sim.x0=[{a!r},{b!r}]"])
            run(cfg, root / str(job - 1), echo=_warnings_only, auto_progress=False)
            if job in at:
                rows.append((job, threads(), rss_mb(), time.perf_counter() - start))
                print(f"job {job}: {rows[-1][1]} threads, {rows[-1][2]:.1f} MB", file=sys.stderr, flush=True)
    print(f"kexp {kexp.__file__}; {args.jobs} jobs in one process (logging.rrd={args.rrd}); "
          f"before the first job: {before[0]} threads, {before[1]:.1f} MB")
    print("\n| after job | threads | RSS [MB] | elapsed [s] |")
    print("|---:|---:|---:|---:|")
    for job, t, r, s in rows:
        print(f"| {job} | {t} | {r:.1f} | {s:.0f} |")
    (j0, t0, r0, _), (j1, t1, r1, _) = rows[0], rows[-1]
    print(f"\njob {j1} / job {j0}: threads ×{t1 / t0:.2f} ({t1 - t0:+d}), RSS ×{r1 / r0:.2f} ({r1 - r0:+.1f} MB)")
    if len(rows) > 2:   # the first jobs also load code and fill caches: the steady growth is from the second row on
        (jm, tm, rm, _) = rows[1]
        print(f"job {j1} / job {jm}: threads ×{t1 / tm:.2f} ({t1 - tm:+d}), RSS ×{r1 / rm:.2f} "
              f"({(r1 - rm) / (j1 - jm) * 1e3:+.0f} kB per job)")
    print(f"threads at the end: {dict(sorted(thread_names().items()))}")


if __name__ == "__main__":
    main()
