"""Turn a composed config (any mapping) into kexp's typed, validated objects.  Nothing Hydra-specific travels
past this module."""
from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from ..data import DataConfig, Excitation, IntegratorOptions, RegionFilter, make_sampler
from ..dictionary import Monomials
from ..errors import ConfigError
from ..identify import IdentifyConfig, auto_scale
from ..systems import make_system


def _plain(obj: Any) -> Any:
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf
        if isinstance(obj, (DictConfig, ListConfig)):
            return OmegaConf.to_container(obj, resolve=True)
    except ImportError:  # pragma: no cover
        pass
    return obj


def construct(cls, mapping: Mapping[str, Any] | None, where: str, **overrides):
    """``cls(**mapping)`` with unknown keys reported by name, e.g. 'data.filter.hgih: unknown key; valid: …'."""
    mapping = dict(_plain(mapping) or {})
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    for key in mapping:
        if key not in names:
            raise ConfigError(f"{where}.{key}: unknown key; valid keys: {sorted(names)}")
    mapping.update(overrides)
    try:
        return cls(**mapping)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def build_system(cfg: Mapping[str, Any]):
    cfg = dict(_plain(cfg))
    unknown = set(cfg) - {"name", "params"}
    if unknown:
        raise ConfigError(f"system.{sorted(unknown)[0]}: unknown key; valid keys: ['name', 'params']")
    if "name" not in cfg:
        raise ConfigError("system.name is missing; e.g. system=vanderpol")
    return make_system(cfg["name"], cfg.get("params") or {})


def build_data(cfg: Mapping[str, Any]):
    """Returns (sampler, DataConfig)."""
    cfg = dict(_plain(cfg))
    sampler_cfg = dict(cfg.pop("sampler", None) or {})
    if "kind" not in sampler_cfg:
        raise ConfigError("data.sampler.kind is missing; valid: circle, box, points")
    kind = sampler_cfg.pop("kind")
    sampler = make_sampler(kind, **sampler_cfg)
    exc = cfg.pop("excitation", None)
    flt = cfg.pop("filter", None)
    integ = cfg.pop("integrator", None)
    data = construct(DataConfig, cfg, "data",
                     excitation=None if exc is None else construct(Excitation, exc, "data.excitation"),
                     filter=construct(RegionFilter, flt, "data.filter"),
                     integrator=construct(IntegratorOptions, integ, "data.integrator"))
    return sampler, data


def build_dictionary(cfg: Mapping[str, Any], n: int, dataset=None) -> Monomials:
    cfg = dict(_plain(cfg))
    kind = cfg.pop("kind", "monomials")
    if kind != "monomials":
        raise ConfigError(f"dictionary.kind={kind!r}; valid: 'monomials'")
    scale = cfg.get("scale")
    if isinstance(scale, str):
        if scale != "auto":
            raise ConfigError(f"dictionary.scale={scale!r}; use 'auto', null, or a list of positive numbers")
        if dataset is None:
            raise ConfigError("dictionary.scale='auto' needs the data set")
        cfg["scale"] = auto_scale(dataset)
    if cfg.get("weights") is not None:
        cfg["weights"] = tuple(cfg["weights"])
    return construct(Monomials, cfg, "dictionary", n=n)


def build_identification(cfg: Mapping[str, Any]) -> IdentifyConfig:
    return construct(IdentifyConfig, cfg, "identification")
