"""One sample-and-hold step of the true system, fast: x(t_k + Δ) from x(t_k) with u held over the step.

The closed loop integrates a thousand short intervals per run.  ``scipy.integrate.solve_ivp`` spends more time
on each call's bookkeeping (building a solver object, validation, output) than on the right-hand side's
evaluations; Hairer's DOP853 behind ``scipy.integrate.ode`` does the same adaptive 8th-order step with the same
error control (rtol, atol) without it (with the constant-G path below: 4.8–5.3× faster per step on a quiet
machine, ``benchmarks/stepper.py``).  The two take the same steps here (results equal to 2.2e-16 on 200 random
states and inputs; the test allows 1e-12, far below the tolerance).  Methods other than DOP853 and RK45 (``dopri5``) fall back to ``integrate``.

A system that declares ``constant_input_matrix = True`` (all of kexp's own) has G·u formed once per step by
``ControlAffineSystem.input_term``, the term ``rhs`` adds; each right-hand-side call is then the drift plus that vector
(bit-identical to ``rhs``, a test), about a quarter of the time per call.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from ..data.integrate import IntegrationFailure, IntegratorOptions, integrate

_ODE_NAMES = {"DOP853": "dop853", "RK45": "dopri5"}
MAX_STEPS = 100_000   # internal steps per interval before the step counts as failed (a blow-up, or a stiff plant)


class HeldInputStepper:
    """x(t1) from x(t0) for ``system`` with the input ``u`` held over [t0, t1] (:meth:`step`).  One instance per
    closed loop (the integrator keeps its work arrays between steps; nothing else carries over)."""

    def __init__(self, system, options: IntegratorOptions = IntegratorOptions(batch=1)):
        self.system, self.options = system, options
        self._u = np.zeros((1, system.m))
        self._gu = None    # G·u of the current step when G is constant, else None
        self.seconds = 0.0    # wall-clock time spent in step (a job's time breakdown)
        self._ode = None
        name = _ODE_NAMES.get(options.method)
        if name is not None:
            from scipy.integrate import ode
            self._ode = ode(self._rhs).set_integrator(name, rtol=options.rtol, atol=options.atol, nsteps=MAX_STEPS)
            self._ode.set_solout(self._solout)
        self._error: BaseException | None = None

    def _rhs(self, _t, y):
        # an exception cannot cross the Fortran integrator (scipy reports something else, after up to MAX_STEPS
        # steps): keep it, return a harmless derivative, stop at the next accepted step (_solout) and re-raise it
        if self._error is not None:
            return np.zeros_like(y)
        try:
            if self._gu is not None:
                return self.system.drift(y[None])[0] + self._gu
            return self.system.rhs(y[None], self._u)[0]
        except BaseException as exc:  # noqa: BLE001 - re-raised by step(), unchanged
            self._error = exc
            return np.zeros_like(y)

    def _solout(self, _t, _y):
        return -1 if self._error is not None else 0

    def step(self, x: np.ndarray, u: np.ndarray, t0: float, t1: float) -> np.ndarray:
        """The state at t1 (n,); raises :class:`~kexp.data.integrate.IntegrationFailure` if the integration
        fails or leaves the finite numbers."""
        start = time.perf_counter()
        try:
            return self._step(x, u, t0, t1)
        finally:
            self.seconds += time.perf_counter() - start

    def _step(self, x, u, t0, t1):
        if self._ode is None:
            return integrate(self.system, x[None], np.array([t0, t1]), np.asarray(u, float)[None, None],
                             self.options)[0, 1]
        self._u = np.asarray(u, float).reshape(1, -1)
        self._error = None
        self._gu = None
        if self.system.constant_input_matrix:
            self._gu = self.system.input_term(np.asarray(x, float)[None], self._u)[0]   # as rhs adds it
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # dop853 warns before it gives up; the failure is raised below
            try:
                self._ode.set_initial_value(np.asarray(x, float), t0)
                y = self._ode.integrate(t1)
            except (ValueError, FloatingPointError, OverflowError) as exc:
                raise IntegrationFailure(f"integration failed on [{t0:.4g}, {t1:.4g}]: {exc}") from None
        if self._error is not None:   # the system's own code raised: its exception, as solve_ivp would give it
            error, self._error = self._error, None
            raise error
        if not self._ode.successful() or not np.all(np.isfinite(y)):
            code = self._ode.get_return_code()
            raise IntegrationFailure(f"integration failed on [{t0:.4g}, {t1:.4g}]: "
                                     f"{self.options.method} return code {code}")
        return np.array(y, dtype=float)
