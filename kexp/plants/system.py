"""The system of a plant kexp has no formula for (``system=plant``): its n, m, equilibrium and state names, which
data collection, identification, the CLF and the LMPC read.  F and G do not exist: a stage that needs them (the
input projection, the NMPC oracle, the formula LQR, an open-loop integration) gets one PlantError line saying so."""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import PlantError
from ..systems.base import FormulaFreeSystem


@dataclass(frozen=True)
class PlantSystem(FormulaFreeSystem):
    """n, m, x_eq and names of plant ``plant_id`` (``equilibrium`` (n,), ``names`` n strings)."""

    plant_id: str = "plant"
    n_states: int = 1
    n_inputs: int = 1
    x_eq: tuple = ()
    names: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "name", self.plant_id)
        object.__setattr__(self, "n", int(self.n_states))
        object.__setattr__(self, "m", int(self.n_inputs))
        x_eq = tuple(float(v) for v in self.x_eq) if self.x_eq else (0.0,) * self.n
        names = tuple(self.names) if self.names else tuple(f"x{i + 1}" for i in range(self.n))
        if len(x_eq) != self.n:
            raise PlantError(f"plant.equilibrium has {len(x_eq)} entries; plant {self.plant_id!r} has n={self.n} "
                             "states")
        if len(names) != self.n:
            raise PlantError(f"plant.state_names has {len(names)} entries; plant {self.plant_id!r} has n={self.n} "
                             "states")
        object.__setattr__(self, "x_eq", x_eq)
        object.__setattr__(self, "names", names)

    def _no_formula(self, what: str):
        raise PlantError(f"plant {self.plant_id!r} has no formula ({what} is unknown): use what works from data "
                         "(identification.inputs=regression, controller=lmpc, model_lqr or lqr on the plant's "
                         "numerical linearisation)")
