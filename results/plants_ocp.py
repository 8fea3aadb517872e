#!/usr/bin/env python
"""Could a failure be saved at all?  A long-horizon optimal-control problem through a Gymnasium plant's own step.

For each initial state x0 this searches for an admissible input sequence that brings the plant into the success
ball ‖x(T) − x_eq‖ < sim.tol and holds it there, and writes ``results/plants/<experiment>_ocp.csv`` with columns
x0_1…x0_n, feasible, final_error, cost (J over [0, sim.T], kexp's cost: ∫‖x − x_eq‖² + r‖u‖² dt): the file
``kexp-results plants`` reads next to the rows ``<experiment>_<configuration>.csv`` (``--name`` for another
system name).  The x0 are those of ``results/sweep_lib.sh x0_box LOW HIGH SEED N`` (or a row's, ``--x0-csv``).

    python results/plants_ocp.py gym_pendulum --low=-0.6,-1.5 --high=0.6,1.5           # 100 x0, seed 42
    python results/plants_ocp.py gym_inverted_pendulum --low=-0.5,-0.6,0,0 --high=0.5,0.6,0,0 -n 100
    python results/plants_ocp.py gym_pendulum --x0-csv ROW.csv        # the x0 of a results row instead

The method, and why:
- *Through the environment's own step* (kexp's gymnasium plant, the unwrapped env): no formula is trusted, the
  input clip, Pendulum-v1's speed clip at ±8 rad/s and MuJoCo's joint limits and contacts are the plant's own.
  InvertedPendulum-v5 has no formula to write down at all.
- *LQR-stabilised single shooting*: u_k = sat(−K(x_k − x_eq) + v_k), with K the discrete LQR gain of the
  plant's numerical linearisation (central differences, step 1e-5 in x, 1e-4 in u; Q = Δ·I, R = r·Δ·I) and the
  decision variables v a feedforward held over blocks of ``--block`` steps during the first ``--horizon`` seconds
  (v = 0 after: the saturated LQR holds what the optimiser brought into its basin).  During the free part sat is
  smooth, c + w·tanh((·− c)/w) for the bounds c ± w (a hard clip has no gradient where it saturates, and a fall
  saturates the LQR for seconds); the inputs stay inside the bounds.  Plain single shooting over 3 s of an
  unstable plant (e^{λT} ≈ 1e5 for Pendulum-v1) is too ill-conditioned for a gradient method; with the feedback in
  the loop the rollouts stay bounded and v = 0 is (nearly: the smooth sat) the LQR, so the search starts there.
  The bounds |u| ≤ u_max hold by construction (sat); any input sequence is reachable (|v| ≤ 4·u_max overrides
  the feedback).
- L-BFGS-B on J(v) over [0, horizon + 2 s] plus (‖x(end) − x_eq‖/tol)², forward-difference gradients (only the
  steps after a perturbed block are re-simulated); starts: v = 0, then (when that ends outside the ball) ±u_max
  over the first second; the best of these and of the plain saturated LQR (so the answer never costs more than
  the LQR where the LQR succeeds).  The answer is then *replayed* on the plant to sim.T: ``feasible`` is
  what the replay reached, so True is a constructive proof (an input sequence that does it, on the env), while
  False only says this search found none.

Runtime (measured on the shared 2-core machine, one core): Pendulum-v1 0.1-7 s per x0, 100 x0 in 3.8 min;
InvertedPendulum-v5 2-8 s per x0 the LQR already brings home, 15-60 s where it has to search (three starts),
100 x0 of x ∈ [-0.5, 0.5], θ ∈ [-0.6, 0.6] in 10.5 min.  A shorter search (--horizon 3 --block 5) is about twice
as fast but missed one of five savable x0 tried and found costlier inputs for the others.

Committed answers (results/plants/gym_*_ocp.csv), the 100 x0 of each command above: Pendulum-v1 100/100 feasible (the
LQR's one failure by a fall and a swing back, J = 105), InvertedPendulum-v5 98/100 (10 of the LQR's 12 failures,
J 4.8-27, by inputs that ride the slider's stop).
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg as sla
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def experiment_settings(experiment: str, overrides=()):
    """(plant config, x_eq or None, sim.T, sim.tol, sim.r) of ``+experiment=<experiment>``, composed as kexp does."""
    from hydra import compose, initialize_config_dir

    from kexp.app.build import build_plant_config
    from kexp.app.conf import CONF_DIR
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("config", overrides=[f"+experiment={experiment}", *overrides])
    plant_cfg = build_plant_config(cfg.get("plant"))
    eq = plant_cfg.equilibrium
    return plant_cfg, (None if eq is None else np.asarray(eq, dtype=float)), float(cfg.sim.T), float(cfg.sim.tol), \
        float(cfg.sim.r)


class Shooter:
    """The plant with its LQR (gain K about x_eq) and the rollout u_k = sat(−K(x_k − x_eq) + v_k)."""

    def __init__(self, plant, x_eq, r: float):
        self.p, self.xe, self.r = plant, np.asarray(x_eq, dtype=float), r
        bounds = plant.input_bounds()
        self.lo, self.hi = (np.full(plant.m, -np.inf), np.full(plant.m, np.inf)) if bounds is None else bounds
        self.dt, self.n, self.m = plant.dt, plant.n, plant.m
        A, B = self.linearise()
        Q, R = self.dt * np.eye(self.n), r * self.dt * np.eye(self.m)
        P = sla.solve_discrete_are(A, B, Q, R)
        self.K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)

    def step(self, x, u):
        self.p.reset(x)
        return self.p.step(u)

    def linearise(self, h=1e-5, hu=1e-4):
        """A (n, n), B (n, m) of the step map at (x_eq, 0) by central differences through the plant's step."""
        n, m, xe, u0 = self.n, self.m, self.xe, np.zeros(self.m)
        A = np.column_stack([(self.step(xe + h * e, u0) - self.step(xe - h * e, u0)) / (2 * h) for e in np.eye(n)])
        B = np.column_stack([(self.step(xe, hu * e) - self.step(xe, -hu * e)) / (2 * hu) for e in np.eye(m)])
        return A, B

    def rollout(self, x0, v, n_steps, start=0, x_start=None):
        """States (n_steps + 1, n) and inputs (n_steps, m) from x0 under the feedforward v (steps, m; zero beyond
        its end); from step ``start`` on when ``x_start`` (the state there) is given (the earlier rows left 0)."""
        x = np.zeros((n_steps + 1, self.n))
        u = np.zeros((n_steps, self.m))
        k0 = start if x_start is not None else 0
        x[k0] = x_start if x_start is not None else x0
        self.p.reset(x[k0])
        c, w = (self.hi + self.lo) / 2, (self.hi - self.lo) / 2
        smooth = bool(np.all(np.isfinite(w)))
        for k in range(k0, n_steps):
            fb = -self.K @ (x[k] - self.xe)
            if k < len(v) and smooth:   # the free part: a smooth saturation, so that v keeps a gradient
                u[k] = c + w * np.tanh((fb + v[k] - c) / w)
            else:
                u[k] = np.clip(fb + (v[k] if k < len(v) else 0.0), self.lo, self.hi)
            x[k + 1] = self.p.step(u[k])
        return x, u

    def cost(self, x, u):
        e = np.sum((x - self.xe) ** 2, axis=1)
        return float(self.dt * np.sum(0.5 * (e[:-1] + e[1:])) + self.r * self.dt * np.sum(u ** 2))


