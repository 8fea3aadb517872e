"""Turn a composed config (any mapping) into kexp's typed, validated objects.  Nothing Hydra-specific travels
past this module."""
from __future__ import annotations

import dataclasses
import typing

import numpy as np
from typing import Any, Mapping

from ..data import DataConfig, DataSource, Excitation, IntegratorOptions, RegionFilter, make_sampler
from ..dictionary import Monomials
from ..errors import ConfigError, DataError, PlantError
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


_SCALARS = {float: ("a number", (int, float)), int: ("an integer", (int,)), bool: ("true or false", (bool,)),
            str: ("a string", (str,))}


def _check_type(where: str, key: str, value: Any, hint: Any) -> None:
    """Reject a value whose type cannot match the field's annotation (float, int, bool, str, optionally None)."""
    args = typing.get_args(hint)
    allowed = [a for a in (args if args else (hint,)) if a is not type(None)]
    if value is None:
        if type(None) in args or not args and hint is type(None):
            return
        if len(allowed) == 1 and allowed[0] in _SCALARS:
            raise ConfigError(f"{where}.{key}=null: expected {_SCALARS[allowed[0]][0]}")
        return
    if len(allowed) != 1 or allowed[0] not in _SCALARS:
        return  # tuples, unions of several kinds, nested objects: validated by the class itself
    label, types = _SCALARS[allowed[0]]
    ok = isinstance(value, types) and not (allowed[0] in (int, float) and isinstance(value, bool))
    if not ok:
        raise ConfigError(f"{where}.{key}={value!r}: expected {label}")


def construct(cls, mapping: Mapping[str, Any] | None, where: str, **overrides):
    """``cls(**mapping)`` with unknown keys and wrongly typed values reported by name, e.g.
    'data.filter.hgih: unknown key; valid: …' or "data.dt='abc': expected a number"."""
    mapping = dict(_plain(mapping) or {})
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    for key in mapping:
        if key not in names:
            raise ConfigError(f"{where}.{key}: unknown key; valid keys: {sorted(names)}")
    hints = typing.get_type_hints(cls)
    for key, value in mapping.items():
        _check_type(where, key, value, hints.get(key))
    mapping.update(overrides)
    try:
        return cls(**mapping)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def system_settings(cfg: Mapping[str, Any]) -> dict:
    """``{"name", "params"}``: the system and the parameters that apply to it.

    A system group file's parameters belong to the system that file names; the file records both as ``origin``.
    If ``system.name`` is then changed to another system (on the command line or in a preset), the parameters
    still as that file gave them are dropped, so the new class starts from its own defaults plus the parameters
    set after the file (``+system.params={...}``, ``system.params.x=...``, a preset's ``system.params``)."""
    cfg = dict(_plain(cfg))
    unknown = set(cfg) - {"name", "params", "origin"}
    if unknown:
        raise ConfigError(f"system.{sorted(unknown)[0]}: unknown key; valid keys: ['name', 'origin', 'params']")
    if not cfg.get("name"):
        raise ConfigError("system.name is missing; e.g. system=vanderpol")
    params = dict(cfg.get("params") or {})
    origin = cfg.get("origin") or {}
    if origin and origin.get("name") != cfg["name"]:
        given = origin.get("params") or {}
        params = {k: v for k, v in params.items() if k not in given or given[k] != v}
    return {"name": cfg["name"], "params": params}


def build_system(cfg: Mapping[str, Any]):
    settings = system_settings(cfg)
    if settings["name"] == PLANT_SYSTEM:
        raise ConfigError("system=plant is the system of an external plant: set plant=gymnasium (plant.env_id=…) "
                          "or plant=python (plant.target=module:Class)")
    if settings["name"] == "data":   # kexp.app.data_only.DATA_SYSTEM: n, m come from the recorded runs
        raise ConfigError("system=data is known only from its recorded runs: it is built from data.source "
                          "(kexp.app.data_only.build_data_system)")
    return make_system(settings["name"], settings["params"])


