"""The long-horizon oracle (issue 35): results/horizon/<system>_nmpc-h300.csv are the true-model NMPC with a 3-s
horizon by kexp's SQP at the results table's 100 initial conditions (results/robustness.sh <system>_nmpc-h300), and
results/horizon.md is their table against the tables' own oracle, never typed by hand."""
from __future__ import annotations

import csv
from pathlib import Path

from kexp.app.results import table

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_committed_horizon_table_is_generated_from_the_committed_csvs():
    rows = sorted((RESULTS / "horizon").glob("*_nmpc-h300.csv"))
    assert len(rows) == 4, "results/robustness.sh {vanderpol,pendulum,duffing,cart_pendulum}_nmpc-h300"
    oracles = [RESULTS / (p.name.replace("-h300", "")) for p in rows]
    committed = RESULTS / "horizon.md"
    assert committed.is_file(), "kexp-results table results/*_nmpc.csv results/horizon/*.csv > results/horizon.md"
    assert table(sorted(oracles) + rows).strip() == committed.read_text().strip()
    for long, short in zip(rows, oracles):
        got, ref = _rows(long), _rows(short)
        # the same 100 x0, each run by the SQP oracle, to completion
        assert [(r["x0_1"], r["x0_2"]) for r in got] == [(r["x0_1"], r["x0_2"]) for r in ref] and len(got) == 100
        assert {r["controller"] for r in got} == {"nmpc_sqp"} and {r["status"] for r in got} == {"completed"}
