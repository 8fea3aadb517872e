"""Bad arguments to systems, dictionaries, identification and models are refused at once, with one line that
names the field, the bad value and what to do (no numpy traceback later, no silent acceptance, no hang)."""
import dataclasses
import json

import numpy as np
import pytest

from kexp.data import Circle, DataConfig, collect
from kexp.dictionary import Monomials
from kexp.errors import ConfigError, DataError, KexpError, ModelFileError, SystemDefinitionError
from kexp.identify import IdentifyConfig, KoopmanBilinearModel, identify
from kexp.identify.quality import prediction_error
from kexp.systems import Duffing, Linear, Pendulum, SlowManifold, VanDerPol, make_system

NAN, INF = float("nan"), float("inf")


@pytest.fixture(scope="module")
def vdp_data():
    s = VanDerPol()
    return collect(s, Circle(30, 2.0), DataConfig(T=3.0))


@pytest.fixture(scope="module")
def model(vdp_data):
    return identify(VanDerPol(), vdp_data, Monomials(2, 3))


def _refused(call, kind, fragment) -> str:
    """``call()`` raises ``kind`` (or a subclass) with a one-line message holding ``fragment``; returns it."""
    with pytest.raises(kind) as exc_info:
        call()
    msg = str(exc_info.value)
    assert "\n" not in msg
    assert fragment in msg, msg
    return msg


SYSTEM_CALLS = [
    (lambda: VanDerPol(mu=NAN), "mu=nan"),
    (lambda: VanDerPol(mu=INF), "mu=inf"),
    (lambda: VanDerPol(mu="a"), "mu='a'"),
    (lambda: Pendulum(c=None), "c=None"),
    (lambda: Duffing(alpha=INF), "alpha=inf"),
    (lambda: Duffing(beta="x"), "beta='x'"),
    (lambda: SlowManifold(mu=NAN), "mu=nan"),
    (lambda: make_system("vanderpol", {"mu": True}), "mu=True"),
    (lambda: make_system("pendulum", {"c": [1, 2]}), "c=[1, 2]"),
    (lambda: make_system(None), "system name None"),
    (lambda: make_system(5), "system name 5"),
    (lambda: make_system("vanderpol", "mu=2"), "params='mu=2'"),
    (lambda: make_system("linear", {"A": "ab"}), "A='ab'"),
    (lambda: Linear(A=[[1, 2], [3]]), "give a matrix of numbers"),
    (lambda: Linear(A=[[True]], B=[[1.0]]), "A=[[True]]"),
]


@pytest.mark.parametrize("call, fragment", SYSTEM_CALLS)
def test_bad_system_parameters_are_refused(call, fragment):
    _refused(call, SystemDefinitionError, fragment)


def test_valid_system_parameters_still_accepted():
    assert VanDerPol(mu=0).mu == 0 and VanDerPol(mu=-1.0).mu == -1.0 and VanDerPol(mu=2).mu == 2
    assert Pendulum(c=np.float64(-0.1)).c == -0.1
    assert make_system("linear", {"A": [[-1.0]], "B": [[1.0]]}).n == 1
    assert make_system("kexp.systems:VanDerPol", {"mu": 2.0}).mu == 2.0


def test_nan_parameter_no_longer_reaches_the_integrator():
    # before: VanDerPol(mu=nan) was accepted and collect() looped forever in scipy's solve_ivp
    with pytest.raises(SystemDefinitionError, match="mu=nan"):
        collect(VanDerPol(mu=NAN), Circle(3, 1.0), DataConfig(T=0.1))


DICTIONARY_CALLS = [
    (lambda: Monomials(True, 3), "dictionary.n=True"),
    (lambda: Monomials(2, True), "dictionary.degree=True"),
    (lambda: Monomials(2, 3, include_constant="no"), "include_constant='no'"),
    (lambda: Monomials(2, 3, weights=(1.5, 1)), "weights=(1.5, 1)"),
    (lambda: Monomials(2, 3, weights=(True, 1)), "weights=(True, 1)"),
    (lambda: Monomials(2, 3, weights="ab"), "weights='ab'"),
    (lambda: Monomials(2, 3, weights=5), "weights=5"),
    (lambda: Monomials(2, 3, scale="x"), "scale='x'"),
    (lambda: Monomials(2, 3, scale=[[1, 2]]), "scale=[[1, 2]]"),
    (lambda: Monomials(2, 3, scale=[1, None]), "scale=[1, None]"),
    (lambda: Monomials(2, 3).lift("ab"), "of numbers"),
]