def build_data(cfg: Mapping[str, Any]):
    """Returns (sampler, DataConfig); the sampler is None for recorded data (``data.source.kind=files``)."""
    cfg = dict(_plain(cfg))
    cfg.pop("noise", None)  # data.noise: applied after collection (build_data_noise, kexp.data.noise)
    cfg.pop("smooth", None)  # data.smooth: applied after the noise (build_data_smoothing, kexp.data.smoothing)
    sampler_cfg = dict(cfg.pop("sampler", None) or {})
    source = construct(DataSource, cfg.pop("source", None), "data.source")
    sampler = None
    if source.kind == "plant" and source.path:
        raise ConfigError(f"data.source.path={source.path!r} applies to data.source.kind=files, not plant")
    if source.kind in ("simulate", "plant"):
        if "kind" not in sampler_cfg:
            raise ConfigError("data.sampler.kind is missing; valid: circle, box, points")
        kind = sampler_cfg.pop("kind")
        # the schema holds every sampler's parameters: those left null are not this sampler's (or its default)
        sampler = make_sampler(kind, **{k: v for k, v in sampler_cfg.items() if v is not None})
    exc = cfg.pop("excitation", None)
    flt = cfg.pop("filter", None)
    integ = cfg.pop("integrator", None)
    data = construct(DataConfig, cfg, "data",
                     excitation=None if exc is None else construct(Excitation, exc, "data.excitation"),
                     filter=construct(RegionFilter, flt, "data.filter"),
                     integrator=construct(IntegratorOptions, integ, "data.integrator"), source=source)
    return sampler, data


def build_noise(cfg: Mapping[str, Any] | None, where: str, n: int):
    """The NoiseConfig of ``data.noise`` or ``sim.noise`` (``where``) for ``n`` states, errors naming that key."""
    import re
    from ..data.noise import NoiseConfig
    try:
        noise = construct(NoiseConfig, cfg, where)
        noise.sigma(n, np.ones(n))  # one std, or one per state
        return noise
    except ConfigError as exc:
        raise ConfigError(re.sub(r"(?<![\w.])noise\.", f"{where}.", str(exc))) from None


def build_data_smoothing(cfg: Mapping[str, Any]):
    """The SmoothConfig of ``data.smooth`` (off if absent), errors naming that key."""
    import re
    from ..data.smoothing import SmoothConfig
    try:
        return construct(SmoothConfig, dict(_plain(cfg)).get("smooth"), "data.smooth")
    except ConfigError as exc:
        raise ConfigError(re.sub(r"(?<![\w.])smooth\.", "data.smooth.", str(exc))) from None


def build_data_noise(cfg: Mapping[str, Any], n: int):
    """The NoiseConfig of ``data.noise`` (none if absent) for ``n`` states."""
    noise = build_noise(dict(_plain(cfg)).get("noise"), "data.noise", n)
    if noise is not None and getattr(noise, "per_x0", False):
        raise ConfigError("data.noise.per_x0=true: only the closed loop's noise has an initial condition; use "
                          "sim.noise.per_x0=true, or set data.noise.seed")
    return noise


def build_plant(nominal, system_cfg: Mapping[str, Any], sim_cfg: Mapping[str, Any]):
    """(plant, params): the system the closed loop runs on — the configured system ``nominal`` (built by
    :func:`build_system` from ``system_cfg``) with ``sim.plant_params`` overriding its parameters (plant mismatch:
    the data and the identification keep the nominal system) — and the plant's parameters as used.  An unknown
    parameter name is a ConfigError naming the valid ones."""
    settings = system_settings(system_cfg)
    overrides = dict(_plain(dict(_plain(sim_cfg)).get("plant_params")) or {})
    valid = sorted(f.name for f in dataclasses.fields(nominal) if f.init) if dataclasses.is_dataclass(nominal) \
        else []
    for key in overrides:
        if key not in valid:
            raise ConfigError(f"sim.plant_params.{key}: not a parameter of system {settings['name']!r}; valid: "
                              f"{valid}")
    if not overrides:
        return nominal, {name: getattr(nominal, name) for name in valid}
    plant = make_system(settings["name"], {**settings["params"], **overrides})
    return plant, {name: getattr(plant, name) for name in valid}


