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
        ("data", "data.sampler.radius=2.0"),
        ("data", "data.excitation={low: -1.0, high: 1.0, hold: 10}"), ("dictionary", "dictionary.degree=4"),
        ("dictionary", "dictionary.include_constant=false"), ("identification", "identification.rcond=1e-12"),
        ("identification", "identification.holdout=0.3")]
# settings of every other group: each must hit the model cache
HIT = [("clf", "clf.grid=21"), ("controller", "controller.lmpc.horizon=30"), ("controller", "controller.u_max=4.0"),
       ("controller", "controller.law=lie_gain"), ("sim", "sim.T=2.0"), ("sim", "sim.x0=[0.5,0.5]"),
       ("logging", "logging.mcap=false"), ("cache", "cache.dir=/tmp/elsewhere"), ("cache", "cache.enabled=false"),
       ("sweep", "sweep.resume=true"),
       ("plant", "plant=python")]   # with simulated data; data from a plant key the plant (test_plants.py)


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
    m, other = _key(), _key(["data.seed=1"])
    key = clf_key(m, base, "sontag", {}, -5.0, 5.0)
    assert clf_key(m, base, "sontag", {}, -5.0, 5.0) == key
    assert clf_key(other, base, "sontag", {}, -5.0, 5.0) != key
    assert clf_key(m, config_dict(_cfg(["clf.grid=21"])), "sontag", {}, -5.0, 5.0) != key
    assert clf_key(m, base, "lie_gain", {}, -5.0, 5.0) != key
    assert clf_key(m, base, "sontag", {}, -5.0, 4.0) != key
    assert clf_key(m, config_dict(_cfg(["controller.lmpc.horizon=30", "sim.T=2.0"])), "sontag", {}, -5.0, 5.0) == key
    assert key.name.startswith("clf-") and key.name != clf_key(other, base, "sontag", {}, -5.0, 5.0).name


def test_runs_report_hits_and_misses_under_the_model_key(tmp_path):
    """Three runs sharing one cache: the first computes, a controller/sim/logging change reuses both results, a
    data change identifies again; the entry names are the keys above (so run() builds its key with model_key)."""
    common = [f"cache.dir={tmp_path / 'cache'}"]

    def go(name, overrides):
        cfg = _cfg(common + overrides)
        run(cfg, tmp_path / name, echo=lambda *_: None)
        cache = json.loads((tmp_path / name / "summary.json").read_text())["cache"]
        return cache, model_key(config_dict(cfg), FORMAT_VERSION).name

    first, name = go("a", [])
    assert first["hits"] == [] and len(first["misses"]) == 2 and first["misses"][0] == name
    second, name2 = go("b", ["controller.lmpc.horizon=15", "sim.T=0.3", "logging.mcap=false"])
    assert name2 == name and second["misses"] == [] and second["hits"] == first["misses"]
    third, name3 = go("c", ["data.seed=1"])
    assert name3 != name and third["hits"] == [] and third["misses"][0] == name3


# -- an entry proves what it is: its key is stored in it and checked on load (issue 32) ---------------------------
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from kexp.app.cache import CLF_CODE, MODEL_CODE, Cache, code_digest, read_key  # noqa: E402
from kexp.identify import KoopmanBilinearModel  # noqa: E402

KEXP = Path(__file__).resolve().parents[1] / "kexp"


def test_the_files_digest_and_the_code_are_in_the_model_key():
    cfg = config_dict(_cfg())
    simulated, a, b = (model_key(cfg, FORMAT_VERSION, d) for d in (None, "a" * 16, "b" * 16))
    assert len({simulated, a, b}) == 3 and len({k.name for k in (simulated, a, b)}) == 3
    parts = simulated.parts
    assert parts["code"] == code_digest(MODEL_CODE) and parts["format"] == FORMAT_VERSION
    assert parts["data"]["excitation"] is None and parts["system"]["name"] == "vanderpol"
    assert model_key(cfg, FORMAT_VERSION + 1) != simulated


def _run(tmp_path, name, overrides, lines=None):
    cfg = _cfg([f"cache.dir={tmp_path / 'cache'}", "logging.mcap=false"] + overrides)
    run(cfg, tmp_path / name, echo=(lambda *_: None) if lines is None else lines.append)
    return json.loads((tmp_path / name / "summary.json").read_text()), cfg