@pytest.mark.parametrize("call, fragment", DICTIONARY_CALLS)
def test_bad_dictionary_settings_are_refused(call, fragment):
    _refused(call, ConfigError, fragment)


def test_valid_dictionary_settings_unchanged():
    d = Monomials(np.int64(2), 3, include_constant=np.bool_(False), weights=np.array([1, 2]), scale=2)
    assert d.weights == (1, 2) and d.scale == (2.0, 2.0)
    assert Monomials(2, 3, scale=(1.0, 2.0)).scale == (1.0, 2.0)


CONFIG_CALLS = [
    (dict(keep=2.5), "identification.keep=2.5"),
    (dict(keep=True), "identification.keep=True"),
    (dict(keep=NAN), "identification.keep=nan"),
    (dict(keep="3"), "identification.keep='3'"),
    (dict(max_residual="x"), "identification.max_residual='x'"),
    (dict(max_residual=True), "identification.max_residual=True"),
    (dict(residual_horizon=INF), "identification.residual_horizon=inf"),
    (dict(prediction_horizon=INF), "identification.prediction_horizon=inf"),
    (dict(compare_projection="no"), "identification.compare_projection='no'"),
]


@pytest.mark.parametrize("kwargs, fragment", CONFIG_CALLS)
def test_bad_identify_config_is_refused(kwargs, fragment):
    _refused(lambda: IdentifyConfig(**kwargs), ConfigError, fragment)


def test_valid_identify_config_still_accepted():
    IdentifyConfig(keep=np.int64(4), max_residual=INF, residual_horizon=1e3, compare_projection=np.bool_(True))


def _identify_calls(vdp_data):
    d = Monomials(2, 3)
    return {
        "pendulum on vdp data": (lambda: identify(make_system("pendulum"), vdp_data, d), DataError,
                                 "collected with system 'vanderpol'"),
        "holdout took all": (lambda: identify(VanDerPol(), vdp_data, d, IdentifyConfig(holdout=0.99)), DataError,
                             "identification.holdout=0.99 holds out all 30 trajectories"),
        "config None": (lambda: identify(VanDerPol(), vdp_data, d, None), ConfigError, "config=None"),
        "dataset None": (lambda: identify(VanDerPol(), None, d), ConfigError, "dataset=None"),
        "dictionary None": (lambda: identify(VanDerPol(), vdp_data, None), ConfigError, "dictionary=None"),
    }


@pytest.mark.parametrize("case", ["pendulum on vdp data", "holdout took all", "config None", "dataset None",
                                  "dictionary None"])
def test_bad_identify_arguments_are_refused(vdp_data, case):
    call, kind, fragment = _identify_calls(vdp_data)[case]
    _refused(call, kind, fragment)


def test_pendulum_data_with_vdp_system_refused():
    p = make_system("pendulum")
    data = collect(p, Circle(5, 1.0), DataConfig(T=0.5))
    with pytest.raises(DataError, match="collected with system 'pendulum'"):
        identify(VanDerPol(), data, Monomials(2, 2))


def test_dataset_without_a_system_name_is_not_compared(vdp_data):
    unnamed = dataclasses.replace(vdp_data, system_name="recorded")   # what read_runs gives without a name
    assert identify(make_system("pendulum"), unnamed, Monomials(2, 2)).system == "pendulum"


def test_prediction_error_refuses_other_dt_and_dimension(model):
    s = VanDerPol()
    with pytest.raises(DataError, match=r"dt=0.02, the model at dt=0.01"):
        prediction_error(model, collect(s, Circle(5, 1.0), DataConfig(T=0.5, dt=0.02)), 1)
    lin = make_system("linear", {"A": -np.eye(3), "B": np.ones((3, 1))})
    with pytest.raises(DataError, match="n=3 states, the model n=2"):
        prediction_error(model, collect(lin, Circle(5, 1.0), DataConfig(T=0.5)), 1)


