"""The folder of kexp's caches on this machine: ``$KEXP_CACHE_DIR``, else ``~/.cache/kexp``.  It holds the model and
CLF cache (``kexp.app.cache``, unless ``cache.dir`` says otherwise), the compiled kernels (``numba/``,
``kexp.control.jit_cache``), the oracle's generated dynamics and the parsed CSV files (``parsed/``).  A module of
its own, below both the experiment command and the controllers, so that neither imports the other for it."""
from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """``$KEXP_CACHE_DIR`` if set (non-empty), else ``~/.cache/kexp``; not created here."""
    return Path(os.environ.get("KEXP_CACHE_DIR") or Path.home() / ".cache" / "kexp")
