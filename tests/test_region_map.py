"""Region maps against the oracle (kexp-figures roa CSV... --oracle CSV): the numbers in the titles and the
printed lines are computed per x0 against the oracle's run on the same x0; bad input is one line, exit code 2."""
import csv

import numpy as np
import pytest

from kexp.analysis.figures import main as figures_main
from kexp.analysis.region_map import RegionMapError, compare, read_results, region_map
from kexp.app.results import COLUMNS


def _write(path, x0s, success, cost):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for (a, b), s, c in zip(x0s, success, cost):
            row = {k: "" for k in COLUMNS}
            row.update(x0_1=repr(a), x0_2=repr(b), status="completed", success=str(bool(s)), cost=repr(c))
            w.writerow([row[k] for k in COLUMNS])
    return path


@pytest.fixture
def grid(tmp_path):
    """A 12 × 12 grid on [-2, 2]²: the oracle fails where x1 > 1 (cost 1 elsewhere); 'mpc' fails where the oracle
    does and at (−2, −2), costs 1 + 0.1·|x1| elsewhere; 'lqr' fails where x2 > 1 too."""
    g = np.linspace(-2, 2, 12)
    x0s = [(float(a), float(b)) for a in g for b in g]
    o_ok = [a <= 1 for a, _ in x0s]
    mpc_ok = [ok and not (a == -2 and b == -2) for ok, (a, b) in zip(o_ok, x0s)]
    lqr_ok = [ok and b <= 1 for ok, (_, b) in zip(o_ok, x0s)]
    return (x0s, _write(tmp_path / "sys_nmpc.csv", x0s, o_ok, [1.0] * len(x0s)),
            _write(tmp_path / "sys_mpc.csv", x0s, mpc_ok, [1 + 0.1 * abs(a) for a, _ in x0s]),
            _write(tmp_path / "sys_lqr.csv", x0s, lqr_ok, [1.0] * len(x0s)))


def test_counts_and_ratios_per_initial_condition(grid, tmp_path, capsys):
    x0s, oracle, mpc, lqr = grid
    ref = read_results(oracle)
    f = compare(read_results(mpc), ref)
    n_oracle = sum(a <= 1 for a, _ in x0s)            # 9 of 12 columns: 108
    assert (f["runs"], f["common"], f["oracle_successes"]) == (144, 144, n_oracle)
    assert f["both"] == n_oracle - 1 and f["successes"] == n_oracle - 1
    ratios = [1 + 0.1 * abs(a) for a, b in x0s if a <= 1 and not (a == -2 and b == -2)]
    assert f["median_ratio"] == pytest.approx(np.median(ratios), abs=1e-12)
    assert f["worst_ratio"] == pytest.approx(1.2, abs=1e-12)
    g = compare(read_results(lqr), ref)
    assert g["both"] == sum(a <= 1 and b <= 1 for a, b in x0s) and g["median_ratio"] == 1.0
    out = tmp_path / "map.png"
    with pytest.raises(SystemExit) as exc:
        figures_main(["roa", str(mpc), str(lqr), "--oracle", str(oracle), "-o", str(out)])
    assert exc.value.code == 0 and out.stat().st_size > 10_000
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"sys: mpc: success {n_oracle - 1}/144, where the oracle succeeds "
                               f"{n_oracle - 1}/{n_oracle}")


def test_bad_input_is_one_line(grid, tmp_path, capsys):
    x0s, oracle, mpc, _ = grid
    other = _write(tmp_path / "sys_far.csv", [(5.0, 5.0)], [True], [1.0])
    with pytest.raises(RegionMapError, match="no initial condition in common"):
        region_map([other], oracle, tmp_path / "x.png")
    (tmp_path / "junk.csv").write_text("a,b\n1,2\n")
    for argv in (["roa", str(tmp_path / "junk.csv"), "--oracle", str(oracle)],
                 ["roa", str(mpc), "--oracle", str(tmp_path / "missing.csv")],
                 ["roa", str(other), "--oracle", str(oracle)]):
        with pytest.raises(SystemExit) as exc:
            figures_main([*argv, "-o", str(tmp_path / "y.png")])
        err = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 2 and len(err) == 1 and err[0].startswith("kexp-figures: error:"), err
    with pytest.raises(SystemExit) as exc:   # CSVs without --oracle: argparse's usage error, exit 2
        figures_main(["roa", str(mpc), "-o", str(tmp_path / "z.png")])
    assert exc.value.code == 2 and not (tmp_path / "y.png").exists()


def test_committed_regions_table_is_the_docs():
    """results/regions.md is `kexp-results table results/regions/*.csv` of the committed CSVs, and docs/results.md
    includes it (the far-region and tight-bound rows of issue 13 are never typed by hand)."""
    from pathlib import Path

    from kexp.app.results import table
    root = Path(__file__).resolve().parents[1]
    csvs = sorted((root / "results" / "regions").glob("*.csv"))
    committed = root / "results" / "regions.md"
    assert csvs and committed.is_file(), ("results/regions/*.csv and regions.md are committed: kexp-results table "
                                          "results/regions/*.csv > results/regions.md")
    assert table(csvs).strip() == committed.read_text().strip()
    assert '\n--8<-- "results/regions.md"\n' in (root / "docs" / "results.md").read_text()


def test_committed_region_map_table_is_the_docs():
    """results/regions_map.md is `kexp-results table results/regions/map/*.csv` (the maps' 400 x0 per row: the
    row's 100 and default_rng(43)'s 300), and docs/results.md includes it."""
    from pathlib import Path

    from kexp.app.results import table
    root = Path(__file__).resolve().parents[1]
    csvs = sorted((root / "results" / "regions" / "map").glob("*.csv"))
    committed = root / "results" / "regions_map.md"
    assert csvs and committed.is_file(), ("results/regions/map/*.csv and regions_map.md are committed: kexp-results "
                                          "table results/regions/map/*.csv > results/regions_map.md")
    assert all(sum(1 for _ in open(c)) == 401 for c in csvs)      # 400 x0 and the header
    assert table(csvs).strip() == committed.read_text().strip()
    assert '\n--8<-- "results/regions_map.md"\n' in (root / "docs" / "results.md").read_text()


def test_a_panel_is_labelled_by_system_and_configuration():
    """The configuration follows the last '_' (kexp.app.results.split_name): a system may be named cart_pendulum."""
    from pathlib import Path
    from kexp.analysis.region_map import _label
    assert _label(Path("r/cart_pendulum_lmpc-reg.csv")) == "cart_pendulum: lmpc-reg"
    assert _label(Path("r/pendulum-u0.5_nmpc.csv")) == "pendulum-u0.5: nmpc"
