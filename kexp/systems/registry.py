"""Systems by name: the shipped ones, or a user's own class named as ``"package.module:ClassName"``."""
from __future__ import annotations

import importlib
from typing import Any, Mapping

from ..errors import SystemDefinitionError
from .base import ControlAffineSystem, check_system
from .library import CartPendulum, Duffing, Linear, Pendulum, SlowManifold, VanDerPol

SYSTEMS: dict[str, type[ControlAffineSystem]] = {
    cls.name: cls for cls in (VanDerPol, Pendulum, Duffing, Linear, SlowManifold, CartPendulum)
}


def _import_class(path: str) -> type:
    module_name, _, cls_name = path.partition(":")
    if not cls_name:
        module_name, _, cls_name = path.rpartition(".")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SystemDefinitionError(f"system {path!r}: cannot import module {module_name!r} ({exc}); "
                           "check the name and that it is on PYTHONPATH") from None
    try:
        return getattr(module, cls_name)
    except AttributeError:
        raise SystemDefinitionError(f"system {path!r}: module {module_name!r} has no {cls_name!r}") from None


def make_system(name: str, params: Mapping[str, Any] | None = None) -> ControlAffineSystem:
    """Build and check a system.  ``name`` is one of :data:`SYSTEMS` or ``"module:Class"`` of the user's own
    :class:`ControlAffineSystem` subclass; ``params`` are its constructor's keyword arguments."""
    if not isinstance(name, str) or not name:
        raise SystemDefinitionError(f"system name {name!r}: give a name, one of {sorted(SYSTEMS)} or "
                                    "'package.module:ClassName'")
    if params is not None and not isinstance(params, Mapping):
        raise SystemDefinitionError(f"system {name!r}: params={params!r}; give a mapping of parameter names to "
                                    "values, e.g. {'mu': 2.0}")
    params = dict(params or {})
    if name in SYSTEMS:
        cls = SYSTEMS[name]
    elif ":" in name or "." in name:
        cls = _import_class(name)
        if not (isinstance(cls, type) and issubclass(cls, ControlAffineSystem)):
            raise SystemDefinitionError(f"system {name!r} is not a subclass of kexp.systems.ControlAffineSystem")
    else:
        raise SystemDefinitionError(f"unknown system {name!r}; valid: {sorted(SYSTEMS)} or 'package.module:ClassName'")
    try:
        system = cls(**params)
    except TypeError as exc:
        raise SystemDefinitionError(f"system {name!r}: bad parameters {params} ({exc})") from None
    check_system(system)
    return system


def builtin_state_names(name: str, n: int | None = None) -> list[str] | None:
    """The state names of the built-in system ``name`` (or of a variant named ``<system>-…``, e.g.
    ``pendulum-u0.5``), if it has ``n`` states (any number if None); None otherwise: for labels where a log or CSV
    does not record the names."""
    for key in (name, name.split("-", 1)[0]):
        if key in SYSTEMS:
            names = [str(x) for x in make_system(key).state_names]
            return names if n is None or len(names) == n else None
    return None
