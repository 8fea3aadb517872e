"""The closed loop's plant step: kexp.simulate.stepper.HeldInputStepper (Hairer's DOP853 through
scipy.integrate.ode) against one scipy.integrate.solve_ivp call per step (kexp.data.integrate.integrate), the same
method and tolerances (rtol 1e-10, atol 1e-12), side by side.

For each system, --n random (state, input) pairs (x in [-2, 2]², u in [-5, 5], default_rng(0)); each pair is
stepped over Δ = 0.01 s by both, alternating which goes first, --repeat times; the table gives the median and
p90 per step of each, their ratio, and the largest difference between the two results.

    python benchmarks/stepper.py [--n 300] [--repeat 5]
"""
import argparse
import os
import time

import numpy as np

from kexp.data.integrate import IntegratorOptions, integrate
from kexp.simulate.stepper import HeldInputStepper
from kexp.systems import Pendulum, VanDerPol


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=300)
    p.add_argument("--repeat", type=int, default=5)
    args = p.parse_args()
    print(f"load: {' / '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)\n")
    print("| system | solve_ivp median / p90 [ms] | HeldInputStepper median / p90 [ms] | ratio (medians) | max difference |")
    print("|---|---:|---:|---:|---:|")
    opts = IntegratorOptions(batch=1)
    t = np.array([0.0, 0.01])
    for system in (VanDerPol(), Pendulum()):
        stepper = HeldInputStepper(system, opts)
        rng = np.random.default_rng(0)
        pairs = [(rng.uniform(-2, 2, 2), rng.uniform(-5, 5, 1)) for _ in range(args.n)]
        ivp, ode, diff = [], [], 0.0
        for rep in range(args.repeat):
            for i, (x, u) in enumerate(pairs):
                first_ivp = (i + rep) % 2 == 0
                for which in ((0, 1) if first_ivp else (1, 0)):
                    start = time.perf_counter()
                    if which == 0:
                        a = integrate(system, x[None], t, u[None, None], opts)[0, 1]
                        ivp.append(time.perf_counter() - start)
                    else:
                        b = stepper.step(x, u, 0.0, 0.01)
                        ode.append(time.perf_counter() - start)
                diff = max(diff, float(np.max(np.abs(a - b))))
        mi, mo = np.median(ivp) * 1e3, np.median(ode) * 1e3
        print(f"| {system.name} | {mi:.3f} / {np.percentile(ivp, 90) * 1e3:.3f} | {mo:.3f} / "
              f"{np.percentile(ode, 90) * 1e3:.3f} | {mi / mo:.2f}× | {diff:.1e} |")


if __name__ == "__main__":
    main()
