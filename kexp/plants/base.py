"""What the closed loop and the data collection act on: a plant (sampling time Δ, reset to a state, one held input
for one Δ → the next state), and the checks every plant's answers pass through.

A plant is anything with ``dt`` (s), ``n``, ``m``, ``reset(x0)`` and ``step(u) -> x`` (:class:`Plant`).  kexp's
own integrator of a :class:`~kexp.systems.base.ControlAffineSystem` is one (:mod:`kexp.plants.integrator`); a
Gymnasium environment (:mod:`kexp.plants.gymnasium`) and a user's class (:mod:`kexp.plants.user`) are others.
:class:`CheckedPlant` wraps any of them: every answer is checked (shape, finite) and every exception becomes one
:class:`~kexp.errors.PlantError` line that names the plant, the call and the step.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import PlantError


class Plant:
    """Base of kexp's plants.  Subclasses set ``dt`` (s, > 0), ``n`` (states), ``m`` (inputs) and implement
    :meth:`reset` and :meth:`step`; :meth:`info` says what the plant is (logged in ``/run_info`` and
    ``summary.json``); :meth:`input_bounds` the bounds the plant itself imposes (None: none)."""

    kind: str = "plant"
    dt: float = 0.0
    n: int = 0
    m: int = 0

    def reset(self, x0: np.ndarray) -> None:
        """Put the plant in state ``x0`` (n,) at time 0."""
        raise NotImplementedError

    def step(self, u: np.ndarray) -> np.ndarray:
        """Hold ``u`` (m,) for one Δ; return the state at the end (n,)."""
        raise NotImplementedError

    def info(self) -> dict:
        """What the plant is: at least ``kind`` and ``id``; package versions under ``versions``."""
        return {"kind": self.kind, "id": type(self).__name__, "dt": self.dt, "versions": {}}

    def input_bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(low (m,), high (m,)) the plant accepts, or None for no bounds of its own."""
        return None

    def close(self) -> None:
        """Release what the plant holds (an environment, a device)."""


def _short(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}"[:300] if text else type(exc).__name__


class CheckedPlant(Plant):
    """``plant`` with every answer checked: ``reset`` and ``step`` raise :class:`~kexp.errors.PlantError` (one line:
    the plant's id, the call, the step, what it returned or raised, what to fix) instead of the plant's own
    exception, a wrong shape, NaN or inf.  The step count since the last reset is ``k``."""

    def __init__(self, plant, name: str | None = None):
        self.plant = plant
        self.kind = getattr(plant, "kind", "python")
        self.dt, self.n, self.m = float(plant.dt), int(plant.n), int(plant.m)
        if name is None:
            name = str(plant.info().get("id", type(plant).__name__)) if hasattr(plant, "info") else type(plant).__name__
        self.name = name
        self.k = 0

    def _fail(self, call: str, reason: str, hint: str) -> PlantError:
        where = "reset" if call == "reset" else f"step {self.k} (t = {self.k * self.dt:.4g} s)"
        return PlantError(f"plant {self.name!r}: {where} {reason}; {hint}")

    def reset(self, x0) -> None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.n,) or not np.all(np.isfinite(x0)):
            raise PlantError(f"plant {self.name!r}: reset needs {self.n} finite numbers, got {x0.tolist()}")
        self.k = 0
        try:
            self.plant.reset(x0.copy())
        except PlantError:
            raise
        except Exception as exc:  # noqa: BLE001 - the plant's own code: one line, its type and message
            raise self._fail("reset", f"raised {_short(exc)}", "check the plant's reset(x0)") from None

    def step(self, u) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        try:
            x = self.plant.step(u.copy())
        except PlantError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise self._fail("step", f"raised {_short(exc)}", "check the plant's step(u)") from None
        try:
            x = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise self._fail("step", f"returned {x!r:.80}", f"return the next state as {self.n} numbers") from None
        if x.shape != (self.n,):
            raise self._fail("step", f"returned shape {x.shape}", f"return the next state as {self.n} numbers")
        if not np.all(np.isfinite(x)):
            raise self._fail("step", f"returned a non-finite state {x.tolist()}",
                             "the plant blew up or its state is undefined")
        self.k += 1
        return x

    def info(self) -> dict:
        return self.plant.info() if hasattr(self.plant, "info") else {"kind": self.kind, "id": self.name}

    def input_bounds(self):
        return self.plant.input_bounds() if hasattr(self.plant, "input_bounds") else None

    def close(self) -> None:
        if hasattr(self.plant, "close"):
            self.plant.close()


def check_dt(plant_dt: float, dt: float, where: str, name: str) -> None:
    """Refuse a sampling time ``dt`` (data.dt, the model's Δ) that is not the plant's own Δ (relative 1e-9)."""
    if not math.isclose(plant_dt, dt, rel_tol=1e-9, abs_tol=0.0):
        raise PlantError(f"{where}={dt:g} s, but plant {name!r} steps Δ = {plant_dt:g} s: set {where}={plant_dt:g} "
                         "(a plant's Δ is its own)")

