#!/usr/bin/env python
"""Identification under measurement noise: least squares (LS) against instrumental variables (IV), issue 34.

For each system, data kind, noise level and estimator the model is identified from noisy data and judged on
clean held-out runs of the same kind:

- eigenvalue error: the slow manifold ẋ1 = μx1, ẋ2 = λ(x2 − x1²) (μ = −0.7, λ = 0.4: its x2 mode grows) has the
  Koopman eigenvalues μ, λ, 2μ on the monomials of degree 2; the error is the largest relative distance from each
  to the nearest identified eigenvalue.  Van der Pol (μ = 1) has no finite invariant subspace; its error is that of
  the model's linearisation at x_eq (the n×n Jacobian C·Λ·∂z/∂x, kexp.identify.diagnostics style) against the true
  0.5 ± 0.866i, and "lost" when the pair came out real;
- 1-s and 2-s RMSE of the model's prediction (model.predict under the recorded inputs for forced data) from
  windows of the clean held-out runs, in state units.

Data: the slow manifold from the box [-1, 1]² (100 runs × 4 s), Van der Pol from [-2.5, 2.5]² (100 runs × 10 s, the
working preset's box), both at Δ = 0.01 s; forced data under the robustness rows' excitation (uniform in [-1, 1]
held 10 steps) with B, b regressed (G unknown).  Noise: Gaussian, σ = p × the data's RMS per state, on every
sample (kexp.data.noise.add_measurement_noise), unsmoothed.  Each cell is the worst over --seeds noise draws
(default 3).  The table is written by ``--write results/identification.md`` and read by the README and
tests/test_identification_table.py; nothing in it is typed by hand.

    python benchmarks/identification_noise.py [--seeds 3] [--write results/identification.md] [--quick]
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

NOISE = (0.0, 0.01, 0.03, 0.05)
ESTIMATORS = ("ls", "iv")
VDP_TRUE = np.array([0.5 + 0.8660254037844386j, 0.5 - 0.8660254037844386j])


def setups(quick: bool):
    """(name, system, dictionary, sampler, data config kwargs, held-out config kwargs) per system."""
    from kexp.data import Box
    from kexp.dictionary import Monomials
    from kexp.systems import SlowManifold, VanDerPol
    scale = 0.25 if quick else 1.0
    return [
        ("slow_manifold", SlowManifold(mu=-0.7, lam=0.4), Monomials(2, 2, include_constant=False),
         Box(max(8, int(100 * scale)), -1.0, 1.0), dict(T=4.0), Box(10, -1.0, 1.0)),
        ("vanderpol", VanDerPol(), Monomials(2, 5, include_constant=False),
         Box(max(20, int(100 * scale)), -2.5, 2.5), dict(T=10.0), Box(10, -2.0, 2.0)),
    ]


def true_eigs(name: str, system) -> np.ndarray | None:
    if name == "slow_manifold":
        return np.array([system.mu, system.lam, 2 * system.mu], dtype=complex)
    return None


def linearisation(model) -> np.ndarray:
    """Eigenvalues of the model's vector field's Jacobian at x_eq: C Λ ∂z/∂x(x_eq)."""
    J = model.lift_jacobian(model.x_eq[None])[0]
    return np.linalg.eigvals(model.C @ model.Lambda @ J)


def eig_error(name, system, model) -> tuple[float, str]:
    """(relative eigenvalue error, note) as the module docstring defines it."""
    ref = true_eigs(name, system)
    if ref is not None:
        err = max(np.min(np.abs(model.eigenvalues - v)) / abs(v) for v in ref)
        return float(err), ""
    lin = linearisation(model)
    if np.all(np.abs(lin.imag) < 1e-12):
        return float("inf"), "lost"
    err = max(np.min(np.abs(lin - v)) / abs(v) for v in VDP_TRUE)
    return float(err), ""


def rmse(model, test, horizon: float, forced: bool, stride: int = 50) -> float:
    h = int(round(horizon / model.dt))
    errs = []
    for i in range(test.n_traj):
        x = test.x[i]
        u = test.u[i] if forced else np.zeros((x.shape[0] - 1, model.m))
        for t0 in range(0, x.shape[0] - h, stride):
            xh, _ = model.predict(x[t0], u[t0:t0 + h])
            errs.append(xh[-1] - x[t0 + h])
    e = np.asarray(errs)
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))


def cell(name, system, dic, sampler, dkw, held, forced, noise, estimator, seeds):
    from kexp.data import DataConfig, Excitation, collect
    from kexp.data.noise import add_measurement_noise
    from kexp.identify import IdentifyConfig, identify
    exc = Excitation(-1.0, 1.0, 10) if forced else None
    data = collect(system, sampler, DataConfig(**dkw, excitation=exc))
    test = collect(system, held, DataConfig(T=3.0, seed=7, excitation=exc))
    cfg = IdentifyConfig(inputs="regression" if forced else "projection", estimator=estimator, holdout=0.0)
    worst = {"eig": 0.0, "note": "", "1s": 0.0, "2s": 0.0}
    lost = 0
    for seed in range(seeds if noise > 0 else 1):
        noisy = add_measurement_noise(data, noise, seed=seed, x_eq=system.equilibrium) if noise > 0 else data
        model = identify(system, noisy, dic, cfg)
        e, note = eig_error(name, system, model)
        lost += note == "lost"
        worst["eig"] = max(worst["eig"], e)
        worst["1s"] = max(worst["1s"], rmse(model, test, 1.0, forced))
        worst["2s"] = max(worst["2s"], rmse(model, test, 2.0, forced))
    worst["note"] = f"pair lost in {lost}/{seeds}" if lost else ""
    return worst


def fmt_eig(v: float, note: str) -> str:
    return note if note and not np.isfinite(v) else f"{100 * v:.3g} %" + (f" ({note})" if note else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="noise draws per cell (the worst is shown)")
    ap.add_argument("--write", type=Path, help="also write the table (Markdown) to this file")
    ap.add_argument("--quick", action="store_true", help="a quarter of the data, one draw: a smoke run")
    args = ap.parse_args(argv)
    seeds = 1 if args.quick else args.seeds
    lines = ["| system | data | noise σ | estimator | eigenvalue error | 1-s RMSE | 2-s RMSE |",
             "|---|---|---:|---|---:|---:|---:|"]
    t0 = time.perf_counter()
    for name, system, dic, sampler, dkw, held in setups(args.quick):
        for forced in (False, True):
            for noise in NOISE:
                for est in ESTIMATORS:
                    c = cell(name, system, dic, sampler, dkw, held, forced, noise, est, seeds)
                    row = (f"| {name} | {'forced, B regressed' if forced else 'unforced'} | "
                           f"{100 * noise:g} % | {est.upper()} | {fmt_eig(c['eig'], c['note'])} | {c['1s']:.4f} | "
                           f"{c['2s']:.4f} |")
                    lines.append(row)
                    print(row, flush=True)
    foot = (f"\nWorst of {seeds} noise draw(s) per cell; clean held-out runs; generated by "
            f"`python benchmarks/identification_noise.py{' --quick' if args.quick else ''}` "
            f"(numpy {np.__version__}, {platform.machine()}, {time.perf_counter() - t0:.0f} s).")
    print(foot)
    if args.write:
        args.write.write_text("\n".join(lines) + "\n" + foot + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
