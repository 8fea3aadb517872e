"""A cache of identification and CLF results, keyed by everything that determines them, so a sweep over initial
conditions or controller settings identifies once.

An entry's key (:class:`Key`) holds the config parts that determine it, the file format, the recorded data
files' digest, a digest of the kexp source code that computes it (:func:`code_digest`) and the versions of the
numerical packages it depends on.  The entry's file name is a hash of the key, and the entry stores the key
itself (a ``cache_key`` member of its ``.npz``): a load checks it, so an entry that was made for anything else (a
file copied over another's name, another kexp's code) is a miss with a one-line warning, recomputed and replaced,
never a wrong model.

Safe under parallel jobs: a per-key lock file (``fcntl.flock``) makes one job compute while the others wait and
then load; results are written to a temporary file (the key added to it) and renamed into place, so a reader
never sees a partial file.
"""
from __future__ import annotations

import fcntl
import functools
import hashlib
import json
import os
import warnings
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

from ..cachedir import default_cache_dir
from ..errors import ConfigError
from ..recording.schema import plain
from .lock import installed_version

T = TypeVar("T")

KEY_MEMBER = "cache_key"   # the .npz member that holds an entry's key (a JSON string)


def key_of(*parts) -> str:
    return hashlib.sha256(json.dumps(plain(list(parts)), sort_keys=True).encode()).hexdigest()[:20]


# the config groups that determine the identified model; every other group (clf, controller, sim, logging,
# cache) must leave its key unchanged, so that a sweep over them identifies once (tests/test_cache.py)
MODEL_GROUPS = ("system", "data", "dictionary", "identification")
# the kexp sources (under kexp/) that compute a model and a CLF, and the packages whose versions their numbers
# depend on; the app's config translation and the run's identification step (build.py: the dictionary's scale
# from the data; experiment.py: noise, smoothing, the report) are among them, the controllers are not
MODEL_CODE = ("identify", "data", "dictionary.py", "systems", "plants", "app/build.py", "app/experiment.py")
CLF_CODE = MODEL_CODE + ("clf", "control/laws.py")
MODEL_PACKAGES = ("numpy", "scipy")
CLF_PACKAGES = MODEL_PACKAGES + ("cvxpy", "clarabel")
_KEXP = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=None)
def code_digest(parts: tuple[str, ...], root: str | Path = _KEXP) -> str:
    """SHA-256 (20 hex digits) of the source files ``parts`` (paths under ``root``, the kexp package: a folder
    means every ``.py`` file below it), each file's relative path and bytes in sorted order; read once per process
    (the sources do not change while a run computes)."""
    root = Path(root)
    files = set()
    for part in parts:
        p = root / part
        if p.is_dir():
            files.update(p.rglob("*.py"))
        elif p.is_file():
            files.add(p)
        else:
            raise FileNotFoundError(f"kexp.app.cache.code_digest: {p} does not exist (a stage's sources moved: "
                                    "update MODEL_CODE/CLF_CODE)")
    h = hashlib.sha256()
    for f in sorted(files, key=lambda f: f.relative_to(root).as_posix()):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:20]


class Key:
    """What a cache entry was made for: ``kind`` ("model", "clf") and ``parts``, a JSON-able mapping (kept as its
    canonical JSON text).  Equal keys have equal text; :attr:`name` is the entry's file name."""

    __slots__ = ("kind", "text")

    def __init__(self, kind: str, parts: dict):
        self.kind = kind
        self.text = json.dumps(plain({"kind": kind, **parts}), sort_keys=True)

    @property
    def parts(self) -> dict:
        return json.loads(self.text)

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.text.encode()).hexdigest()[:20]

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.digest}.npz"

    def __eq__(self, other) -> bool:
        return isinstance(other, Key) and self.text == other.text

    def __hash__(self) -> int:
        return hash(self.text)

    def __repr__(self) -> str:
        return f"Key({self.kind!r}, {self.digest})"


def model_key(cfg: dict, format_version: int, files_digest: str | None = None) -> Key:
    """The key of the model identified from the composed config ``cfg`` (a plain mapping): its groups
    :data:`MODEL_GROUPS`, the model file's ``format_version``, the recorded data files' content digest (None: the
    data are simulated), the digest of the code that identifies (:data:`MODEL_CODE`) and the package versions."""
    return Key("model", {**{group: cfg.get(group) for group in MODEL_GROUPS}, "format": format_version,
                         "files_digest": files_digest, "code": code_digest(MODEL_CODE),
                         "packages": {p: installed_version(p) for p in MODEL_PACKAGES}})


