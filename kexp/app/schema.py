"""Hydra structured configs: the schema that every composed kexp config is checked against at composition.

A misspelled key or a value of the wrong type then fails when Hydra composes the config, with the full key
named (``controller.lmpc.horizon``), before kexp starts.  The schema is derived from the stages' own frozen
config dataclasses (:class:`~kexp.data.DataConfig`, :class:`~kexp.control.LmpcConfig`, ...), so the field
names, types and defaults are written once.  Values that OmegaConf cannot type (tuples, unions such as "a
number or a list") are ``Any`` here and checked by the stages, which also validate ranges and relations
(``u_min < u_max``) — see :mod:`kexp.app.build`.

``config.yaml`` lists ``kexp_schema`` first in its defaults; :func:`register` stores it (idempotent).
"""
import dataclasses
import typing
from dataclasses import MISSING, dataclass, field
from typing import Any, Dict, Optional

from omegaconf import MISSING as OC_MISSING

_SCALARS = (bool, int, float, str)
_DERIVED: dict = {}


def _schema_type(hint: Any):
    """(OmegaConf-compatible annotation, nested schema class or None) for a stage dataclass field annotation."""
    if hint in _SCALARS:
        return hint, None
    if dataclasses.is_dataclass(hint):
        sub = derive(hint)
        return sub, sub
    args = typing.get_args(hint)
    if args and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        if len(rest) == 1 and rest[0] in _SCALARS:
            return Optional[rest[0]], None
        if len(rest) == 1 and dataclasses.is_dataclass(rest[0]):
            # Optional[Schema] would be typed, but OmegaConf 2.3 cannot merge a mapping into it while it is None
            # (data.excitation={low: -1.0, ...} fails with AttributeError): the stage checks these keys instead
            return Any, None
    return Any, None


def _plain_default(value: Any) -> Any:
    return [_plain_default(v) for v in value] if isinstance(value, tuple) else value


def derive(cls: type, *, exclude: tuple[str, ...] = (), extra: tuple = ()) -> type:
    """A mutable OmegaConf schema dataclass with the init fields of the frozen stage dataclass ``cls`` (minus
    ``exclude``), plus ``extra`` fields given as (name, type, dataclasses.field)."""
    if cls in _DERIVED and not exclude and not extra:
        return _DERIVED[cls]
    hints = typing.get_type_hints(cls)
    specs = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name in exclude:
            continue
        typ, sub = _schema_type(hints[f.name])
        if f.default is not MISSING:
            default = _plain_default(f.default)
            spec = field(default_factory=lambda d=default: list(d)) if isinstance(default, list) else field(
                default=default)
        elif f.default_factory is not MISSING:
            spec = field(default_factory=sub) if sub is not None else field(default_factory=f.default_factory)
        else:
            spec = field(default=OC_MISSING)
        specs.append((f.name, typ, spec))
    name = f"{cls.__name__}Schema"
    schema = dataclasses.make_dataclass(name, specs + list(extra), namespace={"__module__": __name__})
    schema.__doc__ = f"Schema of {cls.__module__}.{cls.__qualname__} (derived)."
    globals()[name] = schema  # importable by name: configs that hold it pickle into joblib/submitit jobs
    if not exclude and not extra:
        _DERIVED[cls] = schema
    return schema


@dataclass
class SystemSchema:
    """A system group file sets name, params and origin (the name and params as the file gives them): with another
    system.name, the file's params are dropped (kexp.app.build.system_settings).  params=null: the defaults."""
    name: str = OC_MISSING            # a built-in system (see kexp.systems) or "module:Class"
    params: Optional[Dict[str, Any]] = field(default_factory=dict)
    origin: Optional[Dict[str, Any]] = None


@dataclass
class SamplerSchema:
    """The union of the samplers' parameters; those left null are not passed (kexp.data.samplers)."""
    kind: str = OC_MISSING            # circle | box | points
    n_traj: Optional[int] = None      # circle, box
    radius: Optional[float] = None    # circle
    even: Optional[bool] = None       # circle
    low: Any = None                   # box: a number or one per state
    high: Any = None
    points: Any = None                # points: a list of initial conditions


@dataclass
class LoggingSchema:
    mcap: bool = True                 # run.mcap: every control step, the model, the CLF, the open loop
    rrd: bool = True                  # run.rrd rendered from run.mcap at the end of the run
    prediction_every: int = 20        # the LMPC's predicted horizon every k steps; 0: never
    flush_every: float = 1.0          # seconds of simulated time between flushes
    progress: Any = "auto"            # auto | true | false
    writer: str = "sync"              # sync | process (kexp.recording.process_log)


@dataclass
class CacheSchema:
    enabled: bool = True
    dir: Optional[str] = None


