"""The plants view: each configuration of a system against that system's LQR, initial condition by initial
condition, from the committed results CSVs alone.  For a plant with no formula there is no NMPC oracle (it needs
F and G), so the reference is ``<system>_lqr.csv`` (the LQR on the plant's numerical linearisation):

    kexp-results plants results/gym-pendulum_*.csv results/cartpole_*.csv

Per system and configuration (one CSV ``<system>_<configuration>.csv`` each; runs matched by their full x0,
x0_1 … x0_n, to the CSVs' 10 digits):

- success: successes / runs;
- where LQR succeeds: successes on the x0 where the LQR row succeeds / those x0;
- LQR failures saved: successes on the x0 where the LQR row fails (no success or a failed job) / those x0;
- median J: over this configuration's successful runs;
- J/J_LQR median and worst: over the x0 where both succeed;
- saved of the savable LQR failures: with ``<system>_ocp.csv`` (columns x0_1 … x0_n and ``feasible``
  True/False: whether a long-horizon optimal-control problem stabilises from that x0), the LQR failures this
  configuration saves among those the check found feasible, "k of j"; "not checked" without that file;
- J/J_oracle: "n/a (no formula)" when the system has no ``<system>_nmpc.csv``, else its J/J_oracle median.

Below the table, one line per system: how many LQR failures could be saved at all (the check's verdict).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .aggregate import ReportError
from .csvfiles import is_ocp, oserror, read_csv, split_name, x0_columns

FEASIBLE = ("True", "False")


def _key(values) -> tuple[str, ...]:
    """An x0 as the CSVs agree on it: each entry to 10 significant digits (collect's %.10g), whatever the writer's
    precision."""
    return tuple(f"{float(v):.10g}" for v in values)


def _f(v: str) -> float:
    return float(v) if v not in ("", None) else math.nan


@dataclass(frozen=True)
class Run:
    """One run of a results CSV: success and cost (nan when unknown)."""
    success: bool
    cost: float


def read_runs(path: str | Path) -> dict[tuple[str, ...], Run]:
    """{x0 key: Run} of a results CSV (checked by :func:`kexp.results.csvfiles.read_csv`); runs without an x0 (failed
    jobs that never said theirs) cannot be matched and are left out."""
    rows = read_csv(path)
    cols = x0_columns(rows[0])
    return {_key(r[c] for c in cols): Run(r["success"] == "True", _f(r["cost"])) for r in rows
            if all(r[c] != "" for c in cols)}


def read_ocp(path: str | Path) -> dict[tuple[str, ...], bool]:
    """{x0 key: feasible} of ``<system>_ocp.csv`` (columns x0_1 … x0_n and feasible True/False, one row per x0);
    ReportError (one line naming the file, the line and the column) otherwise."""
    path = Path(path)
    hint = "write x0_1 … x0_n and feasible (True or False) per initial condition"
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            cols = x0_columns(header, path)
            if not cols or "feasible" not in header:
                missing = ([] if cols else ["x0_1 … x0_n"]) + ([] if "feasible" in header else ["feasible"])
                raise ReportError(f"{path}: not an optimal-control check: missing columns {', '.join(missing)}; "
                                  f"{hint}")
            out = {}
            for r in reader:
                if None in r or None in r.values():
                    raise ReportError(f"{path}, line {reader.line_num}: not as many fields as the header; {hint}")
                try:
                    x = [float(r[c]) for c in cols]
                except ValueError:
                    x = [math.nan]
                if not all(math.isfinite(v) for v in x):
                    raise ReportError(f"{path}, line {reader.line_num}: x0 ({', '.join(r[c] for c in cols)}) is not "
                                      f"finite numbers; {hint}")
                if r["feasible"] not in FEASIBLE:
                    raise ReportError(f"{path}, line {reader.line_num}: column feasible holds {r['feasible']!r}; "
                                      f"{hint}")
                out[_key(x)] = r["feasible"] == "True"
    except UnicodeDecodeError:
        raise ReportError(f"{path}: not a text CSV; {hint}") from None
    except csv.Error as exc:
        raise ReportError(f"{path}: not a CSV ({exc}); {hint}") from None
    except OSError as exc:
        raise ReportError(f"cannot read {oserror(exc)}") from None
    if not out:
        raise ReportError(f"{path}: an optimal-control check with no rows; {hint}")
    return out


@dataclass(frozen=True)
class Row:
    """One configuration of a system against its LQR (the numbers of one table row).  Counts are over the x0 both
    CSVs ran; ``ratios`` J / J_LQR over the x0 where both succeed; ``savable`` (saved, feasible LQR failures)
    or None without an optimal-control check; ``oracle`` the J / J_oracle median or None without an oracle."""
    system: str
    config: str
    successes: int
    runs: int
    on_lqr_successes: tuple[int, int] | None
    on_lqr_failures: tuple[int, int] | None
    median_cost: float
    ratios: tuple[float, ...]
    savable: tuple[int, int] | None
    oracle: float | None


def compare(runs: dict, lqr: dict | None, ocp: dict | None, oracle: dict | None, system: str, config: str) -> Row:
    """The :class:`Row` of one configuration's ``runs`` against the system's ``lqr`` runs (None: no LQR row),
    its optimal-control check ``ocp`` and its ``oracle`` runs (None: none)."""
    costs = [r.cost for r in runs.values() if r.success]
    ok_on = fail_on = savable = None
    ratios: list[float] = []
    if lqr is not None:
        common = [k for k in runs if k in lqr]
        good = [k for k in common if lqr[k].success]
        bad = [k for k in common if not lqr[k].success]
        ok_on = (sum(runs[k].success for k in good), len(good))
        fail_on = (sum(runs[k].success for k in bad), len(bad))
        ratios = [runs[k].cost / lqr[k].cost for k in good if runs[k].success and lqr[k].cost > 0]
        if ocp is not None:
            feasible = [k for k in bad if ocp.get(k)]
            savable = (sum(runs[k].success for k in feasible), len(feasible))
    ratio_o = None
    if oracle is not None:
        ro = [runs[k].cost / oracle[k].cost for k in runs
              if k in oracle and runs[k].success and oracle[k].success and oracle[k].cost > 0]
        ratio_o = float(np.median(ro)) if ro else math.nan
    return Row(system, config, sum(r.success for r in runs.values()), len(runs), ok_on, fail_on,
               float(np.median(costs)) if costs else math.nan, tuple(ratios), savable, ratio_o)


def _frac(kn) -> str:
    return "–" if kn is None else f"{kn[0]}/{kn[1]}"


def _num(x: float) -> str:
    return "–" if math.isnan(x) else f"{x:.3f}"


def _line(r: Row, has_ocp: bool) -> str:
    med = _num(float(np.median(r.ratios))) if r.ratios else "–"
    worst = _num(max(r.ratios)) if r.ratios else "–"
    saved = "–" if r.on_lqr_failures is None else f"{r.on_lqr_failures[0]} of {r.on_lqr_failures[1]}"
    could = ("–" if r.on_lqr_failures is None else "not checked" if not has_ocp
             else f"{r.savable[0]} of {r.savable[1]}")
    oracle = "n/a (no formula)" if r.oracle is None else _num(r.oracle)
    return (f"| {r.system} | {r.config} | {_frac((r.successes, r.runs))} | {_frac(r.on_lqr_successes)} | {saved} "
            f"| {_num(r.median_cost)} | {med} | {worst} | {could} | {oracle} |")


def _footnote(system: str, lqr: dict | None, ocp: dict | None, ocp_name: str) -> str:
    if lqr is None:
        return f"- {system}: no {system}_lqr.csv: no LQR reference, the columns against it say –"
    bad = [k for k, r in lqr.items() if not r.success]
    if ocp is None:
        return (f"- {system}: LQR fails from {len(bad)} of {len(lqr)} x0; LQR failures that could be saved: not "
                f"checked (no {ocp_name})")
    feasible = sum(bool(ocp.get(k)) for k in bad)
    unchecked = sum(k not in ocp for k in bad)
    tail = f"; {unchecked} not in the check" if unchecked else ""
    return (f"- {system}: LQR fails from {len(bad)} of {len(lqr)} x0; LQR failures that could be saved: {feasible} "
            f"of {len(bad)} (a long-horizon optimal-control problem stabilises from them, {ocp_name}{tail})")


def table(paths) -> str:
    """The Markdown plants view of the results CSVs ``paths`` (``<system>_ocp.csv`` among them read as the
    optimal-control check): one row per system and configuration, then one line per system on its LQR failures.
    ReportError when a CSV is unreadable or two CSVs of one name are given."""
    results: dict[str, dict[str, Path]] = {}
    ocps: dict[str, Path] = {}
    for p in sorted({Path(p).resolve(): Path(p) for p in paths}.values()):
        system, config = split_name(p)
        where = ocps if is_ocp(p) else results.setdefault(system, {})
        key = system if is_ocp(p) else config
        if key in where:
            raise ReportError(f"{where[key]} and {p}: two CSVs named {p.name}; pass one of them")
        where[key] = p
    for system in ocps:
        if system not in results:
            raise ReportError(f"{ocps[system]}: an optimal-control check of {system} without any results CSV of "
                              f"{system}; pass the system's rows too")
    lines = ["| system | configuration | success | where LQR succeeds | LQR failures saved | median J "
             "| J/J_LQR median | J/J_LQR worst | saved of the savable LQR failures | J/J_oracle |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    notes = []
    for system, configs in sorted(results.items()):
        runs = {c: read_runs(p) for c, p in configs.items()}
        ocp = read_ocp(ocps[system]) if system in ocps else None
        lqr, oracle = runs.get("lqr"), runs.get("nmpc")
        for config in sorted(runs):
            lines.append(_line(compare(runs[config], lqr, ocp, oracle, system, config), ocp is not None))
        notes.append(_footnote(system, lqr, ocp, f"{system}_ocp.csv"))
    return "\n".join(lines + [""] + notes)
