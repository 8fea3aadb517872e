"""system.name=module:Class names the user's own .py file or kexp's: any other module (the standard library, an
installed package, a compiled or built-in one) is refused in one line before it is imported (issue 32)."""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from kexp.errors import SystemDefinitionError
from kexp.systems import make_system

KEXP_BIN = str(Path(sys.executable).parent / "kexp")


def test_naming_this_runs_none_of_its_code_one_line_exit_2(tmp_path):
    """`this` prints the Zen of Python when imported: nothing on stdout, one line on stderr, exit code 2."""
    proc = subprocess.run([KEXP_BIN, "system.name=this:X", f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("kexp: error: system 'this:X': module 'this' is part of Python's standard library")
    assert "your own .py file" in lines[0]


@pytest.mark.parametrize("name,module,why", [
    ("this:X", "this", "part of Python's standard library"),
    ("email.mime.text:MIMEText", "email", "part of Python's standard library"),
    ("sys:X", "sys", "built into Python"),
    ("numpy:ndarray", "numpy", "an installed package"),
    ("numpy.polynomial.polynomial:Polynomial", "numpy", "an installed package"),
])
def test_other_modules_are_refused_before_they_are_imported(name, module, why):
    """In a fresh interpreter: the refusal names the module and why, and the module named was not imported (sys
    and numpy are there before: kexp imports numpy)."""
    target = name.partition(":")[0]
    code = textwrap.dedent(f"""
        import sys
        from kexp.systems import make_system
        before = {target!r} in sys.modules
        try:
            make_system({name!r})
        except Exception as exc:
            print(type(exc).__name__, exc)
        print(before, {target!r} in sys.modules)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    first, imported = proc.stdout.strip().splitlines()
    assert first.startswith(f"SystemDefinitionError system {name!r}: module {module!r} is {why}"), proc.stdout
    assert imported == {"sys": "True True", "numpy": "True True"}.get(target, "False False"), proc.stdout


def test_a_users_own_module_and_package_on_the_path_still_work(tmp_path, monkeypatch):
    body = textwrap.dedent("""
        from dataclasses import dataclass
        import numpy as np
        from kexp.systems import ControlAffineSystem

        @dataclass(frozen=True)
        class Cubic(ControlAffineSystem):
            a: float = 1.0
            name = "cubic"
            n = 1
            m = 1
            def drift(self, x):
                return -self.a * np.asarray(x) ** 3
            def input_matrix(self, x):
                return np.ones(np.shape(x) + (1,))
        """)
    (tmp_path / "h2_own_systems.py").write_text(body)
    (tmp_path / "h2_own_pkg" / "sub").mkdir(parents=True)
    (tmp_path / "h2_own_pkg" / "__init__.py").write_text("")
    (tmp_path / "h2_own_pkg" / "sub" / "mod.py").write_text(body)   # sub: a namespace package (no __init__.py)
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        assert make_system("h2_own_systems:Cubic", {"a": 2.0}).a == 2.0
        assert make_system("h2_own_pkg.sub.mod:Cubic").n == 1
        assert make_system("h2_own_pkg.sub.mod.Cubic").n == 1
        assert make_system("kexp.systems:VanDerPol").name == "vanderpol"
        with pytest.raises(SystemDefinitionError, match=r"cannot import module 'h2_own_pkg\.nope'"):
            make_system("h2_own_pkg.nope:X")
        with pytest.raises(SystemDefinitionError, match=r"module 'h2_own_systems' has no 'Nope'"):
            make_system("h2_own_systems:Nope")
    finally:
        for name in ("h2_own_systems", "h2_own_pkg", "h2_own_pkg.sub", "h2_own_pkg.sub.mod"):
            sys.modules.pop(name, None)


def test_a_module_file_that_is_not_python_source_is_refused(tmp_path, monkeypatch):
    (tmp_path / "h2_compiled.so").write_bytes(b"\x7fELF not really")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(SystemDefinitionError, match=r"module 'h2_compiled' is not a Python source file"):
        make_system("h2_compiled:X")
    assert "h2_compiled" not in sys.modules
