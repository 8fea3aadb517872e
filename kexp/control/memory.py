"""The memory an LMPC step holds, and the budget that refuses a horizon and blocking too large before anything runs
(a huge horizon used to identify the model first and then fail with MemoryError in the first control step)."""
from __future__ import annotations

import os

from ..errors import ConfigError

MEMORY_BUDGET_GB = 4.0  # the default budget of check_memory; the environment variable KEXP_MEMORY_BUDGET_GB sets it


def memory_estimate(config, k: int, m: int) -> int:
    """Bytes (float64) an :class:`~kexp.control.lmpc.Lmpc` with ``config`` (an LmpcConfig) holds at once in a
    control step, for ``k`` eigen-coordinates and ``m`` inputs: the rollout sensitivities S (nu, Np+1, k) and at
    most one array of their size (the cost's output sensitivities), the QP's Hessian with its products and
    factorisation (6 of (nu+1)²) and the constraint rows with their copies (4 of (Np+1)(nu+1)); Np = horizon,
    nu = m·(number of move blocks)."""
    n_steps = int(config.horizon)
    nu = m * (n_steps if config.blocks is None else min(int(config.blocks), n_steps))
    words = 2 * (n_steps + 1) * k * nu + 6 * (nu + 1) ** 2 + 4 * (n_steps + 1) * (nu + 1) + 2 * n_steps * m
    return 8 * words


def memory_budget() -> float:
    """The budget in bytes: ``$KEXP_MEMORY_BUDGET_GB`` or :data:`MEMORY_BUDGET_GB` GB."""
    raw = os.environ.get("KEXP_MEMORY_BUDGET_GB") or MEMORY_BUDGET_GB
    try:
        gb = float(raw)
    except ValueError:
        gb = float("nan")
    if not gb > 0:
        raise ConfigError(f"KEXP_MEMORY_BUDGET_GB={raw!r}: use a number of gigabytes > 0")
    return gb * 1e9


def check_memory(config, k: int, m: int) -> None:
    """Refuse a horizon and blocking whose LMPC would need more than the memory budget (before anything runs)."""
    need, budget = memory_estimate(config, k, m), memory_budget()
    if need > budget:
        blocks = "null" if config.blocks is None else config.blocks
        raise ConfigError(
            f"controller.lmpc.horizon={config.horizon} with blocks={blocks} needs about {need / 1e9:.3g} GB for "
            f"k={k} dictionary functions and m={m} input(s), over the budget of {budget / 1e9:.3g} GB "
            "(KEXP_MEMORY_BUDGET_GB): lower the horizon or controller.lmpc.blocks, or raise the budget")
