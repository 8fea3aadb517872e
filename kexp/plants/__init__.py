"""Plants: what the closed loop acts on (kexp's integrator, a Gymnasium environment, a user's class).  See
:mod:`kexp.plants.base` for the interface and :mod:`kexp.plants.config` for the ``plant`` config section."""
from .base import CheckedPlant, Plant, check_dt
from .config import PLANT_KINDS, PlantConfig, make_plant
from .integrator import IntegratorPlant
from .system import PlantSystem

__all__ = ["CheckedPlant", "IntegratorPlant", "PLANT_KINDS", "Plant", "PlantConfig", "PlantSystem", "check_dt",
           "make_plant"]
