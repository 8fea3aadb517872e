"""Running one experiment: data → identification → CLF → controller → closed loop, logged and summarised
(:func:`run`, which the ``kexp`` command (kexp.app.main) calls once per job), and the config as it is logged,
hashed and keyed (:func:`config_dict`, :func:`config_hash`)."""
from __future__ import annotations

import contextlib
import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ..clf.levelset import level_set_boundary
from ..data import collect
from ..data.runs import check_dictionary_range
from ..data.noise import add_measurement_noise, data_rms
from ..data.streaming import bounds as data_bounds
from ..errors import ConfigError, KexpError
from ..identify import identify
from ..recording.schema import plain
from ..recording.process_log import ProcessRunLogger, prestart as prestart_writer
from ..recording.writer import RunLogger
from ..simulate import closed_loop
from ..clf import load_clf, save_clf, synthesize_clf
from ..clf.synthesis import check_sdp_budget
from ..identify import FORMAT_VERSION, KoopmanBilinearModel
from .budget import check_run_size
from .build import (build_clf, build_controller, build_controller_spec, build_data, build_dictionary,
                    build_data_noise, build_data_smoothing, build_external_plant, build_identification,
                    build_logging, build_plant, build_plant_config, build_sim, build_system, narrow_bounds,
                    check_data_budget, check_file_data, check_memory_budget, dictionary_size, read_data_files,
                    system_settings)
from .cache import Cache, clf_key, model_key
from .data_only import (STOP_LINE, build_data_system, check_data_stages, data_plant, identified_metrics,
                        is_data_system)
from ..identify.datasystem import DataSystem
from ..simulate import SimConfig
from .faults import OutputError, create_exclusive, fault_message, write_json, writing
from .run_folder import RunFolderError, run_files
from .lock import installed_version, lock_info
from .progress import Progress


def _versions() -> dict:
    """The versions of kexp and the packages its numbers depend on (None: not installed); looked up once per
    process (kexp.app.lock.installed_version)."""
    return {pkg: installed_version(pkg) for pkg in ("kexp", "numpy", "scipy", "cvxpy", "clarabel", "piqp", "mcap",
                                             "rerun-sdk", "hydra-core", "numba")}


def config_hash(cfg_dict: dict) -> str:
    return hashlib.sha256(json.dumps(plain(cfg_dict), sort_keys=True).encode()).hexdigest()[:16]


def _to_dict(cfg: Any) -> dict:
    from omegaconf import DictConfig as _DC, OmegaConf
    from omegaconf.errors import InterpolationResolutionError, MissingMandatoryValue
    if isinstance(cfg, _DC):
        try:
            return OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
        except MissingMandatoryValue as exc:
            key = getattr(exc, "full_key", None) or "a key"
            raise ConfigError(f"{key} is missing (???): set it, e.g. {key}=<value>") from None
        except InterpolationResolutionError as exc:   # ${oc.env:UNSET}, ${nope.x}: one line, not a traceback
            from .precheck import interpolation_error_line
            raise ConfigError(interpolation_error_line(exc)) from None
    return dict(cfg)


def config_dict(cfg: Any) -> dict:
    """The composed config as plain data, as logged, hashed and keyed: without ``hydra`` and ``sweep`` (how a sweep
    is run: ``sweep.resume``), without
    ``logging.writer`` (how the log is written, not what: the bytes are the same either way, so a run's hash and
    logged config do not depend on it), and with the system's params those that apply to ``system.name``
    (:func:`~kexp.app.build.system_settings`)."""
    out = {k: v for k, v in _to_dict(cfg).items() if k not in ("hydra", "sweep")}
    if isinstance(out.get("logging"), dict):
        out["logging"] = {k: v for k, v in out["logging"].items() if k != "writer"}
    if "system" in out:
        out["system"] = system_settings(out["system"])
    for path, default in _LATER_KEYS.items():   # at their defaults: the config and its hash as before they existed
        out = _drop_default(out, path, default)
    return out


def _drop_default(d: dict, path: tuple[str, ...], default) -> dict:
    """``d`` without the key at ``path`` if it holds ``default`` (of the same type); copies, never edits."""
    head, *rest = path
    if not isinstance(d, dict) or head not in d:
        return d
    if rest:
        return {**d, head: _drop_default(d[head], tuple(rest), default)}
    value = d[head]
    return {k: v for k, v in d.items() if k != head} if value == default and type(value) is type(default) else d


def _default_plant() -> dict:
    from dataclasses import asdict
    from ..plants import PlantConfig
    return plain({k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(PlantConfig()).items()})


