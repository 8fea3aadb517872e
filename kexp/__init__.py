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
