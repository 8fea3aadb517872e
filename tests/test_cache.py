"""The model/CLF cache: every setting that determines the model misses it, nothing else does (issue 11, item 7)."""
import dataclasses
import json

import pytest
from hydra import compose, initialize_config_dir

from kexp.app.cache import MODEL_GROUPS, clf_key, model_key
from kexp.app.conf import CONF_DIR
from kexp.app.experiment import config_dict, run
from kexp.app.schema import KexpConfig
from kexp.identify import FORMAT_VERSION

SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=0.5", "clf.grid=11", "logging.rrd=false", "logging.progress=false"]

# one changed setting in each group that determines the model: each must miss the model cache
MISS = [("system", "system.params.mu=1.5"), ("data", "data.T=4.0"), ("data", "data.seed=1"),
        ("data", "data.sampler.radius=2.0"), ("dictionary", "dictionary.degree=4"),
        ("dictionary", "dictionary.include_constant=false"), ("identification", "identification.rcond=1e-12"),
        ("identification", "identification.holdout=0.3")]
# settings of every other group: each must hit the model cache
HIT = [("clf", "clf.grid=21"), ("controller", "controller.lmpc.horizon=30"), ("controller", "controller.u_max=4.0"),
       ("controller", "controller.law=lie_gain"), ("sim", "sim.T=2.0"), ("sim", "sim.x0=[0.5,0.5]"),
       ("logging", "logging.mcap=false"), ("cache", "cache.dir=/tmp/elsewhere"), ("cache", "cache.enabled=false"),
       ("sweep", "sweep.resume=true")]


def _cfg(overrides=()):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="config", overrides=SMALL + list(overrides))


def _key(overrides=()):
    return model_key(config_dict(_cfg(overrides)), FORMAT_VERSION)


def test_every_group_is_classified():
    """A new config group must be added to MODEL_GROUPS or to HIT here: the test cannot pass silently."""
    groups = {f.name for f in dataclasses.fields(KexpConfig)}
    assert groups == set(MODEL_GROUPS) | {g for g, _ in HIT}
    assert set(MODEL_GROUPS) == {g for g, _ in MISS}


@pytest.mark.parametrize("group,override", MISS, ids=[o for _, o in MISS])
def test_a_setting_that_determines_the_model_misses_the_cache(group, override):
    assert _key([override]) != _key()


@pytest.mark.parametrize("group,override", HIT, ids=[o for _, o in HIT])
def test_other_settings_hit_the_model_cache(group, override):
    assert _key([override]) == _key()


def test_clf_key_follows_the_model_the_clf_group_and_the_input_bounds():
    base = config_dict(_cfg())
    key = clf_key("m", base, "sontag", {}, -5.0, 5.0)
    assert clf_key("m", base, "sontag", {}, -5.0, 5.0) == key
    assert clf_key("other", base, "sontag", {}, -5.0, 5.0) != key
    assert clf_key("m", config_dict(_cfg(["clf.grid=21"])), "sontag", {}, -5.0, 5.0) != key
    assert clf_key("m", base, "lie_gain", {}, -5.0, 5.0) != key
    assert clf_key("m", base, "sontag", {}, -5.0, 4.0) != key
    assert clf_key("m", config_dict(_cfg(["controller.lmpc.horizon=30", "sim.T=2.0"])), "sontag", {}, -5.0, 5.0) == key


def test_runs_report_hits_and_misses_under_the_model_key(tmp_path):
    """Three runs sharing one cache: the first computes, a controller/sim/logging change reuses both results, a
    data change identifies again; the entry names are the keys above (so run() builds its key with model_key)."""
    common = [f"cache.dir={tmp_path / 'cache'}"]

    def go(name, overrides):
        cfg = _cfg(common + overrides)
        run(cfg, tmp_path / name, echo=lambda *_: None)
        cache = json.loads((tmp_path / name / "summary.json").read_text())["cache"]
        return cache, f"model-{model_key(config_dict(cfg), FORMAT_VERSION)}.npz"

    first, name = go("a", [])
    assert first["hits"] == [] and len(first["misses"]) == 2 and first["misses"][0] == name
    second, name2 = go("b", ["controller.lmpc.horizon=15", "sim.T=0.3", "logging.mcap=false"])
    assert name2 == name and second["misses"] == [] and second["hits"] == first["misses"]
    third, name3 = go("c", ["data.seed=1"])
    assert name3 != name and third["hits"] == [] and third["misses"][0] == name3