def build_plant_config(cfg: Mapping[str, Any] | None):
    """The validated ``plant`` section (:class:`~kexp.plants.PlantConfig`; absent: kexp's integrator)."""
    from ..plants import PlantConfig
    return construct(PlantConfig, cfg, "plant")


PLANT_SYSTEM = "plant"   # system.name of a plant without a formula (conf/system/plant.yaml)


def build_external_plant(plant_cfg, system_cfg: Mapping[str, Any], sim_cfg: Mapping[str, Any]):
    """(plant, system) for an external plant (``plant.kind`` gymnasium or python): the checked plant and the
    system the stages read n, m, x_eq and names from: the configured system's formula where one is named, or the
    plant's own :class:`~kexp.plants.PlantSystem` with ``system=plant``.  ``sim.plant_params`` does not apply (it
    changes kexp's integrator) and is refused."""
    from ..plants import PlantSystem, make_plant
    if dict(_plain(dict(_plain(sim_cfg)).get("plant_params")) or {}):
        raise ConfigError(f"sim.plant_params applies to kexp's integrator (plant=integrator), not plant.kind="
                          f"{plant_cfg.kind}: set the {plant_cfg.kind} plant's own parameters "
                          + ("(plant.env_kwargs)" if plant_cfg.kind == "gymnasium" else "(plant.params)"))
    settings = system_settings(system_cfg)
    system = None if settings["name"] == PLANT_SYSTEM else make_system(settings["name"], settings["params"])
    plant = make_plant(plant_cfg, system)
    if system is None:
        info = plant.info()
        system = PlantSystem(plant_id=str(info.get("id", plant.name)), n_states=plant.n, n_inputs=plant.m,
                             x_eq=plant_cfg.equilibrium or (), names=plant_cfg.state_names or ())
    elif (plant.n, plant.m) != (system.n, system.m):
        plant.close()
        raise ConfigError(f"plant {plant.name!r} has n={plant.n}, m={plant.m}, the system {system.name!r} "
                          f"n={system.n}, m={system.m}: name the system the plant simulates, or system=plant")
    return plant, system


def narrow_bounds(spec, plant, echo=print):
    """``spec`` with its input bounds narrowed to those the plant accepts (a Gymnasium Box), with one line when
    they change; the plant's bounds are the input bounds unless the config narrows them."""
    bounds = plant.input_bounds() if plant is not None else None
    if bounds is None:
        return spec
    lo_p, hi_p = (np.broadcast_to(np.asarray(b, float), (plant.m,)) for b in bounds)
    lo_c = np.broadcast_to(np.asarray(spec.u_min, float), (plant.m,))
    hi_c = np.broadcast_to(np.asarray(spec.u_max, float), (plant.m,))
    lo, hi = np.maximum(lo_c, lo_p), np.minimum(hi_c, hi_p)
    if np.array_equal(lo, lo_c) and np.array_equal(hi, hi_c):
        return spec
    if not np.all(lo < hi):
        raise ConfigError(f"controller.u_min={spec.u_min}, u_max={spec.u_max} do not overlap the plant's input "
                          f"bounds [{lo_p.tolist()}, {hi_p.tolist()}]")
    as_cfg = lambda v: float(v[0]) if v.size == 1 else tuple(float(a) for a in v)  # noqa: E731
    echo(f"input bounds: the plant accepts [{', '.join(f'{a:g}' for a in lo_p)}] … "
         f"[{', '.join(f'{a:g}' for a in hi_p)}]; the controller uses u_min={as_cfg(lo)}, u_max={as_cfg(hi)}")
    return dataclasses.replace(spec, u_min=as_cfg(lo), u_max=as_cfg(hi))


