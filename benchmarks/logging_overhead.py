"""How much MCAP logging adds to a closed-loop run (Van der Pol, LMPC, 10 s = 1000 steps).

Runs the same closed loop without a log, with the per-step RunLogger (flush every simulated second), and with
the LMPC's predicted horizon logged every 10 steps too (an extra exact rollout each time), interleaved, and prints
the median wall times and their ratio.  One BLAS thread.

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
    times = {"no log": [], "MCAP log": [], "MCAP log + predictions every 10 steps": []}
    with tempfile.TemporaryDirectory() as tmp:
        modes = list(times)
        for i in range(args.repeat):
            for mode in modes[i % len(modes):] + modes[: i % len(modes)]:  # rotate the order: no mode always first
                pred = 10 if "predictions" in mode else 0
                ctrl = Lmpc(model, clf, h, LmpcConfig(), -5.0, 5.0, prediction_every=pred)
                logger = RunLogger(Path(tmp) / f"r{i}.mcap", prediction_every=pred) if mode != "no log" else None
                cb = (lambda rec, st: logger.log_step(rec, st, model)) if logger else None
                t0 = time.perf_counter()
                closed_loop(s, ctrl, x0, SimConfig(T=10.0), model=model, lyap=clf.lyap, on_step=cb)
                if logger:
                    logger.close()
                times[mode].append(time.perf_counter() - t0)
    base = np.median(times["no log"])
    print(f"closed loop, Van der Pol, LMPC (RTI), 1000 steps, {args.repeat} interleaved repeats (order rotated), "
          "one BLAS thread\n")
    print("| mode | median wall time [s] | min [s] | overhead vs no log |")
    print("|---|---:|---:|---:|")
    for mode, ts in times.items():
        med = np.median(ts)
        print(f"| {mode} | {med:.3f} | {np.min(ts):.3f} | {100 * (med / base - 1):+.1f} % |")


if __name__ == "__main__":
    main()
