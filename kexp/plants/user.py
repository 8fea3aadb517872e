"""A user's own plant class (``plant.kind=python``, ``plant.target=my_rig:Rig``): a co-simulator, a hardware
driver, a replay of a recorded test bench.  The class needs ``dt`` (s), ``reset(x0)`` and ``step(u) -> x``;
``n`` and ``m`` as class or instance attributes (or taken from the configured system), optionally ``close()``,
``info()`` (a dict logged with the run) and ``input_bounds()`` ((low, high) per input).  Its module must be the
user's own ``.py`` file (as for a system class: :func:`kexp.systems.registry._import_class`)."""
from __future__ import annotations

import math

from ..errors import PlantError, SystemDefinitionError
from ..systems.registry import _import_class
from .base import Plant


class UserPlant(Plant):
    """Adapter around an instance of the user's class: kexp's :class:`~kexp.plants.base.Plant` interface."""

    kind = "python"

    def __init__(self, obj, target: str, n: int, m: int):
        self.obj, self.target = obj, target
        self.dt, self.n, self.m = float(obj.dt), n, m

    def reset(self, x0) -> None:
        self.obj.reset(x0)

    def step(self, u):
        return self.obj.step(u)

    def info(self) -> dict:
        extra = {}
        if callable(getattr(self.obj, "info", None)):
            extra = dict(self.obj.info())
        return {"kind": self.kind, "id": self.target, "dt": self.dt, "versions": {}, **extra}

    def input_bounds(self):
        return self.obj.input_bounds() if callable(getattr(self.obj, "input_bounds", None)) else None

    def close(self) -> None:
        if callable(getattr(self.obj, "close", None)):
            self.obj.close()


def _dimension(obj, key: str, system, target: str) -> int:
    value = getattr(obj, key, None)
    if value is None and system is not None:
        value = getattr(system, key)
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
        raise PlantError(f"plant {target!r}: {key}={value!r}; set {key} (an int >= 1) on the class, or name the "
                         "system it simulates (system=<name>)")
    return value


def make_user_plant(target: str, params: dict, system=None) -> UserPlant:
    """An instance of the class ``target`` names (``module:Class``) built with ``params``, checked for the plant
    interface (PlantError, one line, for anything missing)."""
    try:
        cls = _import_class(target, "plant", "plant.target=my_rig:Rig")
    except SystemDefinitionError as exc:
        raise PlantError(str(exc)) from None
    try:
        obj = cls(**params)
    except Exception as exc:  # noqa: BLE001 - the user's constructor: one line
        text = str(exc).splitlines()[0] if str(exc) else ""
        raise PlantError(f"plant {target!r}: {target}(**{params}) raised {type(exc).__name__}: {text}"[:400]) from None
    missing = [name for name in ("reset", "step") if not callable(getattr(obj, name, None))]
    if missing:
        raise PlantError(f"plant {target!r}: no {' or '.join(f'{m}()' for m in missing)}; a plant class needs dt, "
                         "reset(x0) and step(u) -> x")
    dt = getattr(obj, "dt", None)
    if not (isinstance(dt, (int, float)) and not isinstance(dt, bool) and math.isfinite(dt) and dt > 0):
        raise PlantError(f"plant {target!r}: dt={dt!r}; set dt to the plant's sampling time in s (> 0)")
    return UserPlant(obj, target, _dimension(obj, "n", system, target), _dimension(obj, "m", system, target))