def read_data_files(system, data_cfg: DataConfig, cache_cfg: dict | None = None):
    """The recorded runs ``data_cfg.source`` names, for ``system``, streamed: one pass checks every file and
    keeps counts, bounds and digest; identification then reads one file at a time (kexp.data.streaming).  CSV
    files are parsed once into ``<cache.dir>/parsed`` (kexp.data.parsed), shared by later runs and a sweep's
    jobs; with ``cache.enabled=false`` (or no ``cache_cfg``) into a temporary folder of this process."""
    from ..data.streaming import open_runs
    src = data_cfg.source
    return open_runs(src.path, n=system.n, m=system.m, dt=data_cfg.dt, format=src.format, pair_rule=data_cfg.pairs,
                     system_name=system.name, drift=system.drift, region_filter=data_cfg.filter,
                     x_eq=system.equilibrium, parsed_dir=parsed_dir(cache_cfg))


def parsed_dir(cache_cfg: dict | None):
    """``<cache.dir>/parsed`` (cache.dir None: $KEXP_CACHE_DIR or ~/.cache/kexp), or None when the cache is off."""
    if not cache_cfg or not bool(cache_cfg.get("enabled", True)):
        return None
    from pathlib import Path

    from ..cachedir import default_cache_dir
    return Path(cache_cfg.get("dir") or default_cache_dir()) / "parsed"


def check_file_data(dataset, ident_cfg, dictionary_size: int) -> None:
    """Too few usable pairs in recorded data for the dictionary (the same rule as :func:`check_data_budget`)."""
    train, _ = dataset.split(ident_cfg.holdout, ident_cfg.holdout_seed)
    if train.n_pairs < 2 * dictionary_size:
        raise DataError(f"recorded data gives {train.n_pairs} usable training pairs ({dataset.n_pairs} in all, "
                          f"{dataset.n_traj} runs, identification.holdout={ident_cfg.holdout}) for "
                          f"{dictionary_size} dictionary functions: need at least {2 * dictionary_size}; add runs "
                          "or lower dictionary.degree")


def build_dictionary(cfg: Mapping[str, Any], n: int, dataset=None, x_eq=None) -> Monomials:
    """The dictionary of ``cfg``: ``center: equilibrium`` is the system's ``x_eq`` (None, the origin, where x_eq is 0
    or not given: only the size is wanted), ``scale: auto`` the data's largest |x_i − center_i|."""
    cfg = dict(_plain(cfg))
    kind = cfg.pop("kind", "monomials")
    if kind != "monomials":
        raise ConfigError(f"dictionary.kind={kind!r}; valid: 'monomials'")
    center = cfg.get("center")
    if isinstance(center, str):
        if center != "equilibrium":
            raise ConfigError(f"dictionary.center={center!r}; use 'equilibrium' (the system's x_eq), null (the "
                              "origin) or a list of numbers")
        eq = None if x_eq is None else np.asarray(x_eq, dtype=float)
        cfg["center"] = None if eq is None or not np.any(eq) else tuple(eq.tolist())
    scale = cfg.get("scale")
    if isinstance(scale, str):
        if scale != "auto":
            raise ConfigError(f"dictionary.scale={scale!r}; use 'auto', null, or a list of positive numbers")
        if dataset is None:
            raise ConfigError("dictionary.scale='auto' needs the data set")
        cfg["scale"] = auto_scale(dataset, cfg.get("center"))
    if cfg.get("weights") is not None:
        cfg["weights"] = tuple(cfg["weights"])
    return construct(Monomials, cfg, "dictionary", n=n)


def build_identification(cfg: Mapping[str, Any]) -> IdentifyConfig:
    return construct(IdentifyConfig, cfg, "identification")


def build_clf(cfg: Mapping[str, Any]):
    from ..clf import ClfConfig
    cfg = dict(_plain(cfg))
    for key in ("region_low", "region_high"):
        if isinstance(cfg.get(key), list):
            cfg[key] = tuple(cfg[key])
    return construct(ClfConfig, cfg, "clf")


