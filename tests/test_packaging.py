"""The package installs from a wheel and runs from any folder; its version and the lock it was run with."""
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

import kexp
from kexp.app.lock import _normalise, lock_info, pins
from kexp.recording import read_log

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
# test_recording.SMALL, without the MCAP flush/prediction knobs: a run of a few seconds
SMALL = ["data.sampler.n_traj=20", "data.T=3.0", "dictionary.degree=3", "controller.lmpc.horizon=20",
         "controller.lmpc.blocks=null", "sim.T=1.0", "clf.grid=11", "logging.rrd=false", "logging.progress=false",
         "cache.enabled=false"]


def test_pyproject_lists_every_package_and_config_group():
    """pyproject.toml lists the packages by hand (conf/ is mapped to kexp.conf): a new subpackage or config group
    that is not listed would be missing from the wheel."""
    from setuptools import find_packages
    code = find_packages(str(REPO), include=["kexp*"])
    groups = sorted(p.name for p in (REPO / "conf").iterdir() if p.is_dir())
    listed = PYPROJECT["tool"]["setuptools"]["packages"]
    assert sorted(listed) == sorted(code + ["kexp.conf"] + [f"kexp.conf.{g}" for g in groups])
    assert PYPROJECT["tool"]["setuptools"]["package-dir"] == {"kexp.conf": "conf"}
    assert len(groups) == 11 and "controller" in groups and "plant" in groups


def test_version_is_the_projects_and_kexp_dash_dash_version_prints_it(capsys, monkeypatch):
    assert kexp.__version__ == PYPROJECT["project"]["version"]
    from kexp.app import main as app_main
    monkeypatch.setattr(sys, "argv", ["kexp", "--version"])
    app_main.main()
    assert capsys.readouterr().out == f"kexp {kexp.__version__}\n"   # not Hydra's "Hydra 1.3.x"


def test_version_falls_back_to_pyproject_when_not_installed(monkeypatch):
    import importlib.metadata as md

    def missing(name):
        raise md.PackageNotFoundError(name)
    monkeypatch.setattr(md, "version", missing)
    assert kexp._version() == PYPROJECT["project"]["version"]


def test_lock_info_hashes_the_lock_and_names_the_pins_that_differ(tmp_path):
    import hashlib
    import importlib.metadata as md
    numpy = md.version("numpy")
    lock = tmp_path / "requirements.lock"
    lock.write_text(f"numpy=={numpy} \\\n    --hash=sha256:00\n    # via kexp\nPyYAML==0.0.1\n")
    assert pins(lock.read_text()) == {"numpy": numpy, "pyyaml": "0.0.1"}
    info = lock_info(lock)
    assert info.sha256 == hashlib.sha256(lock.read_bytes()).hexdigest() and info.matches is False
    assert info.note == f"1 of 2 pins differ: pyyaml 0.0.1 locked, {md.version('pyyaml')} installed"
    lock.write_text(f"numpy=={numpy}\n")
    assert lock_info(lock).matches is True and lock_info(lock).note == ""
    none = lock_info(tmp_path / "absent.lock")
    assert (none.sha256, none.matches) == (None, None) and "no absent.lock" in none.note


def test_the_repositorys_lock_pins_every_dependency_exactly():
    """requirements.lock (uv pip compile, with hashes) pins each dependency and test extra of pyproject.toml."""
    text = (REPO / "requirements.lock").read_text()
    pinned = pins(text)
    wanted = PYPROJECT["project"]["dependencies"] + PYPROJECT["project"]["optional-dependencies"]["test"]
    names = {_normalise(w.split(">")[0].split("<")[0].split("=")[0].split("[")[0].strip())
             for w in wanted}
    assert names <= set(pinned), sorted(names - set(pinned))
    assert len(pinned) > len(names) and text.count("--hash=sha256:") >= len(pinned)


