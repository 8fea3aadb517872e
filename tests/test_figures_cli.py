"""kexp-figures refuses bad input in one line, ``kexp-figures: error: ...``, exit code 2 (never a traceback, never
a silent success): logs without steps, -o that matplotlib cannot write or that is a folder, options a kind does
not use, results CSVs kexp-results refuses, CSVs of two systems; valid input still draws."""
import csv
import subprocess
import sys

import numpy as np
import pytest

from kexp.analysis.figures import main
from kexp.results.csvfiles import COLUMNS
from kexp.recording import RunLogger

from cli import refused, run_main

MCAP_BYTES = b"\x89MCAP0\r\n" + bytes(range(256)) * 4


def _log(path, n_steps, dt=0.01):
    """A run log of Van der Pol under a constant input (explicit Euler): /config and ``n_steps`` /step messages."""
    from kexp.systems import VanDerPol
    s, x = VanDerPol(), np.array([0.5, -0.3])
    with RunLogger(path) as log:
        log.log_config({"system": {"name": "vanderpol", "params": {"mu": 1.0}},
                        "controller": {"u_min": -5.0, "u_max": 5.0}}, "0")
        for k in range(n_steps):
            u = np.array([0.1])
            log.write("/step", k * dt, {"k": k, "t": k * dt, "x": x, "u": u})
            x = x + dt * s.rhs(x[None], u[None])[0]
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run folder: run.mcap (60 steps) and a (poor, quickly identified) model.npz."""
    from kexp.data import Box, DataConfig, collect
    from kexp.dictionary import Monomials
    from kexp.identify import identify
    from kexp.systems import VanDerPol
    d = tmp_path_factory.mktemp("run")
    s = VanDerPol()
    model = identify(s, collect(s, Box(5, -2.5, 2.5), DataConfig(T=2.0)), Monomials(2, 2, include_constant=False))
    model.save(d / "model.npz")
    _log(d / "run.mcap", 60, dt=model.dt)
    return d


def _csv(path, success=None, cost=None, n=4):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for i in range(n):
            row = dict.fromkeys(COLUMNS, "")
            row.update(x0_1=str(i / 10), x0_2="0.5", status="completed", success="True", cost=str(1.0 + i))
            if i == 1:
                row.update({k: v for k, v in (("success", success), ("cost", cost)) if v is not None})
            w.writerow([row[k] for k in COLUMNS])
    return path


def _run(capsys, *argv):
    return run_main(main, capsys, *argv)


def _refused(capsys, fragment, *argv):
    return refused(main, "kexp-figures", capsys, fragment, *argv)


def test_a_log_without_steps(tmp_path, capsys):
    empty = _log(tmp_path / "empty.mcap", 0)
    _refused(capsys, f"{empty}: no steps in the log", "paper", empty, "-o", tmp_path / "p.png")
    cut = tmp_path / "cut.mcap"      # the first 5000 bytes of a log: its header, no step
    cut.write_bytes(_log(tmp_path / "long.mcap", 3000).read_bytes()[:5000])
    _refused(capsys, "no steps in the log", "paper", cut, "-o", tmp_path / "p.png")
    assert not (tmp_path / "p.png").exists()


def test_out_paths(run_dir, tmp_path, capsys):
    mcap = run_dir / "run.mcap"
    line = _refused(capsys, "matplotlib cannot write .txt files", "paper", mcap, "-o", tmp_path / "out.txt")
    assert ".png" in line and ".pdf" in line and ".svg" in line
    _refused(capsys, f"-o {tmp_path}: is a folder; give the file to write", "paper", mcap, "-o", tmp_path)
    _refused(capsys, "nowhere does not exist; create it", "paper", mcap, "-o", tmp_path / "nowhere" / "f.png")
    # no suffix: a PNG, and the path printed is the one written
    code, out, err = _run(capsys, "paper", mcap, "-o", tmp_path / "out")
    assert code == 0 and err == [] and out.strip() == f"wrote {tmp_path / 'out.png'}"
    assert not (tmp_path / "out").exists()
    # the PNG is the log's paper figure: the pixels paper_figure draws for it, decoded, and not a blank canvas
    import matplotlib.image as mpimg
    from kexp.analysis.figures import paper_figure
    assert (tmp_path / "out.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img, ref = mpimg.imread(tmp_path / "out.png"), mpimg.imread(paper_figure(mcap, tmp_path / "ref.png"))
    assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 600 and np.array_equal(img, ref)
    assert (img[..., :3] < 0.5).mean() > 0.005 and (img[..., :3] > 0.9).mean() > 0.5   # ink on a white page
    code, out, _ = _run(capsys, "paper", mcap, "-o", tmp_path / "fig.pdf")
    assert code == 0 and out.strip() == f"wrote {tmp_path / 'fig.pdf'}"
    assert (tmp_path / "fig.pdf").read_bytes()[:4] == b"%PDF"


def test_options_and_sources_a_kind_does_not_take(run_dir, tmp_path, capsys):
    mcap, png = run_dir / "run.mcap", tmp_path / "x.png"
    oracle = _csv(tmp_path / "vdp_nmpc.csv")
    _refused(capsys, "--oracle is for roa with results CSVs (a region map); paper does not use it",
             "paper", mcap, "--oracle", oracle, "-o", png)
    _refused(capsys, "theorem1 does not use it", "theorem1", run_dir, "--oracle", oracle, "-o", png)
    _refused(capsys, "a sweep folder's roa figure does not use it", "roa", tmp_path, "--oracle", oracle, "-o", png)
    _refused(capsys, "paper takes one source, got 2", "paper", mcap, mcap, "-o", png)
    _refused(capsys, f"not both: {tmp_path} is not a .csv", "roa", tmp_path, oracle, "-o", png)
    lmpc = _csv(tmp_path / "vdp_lmpc.csv")
    _refused(capsys, f"--oracle is missing: a region map from results CSVs needs the oracle's CSV over the same x0, "
                     f"e.g. --oracle {oracle}", "roa", lmpc, "-o", png)
    noname = _csv(tmp_path / "noname.csv")        # was a traceback (split_name's ReportError went uncaught)
    _refused(capsys, f"{noname}: the file name is not <system>_<configuration>.csv", "roa", noname, "-o", png)
    assert not png.exists()


def test_region_map_inputs_are_checked_as_kexp_results_checks_them(tmp_path, capsys):
    png = tmp_path / "map.png"
    oracle, lmpc = _csv(tmp_path / "vdp_nmpc.csv"), _csv(tmp_path / "vdp_lmpc.csv")
    binary = tmp_path / "vdp_lqr.csv"
    binary.write_bytes(MCAP_BYTES)
    _refused(capsys, f"{binary}: not a text CSV", "roa", binary, "--oracle", oracle, "-o", png)
    _refused(capsys, f"{binary}: not a text CSV", "roa", lmpc, "--oracle", binary, "-o", png)
    _refused(capsys, "line 3: column cost holds 'nan'", "roa", _csv(tmp_path / "vdp_a.csv", cost="nan"),
             "--oracle", oracle, "-o", png)
    _refused(capsys, "line 3: column success holds 'maybe'", "roa", _csv(tmp_path / "vdp_b.csv", success="maybe"),
             "--oracle", oracle, "-o", png)
    _refused(capsys, "line 3: column cost holds 'abc'", "roa", lmpc,
             "--oracle", _csv(tmp_path / "vdp_c.csv", cost="abc"), "-o", png)
    duffing = _csv(tmp_path / "duffing_lmpc.csv")
    _refused(capsys, f"{duffing} holds runs of duffing, the oracle's {oracle} of vdp", "roa", lmpc, duffing,
             "--oracle", oracle, "-o", png)
    assert not png.exists()
    code, out, err = _run(capsys, "roa", lmpc, "--oracle", oracle, "-o", png)
    assert code == 0 and err == [] and out.splitlines()[-1] == f"wrote {png}"
    assert out.startswith("vdp: lmpc: success 4/4, where the oracle succeeds 4/4, J/J_oracle min 1.000, median 1.000")
    # x0 on one line (no triangulation: qhull's 'singular input' was a traceback) and an oracle that fails once
    code, out, err = _run(capsys, "roa", lmpc, "--oracle", _csv(tmp_path / "vdp_d.csv", success="False"), "-o", png)
    assert code == 0 and err == [] and "where the oracle succeeds 3/3" in out


def test_theorem1_takes_the_run_folder_or_its_run_mcap(run_dir, tmp_path, capsys):
    for source in (run_dir, run_dir / "run.mcap"):
        code, out, err = _run(capsys, "theorem1", source, "-o", tmp_path / "t1.png")
        assert code == 0 and err == [] and out.splitlines()[-1] == f"wrote {tmp_path / 't1.png'}"
    lone = tmp_path / "lone"
    lone.mkdir()
    _log(lone / "run.mcap", 5)
    _refused(capsys, f"model file {lone / 'model.npz'} does not exist", "theorem1", lone / "run.mcap",
             "-o", tmp_path / "t.png")
    (lone / "model.npz").write_bytes((run_dir / "model.npz").read_bytes())
    (lone / "run.mcap").unlink()   # a log is created exclusively
    _log(lone / "run.mcap", 1)
    _refused(capsys, "run.mcap: 1 step in the log, 2 needed", "theorem1", lone, "-o", tmp_path / "t.png")
    _refused(capsys, "not a run folder nor an .mcap log", "theorem1", run_dir / "model.npz", "-o", tmp_path / "t.png")


def test_the_installed_command_prints_one_line_and_no_traceback(tmp_path):
    empty = _log(tmp_path / "empty.mcap", 0)
    proc = subprocess.run([sys.executable, "-m", "kexp.analysis.figures", "paper", str(empty), "-o",
                           str(tmp_path / "p.png")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == "" and "Traceback" not in proc.stderr
    (line,) = proc.stderr.splitlines()
    assert line.startswith(f"kexp-figures: error: {empty}: no steps in the log")
