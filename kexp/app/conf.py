"""Where the Hydra configs are (:data:`CONF_DIR`, found by :mod:`kexp.app.confdir`), with kexp's config schema
registered in Hydra's ConfigStore as ``kexp_schema`` (conf/config.yaml extends it): import this before composing a
config."""
from __future__ import annotations

from .confdir import CONF_DIR  # noqa: F401 - the place callers import it from
from .schema import register as _register_schema

_register_schema()  # 'kexp_schema' in Hydra's ConfigStore: conf/config.yaml extends it
