"""A faster batch check for Hydra's basic sweeper: one composition per job *structure*, not per job.

Before it launches a batch, Hydra's basic sweeper composes the config of every job of it in the parent process,
one after the other, to find composition errors early (``BasicSweeper.validate_batch_is_legal``); the launcher
then composes each job again where it runs.  With kexp's config one composition takes 0.2–0.5 s, so a 100-job
sweep spent 20–45 s composing before its first job started (``benchmarks/sweep.py``).

Jobs whose overrides differ only in the values of dotted keys (``sim.x0=…``, ``controller.lmpc.horizon=…``) have
the same defaults list, so composing one of them finds every error of the group choices, ``+``/``~`` overrides
and config files; the values themselves were checked against the typed schema before Hydra started
(``kexp.app.main._precheck_sweep``), and a value that is legal in type but not in range is reported by its own
job.  :func:`install` makes the basic sweeper check one job per structure (:func:`representatives`); the ``kexp``
command calls it before Hydra runs (Hydra accepts sweeper classes only from its ``hydra_plugins`` namespace, so
kexp changes the one method instead of shipping a plugin package).  A sweep over 100 initial conditions then
composes once in the parent.
"""
from __future__ import annotations

from typing import Sequence


def structure_of(override: str) -> str:
    """The part of an override string that decides the defaults list: the whole override for a group choice
    (a key without a dot, or with a '/') and for ``+``/``~`` overrides; only the key for a value of a dotted key."""
    key = override.split("=", 1)[0]
    if key.startswith(("+", "~")) or "." not in key or "/" in key:
        return override
    return key + "=<value>"


def representatives(batch: Sequence[Sequence[str]]) -> list[Sequence[str]]:
    """One job (its overrides) per distinct structure in ``batch``, in the order first seen."""
    seen: dict[tuple[str, ...], Sequence[str]] = {}
    for overrides in batch:
        seen.setdefault(tuple(structure_of(o) for o in overrides), overrides)
    return list(seen.values())


def install() -> None:
    """Make Hydra's basic sweeper check one job per structure of each batch (idempotent)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    if getattr(BasicSweeper.validate_batch_is_legal, "_kexp", False):
        return
    check_all = BasicSweeper.validate_batch_is_legal

    def validate_batch_is_legal(self, batch):
        return check_all(self, representatives(batch))

    validate_batch_is_legal._kexp = True
    BasicSweeper.validate_batch_is_legal = validate_batch_is_legal