_DEFAULT_PLANT = _default_plant()

# keys added after runs were logged, with the default that leaves a config's hash as it was: the plant (kexp's
# integrator), unpaced runs, the automatic linearisation, issue 34's identification and noise keys (the model
# cache keys on the identification code's digest as well, so a changed default still re-identifies)
_LATER_KEYS = {("plant",): _DEFAULT_PLANT, ("sim", "realtime"): False, ("controller", "linearisation"): None,
               ("controller", "solver"): None, ("controller", "init"): None,
               ("identification", "fix_equilibrium"): None, ("identification", "estimator"): "ls",
               ("identification", "iv_lag"): 1, ("sim", "noise", "per_x0"): False, ("data", "noise", "per_x0"): False}


def _perturbation(system, plant_params: dict, model, sim_cfg) -> dict:
    """Noise and mismatch as used (summary.json, /summary): σ per state of the data noise and of the closed
    loop's measurement noise (absolute), σ per input of the disturbance, the data RMS a relative σ refers to, and
    the plant's parameters with those that differ from the nominal system."""
    rms = model.report.get("data_rms")
    if sim_cfg.noise.active and sim_cfg.noise.relative and rms is None:
        raise ConfigError("sim.noise.relative=true: this model's report has no data RMS (a model file from before "
                          "kexp recorded it); set sim.noise.relative=false with an absolute std, or re-identify "
                          "with cache.enabled=false")
    sim_std = sim_cfg.noise.sigma(system.n, rms) if sim_cfg.noise.active else np.zeros(system.n)
    dist_std = sim_cfg.disturbance.sigma(system.m) if sim_cfg.disturbance.active else np.zeros(system.m)
    return {"noise": {"data_rms": rms, "data_noise_std": model.report.get("data_noise_std"),
                      "data_smoothing": model.report.get("data_smoothing", "none"),
                      "sim_noise_std": sim_std.tolist(), "disturbance_std": dist_std.tolist(),
                      # a draw per x0 (sim.noise.per_x0): written only when set, so older logs stay as they were
                      **({"sim_noise_per_x0": True} if sim_cfg.noise.per_x0 else {})},
            "plant": {"params": plant_params,
                      "mismatch": {k: {"nominal": getattr(system, k), "plant": v} for k, v in plant_params.items()
                                   if getattr(system, k) != v}}}


def _perturbation_lines(p: dict) -> list[str]:
    fmt = lambda v: "[" + ", ".join(f"{x:.4g}" for x in v) + "]"  # noqa: E731
    out = []
    if p["plant"]["mismatch"]:
        out.append("plant mismatch: " + ", ".join(f"{k} = {d['plant']:g} (data: {d['nominal']:g})"
                                                  for k, d in p["plant"]["mismatch"].items()))
    if any(p["noise"]["sim_noise_std"]):
        out.append(f"closed-loop measurement noise σ per state: {fmt(p['noise']['sim_noise_std'])}")
    if any(p["noise"]["disturbance_std"]):
        out.append(f"process disturbance on the input σ: {fmt(p['noise']['disturbance_std'])}")
    return out


def run(cfg: Any, out_dir: str | Path = ".", *, echo=print, auto_progress: bool | None = None) -> dict:
    """Run the experiment described by ``cfg`` (a mapping or DictConfig) and write its files into ``out_dir``:
    data → identification → CLF → controller → closed loop on the true system from ``sim.x0``, logged to
    ``run.mcap`` (and rendered to ``run.rrd``).  Returns the metrics, also written to ``summary.json``.
    ``echo`` receives the printed lines; ``auto_progress`` is what ``logging.progress=auto`` means (None: a bar
    when stderr is a terminal; a sweep job passes False, its bars would overwrite each other).  The log is written
    in this process (``logging.writer=sync``; RunLogger's writer thread measured slower on this 2-core machine) or
    by a child process (``process``: the same bytes, less of the run's time for runs of 10 s and more;
    benchmarks/logging_overhead.py).

    A folder that holds a run already (kexp.app.run_folder.run_files) is refused (RunFolderError) and left as it
    is: every file is created exclusively.  A file that cannot be written (disk full, a size limit, a folder in its
    place) raises :class:`~kexp.app.faults.OutputError`, whose one line says what was saved; what was written
    before stays (summary.json is replaced whole or not at all)."""
    out_dir = Path(out_dir)
    try:
        taken = run_files(out_dir)
        if taken:
            raise RunFolderError(f"{out_dir} holds a run already ({', '.join(taken)}); kexp never overwrites a run: "
                                 "give another folder")
        with writing(out_dir):
            out_dir.mkdir(parents=True, exist_ok=True)
        with contextlib.ExitStack() as stack:   # an external plant is closed however the run ends
            return _run(cfg, out_dir, echo, auto_progress, stack)
    except OSError as exc:
        if isinstance(exc, KexpError):
            raise
        raise OutputError(fault_message(exc, out_dir)) from exc


