"""The Gymnasium plant (plant.kind=gymnasium) on real environments: Pendulum-v1 steps by its own semi-implicit
Euler formula, MuJoCo's InvertedPendulum-v5 is reset exactly and keeps stepping past its termination, a user's
state mapping reads what qpos_qvel reads, and every bad input is one PlantError line (through make_plant, so
CheckedPlant is included)."""
import json
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.envs.registration import EnvSpec
from gymnasium.spaces import Box

from kexp.errors import PlantError
from kexp.plants import CheckedPlant, PlantConfig, make_plant


def _plant(env_id, **kw):
    return make_plant(PlantConfig(kind="gymnasium", env_id=env_id, **kw))


def _pendulum_step(x, u):
    """Pendulum-v1's own step (gymnasium/envs/classic_control/pendulum.py), written out with its g = 10, m = 1,
    l = 1, Δ = 0.05: u clipped to ±2 (in the Box's float32, as the env receives it), θ̇' = θ̇ + (3g/(2l) sin θ +
    3/(m l²) u)·Δ clipped to ±8, θ' = θ + θ̇'·Δ.  The same numpy operations on the same types: exact."""
    g, m, l, dt = 10.0, 1.0, 1.0, 0.05
    th, thdot = x
    u = np.clip(np.asarray([u], dtype=np.float32), -2.0, 2.0)[0]
    newthdot = np.clip(thdot + (3 * g / (2 * l) * np.sin(th) + 3.0 / (m * l**2) * u) * dt, -8, 8)
    return np.array([th + newthdot * dt, newthdot])


def test_pendulum_steps_by_its_own_formula_for_300_steps():
    """300 steps (its TimeLimit is 200) of u = 3 sin(0.1 k): every step is the env's formula from the previous
    state to 1e-12; the inputs beyond ±2 were clipped by the env (the unclipped formula differs there)."""
    plant = _plant("Pendulum-v1")
    assert isinstance(plant, CheckedPlant)
    assert (plant.n, plant.m, plant.dt) == (2, 1, 0.05)
    low, high = plant.input_bounds()
    assert low.tolist() == [-2.0] and high.tolist() == [2.0]
    x = np.array([0.4, -0.3])
    plant.reset(x)
    clipped = 0
    for k in range(300):
        u = 3.0 * np.sin(0.1 * k)
        x_next = plant.step(np.array([u]))
        np.testing.assert_allclose(x_next, _pendulum_step(x, u), rtol=0, atol=1e-12)
        if abs(u) > 2.0:
            clipped += 1
            unclipped = x[1] + (15.0 * np.sin(x[0]) + 3.0 * u) * 0.05
            if abs(unclipped) < 8 and abs(x_next[1]) < 8:
                assert abs(unclipped - x_next[1]) == pytest.approx(3 * (abs(u) - 2) * 0.05, abs=1e-6)
        x = x_next
    assert clipped > 50
    assert plant.plant.wrapped.spec.max_episode_steps == 200   # the wrapper's limit, which the plant steps past
    plant.close()


def test_pendulum_reset_writes_the_state_exactly_and_info_names_it():
    plant = _plant("Pendulum-v1")
    x0 = np.array([np.pi - 0.1, 1.25])
    plant.reset(x0)
    assert plant.plant.env.state.dtype == np.float64
    assert plant.plant.env.state.tolist() == x0.tolist()
    assert plant.plant.read().tolist() == x0.tolist()
    info = plant.info()
    assert info == {"kind": "gymnasium", "id": "Pendulum-v1", "dt": 0.05, "env_kwargs": {}, "state": "state",
                    "versions": {"gymnasium": gymnasium.__version__}}
    json.dumps(info)
    plant.close()
    plant.close()   # twice: no error


def test_pendulum_env_kwargs_reach_the_env():
    """g=2 (env_kwargs): the step is the formula with g = 2, not 10."""
    plant = _plant("Pendulum-v1", env_kwargs={"g": 2.0})
    plant.reset(np.array([0.5, 0.0]))
    x = plant.step(np.array([0.0]))
    assert x[1] == pytest.approx(3 * 2.0 / 2 * np.sin(0.5) * 0.05, abs=1e-15)
    assert plant.info()["env_kwargs"] == {"g": 2.0}


