"""Closed loop in sample-and-hold on the TRUE nonlinear system.

At t_k the controller sees the measured state x̃_k = x(t_k) + v_k (and z = Ψ(x̃_k) − Ψ(x_eq) if a model is
given), returns u_k, and the true system (the plant: it may differ from the system the data came from, see
``sim.plant_params``) is integrated accurately (adaptive DOP853, :class:`~kexp.simulate.stepper.HeldInputStepper`) over [t_k, t_k + Δ) with u_k + w_k held.
v_k ~ N(0, diag σ_v²) is the measurement noise (``SimConfig.noise``, 0 by default), w_k ~ N(0, diag σ_w²) the
process disturbance added to the input channel, piecewise constant over each step (``SimConfig.disturbance``,
0 by default); each draws from its own stream of its seed (kexp.data.noise.noise_rng: independent of each other
and of the data's noise, equal seeds included).  Arrays: t (T+1,), x (T+1, n), u (T, m), z (T+1, k).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..data.integrate import IntegrationFailure, IntegratorOptions, integrate
from ..data.noise import DISTURBANCE, MEASUREMENT_NOISE, NoiseConfig, _check_std, _std_active, _std_vector, noise_rng
from ..errors import ConfigError, require_number, require_seed, require_whole_steps
from .pacing import Pacer, RealtimeSummary


@dataclass(frozen=True)
class Disturbance:
    """Additive process disturbance (frozen): w_k ~ N(0, diag std²) drawn from its stream of ``seed`` once per
    control step and added to the input the plant receives, u_k + w_k, held over [t_k, t_k + Δ) like u_k (a
    force in the input channel; not limited by the input bounds).  ``std`` in input units: a number >= 0 or one
    per input; 0 (the default): none.  Raises ConfigError for a negative std or a non-integer seed."""

    std: Any = 0.0
    seed: int = 0

    def __post_init__(self):
        if isinstance(self.std, list):
            object.__setattr__(self, "std", tuple(self.std))
        _check_std(self.std, "sim.disturbance.std")
        require_seed(self.seed, "sim.disturbance.seed")

    @property
    def active(self) -> bool:
        return _std_active(self.std)

    def sigma(self, m: int) -> np.ndarray:
        """The standard deviation per input, (m,)."""
        return _std_vector(self.std, m, "sim.disturbance.std", "input")


@dataclass(frozen=True)
class SimConfig:
    """Closed-loop settings (frozen): horizon ``T`` and control step ``dt`` in seconds (0 < dt ≤ T; ``n_steps`` =
    round(T/dt) sample-and-hold steps), ``tol`` > 0 the success radius around x_eq, ``r`` the input weight of
    the reported cost, ``diverge_bound`` the ‖x − x_eq‖ where a run stops as diverged, ``integrator`` the ODE
    solver options of each step, ``noise`` the measurement noise on what the controller sees (relative: a
    fraction of the data's RMS per state, passed to :func:`closed_loop` as ``noise_scale``), ``disturbance`` the
    process disturbance on the input channel, ``realtime`` true to hold each step to wall-clock Δ
    (:mod:`kexp.simulate.pacing`; off by default).  Raises :class:`~kexp.errors.ConfigError` for values outside those
    ranges."""

    T: float = 10.0
    dt: float = 0.01
    tol: float = 1e-2            # success: ‖x(T) − x_eq‖ < tol
    r: float = 1.0               # input weight in the reported cost J = ∫ ‖x − x_eq‖² + uᵀRu dt
    diverge_bound: float = 1e6
    integrator: IntegratorOptions = field(default_factory=lambda: IntegratorOptions(batch=1))
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    disturbance: Disturbance = field(default_factory=Disturbance)
    realtime: bool = False       # true: each step held to wall-clock Δ, its lateness recorded (kexp.simulate.pacing)

    def __post_init__(self):
        for key in ("T", "dt", "tol", "r", "diverge_bound"):
            require_number(getattr(self, key), f"sim.{key}")
        if not (self.dt > 0 and self.T >= self.dt and math.isfinite(self.T)):
            raise ConfigError(f"sim: need 0 < dt <= T < inf, got dt={self.dt}, T={self.T}")
        if not 0 < self.tol < math.inf:
            raise ConfigError(f"sim.tol={self.tol}: use a finite number > 0")
        require_whole_steps(self.T, self.dt, "sim.T", "sim.dt")   # was rounded silently: T=0.015 ran to 0.02
        for key, kind in (("integrator", IntegratorOptions), ("noise", NoiseConfig), ("disturbance", Disturbance)):
            if not isinstance(getattr(self, key), kind):
                raise ConfigError(f"sim.{key}={getattr(self, key)!r}: expected a {kind.__name__}")
        if not self.diverge_bound > 0:   # inf: never stop a run as diverged
            raise ConfigError(f"sim.diverge_bound={self.diverge_bound}: use a distance > 0 (inf: never stop)")
        if not (math.isfinite(self.r) and self.r >= 0):
            raise ConfigError(f"sim.r={self.r}: use a finite number >= 0")
        if not isinstance(self.realtime, bool):
            raise ConfigError(f"sim.realtime={self.realtime!r}: use true or false")

    @property
    def n_steps(self) -> int:
        return int(round(self.T / self.dt))


@dataclass(frozen=True)
class StepRecord:
    """One control step Δ (all fields logged): ``x`` the true state, ``x_meas`` what the controller saw (x plus
    measurement noise), ``z`` = Ψ(x_meas) − Ψ(x_eq) and V, V̇ at that z, ``u`` the controller's input, ``w`` the
    process disturbance added to it over the step; with ``sim.realtime``, ``late`` the step's lateness (s, end of
    its work − its deadline; negative: time to spare) and ``miss`` (late > 0), else None."""

    k: int
    t: float
    x: np.ndarray
    z: np.ndarray
    u: np.ndarray
    V: float
    Vdot: float              # model V̇ at z with the applied u
    region: str
    active: str
    binds: bool
    slack: float
    status: str
    qp_status: str
    iterations: int
    qp_iterations: int
    solve_time: float
    fallback: bool
    reason: str
    x_meas: np.ndarray | None = None   # None: equal to x
    w: np.ndarray | None = None        # None: no disturbance
    late: float | None = None          # None: not paced (sim.realtime=false)
    miss: bool | None = None


@dataclass(frozen=True)
class RunMetrics:
    """What a closed loop achieved (frozen): ``success`` (all steps run and ‖x(T) − x_eq‖ < tol),
    ``final_error`` = ‖x(T) − x_eq‖, ``cost`` J = ∫ ‖x − x_eq‖² + r‖u‖² dt, ``settling_time`` in s (inf if
    never), ``max_abs_u``, ``time_outside_omega_r`` in s, ``fallbacks`` (steps where the controller fell back to
    h), and wall-clock solve times per step in s (median, p95, p99, max; these vary between repeats).
    ``to_dict()`` gives a plain dict."""

    success: bool
    final_error: float
    cost: float
    settling_time: float     # first t after which ‖x − x_eq‖ stays < tol (inf if never)
    max_abs_u: float
    time_outside_omega_r: float
    fallbacks: int
    solve_time_median: float
    solve_time_p95: float
    solve_time_p99: float
    solve_time_max: float

    def to_dict(self) -> dict:
        from dataclasses import asdict
        return asdict(self)


@dataclass(frozen=True)
class RunResult:
    """What :func:`closed_loop` returns (frozen): ``status`` 'completed' or 'diverged' with its ``message``
    ('' when completed), ``t`` (K+1,), ``x`` (K+1, n), ``u`` (K, m) for the K steps run (fewer than n_steps if
    diverged), one :class:`StepRecord` per step in ``records``, the :class:`RunMetrics`, and ``open_loop``
    (n_steps+1, n) the unforced trajectory from x0 when asked for (None otherwise, or if it failed), and
    ``integrate_s`` the wall-clock seconds spent integrating the plant (a job's time breakdown), ``realtime`` how a
    paced run kept its schedule (:class:`~kexp.simulate.pacing.RealtimeSummary`; None when not paced)."""

    status: str              # 'completed' or 'diverged'
    message: str
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    records: tuple
    metrics: RunMetrics
    open_loop: np.ndarray | None = None
    integrate_s: float = 0.0
    realtime: RealtimeSummary | None = None


def run_cost(t, x, u, x_eq, r) -> float:
    """J = ∫ ‖x − x_eq‖² + r‖u‖² dt: trapezoid on the samples for x, exact for the held u."""
    e = np.sum((x - x_eq) ** 2, axis=1)
    dt = np.diff(t)
    return float(np.sum(dt * 0.5 * (e[:-1] + e[1:])) + r * np.sum(dt * np.sum(u ** 2, axis=1)))


def _metrics(t, x, u, records, x_eq, cfg: SimConfig) -> RunMetrics:
    err = np.linalg.norm(x - x_eq, axis=1)
    above = np.flatnonzero(err >= cfg.tol)
    settle = 0.0 if above.size == 0 else (float(t[above[-1] + 1]) if above[-1] + 1 < len(t) else float("inf"))
    times = np.array([r.solve_time for r in records]) if records else np.zeros(1)
    return RunMetrics(
        success=bool(len(t) == cfg.n_steps + 1 and err[-1] < cfg.tol), final_error=float(err[-1]),
        cost=run_cost(t, x, u, x_eq, cfg.r), settling_time=settle,
        max_abs_u=float(np.max(np.abs(u))) if u.size else 0.0,
        time_outside_omega_r=float(cfg.dt * sum(r.region == "outside" for r in records)),
        fallbacks=int(sum(r.fallback for r in records)),
        solve_time_median=float(np.median(times)), solve_time_p95=float(np.percentile(times, 95)),
        solve_time_p99=float(np.percentile(times, 99)), solve_time_max=float(np.max(times)))


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
        return True
    except (TypeError, ValueError):
        return False


def _check_parts(system, controller, model, lyap) -> None:
    """The model, the controller's own model or CLF and ``lyap`` must fit the system and one another (a model of
    another system, or none for a controller that works on z, failed later inside numpy, or ran silently)."""
    if model is not None and (model.n, model.m) != (system.n, system.m):
        raise ConfigError(f"the model has n={model.n} state(s) and m={model.m} input(s), the system "
                          f"{system.name!r} n={system.n} and m={system.m}: identify the model on this system")
    own = getattr(controller, "model", None)
    clf = getattr(controller, "clf", None)
    k_ctrl = own.k if own is not None else (clf.P.shape[0] if clf is not None else None)
    if k_ctrl is not None and model is None:
        raise ConfigError(f"the controller ({type(controller).__name__}) works on z = Ψ(x) (k={k_ctrl}): pass "
                          "closed_loop(..., model=<its model>)")
    if k_ctrl is not None and k_ctrl != model.k:
        raise ConfigError(f"the controller ({type(controller).__name__}) works on k={k_ctrl} eigen-coordinates, the "
                          f"model given to closed_loop has k={model.k}: pass the controller's own model")
    if lyap is not None and (model is None or lyap.P.shape[0] != model.k):
        raise ConfigError(f"lyap is a V = zᵀPz on k={lyap.P.shape[0]} coordinates, "
                          + ("but no model gives z: pass model=" if model is None else f"the model has k={model.k}")
                          + "; pass the CLF of this model (clf.lyap)")


def closed_loop(system, controller, x0, config: SimConfig = SimConfig(), *, model=None, lyap=None,
                open_loop: bool = False, on_step=None, noise_scale=None, plant=None) -> RunResult:
    """Simulate ``controller`` on ``plant`` from ``x0`` (n,).  ``plant`` (:mod:`kexp.plants`): None integrates
    ``system`` (kexp's own plant, :class:`~kexp.plants.IntegratorPlant`); an external plant (a Gymnasium
    environment, a user's class) must step at ``config.dt`` with ``system``'s n and m, and a
    :class:`~kexp.errors.PlantError` it raises ends the run (the steps so far were passed to ``on_step``).
    ``system`` gives x_eq and n, m.  ``model`` lifts the measured x to
    z for controllers that need it and for the records; ``lyap`` (QuadraticLyapunov) gives V and V̇ in the
    records.  ``on_step(record, control_step)`` is called after each control decision, before the step is
    integrated (logging, progress); with ``config.realtime`` after the plant's step instead, with the step's
    lateness in the record (also for a step whose plant step raised).  ``noise_scale`` (n,): the per-state
    scale of a relative ``config.noise`` (the data's RMS, :func:`kexp.data.noise.data_rms`); ConfigError if a
    relative noise has none."""
    try:
        x0 = np.asarray(x0, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"initial condition {x0!r}: need {system.n} finite numbers") from None
    if x0.shape != (system.n,) or not np.all(np.isfinite(x0)):
        raise ConfigError(f"initial condition {x0.tolist()}: need {system.n} finite numbers")
    _check_parts(system, controller, model, lyap)
    if model is not None and abs(model.dt - config.dt) > 1e-12:
        raise ConfigError(f"sim.dt={config.dt} differs from the model's Δ={model.dt}; use the same sampling time")
    if noise_scale is not None:
        scale = np.asarray(noise_scale, dtype=float) if _numeric(noise_scale) else None
        if scale is None or scale.shape != (system.n,) or not np.all(np.isfinite(scale) & (scale > 0)):
            raise ConfigError(f"noise_scale={noise_scale!r}: give {system.n} finite numbers > 0 (the data's RMS per "
                              "state, kexp.data.noise.data_rms)")
    x_eq = np.asarray(system.equilibrium, float)
    n_steps = config.n_steps
    t = np.arange(n_steps + 1) * config.dt
    xs = np.empty((n_steps + 1, system.n))
    us = np.empty((n_steps, system.m))
    xs[0] = x0
    records = []
    status, message = "completed", ""
    sigma_v = config.noise.sigma(system.n, noise_scale) if config.noise.active else None
    sigma_w = config.disturbance.sigma(system.m) if config.disturbance.active else None
    rng_v = noise_rng(config.noise.seed, MEASUREMENT_NOISE,   # streams independent of each other and of the data's
                      x0 if config.noise.per_x0 else None)
    rng_w = noise_rng(config.disturbance.seed, DISTURBANCE)
    controller.reset()
    if plant is None:
        from ..plants.integrator import IntegratorPlant
        plant = IntegratorPlant(system, config.dt, config.integrator)
    else:
        _check_plant(plant, system, config.dt)
    plant.reset(x0)
    plant_seconds = 0.0
    last = n_steps
    pacer = Pacer(config.dt) if config.realtime else None
    if pacer is not None:
        pacer.start()
    for k in range(n_steps):
        x_meas = xs[k] + sigma_v * rng_v.standard_normal(system.n) if sigma_v is not None else xs[k].copy()
        z = model.lift(x_meas) if model is not None else np.zeros(0)
        step = controller.step(x_meas, z)
        u = np.asarray(step.u, float)
        if u.shape != (system.m,):   # a (1,) u would fill both inputs of a 2-input plant silently
            raise ConfigError(f"the controller ({type(controller).__name__}) returned u of shape {u.shape}; the "
                              f"system {system.name!r} has m={system.m} input(s): build the controller for it")
        if not np.isfinite(u).all():
            u = np.zeros(system.m)
        us[k] = u
        w = sigma_w * rng_w.standard_normal(system.m) if sigma_w is not None else None
        V, Vdot = float("nan"), float("nan")
        if lyap is not None:   # V as lyap.value gives it; V̇ = L_ΛV + L_BV·u at z, once (lyap.at)
            V, a, beta = lyap.at(z)
            Vdot = float(a + np.sum(beta * u))
        rec = StepRecord(k=k, t=float(t[k]), x=xs[k].copy(), z=z, u=u.copy(), V=V, Vdot=Vdot,
                         region=step.region, active=step.active, binds=step.binds, slack=step.slack,
                         status=step.status, qp_status=step.qp_status, iterations=step.iterations,
                         qp_iterations=step.qp_iterations, solve_time=step.solve_time,
                         fallback=step.fallback, reason=step.reason, x_meas=x_meas, w=w)
        records.append(rec)
        if on_step is not None and pacer is None:
            on_step(rec, step)
        try:
            u_plant = u if w is None else u + w
            start = time.perf_counter()
            nxt = plant.step(u_plant)
            plant_seconds += time.perf_counter() - start
        except IntegrationFailure as exc:
            status, message, last = "diverged", f"integration failed at t={t[k]:.3f}: {exc}", k
            break
        finally:
            if pacer is not None:   # the step's work ended: its lateness goes with its record to on_step
                late, miss = pacer.stamp()
                rec = records[-1] = replace(rec, late=late, miss=miss)
                if on_step is not None:
                    on_step(rec, step)
        d = nxt - x_eq
        if not math.sqrt(d @ d) <= config.diverge_bound:    # ‖·‖ as np.linalg.norm has it; NaN and inf fail too
            status, message, last = "diverged", f"state left ‖x‖ ≤ {config.diverge_bound:g} at t={t[k + 1]:.3f}", k
            break
        xs[k + 1] = nxt
        if pacer is not None:
            pacer.wait()
    t, xs, us = t[:last + 1], xs[:last + 1], us[:last]
    ol = None
    if open_loop:
        ol = _open_loop(system, plant, x0, n_steps, config.dt)
    return RunResult(status=status, message=message, t=t, x=xs, u=us, records=tuple(records),
                     metrics=_metrics(t, xs, us, records, x_eq, config), open_loop=ol,
                     integrate_s=getattr(plant, "seconds", plant_seconds),
                     realtime=pacer.summary() if pacer is not None else None)


def _check_plant(plant, system, dt: float) -> None:
    """An external plant must have the system's n and m and step at the closed loop's Δ."""
    from ..plants.base import check_dt
    name = getattr(plant, "name", type(plant).__name__)
    if (plant.n, plant.m) != (system.n, system.m):
        raise ConfigError(f"plant {name!r} has n={plant.n}, m={plant.m}; the system {system.name!r} n={system.n}, "
                          f"m={system.m}: use the plant's own system (system=plant) or a plant of this system")
    check_dt(plant.dt, dt, "the closed loop's Δ (data.dt)", name)


def _open_loop(system, plant, x0, n_steps: int, dt: float):
    """The unforced trajectory from x0 (n_steps+1, n): integrated from the system's F (kexp's own plant), or
    stepped through an external plant with u = 0 (after the closed loop, from a reset); None if it fails."""
    from ..errors import KexpError
    from ..plants.integrator import IntegratorPlant
    if isinstance(plant, IntegratorPlant):
        try:
            return integrate(plant.system, x0[None], np.arange(n_steps + 1) * dt, None, IntegratorOptions())[0]
        except IntegrationFailure:
            return None
    out = np.empty((n_steps + 1, system.n))
    out[0] = x0
    try:
        plant.reset(x0)
        zero = np.zeros(system.m)
        for k in range(n_steps):
            out[k + 1] = plant.step(zero)
    except (KexpError, IntegrationFailure):
        return None
    return out