@dataclass(frozen=True)
class Setup:
    """An experiment's checked configuration (:func:`_prepare`), what every later stage reads: the run folder and
    its echo, the system (with an external plant, if any), the built config sections, the closed loop's simulation
    (``looped`` False: system=data without a plant, no loop), the plant the loop runs on and the cache."""
    cfg: Any
    cfg_dict: dict
    chash: str
    out_dir: Path
    echo: Any
    auto_progress: bool | None
    system: Any
    ext_plant: Any
    plant_cfg: Any
    sampler: Any
    data_cfg: Any
    ident_cfg: Any
    spec: Any
    looped: bool
    file_data: Any
    clf_cfg: Any
    data_noise: Any
    data_smooth: Any
    sim_cfg: Any
    x0: Any
    open_loop: bool
    plant: Any
    plant_params: dict
    plant_info: dict
    log_cfg: dict
    cache: Any

    @property
    def summary_path(self) -> Path:
        return self.out_dir / "summary.json"


class _Clock:
    """Where the job's time goes (summary.json "timing", benchmarks/sweep.py): seconds per phase, in order."""

    def __init__(self, t0: float):
        self.t0, self.phases, self.mark = t0, {}, t0

    def phase(self, name: str) -> None:
        """Add the seconds since the last mark to phase ``name``."""
        now = time.perf_counter()
        self.phases[name] = self.phases.get(name, 0.0) + now - self.mark
        self.mark = now

    @property
    def wall_s(self) -> float:
        """The phases' sum: the run up to the last mark."""
        return self.mark - self.t0


def _run(cfg: Any, out_dir: Path, echo, auto_progress: bool | None, stack: contextlib.ExitStack) -> dict:
    """:func:`run`'s work, in ``out_dir`` (made, holding no run); ``stack`` closes an external plant.  The stages in
    order: prepare (every config section checked, budgets) → identify (data, model) → certify (CLF) → controller →
    log → closed loop → record (log closed, metrics) → finish (summary.json, run.rrd, the result lines)."""
    clock = _Clock(time.perf_counter())
    s = _prepare(cfg, out_dir, echo, auto_progress, stack)
    create_exclusive(s.summary_path, json.dumps({"status": "running", "completed": False, "config_hash": s.chash},
                                                indent=2))
    clock.phase("setup_s")
    model, mkey, model_path = _identify_model(s)
    clock.phase("model_s")
    perturbation = _announce_model(s, model)
    clf = _certify(s, model, mkey)
    clock.phase("clf_s")
    if not s.looped:   # system=data without a plant: the model, its report and the certificate are the run
        return _finish_without_loop(s, model, model_path, perturbation, clf, clock)
    controller = _controller(s, model, clf)
    clock.phase("controller_s")   # includes loading the compiled kernels (numba's cache) on a worker's first job
    logger = _open_log(s, model, clf)
    clock.phase("log_setup_s")
    result, logging_s = _closed_loop(s, controller, model, clf, logger)
    clock.phase("closed_loop_s")
    metrics, files = _record(s, result, logging_s, controller, model, model_path, clf, perturbation, logger, clock)
    _finish(s, result, metrics, files, logger, clock)
    return metrics


