"""kexp-results refuses bad input in one line, ``kexp-results: error: ...``, exit code 2 (never a traceback nor a
table of nothing); valid input still gives the tables and collect still writes NAME.csv."""
import csv
import json
import subprocess
import sys

import pytest

from kexp.app.results import COLUMNS, main

from cli import refused, run_main

MCAP_BYTES = b"\x89MCAP0\r\n" + bytes(range(256)) * 4     # an .mcap's magic and binary data


def _row(i, **kw):
    row = dict.fromkeys(COLUMNS, "")
    row.update(x0_1=str(i / 10), x0_2="0.5", status="completed", success="True", cost=str(1.0 + i),
               settling_time_s="2.5", solve_median_ms="1.0", solve_p99_ms="2.0", max_abs_u="1.0", fallbacks="0",
               certificate="samples", controller="lmpc", inputs="projection", data_noise="0", smoothing="none",
               sim_noise="0")
    row.update(kw)
    return row


def _write(path, rows=None, header=COLUMNS):
    rows = [_row(i) for i in range(3)] if rows is None else rows
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            w.writerow([r.get(k, "") for k in header])
    return path


def _run(capsys, *argv):
    return run_main(main, capsys, *argv)


def _refused(capsys, fragment, *argv):
    return refused(main, "kexp-results", capsys, fragment, *argv)


@pytest.mark.parametrize("cmd", ["table", "robustness"])
def test_missing_columns_name_the_file_and_the_columns(tmp_path, capsys, cmd):
    p = _write(tmp_path / "vdp_lmpc.csv", [{"x0_1": "0", "x0_2": "0", "status": "completed"}],
               header=["x0_1", "x0_2", "status"])
    line = _refused(capsys, "not a results CSV: missing columns success, cost", cmd, p)
    assert str(p) in line


@pytest.mark.parametrize("cmd", ["table", "robustness"])
def test_a_binary_file_is_not_a_text_csv(tmp_path, capsys, cmd):
    p = tmp_path / "vdp_lmpc.csv"
    p.write_bytes(MCAP_BYTES)
    _refused(capsys, "not a text CSV", cmd, p)
    mcap = tmp_path / "run.mcap"
    mcap.write_bytes(MCAP_BYTES)
    _refused(capsys, f"{mcap}: not a text CSV", cmd, mcap)


@pytest.mark.parametrize("cmd", ["table", "robustness"])
def test_a_non_number_names_file_line_and_column(tmp_path, capsys, cmd):
    p = _write(tmp_path / "vdp_lmpc.csv", [_row(0), _row(1, cost="abc")])
    _refused(capsys, f"{p}, line 3: column cost holds 'abc', not a finite number", cmd, p)
    _write(p, [_row(0, solve_median_ms="nan")])
    _refused(capsys, "line 2: column solve_median_ms holds 'nan'", cmd, p)
    _write(p, [_row(0, x0_1="inf")])
    _refused(capsys, "column x0_1 holds 'inf'", cmd, p)


@pytest.mark.parametrize("cmd", ["table", "robustness"])
def test_empty_header_only_and_non_csv_text_are_refused(tmp_path, capsys, cmd):
    empty = tmp_path / "vdp_lmpc.csv"
    empty.write_text("")
    _refused(capsys, "empty file, not a results CSV", cmd, empty)
    header = _write(tmp_path / "vdp_lqr.csv", [])
    _refused(capsys, "a results CSV with no rows", cmd, header)
    text = tmp_path / "vdp_nmpc.csv"
    text.write_text("hello\nthis is not a table\n")
    _refused(capsys, "not a results CSV: missing columns x0_1, x0_2", cmd, text)
    short = _write(tmp_path / "vdp_mpc.csv", [_row(0)])
    with open(short, "a") as f:
        f.write("0.1,0.2,completed\n")
    _refused(capsys, "line 3: fewer fields than the header's 19", cmd, short)


@pytest.mark.parametrize("cmd", ["table", "robustness"])
def test_a_success_value_collect_never_writes_is_refused(tmp_path, capsys, cmd):
    p = _write(tmp_path / "vdp_lmpc.csv", [_row(0), _row(1, success="maybe")])
    _refused(capsys, "line 3: column success holds 'maybe'", cmd, p)
    _write(p, [_row(0, cost="")])
    _refused(capsys, "line 2: a success without a cost", cmd, p)


def test_file_names_and_folders(tmp_path, capsys):
    _refused(capsys, "the file name is not <system>_<configuration>.csv",
             "table", _write(tmp_path / "noname.csv"))
    _refused(capsys, f"{tmp_path}: is a folder; pass the CSV files in it", "table", tmp_path)
    _refused(capsys, "cannot read: No such file or directory", "robustness", tmp_path / "gone_lmpc.csv")
    (tmp_path / "other").mkdir()
    a, b = _write(tmp_path / "vdp_lmpc.csv"), _write(tmp_path / "other" / "vdp_lmpc.csv")
    _refused(capsys, "two CSVs named vdp_lmpc.csv", "table", a, b)


def test_valid_csvs_still_give_the_tables(tmp_path, capsys):
    lmpc = _write(tmp_path / "vdp_lmpc.csv", [_row(0), _row(1, success="False", settling_time_s="inf"),
                                              _row(2, status="error", success="", cost="")])
    oracle = _write(tmp_path / "vdp_nmpc.csv", [_row(i, controller="nmpc_oracle") for i in range(3)])
    code, out, err = _run(capsys, "table", lmpc, oracle, lmpc)          # the same file twice counts once
    assert code == 0 and err == []
    lines = out.splitlines()
    assert len(lines) == 6 and lines[2].startswith("| vdp | lmpc | 1/3 | 1.500 | 2.000 | 1.000 | 1.000 | 2.50 |")
    assert lines[5] == "J_oracle (J*): the true-model NMPC solved by CasADi + IPOPT for every system."
    old = tmp_path / "old" / "vdp_lqr.csv"        # written before the condition columns existed
    old.parent.mkdir()
    old.write_text("x0_1,x0_2,status,success,cost\n0.0,0.5,completed,True,1.0\n")
    code, out, err = _run(capsys, "robustness", lmpc, oracle, old)
    assert code == 0 and err == [] and "| vdp | known | 0 | nominal | 1/3 |" in out