def test_inverted_pendulum_dimensions_bounds_and_exact_reset():
    plant = _plant("InvertedPendulum-v5")
    env = plant.plant.env
    assert (plant.n, plant.m) == (4, 1)
    assert plant.dt == 0.04 == env.model.opt.timestep * env.frame_skip
    low, high = plant.input_bounds()
    assert low.tolist() == [-3.0] and high.tolist() == [3.0]
    info = plant.info()
    assert info["state"] == "qpos_qvel" and info["dt"] == 0.04
    assert info["versions"] == {"gymnasium": gymnasium.__version__, "mujoco": sys.modules["mujoco"].__version__}
    x0 = np.array([0.1, -0.15, 0.2, 0.35])
    plant.reset(x0)
    assert plant.plant.read().tolist() == x0.tolist()
    assert env.data.qpos.tolist() == [0.1, -0.15] and env.data.qvel.tolist() == [0.2, 0.35]
    assert env.data.time == 0.0
    plant.close()


def test_inverted_pendulum_frame_skip_sets_dt():
    plant = _plant("InvertedPendulum-v5", env_kwargs={"frame_skip": 1})
    assert plant.dt == 0.02


def test_inverted_pendulum_keeps_stepping_after_termination_and_resets_to_the_same_steps():
    """600 steps of u = 3 sin(0.05 k) from a small tilt: the pole passes 0.2 rad (the env's `terminated`) and
    falls onto its hinge limit (π/2 = 1.5708; MuJoCo's soft limit: it lands past it, ~1.71, and rests at
    ~1.5732), every state finite.  A reset
    after that gives bit for bit the steps of a fresh plant: nothing of the past run is left in the env."""
    plant = _plant("InvertedPendulum-v5")
    x0 = np.array([0.0, 0.05, 0.0, 0.0])
    plant.reset(x0)
    xs = np.array([plant.step(np.array([3.0 * np.sin(0.05 * k)])) for k in range(600)])
    assert np.all(np.isfinite(xs))
    first = int(np.argmax(np.abs(xs[:, 1]) > 0.2))
    assert 0 < first < 100                                   # terminated early; 500+ steps after it
    assert 1.5708 < abs(xs[-1, 1]) < 1.58 and abs(xs[-1, 3]) < 1e-3   # resting on the hinge limit (π/2)
    assert np.abs(xs[:, 1]).max() < 1.8                      # the soft limit overshoots while the pole lands
    assert 1.0 < np.abs(xs[:, 0]).max() < 1.2                # the slider's soft limit (±1 m) holds, overshot
    fresh = _plant("InvertedPendulum-v5")
    us = [np.array([np.cos(0.3 * k)]) for k in range(40)]
    for p in (plant, fresh):
        p.reset(x0)
    assert plant.plant.env.data.time == 0.0                  # was 24 s: the env's own reset ran
    a = np.array([plant.step(u) for u in us])
    b = np.array([fresh.step(u) for u in us])
    assert np.array_equal(a, b)


def test_inverted_pendulum_inputs_beyond_the_box_are_the_envs_to_clamp():
    """u = 4.5 is passed unclipped; MuJoCo clamps it to the actuator's ctrlrange (±3): the same step as u = 3."""
    plant = _plant("InvertedPendulum-v5")
    x0 = np.array([0.0, 0.1, 0.0, 0.0])
    plant.reset(x0)
    a = plant.step(np.array([4.5]))
    plant.reset(x0)
    b = plant.step(np.array([3.0]))
    plant.reset(x0)
    c = plant.step(np.array([2.9]))
    assert np.array_equal(a, b) and not np.array_equal(b, c)


MAPS = """
import numpy as np


class CartPoleState:
    n = 4

    def get(self, env):
        return np.concatenate([env.data.qpos, env.data.qvel])

    def set(self, env, x):
        env.set_state(np.array(x[:2]), np.array(x[2:]))


STATE = CartPoleState()


class WrongSize(CartPoleState):
    n = 3


class ReadOnly(CartPoleState):
    def set(self, env, x):
        raise ValueError("this rig's state is read-only")


class NoSet:
    n = 4

    def get(self, env):
        return np.zeros(4)
"""


@pytest.fixture
def maps(tmp_path, monkeypatch):
    """A module kexp_test_maps (the user's own .py file) on sys.path."""
    (tmp_path / "kexp_test_maps.py").write_text(MAPS)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "kexp_test_maps", raising=False)
    yield "kexp_test_maps"
    sys.modules.pop("kexp_test_maps", None)


