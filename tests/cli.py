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