CONTROLLER_KINDS = ("lmpc", "explicit", "lqr", "nmpc")
ORACLE_SOLVERS = ("sqp", "ipopt")               # controller.solver (kind nmpc)
ORACLE_INITS = ("lqr", "zero")                  # controller.init (kind nmpc): the first guess after a reset
LINEARISATIONS = ("auto", "formula", "plant")   # controller.linearisation (kind lqr)


@dataclasses.dataclass(frozen=True)
class ControllerSpec:
    """The validated controller section: built before any long computation."""

    kind: str
    law: str
    law_params: dict
    u_min: float | tuple
    u_max: float | tuple
    lmpc: object = None        # LmpcConfig for kind 'lmpc'
    q: float = 1.0
    r: float = 1.0
    horizon: int = 100         # nmpc: prediction horizon in steps
    solver: str = "sqp"        # nmpc: kexp's compiled SQP or CasADi + IPOPT (ORACLE_SOLVERS)
    init: str = "lqr"          # nmpc: the first guess after a reset (ORACLE_INITS)
    linearisation: str = "auto"  # lqr: formula (F, G) | plant (finite differences of its step) | auto


def build_controller_spec(cfg: Mapping[str, Any]) -> ControllerSpec:
    from ..control import LAWS, LmpcConfig
    cfg = dict(_plain(cfg))
    # the schema holds every kind's keys; null ones are not set (kexp.app.schema.ControllerSchema)
    cfg = {k: v for k, v in cfg.items() if not (k in ("lmpc", "q", "r", "horizon", "linearisation", "solver", "init") and v is None)}
    kind = cfg.pop("kind", None)
    if kind not in CONTROLLER_KINDS:
        raise ConfigError(f"controller.kind={kind!r}; valid: {CONTROLLER_KINDS}")
    # 'lmpc' is accepted for every kind (used by kind lmpc only), so that `+experiment=X controller=lqr` works
    # on a preset that tunes the LMPC
    allowed = {"law", "law_params", "u_min", "u_max", "lmpc"} \
        | ({"q", "r"} if kind in ("lqr", "nmpc") else set()) | ({"horizon", "solver", "init"} if kind == "nmpc" else set()) \
        | ({"linearisation"} if kind == "lqr" else set())
    for key in cfg:
        if key not in allowed:
            raise ConfigError(f"controller.{key}: unknown key for kind {kind!r}; valid keys: {sorted(allowed)}")
    u_min, u_max = cfg.get("u_min", -5.0), cfg.get("u_max", 5.0)
    lo, hi = np.asarray(u_min, float), np.asarray(u_max, float)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
        raise ConfigError(f"controller.u_min={u_min}, controller.u_max={u_max}: need finite u_min < u_max")
    law = cfg.get("law", "sontag")
    if law not in LAWS:
        raise ConfigError(f"controller.law={law!r}; valid: {sorted(LAWS)}")
    q, r = float(cfg.get("q", 1.0)), float(cfg.get("r", 1.0))
    if not (q > 0 and r > 0):
        raise ConfigError(f"controller.q={q}, controller.r={r}: both must be > 0")
    lmpc = construct(LmpcConfig, cfg.get("lmpc"), "controller.lmpc") if kind == "lmpc" else None
    to_t = lambda v: tuple(v) if isinstance(v, list) else v  # noqa: E731
    horizon = cfg.get("horizon", 100)
    if not (isinstance(horizon, int) and not isinstance(horizon, bool) and horizon >= 1):
        raise ConfigError(f"controller.horizon={horizon!r}: use an int >= 1")
    solver = cfg.get("solver", "sqp")
    if solver not in ORACLE_SOLVERS:
        raise ConfigError(f"controller.solver={solver!r}; valid: {ORACLE_SOLVERS} (sqp: kexp's compiled SQP, ipopt: "
                          "CasADi + IPOPT; the same problem)")
    init = cfg.get("init", "lqr")
    if init not in ORACLE_INITS:
        raise ConfigError(f"controller.init={init!r}; valid: {ORACLE_INITS} (the oracle's first guess: the LQR "
                          "feedback rolled out, or zero inputs)")
    linearisation = cfg.get("linearisation", "auto")
    if linearisation not in LINEARISATIONS:
        raise ConfigError(f"controller.linearisation={linearisation!r}; valid: {LINEARISATIONS} (auto: the formula's "
                          "F and G where the system has them, the plant's step otherwise)")
    return ControllerSpec(kind=kind, law=law, law_params=dict(cfg.get("law_params") or {}), u_min=to_t(u_min),
                          u_max=to_t(u_max), lmpc=lmpc, q=q, r=r, horizon=horizon, solver=solver,
                          init=init, linearisation=linearisation)


