"""The ``plant`` config section (:class:`PlantConfig`) and :func:`make_plant`, which builds the plant it names.

- ``integrator`` (the default): kexp integrates the configured system's F and G (``sim.plant_params`` applied);
- ``gymnasium``: a registered Gymnasium environment with a Box action space (``env_id``, ``env_kwargs``; how the
  state is read and written: ``state``), :mod:`kexp.plants.gymnasium`;
- ``python``: a user's own class (``target=module:Class``, ``params`` its keyword arguments) with ``dt``,
  ``reset(x0)`` and ``step(u)``, :mod:`kexp.plants.user`.

With ``system=plant`` (conf/system/plant.yaml) there is no formula at all: n, m come from the plant, x_eq and the
state names from ``equilibrium`` and ``state_names`` here (:class:`~kexp.plants.system.PlantSystem`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ..data.checks import items, short
from ..errors import ConfigError

PLANT_KINDS = ("integrator", "gymnasium", "python")


@dataclass(frozen=True)
class PlantConfig:
    """What the closed loop (and ``data.source.kind=plant``) acts on.  ``kind`` one of :data:`PLANT_KINDS`;
    ``env_id``/``env_kwargs``/``state`` for gymnasium, ``target``/``params`` for python; ``equilibrium`` and
    ``state_names`` describe the plant's state when no system formula does (None: zeros, x1…xn).  Raises ConfigError for a key that
    does not belong to ``kind`` or a value of the wrong type."""

    kind: str = "integrator"
    env_id: str | None = None
    env_kwargs: dict = field(default_factory=dict)
    state: str = "auto"
    target: str | None = None
    params: dict = field(default_factory=dict)
    equilibrium: tuple | None = None
    state_names: tuple | None = None

    def __post_init__(self):
        for key in ("equilibrium", "state_names"):
            if isinstance(getattr(self, key), list):
                object.__setattr__(self, key, tuple(getattr(self, key)))
        if not isinstance(self.kind, str) or self.kind not in PLANT_KINDS:
            raise ConfigError(f"plant.kind={self.kind!r}; valid: {PLANT_KINDS}")
        if self.kind == "gymnasium" and not (isinstance(self.env_id, str) and self.env_id):
            raise ConfigError("plant.kind=gymnasium needs plant.env_id, e.g. plant.env_id=Pendulum-v1")
        if self.kind == "python" and not (isinstance(self.target, str) and ":" in self.target):
            raise ConfigError(f"plant.kind=python needs plant.target=<module>:<Class> (your own .py file), got "
                              f"{self.target!r}, e.g. plant.target=my_rig:Rig")
        foreign = {"gymnasium": ("target", "params"), "python": ("env_id", "env_kwargs"),
                   "integrator": ("env_id", "env_kwargs", "target", "params")}[self.kind]
        for key in foreign:
            if getattr(self, key):
                raise ConfigError(f"plant.{key}={short(getattr(self, key))} does not apply to plant.kind={self.kind}")
        if self.kind != "gymnasium" and self.state != "auto":
            raise ConfigError(f"plant.state={self.state!r} applies to plant.kind=gymnasium only")
        for key in ("env_kwargs", "params"):
            if not isinstance(getattr(self, key), dict):
                raise ConfigError(f"plant.{key}={short(getattr(self, key))}: give a mapping of names to values")
        if self.equilibrium is not None:
            values = items(self.equilibrium)
            if not values or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
                raise ConfigError(f"plant.equilibrium={short(self.equilibrium)}: give one finite number per state")
        if self.state_names is not None and not all(isinstance(s, str) and s for s in self.state_names):
            raise ConfigError(f"plant.state_names={short(self.state_names)}: give one name per state")

    @property
    def external(self) -> bool:
        """True for a plant kexp does not integrate itself."""
        return self.kind != "integrator"


def make_plant(config: PlantConfig, system=None, dt: float | None = None, integrator=None):
    """The plant ``config`` names, checked (:class:`~kexp.plants.base.CheckedPlant` for an external one).  The
    integrator plant needs ``system`` (the plant's F and G), ``dt`` and ``integrator`` (IntegratorOptions)."""
    if not isinstance(config, PlantConfig):
        raise ConfigError(f"make_plant: config={config!r:.80}; expected a PlantConfig")
    if config.kind == "integrator":
        from .integrator import IntegratorPlant
        if system is None or dt is None:
            raise ConfigError("the integrator plant integrates a system's F and G: give a system (system=<name>) "
                              "and its Δ")
        return IntegratorPlant(system, dt, integrator) if integrator is not None else IntegratorPlant(system, dt)
    from .base import CheckedPlant
    if config.kind == "python":
        from .user import make_user_plant
        return CheckedPlant(make_user_plant(config.target, config.params, system))
    from .gymnasium import make_gymnasium_plant
    return CheckedPlant(make_gymnasium_plant(config))
