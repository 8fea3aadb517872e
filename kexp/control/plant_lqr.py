"""The LQR baseline of a plant kexp has no formula for: the plant's own discrete linearisation at the equilibrium,
by central finite differences through its ``step`` (:func:`linearise_plant`), and a discrete-time LQR on it
(:class:`PlantLqrController`).

Finite differences: each column comes from two resets and one step each, x_eq ± h_i·e_i with u = u_eq (for Ad) and
x_eq with u = u_eq ± h_j·e_j (for Bd), so 2(n + m) steps plus one from x_eq itself (the equilibrium check).  The
step is h_i = eps·max(1, |c_i|) (c = x_eq for a state, u_eq for an input): eps relative to the coordinate's size,
absolute near 0.  The error of a central difference is truncation, h²·|third derivative|/6, plus the noise δ of one
step over 2h: δ ~ macheps·|x| for a float64 step, ~6e-8·|x| for one in float32.  Measured (tests/test_plant_lqr.py)
on kexp's pendulum upright (x_eq = (π, 0)), stepped by kexp's DOP853 (rtol 1e-10) at Δ = 0.01 s, max error of
(Ad, Bd) against expm of the formula's linearisation:

    eps           1e-2    1e-3    3e-4    1e-4    3e-5    1e-5    1e-6    1e-7
    float64 step  1.6e-6  1.6e-8  1.5e-9  1.6e-10 1.5e-11 8.0e-12 1.8e-10 2.1e-9
    float32 step  2.3e-6  6.9e-5  6.7e-5  7.3e-4  1.9e-3  2.1e-3  2.4e-2

Truncation (∝ eps², exactly h²Δ/6 here) rules above 1e-5, rounding (∝ 1/eps) below; the integrator's tolerance
adds nothing visible (at Δ = 0.5 s, rtol 1e-6 and 1e-10 give the same errors down to eps = 1e-5: the integrator's
error is a smooth function of x0, so it differentiates into a bias of order rtol, not into noise over h).  :data:`EPS` = 1e-4 is one decade above the
float64 minimum: 1.6e-10 there, and ten times less sensitive to a noisy step than 1e-5 (a plant computing in
float32 needs eps ~ 1e-2).  On an exact linear step (tests/plant_rigs.py LinearRig) the error is rounding only,
~1e-17 at x_eq = 0.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, PlantError, require_number
from .explicit import LqrController, lqr_settings

EPS = 1e-4          # relative finite-difference step: the minimum of the error measured above
EQ_TOL = 1e-6       # ‖x⁺ − x_eq‖ / max(1, ‖x_eq‖) above which x_eq is refused as an equilibrium of the plant


@dataclass(frozen=True)
class PlantLinearisation:
    """What :func:`linearise_plant` did: ``eps`` (relative step), ``h_x`` (n,) and ``h_u`` (m,) the steps used,
    ``drift`` = ‖step(x_eq, u_eq) − x_eq‖ (state units), ``dt`` the plant's Δ (s), ``steps`` the plant steps taken."""

    eps: float
    h_x: tuple
    h_u: tuple
    drift: float
    dt: float
    steps: int

    def describe(self) -> str:
        """One line: the step size, the steps taken and the equilibrium drift."""
        return (f"plant linearisation: central differences through the plant's step, eps = {self.eps:g} (relative), "
                f"{self.steps} steps of Δ = {self.dt:g} s; ‖step(x_eq) − x_eq‖ = {self.drift:.2g}")


def _one_step(plant, x0, u) -> np.ndarray:
    plant.reset(np.asarray(x0, dtype=float))
    return np.asarray(plant.step(np.asarray(u, dtype=float)), dtype=float)


