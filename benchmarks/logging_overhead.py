"""How much MCAP logging adds to a closed-loop run (Van der Pol, LMPC, 10 s = 1000 steps).

Runs the same closed loop without a log, with the per-step RunLogger (flush every simulated second), and with
the LMPC's predicted horizon logged every 20 steps (the default) or 10 steps too (an extra exact rollout each
time), with the chunks compressed in the loop's thread instead of McapFile's compression thread
(``RunLogger(compress_thread=False)``), and with the writer thread (``RunLogger(background=True)``: the loop only
queues each message, the thread encodes and writes them at each flush while the loop is in the GIL-free rollout
kernels; measured slower here, so kexp does not use it), interleaved, and prints the median wall times and their
ratio.  Wall-time ratios between runs carry the machine's noise (a few % on a shared 2-core VM), so the cost of
logging is also timed directly inside each run: the time spent in the logging callback and in close() (with the
writer thread: the queueing and the wait for the thread's last messages; with the compression thread: the wait
for the last chunk), plus the exact rollouts the LMPC makes only to log its prediction (kexp.control.lmpc's
rollout and rollout_poly, wrapped here; in RTI mode nothing else calls them), as a share of the no-log run time.
The direct measure of the thread modes does not see the threads' competition for the GIL and the cores; the
wall-time column does.  One BLAS thread.

    python benchmarks/logging_overhead.py [--repeat 7]
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import kexp.control.lmpc as lmpc_module  # noqa: E402
from kexp.clf import ClfConfig, synthesize_clf  # noqa: E402
from kexp.control import Lmpc, LmpcConfig, make_law  # noqa: E402
from kexp.data import Circle, DataConfig, collect  # noqa: E402
from kexp.dictionary import Monomials  # noqa: E402
from kexp.identify import identify  # noqa: E402
from kexp.recording.writer import RunLogger  # noqa: E402
from kexp.simulate import SimConfig, closed_loop  # noqa: E402
from kexp.systems import VanDerPol  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args()
    s = VanDerPol()
    model = identify(s, collect(s, Circle(100, 2.5), DataConfig(T=10.0)), Monomials(2, 5))
    clf = synthesize_clf(model, ClfConfig())
    h = make_law("sontag", clf.lyap, -5.0, 5.0)
    x0 = np.array([0.7, -0.5])
    sim = SimConfig(T=10.0)
    # mode -> (prediction_every, writer thread, compression thread)
    every = {"no log": (0, False, True), "MCAP log": (0, False, True),
             "MCAP log + predictions every 20 steps (the default, what kexp runs)": (20, False, True),
             "MCAP log + predictions every 10 steps": (10, False, True),
             "MCAP log + predictions every 20 steps, chunks compressed in the loop's thread "
             "(RunLogger(compress_thread=False))": (20, False, False),
             "MCAP log + predictions every 20 steps, writer thread (RunLogger(background=True))": (20, True, True)}
    times = {mode: [] for mode in every}
    inside = {mode: [] for mode in times}     # seconds spent on logging inside the run
    spent = [0.0]
    def timed(fn):
        def wrapper(*a):
            t = time.perf_counter()
            out = fn(*a)
            spent[0] += time.perf_counter() - t
            return out
        return wrapper

    lmpc_module.rollout = timed(lmpc_module.rollout)
    lmpc_module.rollout_poly = timed(lmpc_module.rollout_poly)

    def logged(logger):
        def cb(rec, st):
            t = time.perf_counter()
            logger.log_step(rec, st, model)
            spent[0] += time.perf_counter() - t
        return cb

    with tempfile.TemporaryDirectory() as tmp:
        modes = list(times)
        for i in range(args.repeat):
            for mode in modes[i % len(modes):] + modes[: i % len(modes)]:  # rotate the order: no mode always first
                pred, background, compress_thread = every[mode]
                ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0, prediction_every=pred)
                logger = (RunLogger(Path(tmp) / f"r{i}.mcap", prediction_every=pred, background=background,
                                    compress_thread=compress_thread) if mode != "no log" else None)
                cb = logged(logger) if logger else None
                spent[0] = 0.0
                t0 = time.perf_counter()
                closed_loop(s, ctrl, x0, sim, model=model, lyap=clf.lyap, on_step=cb)
                if logger:
                    t1 = time.perf_counter()
                    logger.close()
                    spent[0] += time.perf_counter() - t1
                times[mode].append(time.perf_counter() - t0)
                inside[mode].append(spent[0])
    base = np.median(times["no log"])
    print(f"closed loop, Van der Pol, LMPC (RTI), {sim.n_steps} steps, {args.repeat} interleaved repeats "
          "(order rotated), one BLAS thread\n")
    print("| mode | median wall time [s] | min [s] | wall-time overhead vs no log | logging time inside the run "
          "[ms] | per step [µs] | direct overhead |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for mode, ts in times.items():
        med, ins = np.median(ts), np.median(inside[mode])
        print(f"| {mode} | {med:.3f} | {np.min(ts):.3f} | {100 * (med / base - 1):+.1f} % | {1e3 * ins:.1f} | "
              f"{1e6 * ins / sim.n_steps:.1f} | {100 * ins / base:.1f} % |")


if __name__ == "__main__":
    main()
