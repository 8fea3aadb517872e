"""Argument checks shared by kexp.data's constructors and readers; each failure is a one-line
:class:`~kexp.errors.ConfigError` naming the key, the value and what is valid."""
from __future__ import annotations

from collections.abc import Sequence
from os import PathLike

import numpy as np

from ..errors import ConfigError, is_number


def short(value, limit: int = 80) -> str:
    """repr(value), cut to ``limit`` characters (a long list of points stays one short line)."""
    r = " ".join(repr(value).split())
    return r if len(r) <= limit else r[:limit - 3] + "..."


is_real = is_number   # a real number (int, float, numpy scalar); bools are not numbers (kexp.errors)


def items(value, *, allow_none: bool = False) -> list | None:
    """The entries of a number or a flat list/tuple/1-D array of numbers (None entries too if ``allow_none``),
    or None if ``value`` is not one."""
    if is_real(value) or (allow_none and value is None):
        return [value]
    if isinstance(value, np.ndarray):
        if value.ndim > 1 or value.dtype.kind not in "iuf":
            return None
        return value.reshape(-1).tolist()
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        out = list(value)
        return out if all(is_real(v) or (allow_none and v is None) for v in out) else None
    return None


def real_vector(value, key: str, hint: str = "give a number or a list of numbers") -> np.ndarray:
    """``value`` (a number or a non-empty flat list of numbers) as a 1-D float array; else a ConfigError."""
    entries = items(value)
    if not entries:
        raise ConfigError(f"{key}={short(value)}: {hint}")
    return np.array(entries, dtype=float)


def state_vector(value, n: int, key: str) -> None:
    """Raise a ConfigError unless ``value`` is None or ``n`` finite numbers (one per state)."""
    if value is None:
        return
    entries = items(value)
    if not entries or len(entries) != n or not np.all(np.isfinite(np.array(entries, dtype=float))):
        raise ConfigError(f"{key}={short(value)}: give {n} finite number(s), one per state (or None: the origin)")


def require_type(value, kind, key: str, hint: str = "") -> None:
    """Raise a ConfigError unless ``value`` is an instance of ``kind``."""
    if not isinstance(value, kind):
        article = "an" if kind.__name__[0] in "AEIOU" else "a"
        raise ConfigError(f"{key}={short(value)}: expected {article} {kind.__name__}{hint}")


def require_path(value, key: str) -> None:
    """Raise a ConfigError unless ``value`` is a non-empty path (str or os.PathLike)."""
    if not (isinstance(value, PathLike) or (isinstance(value, str) and value)):
        raise ConfigError(f"{key}={short(value)}: give a path (a str or pathlib.Path) to a file or folder")
