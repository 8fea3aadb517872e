"""collect(): simulate trajectories of a system from an initial-condition sampler and build a Dataset."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, DataError, require_number, require_seed, require_whole_steps
from ..systems.base import ControlAffineSystem
from .checks import items, require_type, short
from .dataset import PAIR_RULES, DataReport, Dataset
from .excitation import Excitation
from .files import DataSource
from .integrate import IntegrationFailure, IntegratorOptions, integrate


@dataclass(frozen=True)
class RegionFilter:
    """Keep samples with low ≤ x − x_eq ≤ high componentwise (None: no bound).  ``mode='mask'`` drops the samples
    (and the pairs touching them); ``mode='drop'`` drops every trajectory that ever leaves the region."""

    low: tuple[float | None, ...] | None = None
    high: tuple[float | None, ...] | None = None
    mode: str = "mask"

    def __post_init__(self):
        if not isinstance(self.mode, str) or self.mode not in ("mask", "drop"):
            raise ConfigError(f"data.filter.mode={self.mode!r}; valid: 'mask', 'drop'")
        lo, hi = _filter_bounds(self.low, "low"), _filter_bounds(self.high, "high")
        if lo is None or hi is None:
            return
        if len(lo) != len(hi) and 1 not in (len(lo), len(hi)):
            raise ConfigError(f"data.filter low={self.low} and high={self.high}: give the same number of bounds "
                              "(or one for every state)")
        lo, hi = lo * (len(hi) if len(lo) == 1 else 1), hi * (len(lo) if len(hi) == 1 else 1)
        if any(a is not None and b is not None and a >= b for a, b in zip(lo, hi)):
            raise ConfigError(f"data.filter: need low < high, got low={self.low}, high={self.high}")

    @property
    def active(self) -> bool:
        return self.low is not None or self.high is not None

    def _bounds(self, n):
        def conv(b, default):
            if b is None:
                return np.full(n, default)
            arr = np.array([default if v is None else float(v) for v in np.atleast_1d(np.asarray(b, dtype=object))])
            if arr.size == 1:
                arr = np.full(n, arr[0])
            if arr.size != n:
                raise ConfigError(f"data.filter bounds {b} must have {n} entries (or one)")
            return arr
        lo, hi = conv(self.low, -np.inf), conv(self.high, np.inf)
        if np.any(lo >= hi):
            raise ConfigError(f"data.filter: need low < high, got low={self.low}, high={self.high}")
        return lo, hi

    def inside(self, dx: np.ndarray) -> np.ndarray:
        lo, hi = self._bounds(dx.shape[-1])
        return np.all((dx >= lo) & (dx <= hi), axis=-1)

    def apply(self, x: np.ndarray, valid: np.ndarray, u: np.ndarray | None, x_eq
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, int]:
        """(x, valid, u, number of trajectories dropped) after the filter: ``mask`` keeps only the valid samples
        inside the region valid; ``drop`` removes every trajectory with a valid sample outside it.  x (n_traj,
        T+1, n), valid (n_traj, T+1), u (n_traj, T, m) or None; samples already invalid are not evaluated."""
        inside = np.zeros_like(valid)
        inside[valid] = self.inside(x[valid] - np.asarray(x_eq, dtype=float))
        if self.mode == "mask":
            return x, inside, u, 0
        keep = np.all(inside | ~valid, axis=1)
        return x[keep], inside[keep], None if u is None else u[keep], int((~keep).sum())

    def describe(self, n) -> str:
        if not self.active:
            return "none"
        lo, hi = self._bounds(n)
        return " × ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi))


def _filter_bounds(value, key: str) -> list | None:
    """The entries of data.filter.low/high (None entries: no bound), or None for no bounds at all."""
    if value is None:
        return None
    entries = items(value, allow_none=True)
    if not entries:
        raise ConfigError(f"data.filter.{key}={short(value)}: give a number, or one per state (null: no bound)")
    if any(v is not None and np.isnan(v) for v in entries):
        raise ConfigError(f"data.filter.{key}={short(value)}: a bound is NaN; give numbers (null: no bound)")
    return entries


@dataclass(frozen=True)
class DataConfig:
    """Settings of data collection (validated here): duration ``T`` seconds at sampling ``dt``, T a whole number
    of dt steps (relative tolerance 1e-9).  ``source`` says whether the data is simulated (collect(), the default)
    or read from recorded runs (kexp.data.files; then ``dt`` must equal the files' sample spacing, and ``T``, the
    sampler and ``excitation`` do not apply)."""

    T: float = 10.0
    dt: float = 0.01
    seed: int = 0
    pairs: str = "next"
    excitation: Excitation | None = None
    filter: RegionFilter = field(default_factory=RegionFilter)
    integrator: IntegratorOptions = field(default_factory=IntegratorOptions)
    source: DataSource = field(default_factory=DataSource)

    def __post_init__(self):
        require_number(self.dt, "data.dt")
        require_number(self.T, "data.T")
        require_seed(self.seed, "data.seed")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"data.dt={self.dt}: the sampling time must be > 0")
        if not (np.isfinite(self.T) and self.T >= self.dt):
            raise ConfigError(f"data.T={self.T}: the duration must be >= dt={self.dt}")
        if not isinstance(self.pairs, str) or self.pairs not in PAIR_RULES:
            raise ConfigError(f"data.pairs={self.pairs!r}; valid: {PAIR_RULES}")
        if self.excitation is not None:
            require_type(self.excitation, Excitation, "data.excitation", " (or None: unforced)")
        require_type(self.filter, RegionFilter, "data.filter", " (RegionFilter(): no filter)")
        require_type(self.integrator, IntegratorOptions, "data.integrator", " (IntegratorOptions(): the defaults)")
        require_type(self.source, DataSource, "data.source", " (DataSource(): simulate)")
        # recorded runs: T does not apply, but T/dt must still be finite
        require_whole_steps(self.T, self.dt, "data.T", "data.dt", whole=self.source.kind != "files")
        if self.excitation is not None:
            self.excitation.check(self.dt)
        if self.source.kind == "files" and self.excitation is not None:
            raise ConfigError("data.excitation applies to simulated data; recorded runs bring their own u "
                              "(set data.excitation=null with data.source.kind=files)")

    @property
    def n_steps(self) -> int:
        return int(round(self.T / self.dt))


def collect(system: ControlAffineSystem, sampler, config: DataConfig = DataConfig()) -> Dataset:
    """Simulate ``sampler.n_traj`` trajectories of ``system`` (unforced, or under ``config.excitation``) for
    ``config.T`` seconds sampled every ``config.dt``; apply the region filter; return a :class:`Dataset`.
    Recorded runs (``config.source.kind='files'``) are read with :func:`~kexp.data.read_runs` / ``open_runs``."""
    _check_collect(system, sampler, config)
    xe = np.asarray(system.equilibrium, dtype=float)
    x0 = sampler.sample(xe, config.seed)
    t = np.arange(config.n_steps + 1) * config.dt
    u = None
    if config.excitation is not None:
        rng = np.random.default_rng([config.seed, 1])
        u = config.excitation.draw(x0.shape[0], config.n_steps, system.m, rng, dt=config.dt)
    try:
        x = integrate(system, x0, t, u, config.integrator)
    except IntegrationFailure as exc:
        raise DataError(f"data collection: {exc}; shrink the initial-condition region or duration") from None
    x, valid, u, n_dropped = apply_filter(config, x, np.ones(x.shape[:2], dtype=bool), u, xe, "data collection")
    fx = system.drift(x) if config.pairs == "euler" else None
    ds = Dataset(t=t, x=x, valid=valid, dt=config.dt, pair_rule=config.pairs, system_name=system.name, u=u, fx=fx)
    report = DataReport(n_traj=int(x0.shape[0]), n_samples=int(valid.size), n_pairs=ds.n_pairs,
                        n_masked_samples=int((~valid).sum()), n_dropped_traj=n_dropped,
                        filter=config.filter.mode if config.filter.active else "none",
                        region=config.filter.describe(system.n),
                        source="simulated" if config.excitation is None else
                        f"simulated, {config.excitation.n_excited(int(x0.shape[0]))} of {int(x0.shape[0])} "
                        f"trajectories excited ({config.excitation.kind})")
    object.__setattr__(ds, "report", report)
    return ds


def apply_filter(config: DataConfig, x, valid, u, x_eq, where: str):
    """(x, valid, u, trajectories dropped) after ``config.filter`` (:meth:`RegionFilter.apply`); DataError naming
    ``where`` when it leaves no sample."""
    n_dropped = 0
    if config.filter.active:
        x, valid, u, n_dropped = config.filter.apply(x, valid, u, x_eq)
    if x.shape[0] == 0 or not valid.any():
        raise DataError(f"{where}: the filter removed every sample; widen data.filter or move the initial "
                        "conditions inside it")
    return x, valid, u, n_dropped


def _check_collect(system, sampler, config) -> None:
    """The arguments' types, the data source, and the states' size against the memory budget."""
    require_type(system, ControlAffineSystem, "collect: system", " (e.g. kexp.systems.VanDerPol())")
    if not callable(getattr(sampler, "sample", None)):
        raise ConfigError(f"collect: sampler={short(sampler)}: expected an initial-condition sampler (Circle, Box, "
                          "Points or make_sampler(...))")
    require_type(config, DataConfig, "collect: config", " (e.g. DataConfig(T=10.0))")
    if config.source.kind != "simulate":
        raise ConfigError(f"collect simulates, but data.source.kind={config.source.kind!r} (path "
                          f"{config.source.path!r}): read recorded runs with kexp.data.read_runs or open_runs")
    n_traj = getattr(sampler, "n_traj", None)
    if isinstance(n_traj, (int, np.integer)):
        check_data_size(n_traj, config, system, "collect")


def data_bytes(n_traj: int, n_steps: int, n: int, m: int) -> float:
    """Bytes the collected data holds at its peak: ``n_traj`` trajectories of ``n_steps`` + 1 samples of n states
    and m inputs, 8·(2n + m + 2) per sample (measured ~37 for n = 2, m = 1; tests/test_memory_budget.py)."""
    return 8.0 * n_traj * (n_steps + 1) * (2 * n + m + 2)


def check_data_size(n_traj: int, config: DataConfig, system, where: str) -> None:
    """Refuse data over the memory budget ($KEXP_MEMORY_BUDGET_GB), before any sample is drawn: ``collect`` and
    the app (kexp.app.budget) call it."""
    from ..control.memory import memory_budget
    need, budget = data_bytes(n_traj, config.n_steps, system.n, system.m), memory_budget()
    if need > budget:
        raise ConfigError(f"{where}: {n_traj} trajectories of data.T={config.T:g} s at Δ = {config.dt:g} s are "
                          f"{n_traj * (config.n_steps + 1):.3g} samples, about {need / 1e9:.3g} GB, over the budget "
                          f"of {budget / 1e9:.3g} GB (KEXP_MEMORY_BUDGET_GB): shorten data.T, use fewer "
                          "trajectories, or raise the budget")