def solve(sh: Shooter, x0, T: float, tol: float, horizon: float, block: int, max_iter: int):
    """(feasible, final_error, cost over [0, T], seconds) of the best feedforward the search finds from x0."""
    t0 = time.perf_counter()
    n_free = int(round(horizon / sh.dt))
    n_blocks = -(-n_free // block)
    n_obj = n_free + int(round(2.0 / sh.dt))
    n_sim = int(round(T / sh.dt))
    vmax = 4.0 * float(np.max(np.where(np.isfinite(sh.hi), sh.hi, 1.0)))

    def expand(p):
        return np.repeat(p.reshape(n_blocks, sh.m), block, axis=0)[:n_free]

    def objective(x, u):
        return sh.cost(x, u) + float(np.sum((x[-1] - sh.xe) ** 2)) / tol ** 2

    def fun_grad(p):
        v = expand(p)
        x, u = sh.rollout(x0, v, n_obj)
        f = objective(x, u)
        g = np.zeros_like(p)
        eps = 1e-4
        for j in range(p.size):
            b = j // sh.m
            q = p.copy()
            q[j] += eps
            k = b * block
            xs, us = sh.rollout(x0, expand(q), n_obj, start=k, x_start=x[k])
            xs[:k], us[:k] = x[:k], u[:k]
            g[j] = (objective(xs, us) - f) / eps
        return f, g

    starts = [np.zeros(n_blocks * sh.m)]
    first_s = max(1, int(round(1.0 / (sh.dt * block))))
    for s in (1.0, -1.0):
        p = np.zeros((n_blocks, sh.m))
        p[:first_s] = s * vmax / 4.0
        starts.append(p.reshape(-1))
    x, u = sh.rollout(x0, np.zeros((0, sh.m)), n_sim)   # the saturated LQR itself (hard clip, v = 0)
    err = float(np.linalg.norm(x[-1] - sh.xe))
    best = (err < tol, err, sh.cost(x, u))
    for p0 in starts:
        res = minimize(fun_grad, p0, jac=True, method="L-BFGS-B", bounds=[(-vmax, vmax)] * p0.size,
                       options={"maxiter": max_iter})
        x, u = sh.rollout(x0, expand(res.x), n_sim)
        err = float(np.linalg.norm(x[-1] - sh.xe))
        cand = (err < tol, err, sh.cost(x, u))
        if (cand[0], -cand[2]) > (best[0], -best[2]) or (not best[0] and not cand[0] and cand[1] < best[1]):
            best = cand
        if cand[0]:
            break
    return (*best, time.perf_counter() - t0)


def x0_list(args, n: int):
    if args.x0_csv:
        with open(args.x0_csv, newline="") as f:
            rows = list(csv.DictReader(f))
        cols = [f"x0_{i + 1}" for i in range(n)]
        return np.array([[float(r[c]) for c in cols] for r in rows])
    lo = np.array([float(v) for v in args.low.split(",")])
    hi = np.array([float(v) for v in args.high.split(",")])
    if lo.size != n or hi.size != n:
        raise SystemExit(f"plants_ocp: --low/--high need {n} numbers (one per state)")
    # the draw of results/sweep_lib.sh x0_box (kexp-results x0): state by state, so a row's x0 are these
    x = np.random.default_rng(args.seed).uniform(lo[:, None], hi[:, None], (n, args.n)).T
    return np.where(hi > lo, x, lo)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("experiment", help="a kexp experiment preset on a gymnasium plant, e.g. gym_pendulum")
    ap.add_argument("--low", help="the x0 box's lower corner, one number per state (comma-separated)")
    ap.add_argument("--high", help="the x0 box's upper corner")
    ap.add_argument("-n", type=int, default=100, help="number of x0 drawn uniformly from the box (default 100), "
                                                      "as results/sweep_lib.sh x0_box LOW HIGH SEED N draws them")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--x0-csv", help="take the x0 from this CSV's x0_1…x0_n columns instead (a results row)")
    ap.add_argument("--horizon", type=float, default=4.0, help="seconds of free feedforward (default 4)")
    ap.add_argument("--block", type=int, default=3, help="steps per feedforward block (default 3)")
    ap.add_argument("--max-iter", type=int, default=60, help="L-BFGS-B iterations per start (default 60)")
    ap.add_argument("-o", "--out", default=str(ROOT / "results" / "plants"),
                    help="folder of the CSV (default results/plants/)")
    ap.add_argument("--name", help="the CSV's system name, <name>_ocp.csv, as the rows' <name>_<configuration>.csv "
                                   "(default: the experiment's name)")
    args = ap.parse_args(argv)
    if not args.x0_csv and not (args.low and args.high):
        ap.error("give --low and --high (the x0 box) or --x0-csv")
    from threadpoolctl import threadpool_limits

    from kexp.plants.gymnasium import make_gymnasium_plant
    threadpool_limits(1)   # tiny products: BLAS threads only cost (and the machine is shared)
    plant_cfg, x_eq, T, tol, r = experiment_settings(args.experiment)
    plant = make_gymnasium_plant(plant_cfg)
    try:
        xe = np.zeros(plant.n) if x_eq is None else x_eq
        sh = Shooter(plant, xe, r)
        X0 = x0_list(args, plant.n)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{args.name or args.experiment}_ocp.csv"
        rows = []
        for i, x0 in enumerate(X0):
            ok, err, cost, sec = solve(sh, x0, T, tol, args.horizon, args.block, args.max_iter)
            rows.append((x0, ok, err, cost))
            print(f"{i + 1:3d}/{len(X0)} x0={np.round(x0, 4).tolist()} feasible={ok} final_error={err:.2e} "
                  f"J={cost:.4f} ({sec:.1f} s)", flush=True)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow([f"x0_{i + 1}" for i in range(plant.n)] + ["feasible", "final_error", "cost"])
            for x0, ok, err, cost in rows:
                w.writerow([f"{v:.10g}" for v in x0] + [ok, f"{err:.6g}", f"{cost:.10g}"])
        n_ok = sum(r[1] for r in rows)
        print(f"{path}: feasible from {n_ok}/{len(rows)} x0 (horizon {args.horizon:g} s of free input, then the "
              f"LQR; T = {T:g} s, tol = {tol:g})")
    finally:
        plant.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
