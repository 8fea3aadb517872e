from ..errors import SystemDefinitionError
from .base import ControlAffineSystem, check_system
from .library import Duffing, Linear, Pendulum, SlowManifold, VanDerPol
from .registry import SYSTEMS, make_system

__all__ = ["ControlAffineSystem", "SystemDefinitionError", "check_system", "Duffing", "Linear", "Pendulum",
           "SlowManifold", "VanDerPol", "SYSTEMS", "make_system"]
