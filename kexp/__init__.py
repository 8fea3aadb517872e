"""kexp: Koopman-based Lyapunov MPC from data, as a logged experiment framework with replay."""
from __future__ import annotations


def _version() -> str:
    """The installed distribution's version; in a bare checkout (not installed) the one pyproject.toml states."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("kexp")
    except PackageNotFoundError:
        pass
    import tomllib
    from pathlib import Path
    try:
        with open(Path(__file__).resolve().parents[1] / "pyproject.toml", "rb") as f:
            return str(tomllib.load(f)["project"]["version"])
    except (OSError, KeyError, tomllib.TOMLDecodeError):
        return "0+unknown"


__version__ = _version()

_LAZY = {"fit": "kexp.identify.estimator", "FittedModel": "kexp.identify.estimator"}


def __getattr__(name: str):
    """``kexp.fit`` and ``kexp.FittedModel`` (kexp.identify.estimator), imported on first use so that ``import
    kexp`` stays fast."""
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'kexp' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))
