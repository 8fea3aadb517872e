"""Where the Hydra configs are (:data:`CONF_DIR`), with kexp's config schema registered in Hydra's ConfigStore as
``kexp_schema`` (conf/config.yaml extends it): import this before composing a config."""
from __future__ import annotations

from pathlib import Path

from .schema import register as _register_schema

_register_schema()  # 'kexp_schema' in Hydra's ConfigStore: conf/config.yaml extends it


def _conf_dir() -> str:
    """The Hydra configs: ``kexp/conf`` inside an installed wheel (pyproject.toml maps the repository's ``conf/``
    there), else ``conf/`` at the top of the checkout (an editable install or PYTHONPATH)."""
    package = Path(__file__).resolve().parents[1]
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return str(candidate)
    return str(package.parent / "conf")  # Hydra's error names it


CONF_DIR = _conf_dir()
