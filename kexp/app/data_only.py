"""``system=data``: the ``kexp`` command on a system known only from its recorded runs (conf/system/data.yaml).

Spelled as ``system=plant`` is: the system group names where n and m come from — there the plant, here the data
files (``data.source.kind=files``, read with :mod:`kexp.data.layout`).  The equilibrium and state names are
``system.params.equilibrium`` / ``system.params.state_names`` (null: the origin, x1…xn).  F and G do not exist:
B and b are regressed from the forced runs (``identification.inputs=regression``), and whatever needs F or G
(simulated data, Euler pairs, the projection of G, the NMPC oracle, the formula LQR) is refused in one line before
any work (:func:`check_data_stages`).  Identification, the CLF and its certificate need neither; the closed loop
needs something to act on: an external plant (``plant=python`` / ``plant=gymnasium``) with the data's n and m.
Without one the run says so in one line (:data:`STOP_LINE`), stops after the certificate, and writes its model,
``summary.json`` (status ``identified``, completed) and the printed report; exit code 0."""
from __future__ import annotations

from typing import Any, Mapping

from ..errors import ConfigError
from ..identify.datasystem import DATA_SYSTEM, DataSystem
from .build import PLANT_SYSTEM, build_external_plant, system_settings

PARAMS = ("equilibrium", "state_names")
STATUS = "identified"   # summary.json of a run that stopped after identification and the certificate
STOP_LINE = ("system=data without a plant: this run identifies, certifies and reports, then stops (the closed loop "
             "needs a plant: plant=python plant.target=<module>:<Class> or plant=gymnasium plant.env_id=<id>)")


def is_data_system(system_cfg: Mapping[str, Any]) -> bool:
    """True for ``system=data`` (``system.name: data``)."""
    return system_settings(system_cfg)["name"] == DATA_SYSTEM


def build_data_system(system_cfg: Mapping[str, Any], data_cfg) -> DataSystem:
    """The :class:`~kexp.identify.datasystem.DataSystem` of ``system=data``: n and m from the first recorded run at
    ``data.source.path``, x_eq and names from ``system.params``; the name a ``run.mcap`` was recorded with (else
    'data')."""
    from ..data.layout import run_layout
    params = dict(system_settings(system_cfg)["params"])
    for key in params:
        if key not in PARAMS:
            raise ConfigError(f"system.params.{key}: not a parameter of system=data; valid: {list(PARAMS)}")
    src = data_cfg.source
    if src.kind != "files":
        raise ConfigError(f"system=data is known only from recorded runs, not data.source.kind={src.kind}: set "
                          "data.source.kind=files and data.source.path=<a folder of runs> (runs of a plant: system="
                          "plant)")
    layout = run_layout(src.path, src.format)
    if layout.m == 0:
        raise ConfigError(f"system=data: the runs at {src.path} have no inputs ({layout.first.name} has no u column "
                          "or array): the CLF needs an input model, regressed from forced runs; record (t, x, u) "
                          "runs under an input, or use kexp.fit in Python for a drift-only model")
    names = params.get("state_names")
    try:
        return DataSystem(label=layout.system or DATA_SYSTEM, n_states=layout.n, n_inputs=layout.m,
                          x_eq=tuple(params.get("equilibrium") or ()), names=tuple(names or ()))
    except (ConfigError, TypeError) as exc:
        raise ConfigError(f"system.params: {str(exc).splitlines()[0]} (the runs at {src.path} have n={layout.n})"
                          ) from None


def data_plant(plant_cfg, system: DataSystem, sim_cfg):
    """The external plant (``plant=python`` / ``gymnasium``) the loop of a ``system=data`` run acts on, checked to
    have the recorded runs' n and m."""
    plant, _ = build_external_plant(plant_cfg, {"name": PLANT_SYSTEM}, sim_cfg)
    if (plant.n, plant.m) != (system.n, system.m):
        plant.close()
        raise ConfigError(f"plant {plant.name!r} has n={plant.n}, m={plant.m}, the recorded runs n={system.n}, "
                          f"m={system.m}: give runs of this plant")
    return plant


def check_data_stages(system: DataSystem, data_cfg, ident_cfg, spec) -> None:
    """What needs F or G, refused in one line before any work (as ``system=plant``'s checks)."""
    if data_cfg.pairs == "euler":
        raise ConfigError("data.pairs=euler needs F at the samples; system=data has no formula: set data.pairs=next")
    if ident_cfg.inputs != "regression":
        raise ConfigError("system=data: G is unknown, so B cannot be projected from it: set "
                          "identification.inputs=regression (B, b regressed from the recorded inputs)")
    if ident_cfg.compare_projection:
        raise ConfigError("identification.compare_projection needs G; system=data has no formula: set it false")
    if spec.kind == "lqr" and spec.linearisation == "formula":
        raise ConfigError("controller.linearisation=formula needs F and G; system=data has none: set "
                          "controller.linearisation=plant (or auto) with a plant")
    if spec.kind == "nmpc":
        raise ConfigError("controller=nmpc (the true-model oracle) needs a formula (F, G); system=data has none "
                          "(use controller=lmpc, model_lqr, or lqr with a plant)")


def identified_metrics(chash: str, system, model_info: dict, noise: dict, clf, versions: dict, lock: dict, cache,
                       model_file: str) -> dict:
    """summary.json of a run that stopped after the certificate (status :data:`STATUS`, completed): the model,
    the CLF and its certificate, the data noise, versions, lock and cache as a looped run's; no "metrics"."""
    return {"status": STATUS, "completed": True, "message": STOP_LINE, "config_hash": chash, "system": system.name,
            "model": model_info, "noise": noise, "plant": {"kind": "none", "id": None, "versions": {}},
            "clf": {"status": clf.status, "r": clf.r, "r_hat": clf.r_hat, "certificate": clf.certificate.to_dict()},
            "versions": versions, "lock": lock,
            "cache": {"dir": str(cache.dir) if cache.enabled else None, "hits": cache.hits, "misses": cache.misses},
            "files": {"model": model_file}}