def build_controller(spec: ControllerSpec, system, model, clf, *, prediction_every: int = 0, ext_plant=None):
    """The controller for a validated spec, an identified model and its CLF.  ``system`` is what the true-model
    baselines (kind lqr: the linearisation; kind nmpc: the oracle's model) know: kexp passes the plant the closed
    loop runs on (``sim.plant_params`` included), so that they stay references under plant mismatch.  Kind lqr
    with ``spec.linearisation`` plant (auto: when ``system`` has no formula) linearises ``ext_plant`` (None: kexp's
    integrator of ``system`` at the model's Δ) by finite differences (:mod:`kexp.control.plant_lqr`); this resets
    and steps that plant before the closed loop resets it."""
    from ..control import ExplicitController, LqrController, make_law
    from ..control.lmpc import Lmpc
    law = make_law(spec.law, clf.lyap, spec.u_min, spec.u_max, model=model,
                   weights=(clf.config.q_x, clf.config.r_u), **spec.law_params)
    if spec.kind == "lmpc":
        return Lmpc(model, clf, law, spec.lmpc, spec.u_min, spec.u_max, prediction_every=prediction_every)
    if spec.kind == "explicit":
        return ExplicitController(law, clf)
    if spec.kind == "nmpc":
        if spec.solver == "sqp":
            from ..control.sqp_oracle import SqpOracle as Oracle
        else:
            from ..control.oracle import NmpcOracle as Oracle
        return Oracle(system, None, spec.u_min, spec.u_max, horizon_steps=spec.horizon, dt=model.dt, q=spec.q,
                      r=spec.r, terminal="lqr", clf=clf, law=law, init=spec.init)
    from ..plants import PlantSystem
    no_formula = isinstance(system, PlantSystem)
    if spec.linearisation == "formula" and no_formula:
        raise ConfigError(f"controller.linearisation=formula needs F and G; plant {system.name!r} has none: set "
                          "controller.linearisation=plant (or auto)")
    if spec.linearisation == "plant" or no_formula:
        from ..control.plant_lqr import PlantLqrController
        from ..plants import IntegratorPlant
        if no_formula and ext_plant is None:
            raise PlantError(f"controller=lqr on plant {system.name!r} (no formula) linearises the plant itself: "
                             "build_controller needs ext_plant=<the plant>")
        plant = ext_plant if ext_plant is not None else IntegratorPlant(system, model.dt)
        return PlantLqrController(plant, system.equilibrium, spec.u_min, spec.u_max, q=spec.q, r=spec.r, clf=clf)
    return LqrController(system, spec.u_min, spec.u_max, q=spec.q, r=spec.r, clf=clf)


def dictionary_size(cfg: Mapping[str, Any], n: int) -> int:
    """The number of dictionary functions, known before any data (``scale: auto`` does not change it): an upper
    bound of the model's k."""
    cfg = dict(_plain(cfg))
    if cfg.get("scale") == "auto":
        cfg["scale"] = None
    return build_dictionary(cfg, n).size


def check_memory_budget(spec: ControllerSpec, k: int, m: int) -> None:
    """An LMPC horizon whose memory exceeds the budget: refuse before identification (kexp.control.lmpc)."""
    if spec.kind == "lmpc":
        from ..control.memory import check_memory
        check_memory(spec.lmpc, k, m)