@dataclass
class SweepSchema:
    """How a sweep is run, not what its jobs compute: not in a run's config hash (kexp.app.experiment.config_dict)
    nor in a job's overrides (kexp.app.resume)."""
    resume: bool = False              # sweep.resume=true: skip the jobs whose folder holds their completed run


def _build() -> type:
    from ..clf import ClfConfig
    from ..control import LmpcConfig
    from ..data import DataConfig
    from ..dictionary import Monomials
    from ..identify import IdentifyConfig
    from ..simulate import SimConfig

    lmpc_s = derive(LmpcConfig)
    from ..data.noise import NoiseConfig
    from ..data.smoothing import SmoothConfig
    noise_s, smooth_s = derive(NoiseConfig), derive(SmoothConfig)
    data_s = derive(DataConfig, extra=(("sampler", SamplerSchema, field(default_factory=SamplerSchema)),
                                       ("noise", noise_s, field(default_factory=noise_s)),
                                       ("smooth", smooth_s, field(default_factory=smooth_s))))
    dictionary_s = derive(Monomials, exclude=("n",), extra=(("kind", str, field(default="monomials")),))
    ident_s, clf_s = derive(IdentifyConfig), derive(ClfConfig)
    from ..plants import PlantConfig
    plant_s = derive(PlantConfig)
    sim_s = derive(SimConfig, exclude=("dt",), extra=(
        ("x0", Any, field(default=None)), ("open_loop", bool, field(default=True)),
        ("allow_outside_data", bool, field(default=False)),
        ("plant_params", Dict[str, Any], field(default_factory=dict))))

    @dataclass
    class ControllerSchema:
        """kind-specific keys are null unless the option sets them (kexp.app.build.build_controller_spec)."""
        kind: str = OC_MISSING        # lmpc | explicit | lqr | nmpc
        law: str = "sontag"
        law_params: Dict[str, Any] = field(default_factory=dict)
        u_min: Any = -5.0             # a number, or one per input
        u_max: Any = 5.0
        lmpc: Optional[lmpc_s] = None   # kind lmpc
        q: Optional[float] = None     # kinds lqr, nmpc
        r: Optional[float] = None
        horizon: Optional[int] = None  # kind nmpc
        solver: Optional[str] = None  # kind nmpc: sqp | ipopt (null: sqp)
        init: Optional[str] = None    # kind nmpc: lqr | zero (null: lqr)
        linearisation: Optional[str] = None  # kind lqr: auto | formula | plant (null: auto)

    ControllerSchema.__module__ = __name__
    ControllerSchema.__qualname__ = "ControllerSchema"
    globals()["ControllerSchema"] = ControllerSchema

    @dataclass
    class KexpConfig:
        """The whole experiment: what ``kexp`` composes from conf/."""
        system: SystemSchema = field(default_factory=SystemSchema)
        data: data_s = field(default_factory=data_s)
        dictionary: dictionary_s = field(default_factory=dictionary_s)
        identification: ident_s = field(default_factory=ident_s)
        clf: clf_s = field(default_factory=clf_s)
        controller: ControllerSchema = field(default_factory=ControllerSchema)
        sim: sim_s = field(default_factory=sim_s)
        plant: plant_s = field(default_factory=plant_s)
        logging: LoggingSchema = field(default_factory=LoggingSchema)
        cache: CacheSchema = field(default_factory=CacheSchema)
        sweep: SweepSchema = field(default_factory=SweepSchema)

    KexpConfig.__module__ = __name__
    KexpConfig.__qualname__ = "KexpConfig"
    globals()["KexpConfig"] = KexpConfig
    return KexpConfig


# built at import, so that every schema class is a module attribute: a composed config refers to them, and
# unpickling it in a joblib/submitit worker imports this module to find them
KexpConfig = _build()
_REGISTERED = False


def register() -> type:
    """Store the schema as ``kexp_schema`` in Hydra's ConfigStore (once) and return it."""
    global _REGISTERED
    if not _REGISTERED:
        from hydra.core.config_store import ConfigStore
        ConfigStore.instance().store(name="kexp_schema", node=KexpConfig)
        _REGISTERED = True
    return KexpConfig


def filled(schema: type):
    """``OmegaConf.structured(schema)`` with every optional nested section (``controller.lmpc``,
    ``data.excitation``) present with its defaults: a typed template that any key path can be checked against."""
    from omegaconf import OmegaConf

    def instance(cls):
        hints = typing.get_type_hints(cls)
        kwargs = {}
        for f in dataclasses.fields(cls):
            args = [a for a in typing.get_args(hints[f.name]) if a is not type(None)]
            target = hints[f.name] if dataclasses.is_dataclass(hints[f.name]) else (
                args[0] if len(args) == 1 and dataclasses.is_dataclass(args[0]) else None)
            if target is not None:
                kwargs[f.name] = instance(target)
        return cls(**kwargs)

    return OmegaConf.structured(instance(schema))
