"""A registered Gymnasium environment as a plant (``plant.kind=gymnasium``, ``plant.env_id=InvertedPendulum-v5``).

kexp acts on the *unwrapped* environment: the TimeLimit, OrderEnforcing and PassiveEnvChecker wrappers that
``gymnasium.make`` adds, and the episode's ``terminated``, never stop an experiment (kexp chooses the states it
resets to and keeps stepping).  The state x is read from and written to the environment by a *state mapping*
(``plant.state``), never taken from the observation:

- ``qpos_qvel`` (MuJoCo environments): x = (qpos, qvel) of ``unwrapped.data``, n = nq + nv, written with
  ``unwrapped.set_state(qpos, qvel)``;
- ``state`` (classic control, e.g. Pendulum-v1): x = ``unwrapped.state`` flattened, written back in the
  environment's own dtype and shape;
- ``module:Object``: an object (or a class, built without arguments) from the user's own ``.py`` file with ``n``,
  ``get(env) -> (n,)`` and ``set(env, x)``, ``env`` being the unwrapped environment;
- ``auto`` (the default): ``qpos_qvel`` for a MuJoCo environment, else ``state`` when the environment has one.

Δ is the environment's: ``unwrapped.dt`` (MuJoCo: ``model.opt.timestep * frame_skip``), else ``unwrapped.tau``.
The action space must be a 1-D ``Box`` of floats (m = its size); u is handed to ``unwrapped.step`` in the Box's dtype (a
float32 Box rounds u to float32), unclipped: what the environment does beyond its bounds is its own (Pendulum-v1
clips to ±2, MuJoCo clamps to a limited actuator's ctrlrange).  :meth:`GymnasiumPlant.input_bounds` reports the
Box; kexp narrows the controller's bounds to it.

:meth:`GymnasiumPlant.reset` first calls the environment's own ``reset()`` (no seed: the random stream continues
from the ``seed=0`` reset at construction) and then writes x0, so a reset clears what the state mapping does not
hold (MuJoCo's time, warm start and activations, Pendulum's last input): the steps from x0 do not depend on what
ran before.  Every failure is one :class:`~kexp.errors.PlantError` line.
"""
from __future__ import annotations

import difflib
import importlib
import math
import sys

import numpy as np

from ..data.checks import short
from ..errors import PlantError, SystemDefinitionError, is_number
from ..systems.registry import _import_class
from .base import Plant, _short

EXTRA = "plant.kind=gymnasium needs the plants extra: pip install 'kexp[plants]'"
STATE_MAPS = ("auto", "qpos_qvel", "state")


def _import_gymnasium():
    try:
        import gymnasium
    except ImportError:
        raise PlantError(EXTRA) from None
    return gymnasium


def _is_mujoco(env) -> bool:
    """True for a MuJoCo environment: ``model``, ``data`` and ``set_state`` on the unwrapped env."""
    return all(hasattr(env, a) for a in ("model", "data")) and callable(getattr(env, "set_state", None))


class QposQvel:
    """x = (qpos (nq,), qvel (nv,)) of a MuJoCo environment's ``data``; n = nq + nv."""

    name = "qpos_qvel"

    def __init__(self, env):
        self.nq, self.nv = int(env.model.nq), int(env.model.nv)
        self.n = self.nq + self.nv

    def get(self, env) -> np.ndarray:
        return np.concatenate([env.data.qpos, env.data.qvel]).astype(float)

    def set(self, env, x) -> None:
        env.set_state(np.array(x[:self.nq], dtype=float), np.array(x[self.nq:], dtype=float))


class StateAttribute:
    """x = the environment's ``state`` attribute flattened (float); written back in its own dtype and shape."""

    name = "state"

    def __init__(self, env):
        state = np.asarray(env.state)
        self.dtype, self.shape, self.n = state.dtype, state.shape, int(state.size)

    def get(self, env) -> np.ndarray:
        return np.asarray(env.state, dtype=float).reshape(-1)

    def set(self, env, x) -> None:
        env.state = np.asarray(x, dtype=self.dtype).reshape(self.shape)


def _user_mapping(path: str):
    """The user's mapping ``module:Object`` (a class is built without arguments), checked for n, get and set."""
    try:
        obj = _import_class(path, "plant.state", "plant.state=my_maps:CartPoleState")
    except SystemDefinitionError as exc:
        raise PlantError(str(exc)) from None
    if isinstance(obj, type):
        try:
            obj = obj()
        except Exception as exc:  # noqa: BLE001 - the user's constructor: one line
            raise PlantError(f"plant.state={path!r}: {path}() raised {_short(exc)}") from None
    n = getattr(obj, "n", None)
    missing = [f"{a}()" for a in ("get", "set") if not callable(getattr(obj, a, None))]
    if missing or not (is_number(n, integer=True) and n >= 1):
        raise PlantError(f"plant.state={path!r}: {'no ' + ' or '.join(missing) if missing else f'n={n!r}'}; a state "
                         "mapping needs n (an int >= 1), get(env) -> n numbers and set(env, x)")
    return UserMapping(obj, path, int(n))


