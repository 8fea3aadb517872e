"""A cache of identification and CLF results, keyed by a hash of the config parts that determine them, so a
sweep over initial conditions or controller settings identifies once.

Safe under parallel jobs: a per-key lock file (``fcntl.flock``) makes one job compute while the others wait and
then load; results are written to a temporary file and renamed into place, so a reader never sees a partial file.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, TypeVar

from ..errors import ConfigError
from ..recording.schema import plain

T = TypeVar("T")


def default_cache_dir() -> Path:
    return Path(os.environ.get("KEXP_CACHE_DIR") or Path.home() / ".cache" / "kexp")


def key_of(*parts) -> str:
    return hashlib.sha256(json.dumps(plain(list(parts)), sort_keys=True).encode()).hexdigest()[:20]


# the config groups that determine the identified model; every other group (clf, controller, sim, logging,
# cache) must leave its key unchanged, so that a sweep over them identifies once (tests/test_cache.py)
MODEL_GROUPS = ("system", "data", "dictionary", "identification")


def model_key(cfg: dict, format_version: int) -> str:
    """The cache key of the model identified from the composed config ``cfg`` (a plain mapping)."""
    return key_of("model", format_version, *(cfg.get(group) for group in MODEL_GROUPS))


def clf_key(model: str, cfg: dict, law: str, law_params, u_min, u_max) -> str:
    """The cache key of the CLF synthesised for the model with key ``model``: the clf group and the controller
    settings the synthesis uses (law, its parameters and the input bounds)."""
    return key_of("clf", model, cfg.get("clf"), law, law_params, u_min, u_max)


@contextmanager
def _locked(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(path.suffix + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


class Cache:
    """The cache in ``directory`` (None: $KEXP_CACHE_DIR or ~/.cache/kexp), created at construction when
    ``enabled``; a folder that cannot be created or written raises ConfigError (before anything long runs)."""

    def __init__(self, directory: str | Path | None, enabled: bool = True):
        self.dir = Path(directory) if directory else default_cache_dir()
        self.enabled = enabled
        self.hits: list[str] = []
        self.misses: list[str] = []
        if enabled:
            try:
                self.dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ConfigError(f"cache.dir={str(self.dir)!r}: cannot create it ({type(exc).__name__}: "
                                  f"{exc.strerror or exc}); give a writable folder, or cache.enabled=false") from None
            if not os.access(self.dir, os.W_OK | os.X_OK):
                raise ConfigError(f"cache.dir={str(self.dir)!r}: not writable; give a writable folder, or "
                                  "cache.enabled=false")

    def get_or_create(self, name: str, create: Callable[[], T], save: Callable[[T, Path], None],
                      load: Callable[[Path], T]) -> T:
        if not self.enabled:
            return create()
        path = self.dir / name
        with _locked(path):
            if path.exists():
                try:
                    value = load(path)
                    self.hits.append(name)
                    return value
                except Exception:  # noqa: BLE001 - a stale or corrupt entry is recomputed
                    path.unlink(missing_ok=True)
            value = create()
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp{path.suffix}")
            save(value, tmp)
            os.replace(tmp, path)
            self.misses.append(name)
            return value
