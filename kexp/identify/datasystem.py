"""A system known only from its data (``system=data``, ``kexp.fit``, ``identify(None, ...)``): its n, m, equilibrium
and state names, which identification, the CLF and the LMPC read.  F and G are unknown: a stage that needs them
(the input projection, Euler pairs, the NMPC oracle, the formula LQR, simulated data) gets one ConfigError line
saying so, and never a traceback."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..systems.base import FormulaFreeSystem

DATA_SYSTEM = "data"   # system.name of a system known only from recorded runs (conf/system/data.yaml)


@dataclass(frozen=True)
class DataSystem(FormulaFreeSystem):
    """n states, m inputs (m = 0: no input model, a drift-only fit), ``x_eq`` (n,) the equilibrium the model is
    centred on (empty: the origin), ``names`` n state names (empty: x1…xn), ``label`` the name models and logs
    carry.  ``drift`` and ``input_matrix`` raise a one-line ConfigError: there is no formula."""

    label: str = DATA_SYSTEM
    n_states: int = 1
    n_inputs: int = 0
    x_eq: tuple = ()
    names: tuple = ()

    def __post_init__(self):
        for key, low in (("n_states", 1), ("n_inputs", 0)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ConfigError(f"DataSystem: {key}={v!r}; use an int >= {low}")
        object.__setattr__(self, "name", str(self.label))
        object.__setattr__(self, "n", int(self.n_states))
        object.__setattr__(self, "m", int(self.n_inputs))
        x_eq = np.zeros(self.n) if self.x_eq is None or len(self.x_eq) == 0 else np.asarray(self.x_eq, float)
        if x_eq.shape != (self.n,) or not np.all(np.isfinite(x_eq)):
            raise ConfigError(f"equilibrium={np.asarray(self.x_eq).tolist()!r:.80}: give {self.n} finite number(s), "
                              f"one per state of the data (n={self.n}), or None for the origin")
        names = tuple(f"x{i + 1}" for i in range(self.n)) if not self.names else tuple(self.names)
        if len(names) != self.n or not all(isinstance(s, str) and s for s in names):
            raise ConfigError(f"state_names={self.names!r:.80}: give {self.n} non-empty names, one per state")
        object.__setattr__(self, "x_eq", tuple(float(v) for v in x_eq))
        object.__setattr__(self, "names", names)

    def _no_formula(self, what: str):
        raise ConfigError(f"system {self.name!r} is known only from its data: {what} is unknown; identify from "
                          "forced runs (t, x, u) with identification.inputs=regression, or without inputs (m = 0) for "
                          "a drift-only model")


def data_inputs(dataset) -> int:
    """m of a data set (a Dataset or RecordedRuns): its inputs' width, 0 if it has none."""
    if not dataset.has_inputs:
        return 0
    m = getattr(dataset, "m", None)
    return int(m) if m is not None else int(dataset.u.shape[2])


def system_of_data(dataset) -> DataSystem:
    """The :class:`DataSystem` of ``dataset`` (what :func:`~kexp.identify.identify` uses for ``system=None``): n and
    m from the data (m = 0 for unforced data: there is no input model without inputs or G), the origin as the
    equilibrium, the data's system name as its label."""
    name = getattr(dataset, "system_name", None) or DATA_SYSTEM
    return DataSystem(label=name, n_states=dataset.n, n_inputs=data_inputs(dataset) if dataset.forced else 0)