class UserMapping:
    """The user's mapping object ``obj`` (named ``name``: its module:Object) with its ``n``, ``get`` and ``set``."""

    def __init__(self, obj, name: str, n: int):
        self.obj, self.name, self.n = obj, name, n

    def get(self, env):
        return self.obj.get(env)

    def set(self, env, x) -> None:
        self.obj.set(env, x)


def _mapping(choice: str, env, env_id: str):
    """The state mapping ``plant.state=choice`` names, for the unwrapped ``env``."""
    if not isinstance(choice, str) or not (choice in STATE_MAPS or ":" in choice):
        raise PlantError(f"plant.state={choice!r}: use auto, qpos_qvel, state or module:Object (an object in your "
                         "own .py file with n, get(env) and set(env, x))")
    if ":" in choice:
        return _user_mapping(choice)
    has_state = getattr(env, "state", None) is not None
    if choice == "auto":
        if not (_is_mujoco(env) or has_state):
            raise PlantError(f"plant.env_id={env_id!r}: kexp cannot tell how to read and write its state (neither "
                             "MuJoCo qpos/qvel nor a state attribute); set plant.state=module:Object, an object in "
                             "your own .py file with n, get(env) and set(env, x)")
        choice = "qpos_qvel" if _is_mujoco(env) else "state"
    if choice == "qpos_qvel":
        if not _is_mujoco(env):
            raise PlantError(f"plant.state=qpos_qvel: {env_id!r} is not a MuJoCo environment (no model, data and "
                             "set_state); use plant.state=auto, state or module:Object")
        return QposQvel(env)
    if not has_state:
        raise PlantError(f"plant.state=state: {env_id!r} has no state attribute; use plant.state=auto, qpos_qvel "
                         "or module:Object")
    return StateAttribute(env)


def _env_dt(env, env_id: str) -> float:
    for attr in ("dt", "tau"):
        dt = getattr(env, attr, None)
        if dt is not None:
            if not (is_number(dt) and math.isfinite(dt) and dt > 0):
                raise PlantError(f"plant.env_id={env_id!r}: its {attr}={dt!r} is not a sampling time (s, > 0)")
            return float(dt)
    raise PlantError(f"plant.env_id={env_id!r}: the environment has neither dt nor tau, so its sampling time is "
                     "unknown; wrap it in your own plant class with a dt (plant.kind=python)")


def _registered(gym, env_id: str) -> str:
    """The registry id ``env_id`` names (``module:Env-v0`` imports ``module`` first, as gymnasium.make does)."""
    name = env_id
    if ":" in env_id:
        module, _, name = env_id.partition(":")
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise PlantError(f"plant.env_id={env_id!r}: cannot import module {module!r} ({_short(exc)}); check "
                             "the name and that it is installed or on PYTHONPATH") from None
    if name not in gym.envs.registry:
        close = difflib.get_close_matches(name, list(gym.envs.registry), n=5)
        hint = (f"close: {', '.join(close)}" if close else
                "list them with: python -c 'import gymnasium; gymnasium.pprint_registry()'")
        raise PlantError(f"plant.env_id={env_id!r} is not a registered Gymnasium environment; {hint}")
    return name


