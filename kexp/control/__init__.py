from .jit_cache import configure as _configure_jit_cache

_configure_jit_cache()   # before any kernel module is imported: numba picks a kernel's cache folder at decoration
from .laws import LAWS, LieGain, ModelLqrGain, Sontag, make_law  # noqa: E402

__all__ = ["LAWS", "LieGain", "ModelLqrGain", "Sontag", "make_law"]
from .explicit import ExplicitController, LqrController, linearise  # noqa: E402
from .lmpc import ControlStep, Lmpc, LmpcConfig  # noqa: E402

__all__ += ["ExplicitController", "LqrController", "linearise", "ControlStep", "Lmpc", "LmpcConfig"]
from .plant_lqr import PlantLinearisation, PlantLqrController, linearise_plant  # noqa: E402

__all__ += ["PlantLinearisation", "PlantLqrController", "linearise_plant"]
