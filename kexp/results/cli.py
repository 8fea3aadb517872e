"""The results table: from sweeps over initial conditions to one row per system and configuration, with the cost
ratio to the oracle (nonlinear MPC with the true model) on the same initial conditions.

    kexp-results collect SWEEP_DIR NAME [-o results/]   # condense a sweep into results/NAME.csv (committed)
    kexp-results table results/*.csv                     # print the Markdown table (the README's)
    kexp-results robustness results/*.csv results/robustness/*.csv   # the robustness table (the README's)
    kexp-results sample CSV N / compare CSV NEW.csv      # re-run a committed row's x0 and compare (reproduce.py)
    kexp-results plants results/<system>_*.csv           # each configuration against the system's LQR (plants)
    kexp-results x0 [--seed 42] [-n 100] -- L1,…,Ln H1,…,Hn  # a box's x0 as a Hydra list (reproduce.py)

The condensed CSVs are small and committed, so the table can be regenerated (and is, by a test) without
re-running the sweeps.  A CSV's name is ``<system>_<config>.csv``; the oracle of a system is its ``*_nmpc.csv``;
a system without one (a plant with no formula: no oracle can run) gets "n/a (no oracle)" in the ratio columns.
The initial condition is the columns x0_1 … x0_n, n the number of states (the runs' own x0; 2 for the built-in
systems, whose column order is unchanged), and a run is known by its full x0.  ``<system>_ocp.csv`` is no row:
it is the optimal-control feasibility check the plants view reads (kexp.results.plants_view), skipped here.
:func:`kexp.results.csvfiles.read_csv` checks a CSV as ``collect`` writes it (also for ``kexp-figures roa
--oracle``): bad input is a
:class:`~kexp.results.aggregate.ReportError` of one line naming the file, the line and the column.
This module is kexp-results' argument parsing and dispatch: the only one in kexp.results that imports the tables
(table, robustness, plants_view) and reproduce; they read the CSVs through kexp.results.csvfiles.
"""
from __future__ import annotations

import sys

from ..cli import Parser, emit
from .aggregate import ReportError
from .csvfiles import collect, oserror
from .table import table


def main(argv=None) -> None:
    p = Parser(prog="kexp-results", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect", help="condense a sweep into NAME.csv")
    c.add_argument("sweep")
    c.add_argument("name", help="<system>_<configuration>, e.g. pendulum_lmpc; the oracle is <system>_nmpc")
    c.add_argument("-o", "--out", default="results", help="the folder to write NAME.csv into (created)")
    t = sub.add_parser("table", help="print the Markdown results table")
    t.add_argument("csv", nargs="+")
    rb = sub.add_parser("robustness", help="print the Markdown robustness table (kexp.results.robustness)")
    rb.add_argument("csv", nargs="+")
    sa = sub.add_parser("sample", help="print N of a CSV's x0 as one Hydra list value (kexp.results.reproduce)")
    sa.add_argument("csv")
    sa.add_argument("n", type=int, help="how many x0, evenly spaced over the CSV's rows")
    co = sub.add_parser("compare", help="compare a re-run's CSV with the committed one, run by run (exit 1 if "
                                        "any run disagrees)")
    co.add_argument("committed")
    co.add_argument("new")
    co.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance on cost and max |u| (1e-6)")
    pl = sub.add_parser("plants", help="print the Markdown plants view: each configuration against the system's "
                                       "LQR, x0 by x0 (kexp.results.plants_view)")
    pl.add_argument("csv", nargs="+", help="<system>_<configuration>.csv rows (and <system>_ocp.csv, if any)")
    x0 = sub.add_parser("x0", help="print N x0 drawn from a box of n states as one Hydra list value "
                                   "(kexp.results.reproduce.generated_x0)")
    x0.add_argument("low", help="the box's low corner, one number per state, comma-separated: -0.5,-0.2,0,0")
    x0.add_argument("high", help="its high corner; a state whose low equals its high is fixed (zero velocities)")
    x0.add_argument("--seed", type=int, default=42, help="numpy default_rng seed (42)")
    x0.add_argument("-n", type=int, default=100, help="how many x0 (100)")
    args = p.parse_args(argv)
    try:
        if args.cmd in ("sample", "compare"):
            from . import reproduce
            if args.cmd == "sample":
                emit(reproduce.hydra_list(reproduce.sample(args.csv, args.n)))
            else:
                comparison = reproduce.compare(args.committed, args.new, args.rtol)
                emit(comparison.report())
                sys.exit(0 if comparison.agrees else 1)
        elif args.cmd == "plants":
            from .plants_view import table as plants_table
            emit(plants_table(args.csv))
        elif args.cmd == "x0":
            from . import reproduce
            emit(reproduce.hydra_list(reproduce.generated_x0(args.seed, reproduce.corner("low", args.low),
                                                             reproduce.corner("high", args.high), args.n)))
        elif args.cmd == "collect":
            print(f"wrote {collect(args.sweep, args.name, args.out)}")
        elif args.cmd == "robustness":
            from .robustness import table as robustness_table
            emit(robustness_table(args.csv))
        else:
            emit(table(args.csv))
    except ReportError as exc:
        print(f"kexp-results: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except OSError as exc:
        print(f"kexp-results: error: {oserror(exc)}", file=sys.stderr)
        sys.exit(2)
    sys.exit(0)


if __name__ == "__main__":
    main()