class GymnasiumPlant(Plant):
    """The unwrapped environment ``env`` (``wrapped``: what gymnasium.make returned), state mapping ``mapping``
    (n states), action space ``space`` (a 1-D Box, m inputs), Δ = ``dt`` s.  Build with
    :func:`make_gymnasium_plant`."""

    kind = "gymnasium"

    def __init__(self, wrapped, env_id: str, env_kwargs: dict, mapping, space, dt: float, versions: dict):
        self.wrapped, self.env = wrapped, wrapped.unwrapped
        self.env_id, self.env_kwargs, self.mapping, self.space = env_id, dict(env_kwargs), mapping, space
        self.dt, self.n, self.m = float(dt), int(mapping.n), int(space.shape[0])
        self.versions = versions
        self._closed = False

    def read(self) -> np.ndarray:
        """The environment's state x (n,) through the mapping."""
        try:
            x = self.mapping.get(self.env)
        except Exception as exc:  # noqa: BLE001 - a user's mapping: one line
            raise PlantError(f"plant.state={self.mapping.name!r}: get(env) raised {_short(exc)}") from None
        try:
            x = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise PlantError(f"plant.state={self.mapping.name!r}: get(env) returned {short(x)}; return the state "
                             f"as n={self.n} numbers") from None
        if x.shape != (self.n,):
            raise PlantError(f"plant.state={self.mapping.name!r}: get(env) returned shape {x.shape}, but the mapping "
                             f"says n={self.n}; return the state as {self.n} numbers")
        return x

    def write(self, x) -> None:
        """Write the state x (n,) into the environment through the mapping."""
        try:
            self.mapping.set(self.env, np.array(x, dtype=float))
        except Exception as exc:  # noqa: BLE001
            raise PlantError(f"plant.state={self.mapping.name!r}: set(env, x) raised {_short(exc)} for "
                             f"x={short(np.asarray(x).tolist())}") from None

    def reset(self, x0) -> None:
        self.env.reset()
        self.write(x0)

    def step(self, u) -> np.ndarray:
        u = np.asarray(u)
        if u.size != self.m:
            raise PlantError(f"plant {self.env_id!r}: step needs u as m={self.m} numbers, got shape {u.shape}")
        self.env.step(np.asarray(u, dtype=self.space.dtype).reshape(self.space.shape))
        return self.read()

    def input_bounds(self):
        """(low (m,), high (m,)) of the Box as floats; an infinite entry means no bound on that side (None when
        the Box bounds nothing)."""
        low, high = np.asarray(self.space.low, dtype=float), np.asarray(self.space.high, dtype=float)
        if not (np.isfinite(low).any() or np.isfinite(high).any()):
            return None
        return low.copy(), high.copy()

    def info(self) -> dict:
        return {"kind": self.kind, "id": self.env_id, "dt": self.dt, "env_kwargs": dict(self.env_kwargs),
                "state": self.mapping.name, "versions": dict(self.versions)}

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.wrapped.close()


def make_gymnasium_plant(config) -> GymnasiumPlant:
    """The environment ``config.env_id`` (a :class:`~kexp.plants.config.PlantConfig`) built with
    ``config.env_kwargs``, reset once with seed 0, with the state mapping ``config.state``.  PlantError (one line)
    when gymnasium (or mujoco, for a MuJoCo environment) is missing, the id is unknown, the environment rejects
    its keyword arguments, has no Δ, a non-Box or non-1-D action space, or the mapping fails."""
    gym = _import_gymnasium()
    env_id, env_kwargs = config.env_id, dict(config.env_kwargs)
    name = _registered(gym, env_id)
    try:
        wrapped = gym.make(name, **env_kwargs)
    except gym.error.DependencyNotInstalled as exc:
        if "mujoco" in str(exc).lower():
            raise PlantError(f"{EXTRA} ({env_id} needs mujoco)") from None
        raise PlantError(f"plant.env_id={env_id!r} needs a package that is not installed: {_short(exc)}") from None
    except ImportError as exc:   # a package the environment imports as it is built (MuJoCo's renderer: imageio)
        missing = getattr(exc, "name", None) or _short(exc)
        raise PlantError(f"{EXTRA} ({env_id} needs the module {missing!r}, which is not installed)") from None
    except Exception as exc:  # noqa: BLE001 - the environment's constructor: one line
        cause = exc.__cause__ or exc   # gymnasium re-raises a TypeError with the kwargs appended
        raise PlantError(f"plant.env_id={env_id!r}, plant.env_kwargs={short(env_kwargs)}: the environment was not "
                         f"built ({_short(cause)}); check the keyword arguments it takes") from None
    try:
        env = wrapped.unwrapped
        space = env.action_space      # what unwrapped.step takes (a wrapper may rescale its own)
        if not (isinstance(space, gym.spaces.Box) and len(space.shape) == 1 and space.shape[0] >= 1
                and np.issubdtype(space.dtype, np.floating)):
            raise PlantError(f"plant.env_id={env_id!r}: its action space is {space}; kexp needs a 1-D Box of floats "
                             "(m continuous inputs)")
        try:
            env.reset(seed=0)
        except Exception as exc:  # noqa: BLE001
            raise PlantError(f"plant.env_id={env_id!r}: reset(seed=0) raised {_short(exc)}") from None
        dt = _env_dt(env, env_id)
        mapping = _mapping(config.state, env, env_id)
        versions = {"gymnasium": gym.__version__}
        if _is_mujoco(env) and "mujoco" in sys.modules:
            versions["mujoco"] = sys.modules["mujoco"].__version__
        plant = GymnasiumPlant(wrapped, env_id, env_kwargs, mapping, space, dt, versions)
        plant.write(plant.read())   # the mapping reads n numbers, and writing them back does not raise
    except BaseException:
        wrapped.close()
        raise
    return plant
