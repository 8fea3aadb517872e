"""kexp --help (kexp's own page, one screen, before anything heavy is imported) and --version on every tool."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import kexp
from kexp.app import help as kexp_help
from kexp.app.confdir import CONF_DIR

MODULES = {"kexp": "kexp.app.main", "kexp-diff": "kexp.recording.diff", "kexp-render": "kexp.recording.render",
           "kexp-report": "kexp.app.report", "kexp-results": "kexp.app.results",
           "kexp-figures": "kexp.analysis.figures", "kexp-compile": "kexp.control.warmup"}


def script(name: str) -> list[str]:
    """The console script installed beside this interpreter (what a user types), else its module."""
    for cand in (Path(sys.executable).parent / name, shutil.which(name)):
        if cand and Path(cand).exists():
            return [str(cand)]
    return [sys.executable, "-m", MODULES[name]]


def _run(*argv, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([*argv], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("name", sorted(MODULES))
def test_every_tool_prints_its_version_and_exits_0(name):
    proc = _run(*script(name), "--version")
    assert (proc.returncode, proc.stdout, proc.stderr) == (0, f"{name} {kexp.__version__}\n", "")


def test_subcommands_have_no_version_of_their_own():
    proc = _run(*script("kexp-results"), "table", "x.csv", "--version")
    assert proc.returncode == 2 and "unrecognized arguments: --version" in proc.stderr


@pytest.fixture(scope="module")
def help_page():
    proc = _run(*script("kexp"), "--help")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    return proc.stdout


def test_help_is_kexps_one_screen_page(help_page):
    lines = help_page.splitlines()
    assert len(lines) <= 45 and max(map(len, lines)) <= 100
    assert lines[0].startswith(f"kexp {kexp.__version__}: Koopman-based Lyapunov MPC from data")
    assert "powered by Hydra" not in help_page and "== Config ==" not in help_page
    presets = sorted(p.stem for p in (Path(CONF_DIR) / "experiment").glob("*.yaml"))
    assert len(presets) >= 10 and all(f" {p} " in help_page or help_page.count(f" {p}\n") for p in presets)
    groups = sorted(p.name for p in Path(CONF_DIR).iterdir() if p.is_dir() and p.name != "experiment")
    for group in groups:
        assert any(ln.startswith(f"  {group} ") for ln in lines), group
    assert "  controller     lie_gain lmpc* lqr model_lqr nmpc sontag" in lines   # * marks config.yaml's default
    for tool in MODULES:
        if tool != "kexp":
            assert any(ln.startswith(f"  {tool} ") for ln in lines), tool
    assert "docs/index.md" in help_page and "kexp --hydra-help" in help_page and "kexp --cfg job" in help_page


def test_dash_h_is_the_same_page(help_page):
    proc = _run(*script("kexp"), "+experiment=pendulum", "-h")
    assert proc.returncode == 0 and proc.stdout == help_page


def test_help_imports_nothing_heavy():
    """The page prints before numpy, scipy, numba, cvxpy or the experiment code are imported (it took 16 s)."""
    code = ("import sys; sys.argv = ['kexp', '--help']; from kexp.app.main import main; main(); "
            "heavy = ('numpy', 'scipy', 'numba', 'cvxpy', 'kexp.app.experiment', 'kexp.app.schema'); "
            "print('loaded:', [m for m in heavy if m in sys.modules])")
    proc = _run(sys.executable, "-c", code)
    assert proc.returncode == 0 and proc.stdout.splitlines()[-1] == "loaded: []", proc.stdout[-500:] + proc.stderr


def test_hydra_help_is_one_flag_away():
    proc = _run(*script("kexp"), "--hydra-help")
    assert proc.returncode == 0 and "powered by Hydra" in proc.stdout and "== Config ==" in proc.stdout


def test_page_lists_the_config_folder_as_it_is(tmp_path):
    """Presets and groups come from the folder when asked: a new preset or option shows without an edit."""
    for rel in ("experiment/zeta.yaml", "experiment/alpha.yaml", "controller/lqr.yaml", "controller/mine.yaml",
                ".hidden/x.yaml", "empty/README.md"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("{}\n")
    (tmp_path / "config.yaml").write_text("defaults:\n  - kexp_schema\n  - controller: mine\n  - _self_\n")
    lines = kexp_help.page(tmp_path, "9.9").splitlines()
    assert "Presets (+experiment=NAME): alpha zeta" in lines
    assert "  controller     lqr mine*" in lines
    assert not any(".hidden" in ln or ln.startswith("  empty") for ln in lines)
    assert lines[0].startswith("kexp 9.9: ")
