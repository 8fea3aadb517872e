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
it is the optimal-control feasibility check the plants view reads (kexp.app.plants_view), skipped here.
:func:`read_csv` checks a CSV as ``collect`` writes it (also for ``kexp-figures roa --oracle``): bad input is a
:class:`~kexp.app.aggregate.ReportError` of one line naming the file, the line and the column.
"""
from __future__ import annotations

import csv
import math
import re
import sys
from pathlib import Path

import numpy as np

from ..cli import Parser, emit
from .aggregate import ReportError, aggregate

REST = ["status", "success", "cost", "settling_time_s", "solve_median_ms", "solve_p99_ms", "max_abs_u",
        "fallbacks", "certificate", "controller", "inputs", "data_noise", "smoothing", "sim_noise", "mismatch",
        "estimator", "sim_noise_per_x0"]
"""The columns after the initial condition's x0_1 … x0_n, in collect's order."""


def columns(n: int) -> list[str]:
    """collect's columns for runs of ``n`` states: x0_1 … x0_n, then :data:`REST`."""
    return [f"x0_{i}" for i in range(1, n + 1)] + REST


COLUMNS = columns(2)                             # the built-in systems' (2 states): the committed CSVs' order
X0 = "x0_1 … x0_n"                               # stands for the x0 columns in NEEDED: as many as the CSV's states
NEEDED = (X0, "status", "success", "cost")       # every reader; CSVs before 'controller' lack the rest
TABLE_NEEDED = NEEDED + ("settling_time_s", "solve_median_ms", "solve_p99_ms", "certificate")
NUMERIC = ("cost", "settling_time_s", "solve_median_ms", "solve_p99_ms", "max_abs_u", "fallbacks",
           "data_noise", "sim_noise")            # and x0_1 … x0_n: '' (unknown) or a finite number;
#                                                  settling_time_s may be 'inf'
X0_COLUMN = re.compile(r"x0_([0-9]+)")
OCP = "ocp"                                      # <system>_ocp.csv: the feasibility check, not a row
SUCCESS = ("True", "False", "")                  # what collect writes: the run's success, '' when it has none
# <system>_<configuration>: the configuration is what follows the last "_" (a system may be named cart_pendulum)
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]*_[A-Za-z0-9.+-]+")
HINT = "pass a results CSV written by kexp-results collect"


def split_name(path: str | Path) -> tuple[str, str]:
    """(system, configuration) of a results CSV named ``<system>_<configuration>.csv`` (the configuration follows the
    last underscore, so a system's name may hold one: cart_pendulum_lmpc); ReportError otherwise."""
    stem = Path(path).stem
    if not NAME.fullmatch(stem):
        raise ReportError(f"{path}: the file name is not <system>_<configuration>.csv (e.g. pendulum_lmpc.csv); "
                          "rename it so that the system and the configuration can be read from it")
    return split_stem(stem)


def split_stem(stem: str) -> tuple[str, str]:
    """(system, configuration) of a checked name ``<system>_<configuration>``: split at the last underscore."""
    system, _, config = stem.rpartition("_")
    return system, config


def x0_columns(header, path="") -> list[str]:
    """The x0 columns of a CSV header, x0_1 … x0_n in order (n >= 1; [] when it has none); ReportError when they
    are not numbered 1 … n without a gap (an x0_3 without an x0_2)."""
    nums = sorted(int(m.group(1)) for c in header if (m := X0_COLUMN.fullmatch(c)))
    if nums and nums != list(range(1, len(nums) + 1)):
        gap = next(i for i in range(1, nums[-1] + 1) if i not in nums)
        raise ReportError(f"{path}: column x0_{nums[-1]} without x0_{gap}: the initial condition's columns are "
                          f"x0_1 … x0_n, one per state; fix the header or collect the CSV again")
    return [f"x0_{i}" for i in nums]


def x0_key(row: dict, cols: list[str]) -> tuple[str, ...]:
    """A run's full initial condition as the CSV writes it (the strings of the x0 columns ``cols``)."""
    return tuple(row[c] for c in cols)


