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


def require_number(value, key: str, *, integer: bool = False) -> None:
    """Raise a ConfigError unless ``value`` is a real number (an int if ``integer``); bools are not numbers."""
    import numbers
    ok = isinstance(value, numbers.Integral if integer else numbers.Real) and not isinstance(value, bool)
    if not ok:
        raise ConfigError(f"{key}={value!r}: expected {'an integer' if integer else 'a number'}")


def require_seed(value, key: str) -> None:
    """Raise a ConfigError unless ``value`` is an int >= 0 (what numpy's random generators take)."""
    require_number(value, key, integer=True)
    if value < 0:
        raise ConfigError(f"{key}={value}: use an int >= 0 (a random seed)")
