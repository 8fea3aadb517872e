"""A run records the lock it ran with; kexp-diff warns when two logs come from different package versions."""
import hashlib
import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from kexp.app.lock import lock_info
from kexp.app.main import CONF_DIR, run
from kexp.recording import read_log

REPO = Path(__file__).resolve().parents[1]
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=1.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
         "cache.enabled=false"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="config", overrides=SMALL)
    run(cfg, out, echo=lambda *_: None)
    return out


def test_summary_and_run_info_record_the_repositorys_lock(small_run):
    summary = json.loads((small_run / "summary.json").read_text())
    sha = hashlib.sha256((REPO / "requirements.lock").read_bytes()).hexdigest()
    here = lock_info()
    assert summary["lock"]["file"] == "requirements.lock" and summary["lock"]["sha256"] == sha
    assert summary["lock"]["matches"] is here.matches and summary["lock"]["note"] == here.note
    assert (here.note == "") is here.matches     # a mismatch names the pins that differ
    info = read_log(small_run / "run.mcap").one("/run_info")
    assert info["lock"] == summary["lock"] and info["versions"] == summary["versions"]
