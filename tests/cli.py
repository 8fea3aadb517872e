"""Running a kexp command's main(argv) in-process in tests: its exit code, stdout and stderr lines."""
import pytest


def run_main(main, capsys, *argv):
    """(exit code, stdout, stderr lines) of ``main(argv)`` (a main that ends with sys.exit)."""
    with pytest.raises(SystemExit) as exc:
        main([str(a) for a in argv])
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err.strip().splitlines()


def refused(main, prog, capsys, fragment, *argv):
    """Assert ``main(argv)`` refuses with exit code 2, one stderr line ``<prog>: error: …`` holding ``fragment``
    and nothing on stdout; returns that line."""
    code, out, err = run_main(main, capsys, *argv)
    assert code == 2 and len(err) == 1, (code, err)
    assert err[0].startswith(f"{prog}: error: ") and fragment in err[0], err
    assert out == ""
    return err[0]


def console_script(name: str) -> str:
    """The console script ``name`` (kexp, kexp-diff, …) of the running interpreter's environment — its scripts
    folder, e.g. the venv's bin/ — not whatever a bare name finds first on PATH (another environment's, or
    none when the venv is not activated)."""
    import sys
    import sysconfig
    from pathlib import Path
    for folder in (sysconfig.get_path("scripts"), Path(sys.executable).parent):
        path = Path(folder) / name
        if path.is_file():
            return str(path)
    raise FileNotFoundError(f"no {name} in {sysconfig.get_path('scripts')} (pip install -e '.[test]' installs it)")