def _prepare(cfg: Any, out_dir: Path, echo, auto_progress: bool | None, stack: contextlib.ExitStack) -> Setup:
    """Stage 1: every config section validated and every budget checked before the long computations start; an
    external plant built (and closed by ``stack``); the plant the loop runs on and the cache."""
    cfg_dict = config_dict(cfg)
    chash = config_hash(cfg_dict)
    plant_cfg = build_plant_config(cfg.get("plant"))
    ext_plant = None
    data_only = is_data_system(cfg_dict["system"])
    if data_only:   # system=data: n, m from the recorded runs; a loop only on an external plant (kexp.app.data_only)
        system = build_data_system(cfg_dict["system"], build_data(cfg["data"])[1])
        if plant_cfg.external:
            ext_plant = data_plant(plant_cfg, system, cfg["sim"])
            stack.callback(ext_plant.close)
    elif plant_cfg.external:   # a Gymnasium environment or a user's class: built (and checked) first, it gives n, m
        ext_plant, system = build_external_plant(plant_cfg, cfg_dict["system"], cfg["sim"])
        stack.callback(ext_plant.close)
    else:
        system = build_system(cfg_dict["system"])
    sampler, data_cfg = build_data(cfg["data"])
    ident_cfg = build_identification(cfg["identification"])
    spec = build_controller_spec(cfg["controller"])
    _check_plant_stages(system, ext_plant, data_cfg, ident_cfg, spec)
    looped = not data_only or ext_plant is not None
    if not looped:
        echo(STOP_LINE)
    # recorded runs (data.source.kind=files) are read and checked now; their bounding box is the data region
    file_data = read_data_files(system, data_cfg, dict(cfg.get("cache") or {})) if data_cfg.source.kind == "files" else None
    clf_cfg = build_clf(cfg["clf"])
    data_noise = build_data_noise(cfg["data"], system.n)
    data_smooth = build_data_smoothing(cfg["data"])
    if looped:
        sim_cfg, x0, open_loop = build_sim(cfg["sim"], system, data_cfg.dt,
                                           sampler if file_data is None else data_bounds(file_data))
    else:   # no closed loop: the sim section is not used (its defaults: no closed-loop noise in the summary)
        sim_cfg, x0, open_loop = SimConfig(dt=data_cfg.dt), None, False
    if ext_plant is not None:   # the baselines that need a model of the plant get the system (a formula, or n, m, x_eq)
        plant, plant_params = system, {}
        spec = narrow_bounds(spec, ext_plant, echo)
    elif looped:
        plant, plant_params = build_plant(system, cfg_dict["system"], cfg["sim"])
    else:
        plant, plant_params = None, {}
    plant_info = _plant_identity(ext_plant, plant_cfg, plant)   # kind, id, Δ, versions: logged and keyed
    log_cfg = build_logging(cfg.get("logging") or {})
    if log_cfg["mcap"] and log_cfg["writer"] == "process" and looped:
        prestart_writer()   # the writer process's imports run on the other core during data, identification, CLF
    cache_cfg = dict(cfg.get("cache") or {})
    cache = Cache(cache_cfg.get("dir"), enabled=bool(cache_cfg.get("enabled", True)),
                  warn=lambda msg: echo(f"warning: {msg}"))
    k_max = dictionary_size(cfg["dictionary"], system.n)
    if file_data is None:
        check_data_budget(sampler, data_cfg, ident_cfg, k_max)
    else:
        check_file_data(file_data, ident_cfg, k_max)
    check_memory_budget(spec, k_max, system.m)
    check_sdp_budget(clf_cfg, k_max)   # an SDP CLF over the memory budget: refused before any data
    if looped:
        check_run_size(sim_cfg, system, k_max, sampler if file_data is None else None, data_cfg)
    return Setup(cfg, cfg_dict, chash, out_dir, echo, auto_progress, system, ext_plant, plant_cfg, sampler, data_cfg,
                 ident_cfg, spec, looped, file_data, clf_cfg, data_noise, data_smooth, sim_cfg, x0, open_loop, plant,
                 plant_params, plant_info, log_cfg, cache)


def _identify_model(s: Setup):
    """Stage 2: the data (simulated, recorded or from the plant; noise and smoothing as configured) and the Koopman
    model identified from it, or both from the cache; the model saved as model.npz.  Returns (model, its cache key,
    model.npz's path)."""
    def identify_now():
        if s.data_cfg.source.kind == "plant":
            dataset = _plant_data(s.system, s.ext_plant, s.sampler, s.data_cfg, s.auto_progress,
                                  s.log_cfg["progress"])
        else:
            dataset = collect(s.system, s.sampler, s.data_cfg) if s.file_data is None else s.file_data
        rms = data_rms(dataset, s.system.equilibrium)
        dataset = add_measurement_noise(dataset, s.data_noise, x_eq=s.system.equilibrium).with_smoothing(
            s.data_smooth)
        dictionary = build_dictionary(s.cfg["dictionary"], s.system.n, dataset, s.system.equilibrium)
        check_dictionary_range(dataset.stats(), dictionary.degree, dictionary.scale, dictionary.center)
        model = identify(s.system, dataset, dictionary, s.ident_cfg)
        # kept with the cached model: a relative sim.noise is a fraction of these (clean data, about x_eq)
        model.report["data_rms"] = rms.tolist()
        model.report["data_noise_std"] = None if dataset.report.noise_std is None else list(
            dataset.report.noise_std)
        model.report["data_smoothing"] = dataset.report.smoothing
        return model

    # recorded data: the files' content (not only their path) determines the model
    # data from a plant: its kind, id and package versions (an environment's physics) determine the model too
    digest = s.file_data.report.digest if s.file_data is not None else (
        json.dumps(plain({"plant": s.cfg_dict.get("plant"), **s.plant_info}), sort_keys=True)
        if s.data_cfg.source.kind == "plant"
        else None)
    mkey = model_key(s.cfg_dict, FORMAT_VERSION, digest)
    model = s.cache.get_or_create(mkey, identify_now, lambda m, p: m.save(p), KoopmanBilinearModel.load)
    return model, mkey, _save_model(model, s.out_dir / "model.npz")


