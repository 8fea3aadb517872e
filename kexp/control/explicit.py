"""Controllers with the same step interface as the LMPC: an explicit law h(z) and LQR on the true linearisation."""
from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla

from ..errors import ConfigError, require_number
from .checks import check_clf, check_clf_and_law, input_bounds
from .lmpc import ControlStep, region_of


class ExplicitController:
    """u = h(z) (Sontag or −k·L_BV), saturated.  It works on z = Ψ(x) − Ψ(x_eq): run it with
    ``closed_loop(..., model=<the CLF's model>)``.  Raises :class:`~kexp.errors.ConfigError` for a ``clf`` that is
    not a CLF or a ``law`` that is not callable or is built on another V than ``clf.lyap``."""

    def __init__(self, law, clf):
        check_clf_and_law(clf, law, "ExplicitController")
        self.law, self.clf = law, clf
        self.name = getattr(law, "name", "explicit")

    def reset(self) -> None:
        pass

    def step(self, x0, z0) -> ControlStep:
        t0 = time.perf_counter()
        u = self.law(np.asarray(z0, float)[None])[0]
        V0 = float(self.clf.lyap.value(z0))
        return ControlStep(u=u, status="explicit", qp_status="none", iterations=0, qp_iterations=0,
                           solve_time=time.perf_counter() - t0, region=region_of(V0, self.clf.r, self.clf.r_hat),
                           active="none", binds=False, slack=0.0, fallback=False, reason="")


def linearise(system, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the TRUE system at its equilibrium (central differences of F; G at x_eq)."""
    xe = np.asarray(system.equilibrium, float)
    n = system.n
    A = np.empty((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        A[:, i] = (system.drift((xe + e)[None])[0] - system.drift((xe - e)[None])[0]) / (2 * eps)
    return A, np.asarray(system.input_matrix(xe[None])[0], float)


def lqr_settings(u_min, u_max, m: int, q, r, clf, who: str) -> tuple[np.ndarray, np.ndarray]:
    """The input bounds (low, high) of an LQR baseline ``who`` after the checks every one makes: u_min < u_max
    (finite, a number or m numbers each), q and r finite and > 0, ``clf`` (if given) a CLF.  ConfigError otherwise."""
    lo, hi = input_bounds(u_min, u_max, m)
    require_number(q, "controller.q")
    require_number(r, "controller.r")
    if not (q > 0 and r > 0 and np.isfinite(q) and np.isfinite(r)):
        raise ConfigError(f"lqr weights q={q}, r={r}: both must be finite and > 0 (controller.q, controller.r)")
    if clf is not None:
        check_clf(clf, who)
    return lo, hi


class LqrController:
    """Baseline: LQR (Q = q·I, R = r·I) on the true linearisation at the equilibrium, saturated."""

    name = "lqr"

    def __init__(self, system, u_min, u_max, q: float = 1.0, r: float = 1.0, clf=None):
        """Raises :class:`~kexp.errors.ConfigError` unless u_min < u_max (finite, a number or m numbers each) and
        q, r are finite and > 0."""
        lo, hi = lqr_settings(u_min, u_max, system.m, q, r, clf, "LqrController")
        A, B = linearise(system)
        X = sla.solve_continuous_are(A, B, q * np.eye(system.n), r * np.eye(system.m))
        self.K = np.linalg.solve(r * np.eye(system.m), B.T @ X)
        self.x_eq = np.asarray(system.equilibrium, float)
        self.u_min, self.u_max = lo, hi
        self.clf = clf

    def reset(self) -> None:
        pass

    def step(self, x0, z0) -> ControlStep:
        t0 = time.perf_counter()
        u = np.clip(-self.K @ (np.asarray(x0, float) - self.x_eq), self.u_min, self.u_max)
        region = "n/a"
        if self.clf is not None and z0 is not None:
            region = region_of(float(self.clf.lyap.value(z0)), self.clf.r, self.clf.r_hat)
        return ControlStep(u=u, status="explicit", qp_status="none", iterations=0, qp_iterations=0,
                           solve_time=time.perf_counter() - t0, region=region, active="none", binds=False,
                           slack=0.0, fallback=False, reason="")
