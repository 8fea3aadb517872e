"""Where numba keeps kexp's compiled kernels, and the one line a compile prints.

kexp's kernels (``condense``, ``kernels``, ``expm_kernels``, ``ipm``, ``qp``) are ``@njit(cache=True)``: compiled
once, then loaded from numba's cache by every later process (a run, a sweep's workers, the log writer).  By default
numba writes that cache beside the sources (``kexp/control/__pycache__``), which an installed wheel may not be
allowed to write, and a fresh install starts empty.  :func:`configure` (run by ``kexp.control`` before it imports a
kernel) points numba at one per-user folder instead::

    $NUMBA_CACHE_DIR                                  if the user set it (respected as it is)
    $KEXP_CACHE_DIR/numba/<kexp>-py<X.Y>-numba<V>     else (KEXP_CACHE_DIR defaults to ~/.cache/kexp)

and exports it as ``NUMBA_CACHE_DIR`` so that subprocesses (joblib's workers) use the same folder.  numba itself
keys each entry by the kernel's source (a hash of its file), its argument types and the CPU, so a new kexp version,
Python or numba gets a folder of its own and an edited source recompiles only what changed.

A compile (a cache miss) prints one line on stderr, once per process, while it happens; loading from the cache
prints nothing.  A folder that cannot be written gives one warning line and numba's own default (kernels still
run, compiled in the process when numba finds no writable place).
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numba.core.config as nconfig
import numba.core.event as ev

ANNOUNCEMENT = ("kexp: compiling the controller's kernels once for this install (~30-70 s; cached in {dir}; "
                "later runs load them) …")


def cache_dir() -> Path:
    """The folder numba's cache of kexp's kernels goes to: $NUMBA_CACHE_DIR if set (non-empty), else
    ``<kexp cache>/numba/<kexp version>-py<major.minor>-numba<numba version>``."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return Path(user)
    from importlib.metadata import version

    from .. import __version__
    from ..cachedir import default_cache_dir
    tag = f"{__version__}-py{sys.version_info[0]}.{sys.version_info[1]}-numba{version('numba')}"
    return default_cache_dir() / "numba" / tag


def _writable(path: Path) -> str | None:
    """None if ``path`` can be created and written, else the reason (the OSError's text)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError as exc:
        return f"{type(exc).__name__}: {exc.strerror or exc}"
    return None


_state: dict = {"dir": None, "announced": False, "listener": None}


def configure() -> Path | None:
    """Point numba's cache at :func:`cache_dir` (exported as NUMBA_CACHE_DIR) and install the compile
    announcement.  Idempotent.  Returns the folder, or None when it cannot be written (one warning line on stderr;
    numba then uses its own default)."""
    if _state["listener"] is not None:
        return _state["dir"]
    path = cache_dir()
    problem = _writable(path)
    if problem is None:
        os.environ["NUMBA_CACHE_DIR"] = str(path)
        nconfig.CACHE_DIR = str(path)        # numba read its environment at import, perhaps before this
        _state["dir"] = path
    else:
        print(f"kexp: warning: cannot write the compiled-kernel cache {path} ({problem}); kernels may compile "
              f"again in every run: set NUMBA_CACHE_DIR to a writable folder", file=sys.stderr, flush=True)
        if os.environ.get("NUMBA_CACHE_DIR") == str(path):
            os.environ.pop("NUMBA_CACHE_DIR")   # numba's default locators (beside the sources, or ~/.cache/numba)
        nconfig.CACHE_DIR = ""
    _state["listener"] = _Announce()
    ev.register("numba:compile", _state["listener"])
    return _state["dir"]


class _Announce(ev.Listener):
    """numba's "numba:compile" event fires only on a cache miss (a load from the cache does not trigger it): the
    first one of the process for a kexp kernel prints :data:`ANNOUNCEMENT`."""

    def on_start(self, event):
        if not _state["announced"] and _is_kexps(event.data.get("dispatcher")):
            _state["announced"] = True
            where = _state["dir"] or "numba's default folder"
            print(ANNOUNCEMENT.format(dir=where), file=sys.stderr, flush=True)

    def on_end(self, event):
        pass


def _is_kexps(dispatcher) -> bool:
    """Whether the function being compiled is one of kexp's (a user's own njit code is not announced), the
    oracle's generated dynamics (kexp.control.codegen) included."""
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module == "kexp" or module.startswith(("kexp.", "kexp_dynamics_"))
