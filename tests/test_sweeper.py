"""kexp's batch check for Hydra's basic sweeper (kexp/app/sweeper.py): one composition per job structure, and a
bad group choice in any job still stops the sweep before the first job starts."""
import subprocess

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
    assert seen == [[batch[0], batch[50]]]


def test_a_bad_group_choice_in_a_later_job_stops_the_sweep_before_any_job(tmp_path):
    """controller=lmpc,nosuch: the second structure is composed in the check, so Hydra refuses the sweep and no
    job folder is written (not a failure half-way through)."""
    sweep = tmp_path / "sweep"
    proc: subprocess.CompletedProcess = _kexp_multirun(tmp_path, sweep, "controller=lmpc,nosuch",
                                                       "sim.x0=[0.5,0.5],[0.1,0.1]")
    assert proc.returncode != 0
    assert "nosuch" in proc.stderr
    assert not list(sweep.glob("*/summary.json"))