def _announce_model(s: Setup, model) -> dict:
    """The model's summary and the run's perturbation (noise, plant mismatch) echoed; returns the perturbation
    (logged and in summary.json)."""
    s.echo(model.summary())
    perturbation = _perturbation(s.system, s.plant_params, model, s.sim_cfg)
    if s.ext_plant is not None:   # the log says what the loop ran on (kexp's integrator: the log as it always was)
        perturbation["plant"].update(kind=s.plant_cfg.kind, id=s.plant_info["id"])
    for line in _perturbation_lines(perturbation):
        s.echo(line)
    return perturbation


def _certify(s: Setup, model, mkey: str):
    """Stage 3: the control Lyapunov function of ``model`` for the controller's law and input bounds (or the
    cache's)."""
    spec = s.spec
    return s.cache.get_or_create(
        clf_key(mkey, s.cfg_dict, spec.law, spec.law_params, spec.u_min, spec.u_max),
        lambda: synthesize_clf(model, s.clf_cfg, law=spec.law, u_min=spec.u_min, u_max=spec.u_max,
                               law_params=spec.law_params, progress=s.echo),
        save_clf, lambda p: load_clf(p, model, s.clf_cfg))


def _finish_without_loop(s: Setup, model, model_path: Path, perturbation: dict, clf, clock: _Clock) -> dict:
    """The end of a run with no closed loop (system=data without a plant): summary.json and the result lines."""
    s.echo(clf.summary())
    metrics = identified_metrics(s.chash, s.system, _model_info(model), perturbation["noise"], clf, _versions(),
                                 lock_info().to_dict(), s.cache, model_path.name)
    clock.phase("finish_s")
    metrics.update(timing=clock.phases, wall_time_s=clock.wall_s)
    write_json(s.summary_path, plain(metrics))
    s.echo(f"result: identified and certified, no closed loop (no plant): k = {model.k}, CLF {clf.status}")
    s.echo(f"files: {s.out_dir.resolve()} (model.npz, summary.json)")
    return metrics


def _controller(s: Setup, model, clf):
    """Stage 4: the controller of the spec; the true-model baselines (LQR, NMPC oracle) know the plant they control,
    mismatch included."""
    controller = build_controller(s.spec, s.plant, model, clf,
                                  prediction_every=s.log_cfg["prediction_every"] if s.log_cfg["mcap"] else 0,
                                  ext_plant=s.ext_plant)
    if getattr(controller, "linearisation", None) is not None:   # the LQR on the plant's numerical linearisation
        s.echo(controller.linearisation.describe())
    s.echo(clf.summary())
    return controller


def _open_log(s: Setup, model, clf):
    """Stage 5: run.mcap opened (in this process or a writer process) with the config, the model and the CLF's
    level sets; None when logging.mcap is off."""
    if not s.log_cfg["mcap"]:
        return None
    kw = dict(flush_every=s.log_cfg["flush_every"], prediction_every=s.log_cfg["prediction_every"])
    if s.log_cfg["writer"] == "process":   # the last step's time: the child has the last second framed by close
        logger = ProcessRunLogger(s.out_dir / "run.mcap", last_step=(s.sim_cfg.n_steps - 1) * s.sim_cfg.dt, **kw)
    else:
        logger = RunLogger(s.out_dir / "run.mcap", **kw)
    logger.log_config(s.cfg_dict, s.chash)
    logger.log_model(model)
    omega_r = level_set_boundary(model, clf.lyap, clf.r)
    logger.log_clf(clf, omega_r, omega_r if clf.r_hat == clf.r else level_set_boundary(model, clf.lyap, clf.r_hat))
    return logger