@pytest.mark.parametrize("obj", ["CartPoleState", "STATE"])
def test_a_users_state_mapping_reads_what_qpos_qvel_reads(maps, obj):
    """A class (built without arguments) or an instance: 50 steps, bit for bit the qpos_qvel plant's states."""
    mine = _plant("InvertedPendulum-v5", state=f"{maps}:{obj}")
    builtin = _plant("InvertedPendulum-v5", state="qpos_qvel")
    assert mine.info()["state"] == f"{maps}:{obj}" and mine.n == 4
    x0 = np.array([0.2, 0.1, -0.3, 0.0])
    for p in (mine, builtin):
        p.reset(x0)
    a = np.array([mine.step(np.array([np.sin(k)])) for k in range(50)])
    b = np.array([builtin.step(np.array([np.sin(k)])) for k in range(50)])
    assert np.array_equal(a, b) and np.abs(a - x0).max() > 0.1


class _BoxEnv(gymnasium.Env):
    """A small real environment for the action-space and Δ checks: action space Box(low, high, shape, dtype),
    ``dt`` unless None, a ``state`` attribute when ``with_state``."""

    def __init__(self, shape=(2,), dt=0.1, with_state=True, low=-1.0, high=1.0, dtype=np.float64):
        self.action_space = Box(low, high, shape=shape, dtype=dtype)
        self.observation_space = Box(-np.inf, np.inf, shape=(2,), dtype=np.float64)
        if dt is not None:
            self.dt = dt
        self.with_state = with_state

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if self.with_state:
            self.state = np.zeros(2)
        return np.zeros(2), {}

    def step(self, action):
        return np.zeros(2), 0.0, False, False, {}


@pytest.fixture
def box_envs(monkeypatch):
    for env_id, kwargs in [("KexpBox2x2-v0", {"shape": (2, 2)}), ("KexpNoState-v0", {"with_state": False}),
                           ("KexpBadDt-v0", {"dt": 0.0}), ("KexpIntBox-v0", {"dtype": np.int64}),
                           ("KexpFree-v0", {"low": -np.inf, "high": np.inf}),
                           ("KexpHalf-v0", {"low": np.array([-np.inf, 0.0]), "high": np.array([5.0, np.inf])})]:
        monkeypatch.setitem(gymnasium.envs.registry, env_id, EnvSpec(id=env_id, entry_point=_BoxEnv, kwargs=kwargs))


EXTRA = "plant.kind=gymnasium needs the plants extra: pip install 'kexp[plants]'"


