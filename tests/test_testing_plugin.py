"""The kexp_golden pytest plugin (kexp.testing), exercised as a user would: a test file in a fresh project run by
pytest (pytester), against real run logs."""
import shutil

import pytest

from kexp import testing
from kexp.app import golden
from kexp.recording import copy_log
from kexp.recording.policy import POLICIES

pytest_plugins = "pytester"

RUN = golden.RECORDINGS / "paper_pendulum.mcap"     # a real 2-s run log

USER_TEST = """
def test_mine(kexp_golden):
    kexp_golden.check("runs/run1", "pendulum_run")
"""


@pytest.fixture
def project(pytester):
    """A user's project: a run folder runs/run1 (holding run.mcap) and a test that checks it."""
    (pytester.path / "runs" / "run1").mkdir(parents=True)
    shutil.copyfile(RUN, pytester.path / "runs" / "run1" / "run.mcap")
    pytester.makepyfile(test_user=USER_TEST)
    return pytester


def test_plugin_is_registered_by_the_entry_point(pytester):
    res = pytester.runpytest_subprocess("--help")
    res.stdout.fnmatch_lines(["*--kexp-regen*"])
    assert testing.POLICIES == POLICIES


def test_missing_golden_is_written_then_the_test_passes(project):
    first = project.runpytest()
    first.assert_outcomes(failed=1)
    first.stdout.fnmatch_lines(["*goldens/pendulum_run.mcap did not exist; written*"])
    written = project.path / "goldens" / "pendulum_run.mcap"
    assert written.read_bytes() == RUN.read_bytes()
    project.runpytest().assert_outcomes(passed=1)


def test_a_changed_run_fails_with_its_first_divergence(project):
    project.runpytest()                                     # writes the golden
    run = project.path / "runs" / "run1" / "run.mcap"
    run.unlink()   # a log is created exclusively: the changed run replaces the first
    copy_log(RUN, run, lambda t, p: p["u"].__setitem__(0, p["u"][0] - 0.01) if t == "/step" and p["k"] == 57 else None)
    res = project.runpytest()
    res.assert_outcomes(failed=1)
    res.stdout.fnmatch_lines(["*differs from golden*(portable policy)*",
                              "*first divergence: channel /step, step 57 (t = 0.57 s), field u[[]0[]]:*",
                              "*/step*200 messages compared,*1 different*",
                              "*pytest --kexp-regen*"])
    assert "Traceback" not in res.stdout.str()


def test_regen_rewrites_the_golden_and_fails_once(project):
    project.runpytest()
    run = project.path / "runs" / "run1" / "run.mcap"
    run.unlink()   # a log is created exclusively: the changed run replaces the first
    copy_log(RUN, run, lambda t, p: p.update(V=p["V"] * 2) if t == "/step" and p["k"] == 3 else None)
    project.runpytest().assert_outcomes(failed=1)
    regen = project.runpytest("--kexp-regen")
    regen.assert_outcomes(failed=1)
    regen.stdout.fnmatch_lines(["*regenerated (--kexp-regen)*"])
    assert (project.path / "goldens" / "pendulum_run.mcap").read_bytes() == run.read_bytes()
    project.runpytest().assert_outcomes(passed=1)


def test_rounding_passes_portable_and_fails_exact(project):
    project.runpytest()
    run = project.path / "runs" / "run1" / "run.mcap"
    run.unlink()   # a log is created exclusively: the changed run replaces the first
    copy_log(RUN, run, lambda t, p: p.update(V=p["V"] * (1 + 1e-13)) if t == "/step" else None)
    project.runpytest().assert_outcomes(passed=1)
    project.makepyfile(test_user=USER_TEST.replace('"pendulum_run")', '"pendulum_run", policy="exact")'))
    project.runpytest().assert_outcomes(failed=1)
    project.makeini("[pytest]\nkexp_golden_policy = exact\n")
    project.makepyfile(test_user=USER_TEST)
    project.runpytest().assert_outcomes(failed=1)


def test_golden_dir_option_and_bad_arguments(pytester):
    shutil.copyfile(RUN, pytester.path / "a.mcap")
    pytester.makeini("[pytest]\nkexp_golden_dir = recordings/logs\n")
    pytester.makepyfile(test_user="""
import pytest

def test_dir(kexp_golden):
    kexp_golden.check("a.mcap", "a")

def test_bad_name(kexp_golden):
    with pytest.raises(ValueError, match="golden name '../a'"):
        kexp_golden.check("a.mcap", "../a")

def test_missing_run(kexp_golden):
    with pytest.raises(FileNotFoundError, match="no run log at"):
        kexp_golden.check("nowhere", "a")

def test_bad_policy(kexp_golden):
    with pytest.raises(ValueError, match="policy 'loose'"):
        kexp_golden.check("a.mcap", "a", policy="loose")
""")
    res = pytester.runpytest()
    res.assert_outcomes(failed=1, passed=3)
    assert (pytester.path / "recordings" / "logs" / "a.mcap").exists()
    pytester.runpytest().assert_outcomes(passed=4)


def test_the_readme_worked_example_runs_as_written(pytester, tmp_path):
    """The docs' example (docs/guides/pytest-plugin.md), extracted verbatim: a real experiment, golden written on the first run, equal on the
    second (a fresh experiment in a fresh folder, so this is a real re-run)."""
    from pathlib import Path
    readme = (Path(__file__).resolve().parents[1] / "docs" / "guides" / "pytest-plugin.md").read_text()
    start = readme.index("# tests/test_my_controller.py")
    code = readme[start:readme.index("```", start)]
    code = code.replace('"sim.T=2.0"', '"sim.T=0.5", "logging.progress=false", f"cache.dir={CACHE!r}"')
    assert 'f"cache.dir=' in code, "the docs' example changed: update this test's small-run edit"
    pytester.makepyfile(test_my_controller=f"CACHE = {str(tmp_path / 'cache')!r}\n" + code)
    first = pytester.runpytest_subprocess()
    first.assert_outcomes(failed=1)
    assert (pytester.path / "goldens" / "vanderpol_2s.mcap").exists()
    pytester.runpytest_subprocess().assert_outcomes(passed=1)