def _closed_loop(s: Setup, controller, model, clf, logger):
    """Stage 6: the closed loop from x0 on the plant, each step logged, with a progress bar.  Returns (the
    closed-loop result, the seconds spent logging); a failure abandons the log (the steps so far stay)."""
    log_seconds = [0.0]
    bar = Progress(s.sim_cfg.n_steps, f"{s.system.name} closed loop",
                   enabled=s.auto_progress if s.log_cfg["progress"] == "auto" else bool(s.log_cfg["progress"]))

    def on_step(rec, step):
        if logger is not None:
            start = time.perf_counter()
            logger.log_step(rec, step, model)
            log_seconds[0] += time.perf_counter() - start
        bar.update()

    try:
        # BLAS threads on tiny products cost 10-100× (design §2.11); a failed write names the log
        with threadpool_limits(limits=1), writing(s.out_dir / "run.mcap"):
            result = closed_loop(s.plant, controller, s.x0, s.sim_cfg, model=model, lyap=clf.lyap,
                                 open_loop=s.open_loop, on_step=on_step, noise_scale=model.report.get("data_rms"),
                                 plant=s.ext_plant)
    except BaseException:
        if logger is not None:
            logger.abandon()   # the steps so far stay in run.mcap
        raise
    finally:
        bar.close()
    return result, log_seconds[0]


def _record(s: Setup, result, logging_s: float, controller, model, model_path: Path, clf, perturbation: dict,
            logger, clock: _Clock) -> tuple[dict, dict]:
    """Stage 7: the log's last messages written and the log closed; the run's metrics (summary.json's content).
    Returns (metrics, {role: file name})."""
    control_s = float(sum(r.solve_time for r in result.records))
    mdict = result.metrics.to_dict()
    deterministic = {k: v for k, v in mdict.items() if not k.startswith("solve_time")}
    timing = {k: v for k, v in mdict.items() if k.startswith("solve_time")}
    versions = _versions()
    versions.update(s.plant_info["versions"])
    lock = lock_info().to_dict()
    files = {"model": model_path.name}
    if logger is not None:
        if result.open_loop is not None:
            logger.log_open_loop(np.arange(len(result.open_loop)) * s.sim_cfg.dt, result.open_loop)
        t_end = float(result.t[-1])
        logger.log_summary(t_end, result.status, result.message, deterministic, completed=True,
                           perturbation=perturbation)
        paced = {"realtime": result.realtime.to_dict()} if result.realtime is not None else {}   # sim.realtime
        logger.log_run_info(t_end, versions, {**timing, **paced, "wall_time_s": time.perf_counter() - clock.t0},
                            lock=lock, plant=s.plant_info)
        with writing(logger.path):
            logger.close()
        files["mcap"] = logger.path.name
    cache = s.cache
    metrics = {
        "status": result.status,
        "completed": True,
        "message": result.message,
        "config_hash": s.chash,
        "system": s.system.name,
        "controller": getattr(controller, "name", type(controller).__name__),
        "x0": s.x0.tolist(),
        "metrics": mdict,
        "model": _model_info(model),
        "noise": perturbation["noise"],
        "plant": {**perturbation["plant"], **s.plant_info},
        "clf": {"status": clf.status, "r": clf.r, "r_hat": clf.r_hat, "certificate": clf.certificate.to_dict()},
        "versions": versions,
        "lock": lock,
        "cache": {"dir": str(cache.dir) if cache.enabled else None, "hits": cache.hits, "misses": cache.misses},
        "files": files,
    }
    if result.realtime is not None:   # sim.realtime: how the run kept its schedule (wall-clock numbers)
        metrics["realtime"] = result.realtime.to_dict()
    clock.phases["closed_loop"] = {"control_s": control_s, "integrate_s": result.integrate_s,
                                   "logging_s": logging_s}
    metrics["timing"] = clock.phases
    fell_back = _fallback_warning(result.metrics.fallbacks, len(result.records))
    if fell_back is not None:   # said with the result below, and kept in summary.json
        metrics["warnings"] = [fell_back]
    return metrics, files


def _finish(s: Setup, result, metrics: dict, files: dict, logger, clock: _Clock) -> None:
    """Stage 8: summary.json written (before the recording is rendered, whatever happens to it), run.rrd rendered,
    the result lines and warnings echoed."""
    def write_summary() -> None:
        clock.phase("finish_s")   # the log's last messages, the Rerun recording, the summary
        metrics["wall_time_s"] = clock.wall_s   # the phases' sum: the run up to its summary
        write_json(s.summary_path, plain(metrics))
    write_summary()
    if logger is not None and s.log_cfg["rrd"]:
        warning = _render(logger.path, s.out_dir / "run.rrd")
        if warning is None:
            files["rrd"] = "run.rrd"
        else:   # the run and its log are complete; say why there is no recording
            s.echo(f"warning: {warning}")
            metrics.setdefault("warnings", []).append(warning)
        write_summary()
    _echo_result(s, result, files)