def check_data_budget(sampler, data_cfg, ident_cfg, dictionary_size: int) -> None:
    """Too few samples for the dictionary: refuse before collecting anything."""
    n_train = sampler.n_traj - max(1 if ident_cfg.holdout > 0 and sampler.n_traj >= 2 else 0,
                                   int(round(ident_cfg.holdout * sampler.n_traj)))
    pairs = n_train * data_cfg.n_steps
    if pairs < 2 * dictionary_size:
        raise ConfigError(f"data gives about {pairs} training pairs ({n_train} trajectories × {data_cfg.n_steps} "
                          f"steps) for {dictionary_size} dictionary functions: need at least {2 * dictionary_size}; "
                          "raise data.sampler.n_traj or data.T, or lower dictionary.degree")


def build_sim(cfg: Mapping[str, Any], system, dt: float, sampler=None):
    """Returns (SimConfig, x0 (n,), open_loop flag).  With ``sampler``, refuses an x0 outside the region the data
    starts from (the model is not fit there) unless ``sim.allow_outside_data``."""
    from ..simulate import SimConfig
    cfg = dict(_plain(cfg))
    if "dt" in cfg:   # SimConfig has a dt, the model's: a sim.dt added with + would be ignored silently
        raise ConfigError(f"sim.dt={cfg['dt']!r}: the closed loop steps at the model's sampling time; set data.dt")
    x0 = cfg.pop("x0", None)
    open_loop = bool(cfg.pop("open_loop", True))
    allow_outside = cfg.pop("allow_outside_data", False)
    if not isinstance(allow_outside, bool):
        raise ConfigError(f"sim.allow_outside_data={allow_outside!r}: expected true or false")
    raw = x0
    try:
        x0 = np.asarray(x0, dtype=float) if x0 is not None else None
    except (TypeError, ValueError):
        raise ConfigError(f"sim.x0={raw!r}: give {system.n} finite numbers as a list, e.g. sim.x0=[0.5,-0.5] "
                          "(without quotes around the list)") from None
    if x0 is None or x0.shape != (system.n,) or not np.all(np.isfinite(x0)):
        raise ConfigError(f"sim.x0={None if x0 is None else x0.tolist()}: give {system.n} finite numbers")
    xe = np.asarray(system.equilibrium, float)
    if sampler is not None and not allow_outside and hasattr(sampler, "contains") and not sampler.contains(x0, xe):
        raise ConfigError(f"sim.x0={x0.tolist()} lies outside the data region ({sampler.describe()}): the model is "
                          "not fit there; move x0, widen the data, or set sim.allow_outside_data=true")
    integ = construct(IntegratorOptions, cfg.pop("integrator", None), "sim.integrator")
    cfg.pop("plant_params", None)  # the plant: build_plant
    from ..simulate import Disturbance
    noise = build_noise(cfg.pop("noise", None), "sim.noise", system.n)
    dist = construct(Disturbance, cfg.pop("disturbance", None), "sim.disturbance")
    dist.sigma(system.m)  # one std, or one per input
    return construct(SimConfig, cfg, "sim", dt=dt, integrator=integ, noise=noise, disturbance=dist), x0, open_loop


def build_logging(cfg: Mapping[str, Any]) -> dict:
    from .schema import LoggingSchema
    cfg = dict(_plain(cfg))
    defaults = {f.name: f.default for f in dataclasses.fields(LoggingSchema)}
    for key in cfg:
        if key not in defaults:
            raise ConfigError(f"logging.{key}: unknown key; valid keys: {sorted(defaults)}")
    out = {**defaults, **cfg}
    from ..recording.writer import check_settings
    check_settings(out["flush_every"], out["prediction_every"])   # the loggers' own check, before anything runs
    if out["progress"] not in ("auto", True, False):
        raise ConfigError(f"logging.progress={out['progress']!r}; valid: auto, true, false")
    if out["writer"] not in ("sync", "process"):
        raise ConfigError(f"logging.writer={out['writer']!r}; valid: sync (in the run's process), process (a child "
                          "process encodes and writes the log)")
    if out["rrd"] and not out["mcap"]:
        raise ConfigError("logging.rrd=true needs logging.mcap=true (the recording is rendered from the log)")
    return out