@pytest.mark.parametrize("env_id, kw, message", [
    ("Pendulm-v1", {}, "plant.env_id='Pendulm-v1' is not a registered Gymnasium environment; close: "
                       "Pendulum-v1, ..."),
    ("Pendulum", {}, "plant.env_id='Pendulum' is not a registered Gymnasium environment; close: Pendulum-v1..."),
    ("Zzzqqq-v9", {}, "plant.env_id='Zzzqqq-v9' is not a registered Gymnasium environment; list them with: "
                      "python -c 'import gymnasium; gymnasium.pprint_registry()'"),
    ("Pendulum-v1", {"env_kwargs": {"gravity": 3.0}},
     "plant.env_id='Pendulum-v1', plant.env_kwargs={'gravity': 3.0}: the environment was not built (TypeError: "
     "PendulumEnv.__init__() got an unexpected keyword argument 'gravity'); check the keyword arguments it takes"),
    ("CartPole-v1", {}, "plant.env_id='CartPole-v1': its action space is Discrete(2); kexp needs a 1-D Box of "
                        "floats (m continuous inputs)"),
    ("KexpBox2x2-v0", {}, "plant.env_id='KexpBox2x2-v0': its action space is Box(-1.0, 1.0, (2, 2), float64); kexp "
                          "needs a 1-D Box of floats (m continuous inputs)"),
    ("KexpIntBox-v0", {}, "plant.env_id='KexpIntBox-v0': its action space is Box(-1, 1, (2,), int64); kexp needs a "
                          "1-D Box of floats (m continuous inputs)"),
    ("MountainCarContinuous-v0", {}, "plant.env_id='MountainCarContinuous-v0': the environment has neither dt nor "
     "tau, so its sampling time is unknown; wrap it in your own plant class with a dt (plant.kind=python)"),
    ("KexpBadDt-v0", {}, "plant.env_id='KexpBadDt-v0': its dt=0.0 is not a sampling time (s, > 0)"),
    ("KexpNoState-v0", {}, "plant.env_id='KexpNoState-v0': kexp cannot tell how to read and write its state "
     "(neither MuJoCo qpos/qvel nor a state attribute); set plant.state=module:Object, an object in your own .py "
     "file with n, get(env) and set(env, x)"),
    ("Pendulum-v1", {"state": "qpos_qvel"}, "plant.state=qpos_qvel: 'Pendulum-v1' is not a MuJoCo environment (no "
     "model, data and set_state); use plant.state=auto, state or module:Object"),
    ("InvertedPendulum-v5", {"state": "state"}, "plant.state=state: 'InvertedPendulum-v5' has no state attribute; "
     "use plant.state=auto, qpos_qvel or module:Object"),
    ("Pendulum-v1", {"state": "qpos"}, "plant.state='qpos': use auto, qpos_qvel, state or module:Object (an object "
     "in your own .py file with n, get(env) and set(env, x))"),
    ("InvertedPendulum-v5", {"state": "kexp_test_maps:WrongSize"}, "plant.state='kexp_test_maps:WrongSize': "
     "get(env) returned shape (4,), but the mapping says n=3; return the state as 3 numbers"),
    ("InvertedPendulum-v5", {"state": "kexp_test_maps:ReadOnly"}, "plant.state='kexp_test_maps:ReadOnly': set(env, "
     "x) raised ValueError: this rig's state is read-only for x=..."),
    ("InvertedPendulum-v5", {"state": "kexp_test_maps:NoSet"}, "plant.state='kexp_test_maps:NoSet': no set(); a "
     "state mapping needs n (an int >= 1), get(env) -> n numbers and set(env, x)"),
    ("InvertedPendulum-v5", {"state": "kexp_test_maps:Missing"}, "plant.state 'kexp_test_maps:Missing': module "
     "'kexp_test_maps' has no 'Missing'"),
    ("InvertedPendulum-v5", {"state": "json:JSONDecoder"}, "plant.state 'json:JSONDecoder': module 'json' is part "
     "of Python's standard library ..."),
])
def test_each_bad_input_is_one_plant_error_line(maps, box_envs, env_id, kw, message):
    with pytest.raises(PlantError) as exc:
        _plant(env_id, **kw)
    text = str(exc.value)
    assert "\n" not in text
    assert text.startswith(message[:-3]) if message.endswith("...") else text == message   # ...: a prefix


def test_gymnasium_not_installed_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)
    with pytest.raises(PlantError) as exc:
        _plant("Pendulum-v1")
    assert str(exc.value) == EXTRA


def _mujoco_env_without(monkeypatch, module: str) -> str:
    """The PlantError line of building InvertedPendulum-v5 with ``module`` hidden (gymnasium's MuJoCo modules are
    re-imported without it)."""
    monkeypatch.setitem(sys.modules, module, None)
    for name in [n for n in sys.modules if n.startswith("gymnasium.envs.mujoco")]:
        monkeypatch.delitem(sys.modules, name)
    try:
        with pytest.raises(PlantError) as exc:
            _plant("InvertedPendulum-v5")
    finally:
        for name in [n for n in sys.modules if n.startswith("gymnasium.envs.mujoco")]:
            del sys.modules[name]   # anything half-imported without it; monkeypatch restores the originals
    return str(exc.value)


def test_mujoco_not_installed_is_one_line(monkeypatch):
    """mujoco missing: gymnasium's MuJoCo modules fail to import (re-imported here with mujoco hidden)."""
    assert _mujoco_env_without(monkeypatch, "mujoco") == f"{EXTRA} (InvertedPendulum-v5 needs mujoco)"


def test_a_module_the_env_imports_when_built_is_one_line(monkeypatch):
    """imageio missing (gymnasium's MuJoCo renderer imports it as an environment is built; gymnasium[mujoco]
    brings it, and the plants extra asks for that): one line naming the extra and the module, not a hint about
    keyword arguments (what a fresh venv without imageio printed)."""
    assert _mujoco_env_without(monkeypatch, "imageio") == \
        f"{EXTRA} (InvertedPendulum-v5 needs the module 'imageio', which is not installed)"