def test_an_entry_copied_over_another_systems_name_is_a_miss_with_a_warning(tmp_path):
    """The pendulum's model entry copied over Van der Pol's (both n = 2): the key stored in the entry says
    pendulum, so the Van der Pol run warns once, identifies again and gets the same model and cost as at first."""
    first, cfg = _run(tmp_path, "vdp", [])
    _run(tmp_path, "pend", ["system=pendulum"])
    vdp_entry = tmp_path / "cache" / model_key(config_dict(cfg), FORMAT_VERSION).name
    pend_entry = tmp_path / "cache" / model_key(config_dict(_cfg(["system=pendulum"])), FORMAT_VERSION).name
    shutil.copyfile(pend_entry, vdp_entry)
    lines = []
    again, _ = _run(tmp_path, "vdp2", [], lines)
    warned = [line for line in lines if line.startswith("warning: cache entry")]
    assert len(warned) == 1 and "system." in warned[0] and "pendulum" in warned[0] and "\n" not in warned[0], lines
    assert vdp_entry.name in again["cache"]["misses"] and vdp_entry.name not in again["cache"]["hits"]
    assert KoopmanBilinearModel.load(tmp_path / "vdp2" / "model.npz") == KoopmanBilinearModel.load(
        tmp_path / "vdp" / "model.npz")
    assert again["metrics"]["cost"] == first["metrics"]["cost"]
    assert read_key(vdp_entry) == model_key(config_dict(cfg), FORMAT_VERSION).text   # replaced by the right one
    third, _ = _run(tmp_path, "vdp3", [])
    assert third["cache"]["hits"][0] == vdp_entry.name


def test_an_entry_without_a_key_or_unreadable_is_recomputed_with_a_warning(tmp_path):
    from kexp.app.cache import Key
    seen, made = [], []
    cache = Cache(tmp_path, warn=seen.append)
    key = Key("model", {"x": 1})

    def save(v, p):
        np.savez(p, v=np.array(v))

    def create():
        made.append(1)
        return 7.0

    load = lambda p: float(np.load(p)["v"])  # noqa: E731
    np.savez(tmp_path / key.name, v=np.array(3.0))               # the right name, but no key inside
    assert cache.get_or_create(key, create, save, load) == 7.0 and len(seen) == 1 and "records no key" in seen[0]
    assert cache.get_or_create(key, create, save, load) == 7.0 and len(made) == 1 and len(seen) == 1   # a hit
    (tmp_path / key.name).write_bytes(b"not a zip")
    assert cache.get_or_create(key, create, save, load) == 7.0 and len(made) == 2 and len(seen) == 2
    other = Key("model", {"x": 2})
    shutil.copyfile(tmp_path / key.name, tmp_path / other.name)
    assert cache.get_or_create(other, lambda: 8.0, save, load) == 8.0
    assert len(seen) == 3 and "x=1 (want 2)" in seen[2], seen


def test_changed_recorded_files_at_the_same_path_miss_the_model_cache(tmp_path):
    from kexp.data import Circle, DataConfig, collect, write_runs
    from kexp.systems import make_system
    names = []
    for seed in (0, 1):
        data = collect(make_system("vanderpol"), Circle(n_traj=20, radius=2.5), DataConfig(T=3.0, seed=seed))
        shutil.rmtree(tmp_path / "runs", ignore_errors=True)
        write_runs(data, tmp_path / "runs", "npz")
        summary, _ = _run(tmp_path, f"files{seed}", ["data.source.kind=files", f"data.source.path={tmp_path / 'runs'}"])
        assert summary["cache"]["hits"] == []
        names.append(summary["cache"]["misses"][0])
    assert names[0] != names[1]


def test_a_change_of_the_source_code_changes_the_key(tmp_path):
    """A copy of kexp's sources: a change in kexp/identify changes the model's and the CLF's code digest, one in
    kexp/clf only the CLF's, one in the controller neither (a controller sweep keeps its model)."""
    root = tmp_path / "kexp"
    shutil.copytree(KEXP, root, ignore=shutil.ignore_patterns("__pycache__"))
    digests = lambda: (code_digest(MODEL_CODE, root), code_digest(CLF_CODE, root))  # noqa: E731
    base = digests()
    assert base == (code_digest(MODEL_CODE), code_digest(CLF_CODE))      # the bytes, not the place
    code_digest.cache_clear()
    with open(root / "control" / "lmpc.py", "a") as f:
        f.write("\n# changed\n")
    assert digests() == base
    code_digest.cache_clear()
    with open(root / "clf" / "synthesis.py", "a") as f:
        f.write("\n# changed\n")
    after_clf = digests()
    assert after_clf[0] == base[0] and after_clf[1] != base[1]
    code_digest.cache_clear()
    with open(root / "identify" / "eigen.py", "a") as f:
        f.write("\n# changed\n")
    after_identify = digests()
    assert after_identify[0] != base[0] and after_identify[1] not in (base[1], after_clf[1])
    code_digest.cache_clear()


