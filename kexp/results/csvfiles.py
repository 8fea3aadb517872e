"""The reading layer of the results CSVs: their columns (x0_1 … x0_n, then the run's measures), names
(``<system>_<config>.csv``), checks (:func:`read_csv`: bad input is a :class:`~kexp.results.aggregate.ReportError`
of one line naming the file, the line and the column; also for ``kexp-figures roa --oracle``), :func:`collect` (a
sweep folder condensed into one committed CSV) and the line naming the oracle's solver.  Every other results module
reads CSVs through this one; it imports only :mod:`kexp.results.aggregate`.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

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

