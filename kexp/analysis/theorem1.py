"""Theorem 1 of the paper: ‖x(t) − x̂(t)‖ ≤ ν/l_x·(e^{l_x t} − 1), where ν bounds the model error of the
vector field, ‖f(x, u) − f̂(x, u)‖ ≤ ν with f̂ = C(Λz + Σu_i(B_i z + b_i)) at z = Ψ(x) − Ψ(x_eq), and l_x is a
Lipschitz constant of f in x.

The theorem evaluates f̂ along the MODEL's trajectory z(t) (x̂ = x_eq + Cz), which leaves the data manifold
z = Ψ(x): on the manifold f̂ can be exact (Van der Pol's F is a cubic polynomial, inside the degree-5 span).  So ν
is estimated along sampled model trajectories (initial states in the box, random piecewise-constant inputs in
their bounds, over ``horizon`` seconds) and l_x as the largest spectral norm of ∂f/∂x (central differences) over
the states visited — an estimate of the bound, checked against measured prediction errors, not a certificate.
The true F is used only here, in the analysis; the controller never sees it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Theorem1Constants:
    nu: float
    l_x: float
    n_samples: int

    def bound(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        return self.nu / self.l_x * np.expm1(self.l_x * t)


def estimate_constants(system, model, *, low=-1.0, high=1.0, u_min=-5.0, u_max=5.0, n_traj: int = 100,
                       horizon: float = 1.0, hold: int = 10, extra: list | None = None, seed: int = 0,
                       eps: float = 1e-6) -> Theorem1Constants:
    """``extra``: more (x0 (n,), u (T, m)) input histories to include (e.g. the logged run being checked).
    Samples count until a trajectory first leaves the box [x_eq + low, x_eq + high]."""
    rng = np.random.default_rng(seed)
    n, m = system.n, system.m
    lo = model.x_eq + np.broadcast_to(np.asarray(low, float), (n,))
    hi = model.x_eq + np.broadcast_to(np.asarray(high, float), (n,))
    steps = max(1, int(round(horizon / model.dt)))
    ulo, uhi = np.broadcast_to(u_min, (m,)), np.broadcast_to(u_max, (m,))
    cases = [(rng.uniform(lo, hi), np.repeat(rng.uniform(ulo, uhi, (-(-steps // hold), m)), hold, axis=0)[:steps])
             for _ in range(n_traj)] + list(extra or [])
    xs, us, zs = [], [], []
    for x0, u in cases:
        xhat, z = model.predict(x0, u)
        # the region of interest: samples of a trajectory up to where it first leaves the box
        inside = np.all(np.isfinite(z), axis=1) & np.all((xhat >= lo) & (xhat <= hi), axis=1)
        ok = np.cumprod(inside[:-1]).astype(bool)
        xs.append(xhat[:-1][ok])
        zs.append(z[:-1][ok])
        us.append(np.asarray(u, float).reshape(len(u), m)[ok])
    x, u, z = np.concatenate(xs), np.concatenate(us), np.concatenate(zs)
    f = system.rhs(x, u)
    fhat = model.rhs(z, u) @ model.C.T
    nu = float(np.max(np.linalg.norm(f - fhat, axis=1)))
    n_samples = x.shape[0]
    jac = np.empty((n_samples, n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        jac[:, :, i] = (system.rhs(x + e, u) - system.rhs(x - e, u)) / (2 * eps)
    l_x = float(np.max(np.linalg.norm(jac, ord=2, axis=(1, 2))))
    return Theorem1Constants(nu=nu, l_x=l_x, n_samples=n_samples)


def measured_error(model, t: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """‖x(t) − x̂(t)‖ where x̂ is the model's open-loop prediction from x(0) under the same (logged) inputs."""
    xhat, _ = model.predict(x[0], u)
    k = min(len(xhat), len(x))
    return np.linalg.norm(x[:k] - xhat[:k], axis=1)
