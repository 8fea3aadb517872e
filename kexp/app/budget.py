"""The run's size against the memory budget, before anything long starts: the data to collect and the closed
loop to run (a ``sim.T=1e9`` used to identify the model first and then fail allocating 745 GiB).  The data's
estimate is collect's own (:func:`kexp.data.collect.check_data_size`).

Per control step, measured with tracemalloc (Van der Pol, k = 20; tests/test_memory_budget.py keeps the estimates
above what a short run holds): the closed loop ~2.6 kB per step at its peak (its StepRecord with x, z, u, the
trajectory, the log's records) and ~6 kB once the log is read back for the rendering, estimated as
3·(2500 + 8·(k + 4n + 2m)) (8.2 kB there).
"""
from __future__ import annotations

from ..control.memory import memory_budget
from ..data.collect import check_data_size
from ..errors import ConfigError


def loop_bytes(n_steps: int, n: int, m: int, k: int) -> float:
    """Bytes a closed loop of ``n_steps`` control steps holds with its log: records, trajectory, the log read back
    (for the rendering)."""
    return 3.0 * n_steps * (2500 + 8 * (k + 4 * n + 2 * m))


def check_run_size(sim_cfg, system, k: int, sampler=None, data_cfg=None) -> None:
    """Refuse a closed loop (``sim_cfg``: T, dt) or simulated data (``sampler``'s trajectories of ``data_cfg.T``)
    that would need more than the memory budget (``$KEXP_MEMORY_BUDGET_GB``), with what to change."""
    if sampler is not None and data_cfg is not None:
        check_data_size(sampler.n_traj, data_cfg, system, "data")   # collect's own check, before the cache
    budget = memory_budget()
    need = loop_bytes(sim_cfg.n_steps, system.n, system.m, k)
    if need > budget:
        raise ConfigError(
            f"sim.T={sim_cfg.T:g} s at Δ = {sim_cfg.dt:g} s is {sim_cfg.n_steps:.3g} control steps, about "
            f"{need / 1e9:.3g} GB for the run's records and log, over the budget of {budget / 1e9:.3g} GB "
            "(KEXP_MEMORY_BUDGET_GB): shorten sim.T or raise the budget")
