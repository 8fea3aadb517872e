"""Where the Hydra configs are (:data:`CONF_DIR`), found without importing anything heavy (``kexp --help`` lists
the presets and config groups from it); :mod:`kexp.app.conf` re-exports it after registering the schema."""
from __future__ import annotations

from pathlib import Path


def _conf_dir() -> str:
    """The Hydra configs: ``kexp/conf`` inside an installed wheel (pyproject.toml maps the repository's ``conf/``
    there), else ``conf/`` at the top of the checkout (an editable install or PYTHONPATH)."""
    package = Path(__file__).resolve().parents[1]
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return str(candidate)
    return str(package.parent / "conf")  # Hydra's error names it


CONF_DIR = _conf_dir()
