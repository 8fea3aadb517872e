"""kexp's exceptions.  Each message is one line that names what is wrong and what would be valid."""


class KexpError(Exception):
    """Base of every error kexp raises on purpose."""


class ConfigError(KexpError, ValueError):
    """A setting or argument is invalid; the message names the key, the value and what is valid."""


class SystemDefinitionError(ConfigError):
    """A system's definition or its F/G output is unusable."""


class DataError(KexpError, ValueError):
    """Data cannot support the requested computation (too few samples, non-finite values, ...)."""


class ClfError(KexpError, RuntimeError):
    """No control Lyapunov function: the SDP failed (infeasible, unbounded, or solved too inaccurately to use) or
    the model's linearisation is not stabilisable (Riccati)."""


class ModelFileError(KexpError, OSError):
    """A model file is missing, corrupt, or from another format version."""


def is_number(value, *, integer: bool = False) -> bool:
    """A real number (an integer if ``integer``): int, float or a numpy scalar; bools are not numbers (True would
    pass for 1).  The one test behind every check of a numeric setting."""
    import numbers
    return isinstance(value, numbers.Integral if integer else numbers.Real) and not isinstance(value, bool)


def require_number(value, key: str, *, integer: bool = False) -> None:
    """Raise a ConfigError unless ``value`` is a real number (an int if ``integer``); bools are not numbers."""
    if not is_number(value, integer=integer):
        raise ConfigError(f"{key}={value!r}: expected {'an integer' if integer else 'a number'}")


STEP_TOLERANCE = 1e-9  # relative: a duration must be a whole number of time steps within this


def require_whole_steps(T: float, dt: float, t_key: str, dt_key: str, *, whole: bool = True) -> int:
    """The number of ``dt`` steps in ``T``; a ConfigError naming the nearest valid T when T is not a whole number
    of steps (relative tolerance :data:`STEP_TOLERANCE`: T was rounded silently before; unless ``whole`` is
    False) or T/dt is not finite."""
    import math
    steps = T / dt
    if not math.isfinite(steps):
        raise ConfigError(f"{t_key}={T}, {dt_key}={dt}: T/dt is not a finite number of steps; use a larger dt or a "
                          "shorter T")
    k = max(1, round(steps))
    if whole and abs(k * dt - T) > STEP_TOLERANCE * T:
        raise ConfigError(f"{t_key}={T}: not a whole number of {dt_key}={dt} steps (T/dt = {steps:.9g}); use "
                          f"{t_key}={k * dt:.12g} ({k} steps)")
    return k


def require_seed(value, key: str) -> None:
    """Raise a ConfigError unless ``value`` is an int >= 0 (what numpy's random generators take)."""
    require_number(value, key, integer=True)
    if value < 0:
        raise ConfigError(f"{key}={value}: use an int >= 0 (a random seed)")


class PlantError(KexpError, RuntimeError):
    """A plant (kexp's integrator, a Gymnasium environment, a user's class) cannot be built, or failed while the
    loop ran (raised, returned the wrong shape, NaN or inf); the message names the plant, the step and what to fix."""