def _no_pythonpath_env() -> dict:
    """The environment without PYTHONPATH, which would import the checkout instead of the venv's wheel."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}


def _deps_pth() -> list[str]:
    """The running interpreter's package folders — a venv's site-packages when pytest runs in one, else the
    system's (and the user's, when enabled) — for a .pth file in the test's venv: its lines are appended to that
    venv's sys.path after its own site-packages (which holds the wheel), and the .pth files in them are not run
    (so an editable kexp of this environment stays out of it)."""
    import site
    import sysconfig
    paths = [*site.getsitepackages(), sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    if site.ENABLE_USER_SITE:
        paths.append(site.getusersitepackages())
    return [p for i, p in enumerate(paths) if p not in paths[:i] and Path(p).is_dir()]


def test_the_deps_pth_lists_this_interpreters_package_folders():
    import sysconfig
    paths = _deps_pth()
    assert sysconfig.get_paths()["purelib"] in paths and len(set(paths)) == len(paths)
    import hydra
    assert any(Path(hydra.__file__).is_relative_to(p) for p in paths)   # where this environment's deps are
    if sys.prefix != sys.base_prefix:     # in a venv: its own folder, not the base interpreter's
        assert Path(paths[0]).is_relative_to(sys.prefix)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_wheel_installs_into_a_fresh_venv_and_runs_kexp_from_an_empty_folder(tmp_path):
    """Build the wheel from a copy of the sources, install it offline into a new venv (no deps: they come from the
    running interpreter's package folders, see _deps_pth), and run a short experiment with the venv's `kexp` from an
    empty folder.  Works whether pytest runs in a venv (the README's `pip install -e '.[test]'` in one) or not:
    --system-site-packages would give the base interpreter's packages, not the enclosing venv's."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    for name in ("kexp", "conf"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    dist = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist),
                    str(src)], check=True, capture_output=True)
    (wheel,) = dist.glob("kexp-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    confs = {f"kexp/conf/{p.relative_to(REPO / 'conf').as_posix()}" for p in (REPO / "conf").rglob("*.yaml")}
    assert len(confs) == 37 and confs <= names and "kexp/conf/config.yaml" in names
    assert "kexp/app/main.py" in names and "kexp/plants/gymnasium.py" in names \
        and "kexp/conf/system/data.yaml" in names and "kexp/identify/iv.py" in names
    assert not any(n.startswith("conf/") for n in names)

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    bindir = venv / "bin"
    env = _no_pythonpath_env()
    env.pop("NUMBA_CACHE_DIR", None)
    env["KEXP_CACHE_DIR"] = str(tmp_path / "kexp_cache")   # a fresh per-user cache: the compiled kernels go there
    # the wheel first, while the venv sees only itself (pip would otherwise find this environment's kexp), offline
    subprocess.run([str(bindir / "python"), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
                   check=True, capture_output=True, env=env)
    purelib = subprocess.run([str(bindir / "python"), "-c",
                              "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             check=True, capture_output=True, text=True, env=env).stdout.strip()
    assert Path(purelib).is_relative_to(venv)
    (Path(purelib) / "_kexp_test_deps.pth").write_text("".join(f"{p}\n" for p in _deps_pth()))
    deps = subprocess.run([str(bindir / "python"), "-c", "import hydra, numpy, scipy, kexp; print(kexp.__file__)"],
                          capture_output=True, text=True, env=env, cwd=tmp_path)
    assert deps.returncode == 0, deps.stderr[-2000:]
    where = subprocess.run([str(bindir / "python"), "-c", "import kexp, kexp.app.main as m; "
                            "print(kexp.__file__); print(m.CONF_DIR)"],
                           check=True, capture_output=True, text=True, env=env, cwd=tmp_path).stdout.split()
    assert Path(where[0]).is_relative_to(venv) and Path(where[1]) == Path(where[0]).parent / "conf"

    work = tmp_path / "empty"
    work.mkdir()
    version = subprocess.run([str(bindir / "kexp"), "--version"], capture_output=True, text=True, env=env, cwd=work)
    assert version.returncode == 0 and version.stdout == f"kexp {kexp.__version__}\n"
    proc = subprocess.run([str(bindir / "kexp"), *SMALL], capture_output=True, text=True, env=env, cwd=work)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (summary_path,) = work.glob("outputs/*/*/summary.json")
    summary = json.loads(summary_path.read_text())
    assert summary["completed"] is True and summary["status"] == "completed"
    # 1 s is too short to settle with this small model; the state is on its way: ‖x(T)‖ ≈ 0.37 < ‖x0‖ ≈ 0.86
    assert summary["metrics"]["final_error"] < 0.5 * float(np.linalg.norm(summary["x0"]))
    log = read_log(summary_path.parent / "run.mcap")
    assert log.completed and len(log.messages("/step")) == 100
    # an installed wheel has no lock beside it: recorded as unknown, with the reason
    assert summary["lock"]["sha256"] is None and summary["lock"]["matches"] is None
    assert "no requirements.lock" in summary["lock"]["note"]
    assert summary["versions"]["kexp"] == kexp.__version__

    # the kernels compiled once, announced in one line, into the per-user cache (not beside the installed sources);
    # a second process in the same install loads them: no line, not one file added or rewritten
    numba_dir = tmp_path / "kexp_cache" / "numba"
    compiled = {p.relative_to(numba_dir).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
                for p in numba_dir.rglob("*") if p.is_file()}
    assert sum(n.endswith(".nbi") for n in compiled) >= 10 and sum(n.endswith(".nbc") for n in compiled) >= 10
    assert proc.stderr.count("kexp: compiling the controller's kernels once for this install") == 1
    assert not list(Path(purelib, "kexp").rglob("*.nbi"))
    again = subprocess.run([str(bindir / "kexp"), *SMALL], capture_output=True, text=True, env=env, cwd=work)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "compiling" not in again.stderr
    assert {p.relative_to(numba_dir).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in numba_dir.rglob("*") if p.is_file()} == compiled