def is_ocp(path: str | Path) -> bool:
    """Whether ``path`` is a ``<system>_ocp.csv`` (the plants view's feasibility check, no results row)."""
    stem = Path(path).stem
    return bool(NAME.fullmatch(stem)) and split_stem(stem)[1] == OCP


def oserror(exc: OSError) -> str:
    """'PATH: what went wrong' of an OSError, without Python's '[Errno N]'."""
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


def read_csv(path: str | Path, needed=NEEDED) -> list[dict]:
    """The rows of a results CSV (``collect``'s), each a dict of strings, after checking that the file is a text
    CSV with a ``<system>_<configuration>`` name, the ``needed`` columns and at least one row, that the numeric
    columns hold numbers ('' for unknown) and ``success`` holds True, False or ''.  ReportError (one line) names
    the file, the line and the column otherwise."""
    path = Path(path)
    if path.is_dir():
        raise ReportError(f"{path}: is a folder; pass the CSV files in it (e.g. {path}/*.csv)")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:   # -sig: a spreadsheet's byte-order mark
            reader = csv.DictReader(f)
            header = reader.fieldnames
            if not header:
                raise ReportError(f"{path}: empty file, not a results CSV; {HINT}")
            x0 = x0_columns(header, path)
            missing = [c for c in needed if c not in header and c != X0]
            if X0 in needed and not x0:
                missing.insert(0, "x0_1, x0_2, … (one per state)")
            if missing:
                raise ReportError(f"{path}: not a results CSV: missing columns {', '.join(missing)}; {HINT}")
            rows = []
            for r in reader:
                if None in r or None in r.values():
                    raise ReportError(f"{path}, line {reader.line_num}: {'more' if None in r else 'fewer'} fields "
                                      f"than the header's {len(header)}; {HINT}")
                rows.append((reader.line_num, r))
    except UnicodeDecodeError:
        raise ReportError(f"{path}: not a text CSV (binary data: an .mcap log?); {HINT}") from None
    except csv.Error as exc:
        raise ReportError(f"{path}: not a CSV ({exc}); {HINT}") from None
    except OSError as exc:
        raise ReportError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not rows:
        raise ReportError(f"{path}: a results CSV with no rows (only the header); collect it again from its sweep")
    split_name(path)
    for line, r in rows:
        for col in (*x0, *NUMERIC):
            v = r.get(col)
            if v in ("", None):
                continue
            try:
                x = float(v)
            except ValueError:
                x = math.nan
            if math.isnan(x) or (math.isinf(x) and not (col == "settling_time_s" and x > 0)):
                raise ReportError(f"{path}, line {line}: column {col} holds {v!r}, not a finite number "
                                  "('' when unknown); fix or collect the CSV again")
        if r["success"] not in SUCCESS:
            raise ReportError(f"{path}, line {line}: column success holds {r['success']!r}; collect writes True, "
                              "False or '' (no result): fix or collect the CSV again")
        if r["success"] == "True" and r["cost"] == "":
            raise ReportError(f"{path}, line {line}: a success without a cost; fix or collect the CSV again")
    return [r for _, r in rows]


