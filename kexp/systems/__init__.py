from ..errors import SystemDefinitionError
from .base import ControlAffineSystem, check_system
from .library import CartPendulum, Duffing, Linear, Pendulum, SlowManifold, VanDerPol
from .registry import SYSTEMS, make_system

__all__ = ["ControlAffineSystem", "SystemDefinitionError", "check_system", "CartPendulum", "Duffing", "Linear",
           "Pendulum", "SlowManifold", "VanDerPol", "SYSTEMS", "make_system"]
