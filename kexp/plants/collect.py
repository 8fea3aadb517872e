"""Data from a plant (``data.source.kind=plant``): each sampled initial state is set with ``reset``, the plant is
stepped ``data.T/Δ`` times under the excitation (u = 0 without one), and the states it returns are the samples.
What a step that fails leaves (the plant raised, returned NaN, or kexp's integrator failed) is masked: the rest of
that trajectory is invalid, the others are kept, and the report counts the trajectories cut short.  The region
filter (``data.filter``) then applies as for simulated data (e.g. to drop samples where a joint sits at its
limit)."""
from __future__ import annotations

import numpy as np

from ..data.collect import DataConfig, apply_filter, check_data_size
from ..data.dataset import DataReport, Dataset
from ..data.integrate import IntegrationFailure
from ..errors import ConfigError, DataError, KexpError
from .base import check_dt


def collect_from_plant(plant, sampler, config: DataConfig, x_eq, name: str, *, progress=None) -> Dataset:
    """A :class:`~kexp.data.Dataset` of ``sampler.n_traj`` runs of ``plant`` (forced when ``config.excitation``
    is set).  ``progress(k)`` is called after each trajectory (a bar).  Raises DataError when no step succeeded,
    ConfigError when ``config.dt`` is not the plant's Δ."""
    check_dt(plant.dt, config.dt, "data.dt", name)
    if config.pairs != "next":
        raise ConfigError("data.pairs=euler needs the drift F(x); a plant gives only its next state: set "
                          "data.pairs=next")
    xe = np.asarray(x_eq, dtype=float)
    x0 = sampler.sample(xe, config.seed)
    n_traj, n_steps = x0.shape[0], config.n_steps
    check_data_size(n_traj, config, plant, "data from the plant")
    t = np.arange(n_steps + 1) * config.dt
    u = None
    if config.excitation is not None:
        rng = np.random.default_rng([config.seed, 1])   # the same draw as collect() makes for a simulated system
        u = config.excitation.draw(n_traj, n_steps, plant.m, rng, dt=config.dt)
    x = np.full((n_traj, n_steps + 1, plant.n), np.nan)
    valid = np.zeros((n_traj, n_steps + 1), dtype=bool)
    zero = np.zeros(plant.m)
    cut, first_failure = 0, ""
    for i in range(n_traj):
        try:
            plant.reset(x0[i])
            x[i, 0] = x0[i]
            valid[i, 0] = True
            for k in range(n_steps):
                x[i, k + 1] = plant.step(zero if u is None else u[i, k])
                valid[i, k + 1] = True
        except (KexpError, IntegrationFailure) as exc:
            cut += 1
            first_failure = first_failure or f"trajectory {i}: {exc}"
        if progress is not None:
            progress(i + 1)
    if not valid.any() or valid.sum() < 2:
        raise DataError(f"data from plant {name!r}: no step succeeded ({first_failure}); check the plant and the "
                        "initial-condition region")
    x, valid, u, n_dropped = apply_filter(config, x, valid, u, xe, "data from the plant")
    x = np.where(valid[..., None], x, 0.0)   # masked samples hold no NaN (Dataset's rule for invalid samples)
    ds = Dataset(t=t, x=x, valid=valid, dt=config.dt, pair_rule="next", system_name=name, u=u)
    excited = "" if config.excitation is None else (
        f", {config.excitation.n_excited(n_traj)} of {n_traj} excited ({config.excitation.kind})")
    report = DataReport(n_traj=n_traj, n_samples=int(valid.size), n_pairs=ds.n_pairs,
                        n_masked_samples=int((~valid).sum()), n_dropped_traj=n_dropped,
                        filter=config.filter.mode if config.filter.active else "none",
                        region=config.filter.describe(plant.n),
                        source=f"plant {name!r}: {n_traj} runs{excited}"
                        + (f"; {cut} cut short by a failed step (first: {first_failure})"[:400] if cut else ""))
    object.__setattr__(ds, "report", report)
    return ds