def linearise_plant(plant, x_eq, u_eq=None, eps: float = EPS, eq_tol: float = EQ_TOL):
    """(Ad (n, n), Bd (n, m), :class:`PlantLinearisation`): x⁺ ≈ x_eq + Ad (x − x_eq) + Bd (u − u_eq) for one Δ of
    ``plant`` (:class:`~kexp.plants.Plant`: dt, n, m, reset, step), by central differences with relative step
    ``eps`` (module doc).  ``u_eq`` (m,) defaults to 0.  Raises :class:`~kexp.errors.PlantError` (one line) when
    ``x_eq`` is not an equilibrium of the plant (‖step(x_eq, u_eq) − x_eq‖ > eq_tol·max(1, ‖x_eq‖)) and
    ConfigError for eps outside (0, 0.1] or x_eq/u_eq of the wrong size.  Resets and steps the plant
    2(n + m) + 1 times; the caller resets it before using it again."""
    require_number(eps, "eps")
    if not (0 < eps <= 0.1):
        raise ConfigError(f"plant linearisation: eps={eps!r}; use a relative step in (0, 0.1] (default {EPS:g})")
    n, m = int(plant.n), int(plant.m)
    xe = np.asarray(x_eq, dtype=float)
    ue = np.zeros(m) if u_eq is None else np.asarray(u_eq, dtype=float)
    if xe.shape != (n,) or ue.shape != (m,) or not (np.all(np.isfinite(xe)) and np.all(np.isfinite(ue))):
        raise ConfigError(f"plant linearisation: x_eq {xe.tolist()} and u_eq {ue.tolist()} need {n} and {m} finite "
                          "numbers (the plant's n, m)")
    h_x, h_u = eps * np.maximum(1.0, np.abs(xe)), eps * np.maximum(1.0, np.abs(ue))
    x_plus = _one_step(plant, xe, ue)
    drift = float(np.linalg.norm(x_plus - xe))
    if not drift <= eq_tol * max(1.0, float(np.linalg.norm(xe))):
        raise PlantError(f"x_eq = {xe.tolist()} is not an equilibrium of the plant: one step with u = {ue.tolist()} "
                         f"moves it by {drift:.3g} (> {eq_tol:g}·max(1, ‖x_eq‖)); set plant.equilibrium to the "
                         "state the plant rests in")
    Ad, Bd = np.empty((n, n)), np.empty((n, m))
    for i in range(n):
        e = np.zeros(n)
        e[i] = h_x[i]
        Ad[:, i] = (_one_step(plant, xe + e, ue) - _one_step(plant, xe - e, ue)) / (2 * h_x[i])
    for j in range(m):
        e = np.zeros(m)
        e[j] = h_u[j]
        Bd[:, j] = (_one_step(plant, xe, ue + e) - _one_step(plant, xe, ue - e)) / (2 * h_u[j])
    report = PlantLinearisation(eps=float(eps), h_x=tuple(h_x.tolist()), h_u=tuple(h_u.tolist()), drift=drift,
                                dt=float(plant.dt), steps=2 * (n + m) + 1)
    return Ad, Bd, report


def discrete_lqr_gain(Ad, Bd, q: float, r: float, dt: float) -> np.ndarray:
    """K (m, n) of the discrete LQR with Q = q·Δ·I, R = r·Δ·I: Σ_k (q|x_k|² + r|u_k|²)·Δ, the sampled version of
    the continuous cost ∫ q|x|² + r|u|² dt that :class:`~kexp.control.explicit.LqrController` minimises (a
    rectangle rule; the gains agree to O(Δ)).  Raises ConfigError (one line) when (Ad, Bd) is not stabilisable."""
    n, m = Bd.shape
    Q, R = q * dt * np.eye(n), r * dt * np.eye(m)
    try:
        P = sla.solve_discrete_are(Ad, Bd, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ConfigError(f"LQR on the plant's linearisation: the discrete Riccati equation has no stabilising "
                          f"solution ({str(exc).splitlines()[0][:120]}); the plant is not stabilisable at x_eq by "
                          "its linearisation") from None
    K = np.linalg.solve(R + Bd.T @ P @ Bd, Bd.T @ P @ Ad)
    if not np.all(np.isfinite(K)) or np.max(np.abs(np.linalg.eigvals(Ad - Bd @ K))) >= 1.0:
        raise ConfigError("LQR on the plant's linearisation: the gain does not stabilise it (|eig(Ad − Bd K)| >= 1)")
    return K


class PlantLqrController(LqrController):
    """Baseline for a plant with no formula: u = clip(−K (x − x_eq)) with K the discrete LQR (Q = q·Δ·I,
    R = r·Δ·I) of the plant's own finite-difference linearisation at x_eq (:func:`linearise_plant`).  The same
    step interface (and name, ``lqr``) as :class:`~kexp.control.explicit.LqrController`.  ``Ad``, ``Bd`` and
    ``linearisation`` (a :class:`PlantLinearisation`) say what it was built on."""

    name = "lqr"

    def __init__(self, plant, x_eq, u_min, u_max, q: float = 1.0, r: float = 1.0, clf=None, eps: float = EPS):
        lo, hi = lqr_settings(u_min, u_max, int(plant.m), q, r, clf, "PlantLqrController")
        t0 = time.perf_counter()
        self.Ad, self.Bd, self.linearisation = linearise_plant(plant, x_eq, eps=eps)
        self.K = discrete_lqr_gain(self.Ad, self.Bd, q, r, float(plant.dt))
        self.seconds = time.perf_counter() - t0
        self.x_eq = np.asarray(x_eq, dtype=float)
        self.u_min, self.u_max = lo, hi
        self.clf = clf
