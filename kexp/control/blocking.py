"""Move blocking: the input is held constant over blocks of steps.  The first ``free`` moves are single steps
(they matter most for the closed loop); the remaining blocks grow geometrically to cover the horizon."""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError


def block_sizes(horizon: int, free: int | None = 5, blocks: int | None = 20) -> np.ndarray:
    """Sizes (summing to ``horizon``) of the move blocks; ``blocks=None`` means no blocking (all size 1)."""
    if horizon < 1:
        raise ConfigError(f"lmpc.horizon={horizon}: use an int >= 1")
    if blocks is None or blocks >= horizon:
        return np.ones(horizon, dtype=int)
    free = 0 if free is None else int(free)
    if not (1 <= blocks and 0 <= free <= blocks):
        raise ConfigError(f"lmpc.move_blocks: need 0 <= free ({free}) <= blocks ({blocks})")
    rest_steps = horizon - free
    rest_blocks = blocks - free
    if rest_blocks == 0:
        if rest_steps:
            raise ConfigError("lmpc.move_blocks: free == blocks leaves steps uncovered; lower free")
        return np.ones(free, dtype=int)
    if rest_steps < rest_blocks:
        raise ConfigError(f"lmpc.move_blocks: {rest_blocks} blocks cannot cover {rest_steps} steps")
    # geometric growth, rounded so the sizes are increasing and sum to rest_steps
    w = np.geomspace(1.0, max(1.0, 2.0 * rest_steps / rest_blocks - 1.0), rest_blocks)
    edges = np.round(np.concatenate([[0.0], np.cumsum(w)]) / w.sum() * rest_steps).astype(int)
    sizes = np.maximum(np.diff(edges), 1)
    sizes[-1] += rest_steps - sizes.sum()
    if sizes[-1] < 1:
        raise ConfigError("lmpc.move_blocks: could not form blocks; use fewer blocks")
    return np.concatenate([np.ones(free, dtype=int), sizes])


def block_of_step(sizes: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(sizes)), sizes).astype(np.int64)
