"""Real-time pacing (sim.realtime): how closely the paced closed loop keeps its period Δ on this machine.

A fast loop (Van der Pol on kexp's integrator, a constant input: ~0.1 ms of work per step) is run paced for --steps
steps at Δ = --dt, once per busy-wait setting (``kexp.simulate.pacing.SPIN_S``: the last part of each wait spent
polling the clock; 0 = ``time.sleep`` alone), alternating, --repeat times.  Each step's start is taken when the
controller is called; the table gives |actual period − Δ| (median, p99, max) over all periods, and the pacer's
own misses and lateness (end of a step's work − its deadline; negative: time to spare).

    python benchmarks/realtime_jitter.py [--steps 500] [--dt 0.01] [--repeat 3]
"""
import argparse
import os
import time

import numpy as np

from kexp.control.lmpc import ControlStep
from kexp.simulate import SimConfig, closed_loop, pacing
from kexp.systems import VanDerPol


class StampedConstant:
    """u = 0.3 every step; the wall-clock time of each call (the start of each step's control) in ``starts``."""
    name = "constant"

    def __init__(self):
        self.starts = []

    def reset(self):
        self.starts = []

    def step(self, x0, z0):
        self.starts.append(time.perf_counter())
        return ControlStep(u=np.array([0.3]), status="explicit", qp_status="none", iterations=0, qp_iterations=0,
                           solve_time=0.0, region="n/a", active="none", binds=False, slack=0.0, fallback=False,
                           reason="")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--dt", type=float, default=0.01)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--spins", type=float, nargs="+", default=[0.0, 1e-3])
    args = p.parse_args()
    print(f"load: {' / '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min); {os.cpu_count()} cores\n")
    cfg = SimConfig(T=args.steps * args.dt, dt=args.dt, realtime=True)
    err = {s: [] for s in args.spins}
    summ = {s: [] for s in args.spins}
    for _ in range(args.repeat):
        for spin in args.spins:
            pacing.SPIN_S = spin
            ctrl = StampedConstant()
            run = closed_loop(VanDerPol(), ctrl, np.array([0.5, -0.2]), cfg)
            err[spin].append(np.abs(np.diff(ctrl.starts) - args.dt))
            summ[spin].append(run.realtime)
    print(f"Δ = {args.dt * 1e3:g} ms, {args.steps} steps × {args.repeat} runs per setting\n")
    print("| busy-wait [ms] | \\|period − Δ\\| median [µs] | p99 [µs] | max [µs] | misses | lateness max [ms] |"
          " lateness median [ms] |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for spin in args.spins:
        e = np.concatenate(err[spin]) * 1e6
        s = summ[spin]
        print(f"| {spin * 1e3:g} | {np.median(e):.1f} | {np.percentile(e, 99):.1f} | {e.max():.1f} | "
              f"{sum(r.misses for r in s)} | {max(r.late_max for r in s) * 1e3:.3f} | "
              f"{np.median([r.late_median for r in s]) * 1e3:.3f} |")


if __name__ == "__main__":
    main()
