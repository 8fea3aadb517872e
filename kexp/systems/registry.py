"""Systems by name: the shipped ones, or a user's own class named as ``"package.module:ClassName"`` (a module
that is the user's own ``.py`` file, or kexp's: any other is refused before it is imported)."""
from __future__ import annotations

import importlib
import importlib.util
import site
import sys
import sysconfig
from pathlib import Path
from typing import Any, Mapping

from ..errors import SystemDefinitionError
from .base import ControlAffineSystem, check_system
from .library import CartPendulum, Duffing, Linear, Pendulum, SlowManifold, VanDerPol

SYSTEMS: dict[str, type[ControlAffineSystem]] = {
    cls.name: cls for cls in (VanDerPol, Pendulum, Duffing, Linear, SlowManifold, CartPendulum)
}


def _system_dirs() -> tuple[list[Path], list[Path]]:
    """(the folders of installed packages, the standard library's folders) of this interpreter."""
    paths = sysconfig.get_paths()
    installed = {paths["purelib"], paths["platlib"], *site.getsitepackages()}
    if site.ENABLE_USER_SITE:
        installed.add(site.getusersitepackages())
    base = sysconfig.get_paths(vars={"base": sys.base_prefix, "platbase": sys.base_exec_prefix,
                                     "installed_base": sys.base_prefix, "installed_platbase": sys.base_exec_prefix})
    stdlib = {paths["stdlib"], paths["platstdlib"], base["stdlib"], base["platstdlib"]}
    resolve = lambda dirs: [Path(d).resolve() for d in dirs if d]  # noqa: E731
    return resolve(installed), resolve(stdlib)


def _not_own(spec) -> str | None:
    """Why the module of ``spec`` (found, not imported) is not a user's own source file: None when it is a
    regular ``.py`` file (or a folder of them) outside the standard library and the installed packages."""
    if spec.origin in ("built-in", "frozen"):
        return "built into Python"
    places = [spec.origin] if spec.origin else list(spec.submodule_search_locations or [])
    if not places:
        return "not a file"
    installed, stdlib = _system_dirs()
    for place in places:
        where = Path(place).resolve()
        if any(d in where.parents for d in installed) or {"site-packages", "dist-packages"} & set(where.parts):
            return f"an installed package ({place})"
        if any(d in where.parents for d in stdlib):
            return f"part of Python's standard library ({place})"
        if spec.origin and where.suffix != ".py":
            return f"not a Python source file ({place})"
    return None


def _import_class(path: str, what: str = "system", example: str = "system.name=my_systems:MySystem") -> type:
    """The class ``path`` names (``module:Class`` or ``module.Class``), from kexp or from a module that is the
    user's own ``.py`` file; any other module (standard library, installed packages, compiled extensions) is
    refused before it is imported, so that naming it runs none of its code."""
    module_name, _, cls_name = path.partition(":")
    if not cls_name:
        module_name, _, cls_name = path.rpartition(".")
    not_found = SystemDefinitionError(f"{what} {path!r}: cannot import module {module_name!r}; check the name and "
                                      "that it is on PYTHONPATH")
    if module_name.split(".")[0] != "kexp":
        parts = module_name.split(".")
        for i in range(1, len(parts) + 1):   # each parent checked before find_spec of its child imports it
            name = ".".join(parts[:i])
            module = sys.modules.get(name)
            try:
                spec = module.__spec__ if module is not None and module.__spec__ is not None else (
                    importlib.util.spec_from_file_location(name, module.__file__) if module is not None
                    and getattr(module, "__file__", None) else importlib.util.find_spec(name))
            except (ImportError, ValueError):
                raise not_found from None
            if spec is None:
                raise not_found
            why = _not_own(spec)
            if why is not None:
                raise SystemDefinitionError(
                    f"{what} {path!r}: module {name!r} is {why}; a {what}'s module must be your own .py file "
                    f"(in the current folder or on PYTHONPATH) or kexp's, e.g. {example}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SystemDefinitionError(f"{what} {path!r}: cannot import module {module_name!r} ({exc}); "
                                    "check the name and that it is on PYTHONPATH") from None
    try:
        return getattr(module, cls_name)
    except AttributeError:
        raise SystemDefinitionError(f"{what} {path!r}: module {module_name!r} has no {cls_name!r}") from None


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