def _echo_result(s: Setup, result, files: dict) -> None:
    """The run's result lines: outcome, cost, settling, solve times, warnings (fallbacks, real time), the files."""
    from .sweep_progress import SETTLED, UNSETTLED   # one word per outcome, as a sweep's job lines
    m, echo, dt = result.metrics, s.echo, s.sim_cfg.dt
    echo(f"result: {SETTLED if m.success else UNSETTLED} ({result.status}) — ‖x(T)‖ = {m.final_error:.2e}, "
         f"cost J = {m.cost:.4f}, settling {m.settling_time:.2f} s, max|u| = {m.max_abs_u:.3f}, "
         f"fallbacks {m.fallbacks}")
    echo(f"solve time per step: median {m.solve_time_median * 1e3:.2f} ms, p99 {m.solve_time_p99 * 1e3:.2f} ms, "
         f"max {m.solve_time_max * 1e3:.2f} ms")
    fell_back = _fallback_warning(m.fallbacks, len(result.records))
    if fell_back is not None:
        echo(f"warning: {fell_back}")
    if m.solve_time_median > dt:   # the controller cannot keep up with the plant in real time
        echo(f"warning: the median solve time {m.solve_time_median * 1e3:.2f} ms exceeds Δ = {dt * 1e3:g} ms: "
             "this controller could not run in real time at this Δ (fewer move blocks, a shorter horizon or a "
             "lower dictionary degree; docs/guides/own-system.md: Four states)")
    if result.realtime is not None:
        rt = result.realtime
        echo(f"real time: {rt.misses} deadline miss(es) in {rt.steps} steps of Δ = {rt.dt * 1e3:g} ms; lateness max "
             f"{rt.late_max * 1e3:.2f} ms (step {rt.late_max_k}), p99 {rt.late_p99 * 1e3:.2f} ms (< 0: time to spare)")
    echo(f"files: {s.out_dir.resolve()} ({', '.join(files.values())})")
    if "rrd" in files:   # a headless machine has no display for the native viewer: say how to view it anyway
        echo(f"view: rerun {s.out_dir.resolve() / files['rrd']}   (no display: rerun --web-viewer …, then "
             "http://localhost:9090; docs/guides/rerun.md)")


def _model_info(model) -> dict:
    """summary.json's "model": k, how B was found, the fit's conditioning and prediction errors, the eigenvalues."""
    return {"k": model.k, "inputs": model.report.get("inputs", "projection"),
            "estimator": model.report.get("estimator", "ls"), "prediction_vs_fit": model.report.get("prediction_vs_fit"),
            "cond_phi_x": model.report["cond_phi_x"],
            "prediction_error": model.report["prediction_error"],
            "input_projection_residual": model.report["input_projection_residual"],
            "eigenvalues": [[float(v.real), float(v.imag)] for v in model.eigenvalues]}


FALLBACK_WARN = 0.1   # the share of steps on the fallback h above which a run says it was mostly h


def _fallback_warning(fallbacks: int, steps: int) -> str | None:
    """The warning of a run whose controller fell back to its explicit law h at more than :data:`FALLBACK_WARN` of
    its steps (its QP failed or was infeasible there: the run measured h, not the MPC), or None."""
    if steps == 0 or fallbacks <= FALLBACK_WARN * steps:
        return None
    return (f"the controller fell back to its explicit law h at {fallbacks} of {steps} steps "
            f"({100 * fallbacks / steps:.0f} %): its QP failed or was infeasible there, so this run measured h "
            "more than the MPC (each step's qp_status is in run.mcap; try a shorter horizon or a lower "
            "dictionary degree)")