def test_a_system_name_may_hold_an_underscore(tmp_path, capsys):
    """<system>_<configuration>: the configuration follows the last underscore (cart_pendulum_lmpc is the system
    cart_pendulum); before, the first one split it, so the row's system was 'cart' and its oracle was not found."""
    from kexp.app.results import split_name
    assert split_name("results/cart_pendulum_lmpc-reg.csv") == ("cart_pendulum", "lmpc-reg")
    assert split_name("x/pendulum-u0.5_nmpc.csv") == ("pendulum-u0.5", "nmpc")
    lmpc = _write(tmp_path / "my_rig_lmpc.csv")
    oracle = _write(tmp_path / "my_rig_nmpc.csv", [_row(i, controller="nmpc_oracle", cost=str(0.5 + 0.5 * i))
                                                   for i in range(3)])
    code, out, err = _run(capsys, "table", lmpc, oracle)
    assert code == 0 and "| my_rig | lmpc | 3/3 | 2.000 | 3.000 | 2.000 | 2.000 |" in out
    code, out, err = _run(capsys, "robustness", lmpc, oracle)
    assert code == 0 and "| my_rig | known | 0 | nominal | 3/3 | 2.000 / 2 | – | – | 3/3 |" in out, out
    code, text, err = _run(capsys, "collect", _sweep(tmp_path / "sweep"), "my_rig_lmpc", "-o", tmp_path / "c")
    assert code == 0 and (tmp_path / "c" / "my_rig_lmpc.csv").exists()


def _sweep(root):
    """A sweep folder of two jobs as kexp writes them (summary.json, .hydra/overrides.yaml)."""
    for i, (x0, cost) in enumerate((([0.5, 0.5], 1.5), ([-0.5, 0.2], 2.5))):
        job = root / str(i)
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "overrides.yaml").write_text(f"- sim.x0=[{x0[0]},{x0[1]}]\n")
        (job / "summary.json").write_text(json.dumps({
            "status": "completed", "completed": True, "system": "vanderpol", "controller": "lmpc", "x0": x0,
            "metrics": {"success": True, "cost": cost, "settling_time": 3.0, "max_abs_u": 1.0, "fallbacks": 0,
                        "solve_time_median": 0.001, "solve_time_p99": 0.002}}))
    return root


def test_collect_takes_a_plain_name_and_a_folder(tmp_path, capsys):
    sweep = _sweep(tmp_path / "sweep")
    out = tmp_path / "a" / "b"
    line = _refused(capsys, "NAME '../../escape_lmpc': give <system>_<configuration>", "collect", sweep,
                    "../../escape_lmpc", "-o", out)
    assert "no path" in line and not list(tmp_path.rglob("escape_lmpc.csv")) and not out.exists()
    for bad in ("nounderscore", "vdp/x_lmpc", "_lmpc", "vdp_", ".hidden_lmpc"):
        _refused(capsys, f"NAME {bad!r}", "collect", sweep, bad, "-o", out)
    afile = tmp_path / "afile"
    afile.write_text("x")
    _refused(capsys, f"-o {afile}: is a file; give the folder to write vdp_lmpc.csv into",
             "collect", sweep, "vdp_lmpc", "-o", afile)
    _refused(capsys, f"-o {afile / 'sub'}: cannot create the folder", "collect", sweep, "vdp_lmpc",
             "-o", afile / "sub")
    (out / "vdp_lmpc.csv").mkdir(parents=True)
    _refused(capsys, "vdp_lmpc.csv: is a folder", "collect", sweep, "vdp_lmpc", "-o", out)
    # valid: written, and read back by table
    code, text, err = _run(capsys, "collect", sweep, "vdp-u0.5_lmpc-reg", "-o", out)
    assert code == 0 and err == [] and text.strip() == f"wrote {out / 'vdp-u0.5_lmpc-reg.csv'}"
    code, text, err = _run(capsys, "table", out / "vdp-u0.5_lmpc-reg.csv")
    assert code == 0 and "| vdp-u0.5 | lmpc-reg | 2/2 | 2.000 | 2.500 |" in text


def test_the_installed_command_prints_one_line_and_no_traceback(tmp_path):
    p = tmp_path / "vdp_lmpc.csv"
    p.write_bytes(MCAP_BYTES)
    proc = subprocess.run([sys.executable, "-m", "kexp.app.results", "table", str(p)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.splitlines() == [f"kexp-results: error: {p}: not a text CSV (binary data: an .mcap log?); "
                                        "pass a results CSV written by kexp-results collect"]


@pytest.mark.parametrize("argv", [["table"], ["compare"]])
def test_a_reader_that_leaves_early_ends_the_output_quietly(tmp_path, argv):
    """`kexp-results table … | head -1`: the table went to a closed pipe and the command said 'error: Broken pipe'
    with exit code 2; now nothing on stderr and the exit code is the command's own (compare: its verdict)."""
    a = _write(tmp_path / "vanderpol_lmpc.csv")
    args = ["table", str(a)] if argv == ["table"] else ["compare", str(a), str(a)]
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from kexp.app.results import main; main()", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()               # no reader left: the command's first write meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait() == 0 and err == "", err
