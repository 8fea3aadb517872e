#!/usr/bin/env python
"""A block's map and its input derivatives on the LMPC's general path (several inputs): the exponential of the
augmented generator M = [[Λ + Σ u_i B_i, Σ u_i b_i], [0, 0]]Δ and its Fréchet derivative along each input's
direction, two ways, side by side on the same generators (issue 14):

* ``taylor × m``: one :func:`kexp.control.expm_kernels.expm_frechet` call per input (Taylor on the pairs (A^j, ∂A^j),
  2^s from ‖M‖∞/0.5) — the general path's kernel until this round;
* ``padé shared``: :func:`kexp.control.expm_kernels.expm_frechet_pade`, the [13/13] Padé approximant and its derivative
  with the powers, numerator, denominator and LU shared by the inputs (what ``block_maps_expm`` calls now).

The model is the scaling benchmark's two-input one (slow manifold, both states actuated, degree 5: k = 20, m = 2);
the inputs are u = (a, −a) for a few sizes a.  For each, the median time per block over --reps calls (interleaved,
one BLAS thread), their ratio, and the largest error of E and of each L against the Van Loan block
expm([[M, D_i], [0, M]]) by scipy, relative to the block's largest entry.

    python benchmarks/expm_maps.py [--reps 300]
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg as sla  # noqa: E402

from kexp.control.expm_kernels import expm_frechet, expm_frechet_pade  # noqa: E402
from kexp.control.kernels import _augmented, _directions  # noqa: E402
from kexp.systems import SlowManifold  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scaling import build  # noqa: E402


def taylor(M, D, E, L):
    for i in range(D.shape[0]):
        expm_frechet(M, D[i], E, L[i])


def errors(M, D, E, L) -> tuple[float, float]:
    n = M.shape[0]
    eE = eL = 0.0
    for i in range(D.shape[0]):
        big = sla.expm(np.block([[M, D[i]], [np.zeros((n, n)), M]]))
        eE = max(eE, np.max(np.abs(E - big[:n, :n])) / np.max(np.abs(big[:n, :n])))
        eL = max(eL, np.max(np.abs(L[i] - big[:n, n:])) / np.max(np.abs(big[:n, n:])))
    return eE, eL


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=300, help="calls per kernel and input size")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    model, _clf, _law = build(SlowManifold(inputs="both"), 5, 100)
    lam, B, b = (np.ascontiguousarray(a) for a in (model.Lambda, model.B, model.b))
    dt = model.dt
    D = _directions(B, b, dt)
    n, m = D.shape[1], D.shape[0]
    kernels = {"taylor × m": taylor, "padé shared": expm_frechet_pade}
    rows = []
    for a in (0.0, 0.5, 2.0, 5.0):
        M = _augmented(lam, B, b, np.array([a, -a]), dt)
        out = {}
        for name, f in kernels.items():                 # warm-up (JIT) and the outputs
            E, L = np.empty((n, n)), np.empty((m, n, n))
            f(M, D, E, L)
            out[name] = errors(M, D, E, L)
        times = {name: [] for name in kernels}
        E, L = np.empty((n, n)), np.empty((m, n, n))
        for rep in range(args.reps):
            for name in (list(kernels) if rep % 2 == 0 else list(kernels)[::-1]):
                t0 = time.perf_counter()
                kernels[name](M, D, E, L)
                times[name].append(time.perf_counter() - t0)
        med = {name: float(np.median(t)) * 1e6 for name, t in times.items()}
        rows.append((a, np.max(np.sum(np.abs(M), axis=0)), med, out))
    print(f"\n- date {time.strftime('%Y-%m-%d %H:%M')}; {os.cpu_count()} CPUs; load average {load0[0]:.2f} at the "
          f"start, {os.getloadavg()[0]:.2f} at the end; one BLAS thread; k = {model.k}, m = {m}, (k+1)² blocks of "
          f"{n}×{n}; {args.reps} calls each, interleaved\n")
    print("| u = (a, −a), a | ‖M‖₁ | taylor × m [µs] | padé shared [µs] | ratio | error E, L (taylor) | "
          "error E, L (padé) |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for a, nrm, med, out in rows:
        t, p = med["taylor × m"], med["padé shared"]
        et, ep = out["taylor × m"], out["padé shared"]
        print(f"| {a:g} | {nrm:.2f} | {t:.1f} | {p:.1f} | {t / p:.2f} | {et[0]:.1e}, {et[1]:.1e} | "
              f"{ep[0]:.1e}, {ep[1]:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
