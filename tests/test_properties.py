"""Property-based tests (hypothesis): validation never crashes with anything but a ConfigError, log round trips
are exact, explicit laws and LMPC outputs are finite and within bounds for random models and states."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from kexp.clf import ClfConfig, QuadraticLyapunov, clf_from_P
from kexp.control import Lmpc, LmpcConfig, make_law
from kexp.data import DataConfig
from kexp.errors import ConfigError
from kexp.recording import read_log
from kexp.recording.schema import plain
from kexp.recording.writer import RunLogger

from toy import toy_model

anything = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10), st.none())


@given(dt=anything, T=anything, pairs=st.sampled_from(["next", "euler", "x", ""]))
@settings(max_examples=200, deadline=None)
def test_data_config_validates_or_says_why(dt, T, pairs):
    try:
        cfg = DataConfig(T=T, dt=dt, pairs=pairs)
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(exc)
    except TypeError:
        pytest.fail("a TypeError escaped validation")
    else:
        assert cfg.dt > 0 and cfg.T >= cfg.dt and cfg.pairs in ("next", "euler")


@given(gamma=anything, cl=anything, cu=anything)
@settings(max_examples=200, deadline=None)
def test_clf_config_validates_or_says_why(gamma, cl, cu):
    try:
        cfg = ClfConfig(gamma=gamma, c_lower=cl, c_upper=cu)
    except ConfigError:
        return
    except TypeError:
        pytest.fail("a TypeError escaped validation")
    assert 0 < cfg.c_lower < cfg.c_upper and cfg.gamma >= 0


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
payloads = st.fixed_dictionaries({
    "k": st.integers(0, 10 ** 6), "x": st.lists(floats, min_size=1, max_size=5), "V": floats,
    "region": st.text(max_size=10), "binds": st.booleans(),
    "nested": st.dictionaries(st.text(min_size=1, max_size=5), st.lists(floats, max_size=3), max_size=3)})


@given(msgs=st.lists(payloads, min_size=1, max_size=20))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_mcap_round_trip_of_arbitrary_records(msgs, tmp_path_factory):
    path = tmp_path_factory.mktemp("rt") / "a.mcap"
    lg = RunLogger(path)
    for i, m in enumerate(msgs):
        lg.write("/step", i * 0.01, m)
    lg.close()
    back = read_log(path).messages("/step")
    assert back == [_nonfinite_to_none(m) for m in msgs]  # NaN/inf become null, everything else exact
    assert back == [plain(m) for m in msgs]                 # as the writer's own normaliser says
    for m, orig in zip(back, msgs):
        assert all(v is None or math.isfinite(v) for v in m["x"])
        assert [v for v in m["x"] if v is not None] == [v for v in orig["x"] if math.isfinite(v)]


def _nonfinite_to_none(v):
    """The expected payload, written apart from the writer's code: non-finite floats null, the rest as it is."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {key: _nonfinite_to_none(x) for key, x in v.items()}
    if isinstance(v, list):
        return [_nonfinite_to_none(x) for x in v]
    return v


def _random_model(seed, k, m):
    rng = np.random.default_rng(seed)
    lam = np.diag(rng.uniform(-3, 1, k))
    B = rng.normal(size=(m, k, k))
    b = rng.normal(size=(m, k))
    return toy_model(lam, B, b)


@given(seed=st.integers(0, 2 ** 31), k=st.integers(2, 6), m=st.integers(1, 2),
       z=arrays(np.float64, 6, elements=st.floats(-1e3, 1e3)), law=st.sampled_from(["sontag", "lie_gain"]),
       lo=st.floats(-10, 0, exclude_max=True), width=st.floats(0.01, 20))
@settings(max_examples=60, deadline=None)
def test_explicit_laws_are_finite_and_within_bounds(seed, k, m, z, law, lo, width):
    model = _random_model(seed, k, m)
    lyap = QuadraticLyapunov.from_model(model, np.eye(k))
    h = make_law(law, lyap, lo, lo + width)
    u = h(z[:k][None])
    assert u.shape == (1, m) and np.all(np.isfinite(u)) and np.all((u >= lo) & (u <= lo + width))


@given(seed=st.integers(0, 2 ** 31), z=arrays(np.float64, 3, elements=st.floats(-5, 5)))
@settings(max_examples=25, deadline=None)
def test_lmpc_output_is_finite_and_within_bounds(seed, z):
    model = _random_model(seed, 3, 1)
    clf = clf_from_P(model, np.eye(3), ClfConfig(grid=5), u_min=-2.0, u_max=1.0)
    h = make_law("sontag", clf.lyap, -2.0, 1.0)
    ctrl = Lmpc(model, clf, h, LmpcConfig(horizon=10, blocks=None), -2.0, 1.0)
    for _ in range(3):
        st_ = ctrl.step(z, z)
        assert np.all(np.isfinite(st_.u)) and np.all((st_.u >= -2.0) & (st_.u <= 1.0))
        assert st_.status in ("solved", "fallback") and (st_.fallback == (st_.status == "fallback"))