def _edited_copy(model, tmp_path, name, edit_meta=None, edit_arrays=None):
    src = model.save(tmp_path / "good.npz")
    with np.load(src, allow_pickle=False) as f:
        z = {k: f[k] for k in f.files}
    meta = json.loads(str(z["meta"]))
    if edit_meta:
        edit_meta(meta)
    if edit_arrays:
        edit_arrays(z)
    z["meta"] = np.array(json.dumps(meta))
    path = tmp_path / name
    np.savez(path, **z)
    return path


def _set(key, value):
    return lambda d: d.__setitem__(key, value)


BAD_FILES = [
    ("negdt.npz", _set("dt", -1.0), None, "dt=-1.0"),
    ("nandt.npz", _set("dt", "abc"), None, "dt='abc'"),
    ("nodict.npz", lambda m: m.pop("dictionary"), None, "missing 'dictionary'"),
    ("baddict.npz", _set("dictionary", {"n": 2, "degree": "x"}), None, "dictionary kind"),
    ("nanxeq.npz", None, _set("x_eq", np.array([np.nan, 0.0])), "x_eq contains NaN"),
    ("shortxeq.npz", None, _set("x_eq", np.array([0.0])), "x_eq"),
    ("badnames.npz", _set("state_names", 5), None, "TypeError"),
]


@pytest.mark.parametrize("name, edit_meta, edit_arrays, fragment", BAD_FILES)
def test_damaged_model_files_are_refused(model, tmp_path, name, edit_meta, edit_arrays, fragment):
    path = _edited_copy(model, tmp_path, name, edit_meta, edit_arrays)
    msg = _refused(lambda: KoopmanBilinearModel.load(path), ModelFileError, fragment)
    assert name in msg and "re-run identification" in msg


def test_good_model_file_round_trips(model, tmp_path):
    assert KoopmanBilinearModel.load(model.save(tmp_path / "m.npz")) == model


MODEL_CALLS = [
    (lambda m: KoopmanBilinearModel.load(None), "load(path=None)"),
    (lambda m: dataclasses.replace(m, dt=NAN), "model dt=nan"),
    (lambda m: dataclasses.replace(m, dt=-1.0), "model dt=-1.0"),
    (lambda m: dataclasses.replace(m, dt="0.01"), "model dt='0.01'"),
    (lambda m: dataclasses.replace(m, x_eq=np.array([NAN, 0.0])), "x_eq contains NaN"),
    (lambda m: m.lift([1.0, 2.0, 3.0]), "with n=2, got (3,)"),
    (lambda m: m.lift(1.0), "with n=2, got ()"),
    (lambda m: m.predict([1.0, 2.0, 3.0], np.zeros((5, 1))), "x0 must have shape (2,), got (3,)"),
    (lambda m: m.step_matrices([1.0, 2.0]), "u must have shape (1,), got (2,)"),
    (lambda m: m.free_response(np.zeros((1, m.k)), -1), "steps=-1"),
    (lambda m: m.free_response(np.zeros((1, m.k)), 2.5), "steps=2.5"),
    (lambda m: m.free_response(np.zeros((1, 3)), 2), "z0 must have shape"),
]


@pytest.mark.parametrize("call, fragment", MODEL_CALLS)
def test_bad_model_arguments_are_refused(model, call, fragment):
    _refused(lambda: call(model), ConfigError, fragment)


def test_valid_model_calls_unchanged(model):
    x = np.array([0.3, -0.2])
    assert np.array_equal(model.lift(x), model.lift(x[None])[0])
    assert model.lift(np.zeros((2, 3, 2))).shape == (6, model.k)
    xa, _ = model.predict(x, np.zeros((3, 1)))
    xb, _ = model.predict(x[None], np.zeros((3, 1)))
    assert np.array_equal(xa, xb)
    assert model.free_response(model.lift(x[None]), 0).shape == (1, 1, model.k)
    assert all(issubclass(k, KexpError) for k in (ConfigError, DataError, ModelFileError))
