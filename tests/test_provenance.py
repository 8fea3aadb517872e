"""A run records the lock it ran with; kexp-diff warns when two logs come from different package versions."""
import hashlib
import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from kexp.app.lock import lock_info
from kexp.app.conf import CONF_DIR
from kexp.app.experiment import run
from kexp.recording import copy_log, read_log

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


def _copy_with_run_info(src: Path, dst: Path, edit) -> None:
    """Rewrite a log, letting ``edit(run_info)`` change the /run_info payload."""
    copy_log(src, dst, lambda topic, payload: edit(payload) if topic == "/run_info" else None)


def test_diff_warns_when_logs_come_from_different_versions_but_still_exits_0(small_run, tmp_path, capsys):
    from kexp.recording import diff_logs
    from kexp.recording.diff import main as diff_main
    from kexp.recording.provenance import version_warnings
    mcap = small_run / "run.mcap"
    assert diff_logs(mcap, mcap).warnings == ()
    other = tmp_path / "other.mcap"

    def older(info):
        info["versions"]["numpy"] = "1.26.4"
        info["lock"] = {**info["lock"], "sha256": "ab" * 32}
    _copy_with_run_info(mcap, other, older)
    numpy = read_log(mcap).one("/run_info")["versions"]["numpy"]
    assert version_warnings(read_log(mcap), read_log(other)) == [
        f"the logs come from different package versions (run.mcap vs other.mcap): numpy {numpy} vs 1.26.4",
        f"the logs come from different lock files (sha256 {read_log(mcap).one('/run_info')['lock']['sha256'][:12]}"
        f" vs abababababab)"]
    res = diff_logs(mcap, other)
    assert res.equal and len(res.warnings) == 2
    assert diff_main([str(mcap), str(other)]) == 0
    captured = capsys.readouterr()
    assert "kexp-diff: warning: the logs come from different package versions" in captured.err
    assert "logs are equal" in captured.out
    # a log without a lock hash (an installed wheel, an older log) is no difference
    nolock = tmp_path / "nolock.mcap"
    _copy_with_run_info(mcap, nolock, lambda info: info.pop("lock"))
    assert version_warnings(read_log(mcap), read_log(nolock)) == []