def collect(sweep_dir: str | Path, name: str, out_dir: str | Path) -> Path:
    if not NAME.fullmatch(name):
        raise ReportError(f"NAME {name!r}: give <system>_<configuration>, e.g. pendulum_lmpc (letters, digits, "
                          "'.', '+', '-'; the configuration follows the last '_'; no path: choose the folder with -o)")
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ReportError(f"-o {out_dir}: is a file; give the folder to write {name}.csv into")
    rows = aggregate(sweep_dir)
    n = _states(rows, sweep_dir)
    out = out_dir / f"{name}.csv"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"-o {out_dir}: cannot create the folder: {oserror(exc)}") from None
    if out.is_dir():
        raise ReportError(f"{out}: is a folder; remove it or choose another -o")
    with open(out, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(columns(n))
        for r in sorted(rows, key=lambda r: tuple(r["x0"] or [np.inf] * n)):
            x0 = r["x0"] or [None] * n
            vals = [*x0, r["status"], r["success"], r["cost"], r["settling_time_s"], r["solve_median_ms"],
                    r["solve_p99_ms"], r["max_abs_u"], r["fallbacks"], r["certificate"], r["controller"], r["inputs"],
                    r["data_noise"], r["smoothing"], r["sim_noise"], r["mismatch"], r["estimator"],
                    r["sim_noise_per_x0"]]
            w.writerow(["" if v is None else (f"{v:.10g}" if isinstance(v, float) else v) for v in vals])
    return out


def _states(rows: list[dict], sweep_dir) -> int:
    """The number of states of a sweep's runs: the length of their x0 (2 when no run has one: a sweep of failed
    jobs keeps the built-in systems' columns); ReportError when runs of one sweep have x0 of different lengths."""
    lengths = sorted({len(r["x0"]) for r in rows if r["x0"]})
    if len(lengths) > 1:
        raise ReportError(f"{sweep_dir}: runs with x0 of {' and '.join(map(str, lengths))} states; one system (one "
                          "number of states) per sweep: collect each system's runs from its own sweep")
    if lengths and lengths[0] < 1:
        raise ReportError(f"{sweep_dir}: runs with an empty x0; collect a sweep over sim.x0")
    return lengths[0] if lengths else 2


def _load_all(paths, needed) -> dict[str, list[dict]]:
    """{file stem: rows} of ``paths`` (read_csv); the same file twice counts once, two files of one name refused."""
    data, where = {}, {}
    for p in sorted(map(Path, paths)):
        if is_ocp(p):
            continue                  # the plants view's feasibility check, no row
        stem = p.stem
        if stem in where and where[stem].resolve() != p.resolve():
            raise ReportError(f"{where[stem]} and {p}: two CSVs named {p.name}; one row per "
                              "<system>_<configuration>: pass one of them")
        if stem not in where:
            where[stem], data[stem] = p, read_csv(p, needed)
    return data


def _f(v: str) -> float:
    return float(v) if v not in ("", None) else float("nan")


NO_ORACLE = "n/a (no oracle)"     # a system without <system>_nmpc.csv: a plant with no formula, no NMPC oracle
# the oracle's solver by its controller name (runs from before the column had only IPOPT's oracle)
ORACLE_SOLVERS = {"nmpc_oracle": "CasADi + IPOPT", "nmpc_sqp": "kexp's compiled SQP"}


def oracle_line(paths: list[str | Path], *, exact: bool = False) -> str:
    """The line under a table that says which solver made its J_oracle: from the ``controller`` column of the
    ``<system>_nmpc*.csv`` among ``paths`` (with ``exact``, ``<system>_nmpc.csv`` alone: the results table's J_oracle;
    '' when there is none)."""
    solvers: dict[str, set] = {}
    for p in sorted({Path(q) for q in paths}):
        config = "" if is_ocp(p) else split_name(p)[1]
        if (config != "nmpc") if exact else (config.split("-")[0] != "nmpc"):
            continue
        for r in read_csv(p):
            name = r.get("controller") or "nmpc_oracle"
            solvers.setdefault(ORACLE_SOLVERS.get(name, name), set()).add(split_name(p)[0])
    if not solvers:
        return ""
    if len(solvers) == 1:
        return f"J_oracle (J*): the true-model NMPC solved by {next(iter(solvers))} for every system."
    return "J_oracle (J*): the true-model NMPC solved by " + "; ".join(
        f"{s} ({', '.join(sorted(v))})" for s, v in sorted(solvers.items())) + "."


def table(paths: list[str | Path]) -> str:
    """The Markdown results table of ``paths`` (one row per CSV; ``<system>_ocp.csv`` skipped): successes, median
    and worst J, J / J_oracle per x0 against ``<system>_nmpc`` (:data:`NO_ORACLE` without one), settling and
    solve times, the certificate."""
    data = _load_all(paths, TABLE_NEEDED)
    lines = ["| system | configuration | success | median J | worst J | J / J_oracle median | J / J_oracle worst "
             "| median settling [s] | solve median / p99 [ms] | certificate |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name, rows in data.items():
        system, config = split_stem(name)
        has_oracle = f"{system}_nmpc" in data
        oracle_rows = data.get(f"{system}_nmpc", [])
        ocols = x0_columns(oracle_rows[0]) if oracle_rows else []
        oracle = {x0_key(r, ocols): _f(r["cost"]) for r in oracle_rows}
        cols = x0_columns(rows[0])
        ok = [r for r in rows if r["status"] == "completed"]
        succ = sum(r["success"] == "True" for r in rows)
        cost = np.array([_f(r["cost"]) for r in ok])
        ratios = np.array([_f(r["cost"]) / oracle[x0_key(r, cols)] for r in ok if x0_key(r, cols) in oracle])
        settle = np.array([_f(r["settling_time_s"]) for r in ok])
        settle = settle[np.isfinite(settle)]
        med = np.array([_f(r["solve_median_ms"]) for r in ok])
        p99 = np.array([_f(r["solve_p99_ms"]) for r in ok])
        words = {"global": "Prop. 1 holds", "samples": "Prop. 1 fails; V̇(h) < 0 on the grid", "fails": "not a CLF",
                 "not in x": "not a CLF in x (V does not bound the state)"}
        certs = sorted({words.get(r["certificate"], r["certificate"]) for r in ok if r["certificate"]})
        # the true-model rows (nmpc-h300 too); a system without an oracle is a plant: its LQR is on a linearisation
        if config.split("-")[0] in ("lqr", "nmpc"):
            certs = ["n/a (true model)" if has_oracle else "n/a (linearisation)"]
        fmt = lambda a, f=".3f", agg=np.median: "–" if a.size == 0 else format(agg(a), f)  # noqa: E731
        r_med, r_max = (fmt(ratios), fmt(ratios, agg=np.max)) if has_oracle else (NO_ORACLE, NO_ORACLE)
        lines.append(
            f"| {system} | {config} | {succ}/{len(rows)} | {fmt(cost)} | {fmt(cost, agg=np.max)} | "
            f"{r_med} | {r_max} | {fmt(settle, '.2f')} | "
            f"{fmt(med, '.2f')} / {fmt(p99, '.2f', np.max)} | {'; '.join(certs) or '–'} |")
    note = oracle_line(paths, exact=True)
    return "\n".join(lines + (["", note] if note else []))


def main(argv=None) -> None:
    p = Parser(prog="kexp-results", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect", help="condense a sweep into NAME.csv")
    c.add_argument("sweep")
    c.add_argument("name", help="<system>_<configuration>, e.g. pendulum_lmpc; the oracle is <system>_nmpc")
    c.add_argument("-o", "--out", default="results", help="the folder to write NAME.csv into (created)")
    t = sub.add_parser("table", help="print the Markdown results table")
    t.add_argument("csv", nargs="+")
    rb = sub.add_parser("robustness", help="print the Markdown robustness table (kexp.app.robustness)")
    rb.add_argument("csv", nargs="+")
    sa = sub.add_parser("sample", help="print N of a CSV's x0 as one Hydra list value (kexp.app.reproduce)")
    sa.add_argument("csv")
    sa.add_argument("n", type=int, help="how many x0, evenly spaced over the CSV's rows")
    co = sub.add_parser("compare", help="compare a re-run's CSV with the committed one, run by run (exit 1 if "
                                        "any run disagrees)")
    co.add_argument("committed")
    co.add_argument("new")
    co.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance on cost and max |u| (1e-6)")
    pl = sub.add_parser("plants", help="print the Markdown plants view: each configuration against the system's "
                                       "LQR, x0 by x0 (kexp.app.plants_view)")
    pl.add_argument("csv", nargs="+", help="<system>_<configuration>.csv rows (and <system>_ocp.csv, if any)")
    x0 = sub.add_parser("x0", help="print N x0 drawn from a box of n states as one Hydra list value "
                                   "(kexp.app.reproduce.generated_x0)")
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
