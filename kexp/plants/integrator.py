"""kexp's own plant: a :class:`~kexp.systems.base.ControlAffineSystem` integrated accurately over each held step
(adaptive DOP853, :class:`~kexp.simulate.stepper.HeldInputStepper`).  The default plant; the closed loop's numbers
are those kexp has always produced (the same steps of the same integrator, bit for bit: a test)."""
from __future__ import annotations

import numpy as np

from ..data.integrate import IntegratorOptions
from ..simulate.stepper import HeldInputStepper
from .base import Plant


class IntegratorPlant(Plant):
    """``system`` in sample-and-hold at Δ = ``dt`` s: :meth:`step` integrates x over [kΔ, (k+1)Δ) with u held.
    Raises :class:`~kexp.data.integrate.IntegrationFailure` when the integration fails (the closed loop counts
    the run as diverged).  ``seconds``: wall-clock time spent integrating."""

    kind = "integrator"

    def __init__(self, system, dt: float, options: IntegratorOptions = IntegratorOptions(batch=1)):
        self.system, self.dt, self.options = system, float(dt), options
        self.n, self.m = system.n, system.m
        self._stepper = HeldInputStepper(system, options)
        self._x = np.asarray(system.equilibrium, dtype=float).copy()
        self._k = 0

    @property
    def seconds(self) -> float:
        return self._stepper.seconds

    def reset(self, x0) -> None:
        self._x = np.asarray(x0, dtype=float).copy()
        self._k = 0

    def step(self, u) -> np.ndarray:
        # t_k = k·Δ as the closed loop's time grid has it (np.arange(K + 1) * Δ), so the integrator takes the same
        # steps as before plants existed
        t0, t1 = self._k * self.dt, (self._k + 1) * self.dt
        self._x = self._stepper.step(self._x, u, t0, t1)
        self._k += 1
        return self._x

    def info(self) -> dict:
        return {"kind": self.kind, "id": self.system.name, "dt": self.dt,
                "integrator": {"method": self.options.method, "rtol": self.options.rtol, "atol": self.options.atol},
                "versions": {}}