def test_a_run_with_changed_identification_code_does_not_get_the_old_model(tmp_path):
    """Through the `kexp` command run from a copy of the sources (PYTHONPATH): a warm cache serves the model to
    the unchanged copy; after kexp/identify/eigen.py changed, the same config identifies again."""
    src = tmp_path / "src"
    shutil.copytree(KEXP, src / "kexp", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(KEXP.parent / "conf", src / "conf")            # the package's configs, beside it as in the repo
    cmd = [str(Path(sys.executable).parent / "kexp"), *(o for o in SMALL if not o.startswith("controller")), "controller=lqr",
           "logging.mcap=false",
           f"cache.dir={tmp_path / 'cache'}"]
    env = {**__import__("os").environ, "PYTHONPATH": str(src)}
    where = subprocess.run([sys.executable, "-c", "import kexp; print(kexp.__file__)"], env=env,
                           capture_output=True, text=True, cwd=tmp_path).stdout.strip()
    assert where == str(src / "kexp" / "__init__.py")       # the copy is the code that runs

    def go(name):
        proc = subprocess.run(cmd + [f"hydra.run.dir={tmp_path / name}"], env=env, capture_output=True, text=True,
                              timeout=600, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads((tmp_path / name / "summary.json").read_text())["cache"]

    first = go("a")
    assert first["hits"] == [] and len(first["misses"]) == 2
    assert go("b")["hits"] == first["misses"]
    with open(src / "kexp" / "identify" / "eigen.py", "a") as f:
        f.write("\nTOLERANCE_CHANGED = True\n")
    third = go("c")
    assert third["hits"] == [] and first["misses"][0] not in third["misses"] and len(third["misses"]) == 2


def test_reproduce_script_reruns_with_a_fresh_cache_of_its_own(tmp_path):
    """results/reproduce.sh with kexp stubbed (it records $KEXP_CACHE_DIR and whether that folder exists and is
    empty): the re-runs get a new temporary cache, not the caller's, removed when the script ends."""
    import os
    root = tmp_path / "repo"
    shutil.copytree(KEXP.parent / "results", root / "results", ignore=shutil.ignore_patterns("*.csv", "*.md"))
    shutil.copyfile(KEXP.parent / "results" / "vanderpol_lmpc.csv", root / "results" / "vanderpol_lmpc.csv")
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    seen = tmp_path / "seen"
    (bin_dir / "kexp").write_text(f'#!/bin/sh\n{{ echo "$KEXP_CACHE_DIR"; [ -d "$KEXP_CACHE_DIR" ] && '
                                  f'ls -A "$KEXP_CACHE_DIR" | wc -l; }} > "{seen}"\n')
    (bin_dir / "kexp-results").write_text(
        f'#!/bin/sh\nif [ "$1" = collect ]; then exit 0; fi\n'
        f'exec "{sys.executable}" -c "import sys; from kexp.results.cli import main; main(sys.argv[1:])" "$@"\n')
    for f in bin_dir.iterdir():
        f.chmod(0o755)
    mine = tmp_path / "my-cache"
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "KEXP_CACHE_DIR": str(mine),
           "TMPDIR": str(tmp_path)}
    proc = subprocess.run(["bash", "results/reproduce.sh", "--sample", "1", "results/vanderpol_lmpc.csv"], env=env,
                          capture_output=True, text=True, cwd=root)
    assert proc.returncode == 1 and "no re-run" in proc.stdout, proc.stdout + proc.stderr   # collect is stubbed
    used, count = seen.read_text().split()
    assert Path(used).parent == tmp_path and Path(used).name.startswith("kexp-reproduce-cache.") and count == "0"
    assert not Path(used).exists() and not mine.exists()
