"""kexp's compiled kernels are cached once per install (kexp.control.jit_cache): where, the one line a compile
prints, the warning for a folder that cannot be written, and no second compile in a later process or for a
read-only model."""
import dataclasses
import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

import kexp
from kexp.control import jit_cache

REPO = Path(__file__).resolve().parents[1]
# one kexp kernel called in a fresh interpreter (expm_small and the helpers it calls: a few seconds to compile)
CALL = ("import numpy as np, kexp.control, numba.core.config as c; from kexp.control.expm_kernels import expm_small; "
        "print(expm_small(np.diag([0.0, np.log(2.0)]))[1, 1]); print(c.CACHE_DIR)")


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "KEXP_CACHE_DIR")}
    env["PYTHONPATH"] = str(REPO)
    env.update(extra)
    return env


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.stat().st_size for p in folder.rglob("*") if p.is_file()}


def test_cache_dir_is_per_kexp_python_and_numba_version_under_kexps_cache(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("KEXP_CACHE_DIR", str(tmp_path))
    tag = f"{kexp.__version__}-py{sys.version_info[0]}.{sys.version_info[1]}-numba{version('numba')}"
    assert jit_cache.cache_dir() == tmp_path / "numba" / tag
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))   # the user's own folder is respected
    assert jit_cache.cache_dir() == tmp_path / "mine"
    monkeypatch.setenv("NUMBA_CACHE_DIR", "")                        # empty: not set
    assert jit_cache.cache_dir() == tmp_path / "numba" / tag


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_kernel_compiles_once_with_one_line_and_a_later_process_loads_it(tmp_path):
    """First process: one announcement line on stderr, index files written under KEXP_CACHE_DIR/numba/<tag>.
    Second process: nothing printed, no file added or rewritten (numba loaded every kernel from the cache)."""
    env = _env(KEXP_CACHE_DIR=str(tmp_path))
    first = subprocess.run([sys.executable, "-c", CALL], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    value, where = first.stdout.split("\n")[:2]
    assert float(value) == pytest.approx(2.0, rel=1e-14)
    assert Path(where).parent == tmp_path / "numba" and Path(where).name.startswith(f"{kexp.__version__}-py")
    lines = first.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("kexp: compiling the controller's kernels once") \
        and str(Path(where)) in lines[0]
    files = _files(tmp_path / "numba")
    assert sum(n.endswith(".nbi") for n in files) >= 3 and sum(n.endswith(".nbc") for n in files) >= 3
    second = subprocess.run([sys.executable, "-c", CALL], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert second.returncode == 0 and second.stderr == "" and second.stdout == first.stdout
    assert _files(tmp_path / "numba") == files


def test_a_cache_folder_that_cannot_be_written_warns_once_and_runs(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    env = _env(NUMBA_CACHE_DIR=str(blocker / "numba"))   # under a file: cannot be created, even by root
    proc = subprocess.run([sys.executable, "-c", "import os, kexp.control, numba.core.config as c; "
                           "print(repr(c.CACHE_DIR), os.environ.get('NUMBA_CACHE_DIR'))"],
                          capture_output=True, text=True, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout == "'' None\n"        # numba's own default locators, not the unwritable folder
    (line,) = proc.stderr.splitlines()
    assert line.startswith(f"kexp: warning: cannot write the compiled-kernel cache {blocker / 'numba'} (") \
        and "set NUMBA_CACHE_DIR to a writable folder" in line


def test_a_read_only_model_or_p_does_not_compile_the_kernels_again():
    """A model or CLF loaded from kexp's cache may hold read-only arrays, a different type to numba: the LMPC
    copies them, so a second controller built from read-only arrays adds no signature to any kernel."""
    from kexp.clf import ClfConfig, synthesize_clf
    from kexp.control import Lmpc, LmpcConfig, condense, make_law
    from kexp.data import Circle, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    s = VanDerPol()
    model = identify(s, collect(s, Circle(20, 2.5), DataConfig(T=3.0)), Monomials(2, 3))
    clf = synthesize_clf(model, ClfConfig())
    law = make_law("sontag", clf.lyap, -5.0, 5.0)
    Lmpc(model, clf, law, LmpcConfig(), -5.0, 5.0)
    kernels = [getattr(condense, n) for n in ("condense", "linearised_vmax", "rows_hold", "block_maps_poly")]
    before = [len(k.signatures) for k in kernels]

    def frozen(a):
        a = np.array(a)
        a.flags.writeable = False
        return a
    model_ro = dataclasses.replace(model, Lambda=frozen(model.Lambda), B=frozen(model.B), b=frozen(model.b),
                                   C=frozen(model.C))
    clf_ro = dataclasses.replace(clf, P=frozen(clf.P))
    assert not clf_ro.P.flags.writeable and not model_ro.B.flags.writeable
    ctrl = Lmpc(model_ro, clf_ro, law, LmpcConfig(), -5.0, 5.0)
    assert [len(k.signatures) for k in kernels] == before
    assert ctrl.P.flags.writeable and np.array_equal(ctrl.P, clf.P)
