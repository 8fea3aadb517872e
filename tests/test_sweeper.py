"""kexp's batch check for Hydra's basic sweeper (kexp/app/sweeper.py): one composition per job structure, and a
bad group choice in any job still stops the sweep before the first job starts."""
import subprocess

import pytest

from kexp.app.sweeper import install, representatives, structure_of

from test_sweep import _kexp_multirun


def test_structure_keeps_group_choices_and_drops_values_of_dotted_keys():
    assert structure_of("sim.x0=[0.1,0.2]") == "sim.x0=<value>"
    assert structure_of("controller.lmpc.horizon=50") == "controller.lmpc.horizon=<value>"
    assert structure_of("controller=lqr") == "controller=lqr"
    assert structure_of("+experiment=vanderpol") == "+experiment=vanderpol"
    assert structure_of("hydra/launcher=joblib") == "hydra/launcher=joblib"
    assert structure_of("~clf.grid") == "~clf.grid"
    assert structure_of("+sim.extra=1") == "+sim.extra=1"     # an addition may fail per value: composed each


def test_one_representative_per_structure_in_order():
    batch = [["controller=lmpc", f"sim.x0=[{i},0]"] for i in range(100)]
    batch += [["controller=lqr", f"sim.x0=[{i},0]"] for i in range(100)]
    assert representatives(batch) == [batch[0], batch[100]]
    assert representatives([]) == []


def test_install_checks_the_representatives_only(monkeypatch):
    """install() wraps the basic sweeper's check (whatever it is) so it sees one job per structure; twice is once."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    seen = []
    monkeypatch.setattr(BasicSweeper, "validate_batch_is_legal", lambda self, batch: seen.append(list(batch)))
    install()
    install()
    batch = [["+experiment=vanderpol", f"sim.x0=[{i},0]"] for i in range(50)] + [["+experiment=pendulum",
                                                                                 "sim.x0=[0,0]"]]
    BasicSweeper.validate_batch_is_legal(None, batch)
    assert seen == [[batch[0]], [batch[50]]]


def test_a_bad_group_choice_in_a_later_job_stops_the_sweep_before_any_job(tmp_path):
    """controller=lmpc,nosuch: the second structure is composed in the check, so Hydra refuses the sweep and no
    job folder is written (not a failure half-way through)."""
    sweep = tmp_path / "sweep"
    proc: subprocess.CompletedProcess = _kexp_multirun(tmp_path, sweep, "controller=lmpc,nosuch",
                                                       "sim.x0=[0.5,0.5],[0.1,0.1]")
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert err[-1].startswith("kexp: error: In 'config': Could not find 'controller/nosuch' Available options in "
                              "'controller': lie_gain lmpc lqr model_lqr nmpc sontag"), err
    assert err[-1].endswith("(the sweep's jobs with controller=nosuch; no job started)"), err
    assert not list(sweep.glob("*/summary.json"))


@pytest.mark.parametrize("swept,override,where", [
    (["controller=lqr", "controller.lmpc.horizon=20,30"], "controller.lmpc.horizon=20,30", "(no job started)"),
    (["controller=lmpc,lqr", "controller.lmpc.horizon=20"], "controller.lmpc.horizon=20",
     "(the sweep's jobs with controller=lqr; no job started)")])
def test_a_key_a_job_s_choice_leaves_null_stops_the_sweep_with_one_line(tmp_path, swept, override, where):
    """controller.lmpc.horizon with controller=lqr (no lmpc node): in the sweep's master config, or in the check of
    each job structure, one line naming the override and the choice, exit code 2, no job (was OmegaConf's
    AssertionError, a traceback)."""
    sweep = tmp_path / "sweep"
    proc = _kexp_multirun(tmp_path, sweep, *swept)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert err == [f"kexp: error: {override}: controller.lmpc is null in this config (this controller is kind 'lqr'), "
                   f"so it has no keys to set; drop the override, or choose a controller that has controller.lmpc "
                   f"{where}"]
    assert not list(sweep.glob("*/summary.json"))


def _master(overrides):
    from hydra._internal.utils import create_config_search_path
    from hydra.core.utils import JobRuntime
    from hydra.types import RunMode

    from kexp.app.conf import CONF_DIR
    from kexp.app.sweeper import StructureCachingConfigLoader
    JobRuntime.instance().set("name", "kexp")
    loader = StructureCachingConfigLoader(config_search_path=create_config_search_path(CONF_DIR))
    return loader, loader.load_configuration("config", overrides=overrides, run_mode=RunMode.MULTIRUN)


def test_a_worker_composes_once_per_structure_and_equals_hydra():
    """compose_job: the second and later jobs of a structure come from a copy of the first with their own values
    and override lists applied, and equal Hydra's own composition of them key for key (values of dotted keys, in
    lists and nested, of the app and of Hydra; a group choice; the override lists and override_dirname)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from omegaconf import OmegaConf

    from kexp.app import sweeper
    loader, master = _master(["hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "hydra.sweep.dir=/tmp/kexp-s"])
    sweeper._COMPOSED.clear()
    calls = []
    real = ConfigLoaderImpl.load_sweep_config

    def counting(self, m, o):
        calls.append(list(o))
        return real(self, m, o)

    ConfigLoaderImpl.load_sweep_config = counting
    try:
        jobs = [["+experiment=vanderpol", f"sim.x0=[{a},{b}]", f"controller.lmpc.horizon={h}", f"sim.T={t}"]
                for a, b, h, t in ((0.5, -0.25, 20, 1.0), (-0.75, 0.125, 35, 2.5), (1.0, 0.0, 20, 4.0))]
        jobs += [["+experiment=pendulum", "controller=lqr", "sim.x0=[0.3,0.1]"],
                 ["+experiment=pendulum", "controller=lqr", "sim.x0=[-0.3,0.2]"]]
        got = [sweeper.compose_job(loader, master, j) for j in jobs]
        assert calls == [jobs[0], jobs[3]]               # Hydra composed once per structure
        for job, cfg in zip(jobs, got):
            ref = real(loader, master, job)
            assert OmegaConf.to_container(cfg, resolve=False) == OmegaConf.to_container(ref, resolve=False)
        assert list(got[1].sim.x0) == [-0.75, 0.125] and got[1].controller.lmpc.horizon == 35
        assert got[4].hydra.job.override_dirname == "+experiment=pendulum,controller=lqr,sim.x0=[-0.3,0.2]"
    finally:
        ConfigLoaderImpl.load_sweep_config = real
        sweeper._COMPOSED.clear()
