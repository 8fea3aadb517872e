"""A pytest plugin for log diffing in your own tests (registered through the ``pytest11`` entry point, so it is
active wherever kexp is installed).

    def test_my_controller(kexp_golden, tmp_path):
        run_dir = run_my_experiment(tmp_path)           # a kexp run folder, or the path of a run.mcap
        kexp_golden.check(run_dir, "my_controller")

The golden is ``<golden dir>/my_controller.mcap``; the golden dir is ``goldens/`` beside the test file, or the
``kexp_golden_dir`` ini option (relative to the rootdir), or ``check(..., directory=)``.  A missing golden is
written and the test fails once, asking you to commit it; ``pytest --kexp-regen`` rewrites every golden a test
checks (and fails those tests, so a regeneration is never mistaken for a pass), like pytest-regressions'
``--force-regen``.  Logs are compared under the ``portable`` policy (what holds on any machine; README,
"Golden recordings") unless ``policy="exact"`` (or the ``kexp_golden_policy`` ini option) is given; a failure
shows the first divergence (channel, step, time, field, both values, the tolerance) and a per-channel summary.
"""
from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

# kept light: pytest imports this module in every session where kexp is installed; the diff machinery
# (numpy, scipy, mcap) is imported by check() only
POLICIES = ("exact", "portable")   # kexp.recording.policy.POLICIES (a test keeps them equal)
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


def pytest_addoption(parser):
    """pytest hook: the ``--kexp-regen`` flag and the ``kexp_golden_dir`` / ``kexp_golden_policy`` ini options."""
    group = parser.getgroup("kexp", "kexp golden run logs")
    group.addoption("--kexp-regen", action="store_true", default=False,
                    help="rewrite the golden run logs that kexp_golden.check() compares against (the tests fail)")
    parser.addini("kexp_golden_dir", "folder of golden run logs, relative to the rootdir (default: goldens/ "
                  "beside each test file)", default="")
    parser.addini("kexp_golden_policy", f"default diff policy of kexp_golden.check ({', '.join(POLICIES)})",
                  default="portable")


def _as_log(source) -> Path:
    from .recording.reader import LogError, log_path   # light: the standard library's modules only
    try:
        path = log_path(source)
    except LogError as exc:
        raise FileNotFoundError(f"kexp_golden: {exc}") from None
    if not path.is_file():
        raise FileNotFoundError(f"kexp_golden: no run log at {path} (pass a run folder holding run.mcap, or an "
                                f".mcap file)")
    return path


@dataclass
class GoldenChecker:
    """The ``kexp_golden`` fixture's value: ``check(run_dir_or_mcap, name)`` diffs a run log against a golden."""
    directory: Path
    regen: bool
    policy: str

    def path(self, name: str, directory: str | Path | None = None) -> Path:
        """Where golden ``name`` lives (``<dir>/<name>.mcap``)."""
        if not isinstance(name, str) or not _NAME.match(name) or name.endswith(".mcap"):
            raise ValueError(f"kexp_golden: golden name {name!r}: use letters, digits, '_', '-', '.', without a "
                             f"folder or the .mcap suffix")
        return Path(directory if directory is not None else self.directory) / f"{name}.mcap"

    def check(self, source, name: str, *, policy: str | None = None, directory: str | Path | None = None,
              include_wall_clock: bool = False):
        """Compare the run log ``source`` (a run folder or an .mcap path) with golden ``name``.  Writes the golden
        when it is missing or ``--kexp-regen`` is given (and fails, asking to commit it); otherwise fails with
        the first divergence unless the logs agree under ``policy``.  Returns the DiffResult when they agree."""
        __tracebackhide__ = True
        from .recording.diff import diff_logs
        from .recording.reader import LogError
        policy = policy or self.policy
        if policy not in POLICIES:
            raise ValueError(f"kexp_golden: policy {policy!r}; valid: {', '.join(POLICIES)}")
        new = _as_log(source)
        golden = self.path(name, directory)
        if self.regen or not golden.exists():
            golden.parent.mkdir(parents=True, exist_ok=True)
            existed = golden.exists()
            shutil.copyfile(new, golden)
            why = "regenerated (--kexp-regen)" if existed or self.regen else "did not exist; written"
            pytest.fail(f"kexp golden {golden} {why}: check it in and re-run without --kexp-regen", pytrace=False)
        try:
            res = diff_logs(golden, new, policy=policy, include_wall_clock=include_wall_clock)
        except LogError as exc:
            pytest.fail(f"kexp golden {name!r}: {exc}", pytrace=False)
        if not res.equal:
            pytest.fail(f"run log {new} differs from golden {golden} ({policy} policy):\n{res.report()}\n"
                        f"(after an intended change: pytest --kexp-regen, then commit the golden)", pytrace=False)
        return res


@pytest.fixture
def kexp_golden(request) -> GoldenChecker:
    """Diff kexp run logs against golden recordings kept in your repository: ``kexp_golden.check(run, name)``."""
    ini_dir = request.config.getini("kexp_golden_dir")
    directory = (Path(request.config.rootpath) / ini_dir) if ini_dir else Path(request.path).parent / "goldens"
    return GoldenChecker(directory, bool(request.config.getoption("--kexp-regen")),
                         request.config.getini("kexp_golden_policy") or "portable")