def test_failures_while_running_are_one_line():
    """A step with the wrong number of inputs; a reset to the wrong number of states (CheckedPlant)."""
    plant = _plant("Pendulum-v1")
    plant.reset(np.zeros(2))
    with pytest.raises(PlantError, match=r"^plant 'Pendulum-v1': step needs u as m=1 numbers, got shape \(2,\)$"):
        plant.step(np.zeros(2))
    with pytest.raises(PlantError, match=r"^plant 'Pendulum-v1': reset needs 2 finite numbers, got \[0.0\]$"):
        plant.reset(np.zeros(1))


def test_the_plant_config_group_builds_each_kind():
    """conf/plant/{integrator,gymnasium,python}.yaml are PlantConfigs of their kind; gymnasium.yaml with an env_id
    builds the plant; its env_id is required (null: one line naming the key)."""
    from omegaconf import OmegaConf

    from kexp.app.conf import CONF_DIR
    from kexp.errors import ConfigError

    def load(name):
        return OmegaConf.to_container(OmegaConf.load(f"{CONF_DIR}/plant/{name}.yaml"))

    assert PlantConfig(**load("integrator")).kind == "integrator"
    assert PlantConfig(**{**load("python"), "target": "my_rig:Rig"}).kind == "python"
    with pytest.raises(ConfigError, match=r"^plant.kind=gymnasium needs plant.env_id, e.g. plant.env_id=Pendulum-v1$"):
        PlantConfig(**load("gymnasium"))
    plant = make_plant(PlantConfig(**{**load("gymnasium"), "env_id": "InvertedPendulum-v5"}))
    assert plant.info()["state"] == "qpos_qvel" and plant.dt == 0.04
    plant.close()


def test_input_bounds_are_the_boxs_with_no_bound_where_it_is_infinite(box_envs):
    """A half-open Box keeps ±inf on its open sides (kexp's narrowing then keeps the controller's bound there);
    Box(-inf, inf): None (no bounds of its own); the env's float32 Box(-2, 2) of Pendulum-v1 as floats."""
    low, high = _plant("KexpHalf-v0").input_bounds()
    assert low.tolist() == [-np.inf, 0.0] and high.tolist() == [5.0, np.inf]
    assert _plant("KexpFree-v0").input_bounds() is None
    low, high = _plant("Pendulum-v1").input_bounds()
    assert low.dtype == high.dtype == np.float64 and (low.tolist(), high.tolist()) == ([-2.0], [2.0])


ENVS = """
import gymnasium
import numpy as np
from gymnasium.spaces import Box


class Drift(gymnasium.Env):
    dt = 0.5

    def __init__(self, a=1.0):
        self.a = a
        self.action_space = Box(-1.0, 1.0, shape=(1,), dtype=np.float64)
        self.observation_space = Box(-np.inf, np.inf, shape=(1,), dtype=np.float64)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state = np.zeros(1)
        return self.state.copy(), {}

    def step(self, action):
        self.state = self.state + self.dt * (self.a * self.state + action)
        return self.state.copy(), 0.0, False, False, {}


gymnasium.register("KexpDrift-v0", entry_point=Drift)
"""


def test_an_env_id_with_a_module_imports_the_module_that_registers_it(tmp_path, monkeypatch):
    """plant.env_id=kexp_test_envs:KexpDrift-v0 imports the user's module (which registers the env), as
    gymnasium.make does: x' = x + Δ(a x + u) with the env_kwargs' a = -2."""
    (tmp_path / "kexp_test_envs.py").write_text(ENVS)
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        plant = _plant("kexp_test_envs:KexpDrift-v0", env_kwargs={"a": -2.0})
        assert (plant.n, plant.m, plant.dt) == (1, 1, 0.5) and plant.info()["id"] == "kexp_test_envs:KexpDrift-v0"
        plant.reset(np.array([0.8]))
        assert plant.step(np.array([0.25])).tolist() == [0.8 + 0.5 * (-2.0 * 0.8 + 0.25)]
    finally:
        gymnasium.envs.registry.pop("KexpDrift-v0", None)
        sys.modules.pop("kexp_test_envs", None)
