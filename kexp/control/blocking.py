"""Move blocking: the input is held constant over blocks of steps.  The first ``free`` moves are single steps
(they matter most for the closed loop); the remaining blocks grow geometrically to cover the horizon."""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, require_number


def block_sizes(horizon: int, free: int | None = 5, blocks: int | None = 20) -> np.ndarray:
    """Sizes (summing to ``horizon``) of the move blocks; ``blocks=None`` means no blocking (all size 1).  Raises
    :class:`~kexp.errors.ConfigError` naming ``controller.lmpc.free_moves`` / ``controller.lmpc.blocks`` (ints or
    None) when they cannot cover the horizon."""
    key = "controller.lmpc."
    require_number(horizon, key + "horizon", integer=True)
    for name, value in (("free_moves", free), ("blocks", blocks)):
        if value is not None:
            require_number(value, key + name, integer=True)
    if horizon < 1:
        raise ConfigError(f"{key}horizon={horizon}: use an int >= 1")
    if free is not None and free < 0:
        raise ConfigError(f"{key}free_moves={free}: use an int >= 0 (or null)")
    if blocks is not None and blocks < 1:
        raise ConfigError(f"{key}blocks={blocks}: use an int >= 1 (or null: no blocking)")
    if blocks is None or blocks >= horizon:
        return np.ones(horizon, dtype=int)
    free = 0 if free is None else int(free)
    if free > blocks:
        raise ConfigError(f"{key}free_moves={free} > {key}blocks={blocks}: free_moves counts among the blocks; "
                          "use free_moves <= blocks")
    rest_steps = horizon - free
    rest_blocks = blocks - free
    if rest_blocks == 0:
        if rest_steps:
            raise ConfigError(f"{key}free_moves={free} == {key}blocks={blocks} < horizon={horizon} leaves steps "
                              f"{free + 1}..{horizon} without a block: use free_moves < blocks (or blocks=null: no "
                              "blocking)")
        return np.ones(free, dtype=int)
    if rest_steps < rest_blocks:
        raise ConfigError(f"{key}blocks={blocks}: {rest_blocks} blocks after free_moves={free} cannot cover the "
                          f"other {rest_steps} steps; use fewer blocks")
    # geometric growth, rounded so the sizes are increasing and sum to rest_steps
    w = np.geomspace(1.0, max(1.0, 2.0 * rest_steps / rest_blocks - 1.0), rest_blocks)
    edges = np.round(np.concatenate([[0.0], np.cumsum(w)]) / w.sum() * rest_steps).astype(int)
    sizes = np.maximum(np.diff(edges), 1)
    sizes[-1] += rest_steps - sizes.sum()
    if sizes[-1] < 1:
        raise ConfigError(f"{key}blocks={blocks}: could not form blocks over horizon={horizon}; use fewer blocks")
    return np.concatenate([np.ones(free, dtype=int), sizes])


def block_of_step(sizes: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(sizes)), sizes).astype(np.int64)