def _check_plant_stages(system, ext_plant, data_cfg, ident_cfg, spec) -> None:
    """What a plant without a formula (system=plant) cannot do, refused in one line before any work: simulate
    data, project G, run the NMPC oracle; and a data.dt that is not an external plant's Δ."""
    from ..plants import PlantSystem, check_dt
    if ext_plant is not None:
        check_dt(ext_plant.dt, data_cfg.dt, "data.dt", ext_plant.name)
    if isinstance(system, DataSystem):   # system=data: kexp.app.data_only
        return check_data_stages(system, data_cfg, ident_cfg, spec)
    if not isinstance(system, PlantSystem):
        return
    name = system.name
    if data_cfg.source.kind == "simulate":
        raise ConfigError(f"plant {name!r} has no formula to simulate data from: set data.source.kind=plant (runs "
                          "of the plant under data.excitation) or data.source.kind=files")
    if ident_cfg.inputs != "regression":
        raise ConfigError(f"plant {name!r}: G is unknown, so B cannot be projected from it: set "
                          "identification.inputs=regression (and data.excitation for forced data)")
    if ident_cfg.compare_projection:
        raise ConfigError(f"identification.compare_projection needs G; plant {name!r} has no formula: set it false")
    if spec.kind == "lqr" and spec.linearisation == "formula":
        raise ConfigError(f"controller.linearisation=formula needs F and G; plant {name!r} has none: set "
                          "controller.linearisation=plant (or auto)")
    if spec.kind == "nmpc":
        raise ConfigError(f"controller=nmpc (the true-model oracle) needs a formula (F, G); plant {name!r} has none: "
                          "the oracle is n/a here (use controller=lqr, model_lqr or lmpc)")


def _plant_identity(ext_plant, plant_cfg, system) -> dict:
    """The plant's kind, id and package versions (``/run_info``, ``summary.json``); ``system`` None: no plant."""
    if ext_plant is None and system is None:
        return {"kind": "none", "id": None, "versions": {}}
    if ext_plant is None:
        return {"kind": "integrator", "id": getattr(system, "name", None), "versions": {}}
    info = dict(ext_plant.info())
    return {"kind": plant_cfg.kind, "id": str(info.get("id", ext_plant.name)), "dt": ext_plant.dt,
            "versions": dict(info.get("versions") or {}),
            "info": {k: v for k, v in info.items() if k not in ("kind", "id", "dt", "versions")}}


def _plant_data(system, ext_plant, sampler, data_cfg, auto_progress, progress_cfg):
    """Runs of the plant (kexp's integrator of ``system`` when no external plant is set), with a progress bar."""
    from ..plants.collect import collect_from_plant
    from ..plants.integrator import IntegratorPlant
    plant = ext_plant if ext_plant is not None else IntegratorPlant(system, data_cfg.dt, data_cfg.integrator)
    n_traj = int(getattr(sampler, "n_traj", 0) or 0)
    bar = Progress(max(n_traj, 1), f"{system.name} data", enabled=auto_progress if progress_cfg == "auto"
                   else bool(progress_cfg))
    try:
        return collect_from_plant(plant, sampler, data_cfg, system.equilibrium, system.name,
                                  progress=lambda k: bar.update())
    finally:
        bar.close()


def _save_model(model, path: Path) -> Path:
    """Save ``model`` at ``path``, created exclusively (a file there is never replaced); a failed save leaves no
    file of it."""
    create_exclusive(path)
    try:
        with writing(path):
            return model.save(path)
    except BaseException:
        for p in (path, path.with_name(path.name + ".tmp.npz")):   # KoopmanBilinearModel.save's temporary file
            p.unlink(missing_ok=True)
        raise


def _render(log_path: Path, rrd_path: Path) -> str | None:
    """Render the run log into ``rrd_path`` (never replacing a file there: the recording is made under a
    temporary name and linked into place); None, or the warning that says why there is no recording (a render
    error, a full disk, …: the run and its log are complete)."""
    import os
    from ..recording.render import render
    tmp = rrd_path.with_name(f".{rrd_path.stem}.{os.getpid()}{rrd_path.suffix}")
    try:
        render(log_path, tmp)
        try:
            os.link(tmp, rrd_path)   # exclusive: fails if rrd_path exists
        except FileExistsError:
            return (f"no {rrd_path.name}: {rrd_path} exists already (left as it is; render with `kexp-render "
                    f"{log_path} -o <file>`)")
        except OSError:              # a file system without hard links
            if os.path.lexists(rrd_path):
                return f"no {rrd_path.name}: {rrd_path} exists already"
            os.replace(tmp, rrd_path)
        return None
    except (KexpError, OSError) as exc:
        reason = str(exc) if isinstance(exc, KexpError) else fault_message(exc, rrd_path.parent).split(";")[0]
        return (f"no {rrd_path.name}: {reason.replace(str(tmp), str(rrd_path))} (render later with "
                f"`kexp-render {log_path}`)")
    finally:
        tmp.unlink(missing_ok=True)