def clf_key(model: Key, cfg: dict, law: str, law_params, u_min, u_max) -> Key:
    """The key of the CLF synthesised for the model with key ``model``: the model's key, the clf group, the
    controller settings the synthesis uses (law, its parameters and the input bounds), the digest of the code
    that synthesises (:data:`CLF_CODE`) and the package versions."""
    return Key("clf", {"model": model.parts, "clf": cfg.get("clf"), "law": law, "law_params": law_params,
                       "u_min": u_min, "u_max": u_max, "code": code_digest(CLF_CODE),
                       "packages": {p: installed_version(p) for p in CLF_PACKAGES}})


def _difference(stored, expected, where: str = "") -> str:
    """Where two keys' parts first differ, e.g. ``system.name='pendulum' (want 'vanderpol')``."""
    if isinstance(stored, dict) and isinstance(expected, dict):
        for k in sorted(set(stored) | set(expected)):
            if stored.get(k) != expected.get(k):
                return _difference(stored.get(k), expected.get(k), f"{where}.{k}" if where else k)
    s, e = json.dumps(stored), json.dumps(expected)
    return f"{where}={s[:60]} (want {e[:60]})"


def write_key(path: Path, key: Key) -> None:
    """Add ``key`` to the .npz at ``path`` as its member ``cache_key`` (a 0-d unicode array: no pickle)."""
    with zipfile.ZipFile(path, "a") as zf, zf.open(KEY_MEMBER + ".npy", "w") as f:
        np.lib.format.write_array(f, np.array(key.text), allow_pickle=False)


def read_key(path: Path) -> str | None:
    """The key text stored in the .npz at ``path``; None when it has none (or is not a readable .npz)."""
    try:
        with np.load(path, allow_pickle=False) as f:
            return str(f[KEY_MEMBER]) if KEY_MEMBER in f.files else None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None


@contextmanager
def _locked(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(path.suffix + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _warn(message: str) -> None:
    warnings.warn(message, RuntimeWarning, stacklevel=3)


class Cache:
    """The cache in ``directory`` (None: $KEXP_CACHE_DIR or ~/.cache/kexp), created at construction when
    ``enabled``; a folder that cannot be created or written raises ConfigError (before anything long runs).
    ``warn`` receives the one-line message when an entry is not what its key says (default: a RuntimeWarning)."""

    def __init__(self, directory: str | Path | None, enabled: bool = True, warn: Callable[[str], None] = _warn):
        self.dir = Path(directory) if directory else default_cache_dir()
        self.enabled = enabled
        self.warn = warn
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

    def _check(self, path: Path, key: Key) -> bool:
        """True if the entry at ``path`` stores ``key``; otherwise warn once (one line) and return False."""
        stored = read_key(path)
        if stored == key.text:
            return True
        if stored is None:
            why = "it records no key (an older kexp's entry, or not a cache entry)"
        else:
            try:
                why = "it was made for " + _difference(json.loads(stored), key.parts)
            except ValueError:
                why = "its key is unreadable"
        self.warn(f"cache entry {path} is not the {key.kind} asked for: {why}; recomputing it")
        return False

    def get_or_create(self, key: Key, create: Callable[[], T], save: Callable[[T, Path], None],
                      load: Callable[[Path], T]) -> T:
        """The value for ``key``: loaded from its entry when the entry stores this very key, otherwise made by
        ``create()``, written by ``save(value, path)`` with the key added, and renamed into place."""
        if not self.enabled:
            return create()
        name = key.name
        path = self.dir / name
        with _locked(path):
            if path.exists() and self._check(path, key):
                try:
                    value = load(path)
                    self.hits.append(name)
                    return value
                except Exception as exc:  # noqa: BLE001 - a corrupt entry is recomputed
                    self.warn(f"cache entry {path} is unreadable ({type(exc).__name__}); recomputing it")
            value = create()
            tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp{path.suffix}")
            save(value, tmp)
            write_key(tmp, key)
            os.replace(tmp, path)
            self.misses.append(name)
            return value
