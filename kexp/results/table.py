"""The results table (``kexp-results table``): one Markdown row per ``<system>_<config>.csv`` with successes,
median and worst J, the cost ratio to the oracle (nonlinear MPC with the true model, ``<system>_nmpc.csv``) on the
same initial conditions, settling and solve times and the certificate.  Reads the CSVs through
:mod:`kexp.results.csvfiles`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .aggregate import ReportError
from .csvfiles import NO_ORACLE, TABLE_NEEDED, is_ocp, oracle_line, read_csv, split_stem, x0_columns, x0_key


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

