"""Accurate integration of a control-affine system, batched over trajectories, with inputs held constant
over each sampling interval (sample-and-hold).

``x0`` has shape (B, n); results have shape (B, T+1, n) (batch, time, state).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ..errors import ConfigError, require_number
from ..systems.base import ControlAffineSystem


@dataclass(frozen=True)
class IntegratorOptions:
    """Options of the adaptive integrator (scipy ``solve_ivp``).  Error is controlled per trajectory chunk of
    ``batch`` trajectories, so one trajectory's error is not diluted by many others."""

    method: str = "DOP853"
    rtol: float = 1e-10
    atol: float = 1e-12
    batch: int = 16

    def __post_init__(self):
        if not isinstance(self.method, str) or self.method not in ("DOP853", "RK45", "Radau", "LSODA", "BDF", "RK23"):
            raise ConfigError(f"data.integrator.method={self.method!r}; valid: DOP853, RK45, RK23, Radau, BDF, LSODA")
        require_number(self.rtol, "data.integrator.rtol")
        require_number(self.atol, "data.integrator.atol")
        if not (0 < self.rtol < 1 and 0 < self.atol < 1):
            raise ConfigError(f"data.integrator rtol={self.rtol}, atol={self.atol}: both must be in (0, 1)")
        require_number(self.batch, "data.integrator.batch", integer=True)
        if self.batch < 1:
            raise ConfigError(f"data.integrator.batch={self.batch}: use an int >= 1")


class IntegrationFailure(RuntimeError):
    """The solver could not integrate (blow-up, NaN)."""


class _NonFinite(Exception):
    """The right-hand side returned NaN/inf (at the time it carries): solve_ivp would loop for ever on a NaN step."""


def _flow(system, x0, t_span, t_eval, u, opts):
    b, n = x0.shape

    def rhs(_t, y):
        d = system.rhs(y.reshape(b, n), u).reshape(-1)
        if not np.isfinite(d).all():
            raise _NonFinite(_t)
        return d

    try:
        sol = solve_ivp(rhs, t_span, x0.reshape(-1), method=opts.method, t_eval=t_eval, rtol=opts.rtol,
                        atol=opts.atol)
    except _NonFinite as exc:
        raise IntegrationFailure(f"integration failed on [{t_span[0]:.4g}, {t_span[1]:.4g}]: the system's "
                                 f"right-hand side is NaN/inf at t={exc.args[0]:.4g}") from None
    if not sol.success or sol.y.shape[1] != len(t_eval) or not np.all(np.isfinite(sol.y)):
        raise IntegrationFailure(f"integration failed on [{t_span[0]:.4g}, {t_span[1]:.4g}]: {sol.message}")
    return sol.y.T.reshape(len(t_eval), b, n).transpose(1, 0, 2)


def integrate(system: ControlAffineSystem, x0: np.ndarray, t: np.ndarray, u: np.ndarray | None = None,
              options: IntegratorOptions = IntegratorOptions()) -> np.ndarray:
    """States at times ``t`` (T+1,) from ``x0`` (B, n).  ``u`` is None (unforced) or (B, T, m): input held over
    [t_k, t_{k+1}).  Returns (B, T+1, n).  Raises :class:`IntegrationFailure` if a trajectory blows up."""
    x0 = np.atleast_2d(np.asarray(x0, dtype=float))
    t = np.asarray(t, dtype=float)
    if x0.shape[1] != system.n:
        raise ConfigError(f"initial states have {x0.shape[1]} components; system {system.name} has n={system.n}")
    if not np.all(np.isfinite(x0)):
        raise ConfigError("initial states contain NaN/inf; give finite initial conditions")
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
        raise ConfigError("time grid must be 1-D, increasing, with at least 2 points")
    out = np.empty((x0.shape[0], t.size, system.n))
    for s in range(0, x0.shape[0], options.batch):
        sl = slice(s, s + options.batch)
        if u is None:
            out[sl] = _flow(system, x0[sl], (t[0], t[-1]), t, None, options)
        else:
            uu = np.asarray(u, dtype=float)[sl]
            out[sl, 0] = x0[sl]
            for k in range(t.size - 1):
                seg = _flow(system, out[sl, k], (t[k], t[k + 1]), t[k:k + 2], uu[:, k], options)
                out[sl, k + 1] = seg[:, 1]
    return out
