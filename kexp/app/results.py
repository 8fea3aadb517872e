"""The results table: from sweeps over initial conditions to one row per system and configuration, with the cost
ratio to the oracle (nonlinear MPC with the true model) on the same initial conditions.

    kexp-results collect SWEEP_DIR NAME [-o results/]   # condense a sweep into results/NAME.csv (committed)
    kexp-results table results/*.csv                     # print the Markdown table (the README's)
    kexp-results robustness results/*.csv results/robustness/*.csv   # the robustness table (the README's)

The condensed CSVs are small and committed, so the table can be regenerated (and is, by a test) without
re-running the sweeps.  A CSV's name is ``<system>_<config>.csv``; the oracle of a system is its ``*_nmpc.csv``.
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from .aggregate import ReportError, aggregate

COLUMNS = ["x0_1", "x0_2", "status", "success", "cost", "settling_time_s", "solve_median_ms", "solve_p99_ms",
           "max_abs_u", "fallbacks", "certificate", "controller", "inputs", "data_noise", "smoothing", "sim_noise",
           "mismatch"]


def collect(sweep_dir: str | Path, name: str, out_dir: str | Path) -> Path:
    rows = aggregate(sweep_dir)
    out = Path(out_dir) / f"{name}.csv"
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for r in sorted(rows, key=lambda r: tuple(r["x0"] or [np.inf, np.inf])):
            x0 = r["x0"] or [None, None]
            vals = [x0[0], x0[1], r["status"], r["success"], r["cost"], r["settling_time_s"], r["solve_median_ms"],
                    r["solve_p99_ms"], r["max_abs_u"], r["fallbacks"], r["certificate"], r["controller"], r["inputs"],
                    r["data_noise"], r["smoothing"], r["sim_noise"], r["mismatch"]]
            w.writerow(["" if v is None else (f"{v:.10g}" if isinstance(v, float) else v) for v in vals])
    return out


def _load(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _f(v: str) -> float:
    return float(v) if v not in ("", None) else float("nan")


def table(paths: list[str | Path]) -> str:
    data = {Path(p).stem: _load(Path(p)) for p in sorted(paths)}
    lines = ["| system | configuration | success | median J | worst J | J / J_oracle median | J / J_oracle worst "
             "| median settling [s] | solve median / p99 [ms] | certificate |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name, rows in data.items():
        system, _, config = name.partition("_")
        oracle = {(r["x0_1"], r["x0_2"]): _f(r["cost"]) for r in data.get(f"{system}_nmpc", [])}
        ok = [r for r in rows if r["status"] == "completed"]
        succ = sum(r["success"] == "True" for r in rows)
        cost = np.array([_f(r["cost"]) for r in ok])
        ratios = np.array([_f(r["cost"]) / oracle[(r["x0_1"], r["x0_2"])] for r in ok
                           if (r["x0_1"], r["x0_2"]) in oracle])
        settle = np.array([_f(r["settling_time_s"]) for r in ok])
        settle = settle[np.isfinite(settle)]
        med = np.array([_f(r["solve_median_ms"]) for r in ok])
        p99 = np.array([_f(r["solve_p99_ms"]) for r in ok])
        words = {"global": "Prop. 1 holds", "samples": "Prop. 1 fails; V̇(h) < 0 on the grid", "fails": "not a CLF"}
        certs = sorted({words.get(r["certificate"], r["certificate"]) for r in ok if r["certificate"]})
        if config in ("lqr", "nmpc"):
            certs = ["n/a (true model)"]
        fmt = lambda a, f=".3f", agg=np.median: "–" if a.size == 0 else format(agg(a), f)  # noqa: E731
        lines.append(
            f"| {system} | {config} | {succ}/{len(rows)} | {fmt(cost)} | {fmt(cost, agg=np.max)} | "
            f"{fmt(ratios)} | {fmt(ratios, agg=np.max)} | {fmt(settle, '.2f')} | "
            f"{fmt(med, '.2f')} / {fmt(p99, '.2f', np.max)} | {'; '.join(certs) or '–'} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="kexp-results", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect", help="condense a sweep into NAME.csv")
    c.add_argument("sweep")
    c.add_argument("name", help="<system>_<configuration>, e.g. pendulum_lmpc; the oracle is <system>_nmpc")
    c.add_argument("-o", "--out", default="results")
    t = sub.add_parser("table", help="print the Markdown results table")
    t.add_argument("csv", nargs="+")
    rb = sub.add_parser("robustness", help="print the Markdown robustness table (kexp.app.robustness)")
    rb.add_argument("csv", nargs="+")
    args = p.parse_args(argv)
    try:
        if args.cmd == "collect":
            print(f"wrote {collect(args.sweep, args.name, args.out)}")
        elif args.cmd == "robustness":
            from .robustness import table as robustness_table
            print(robustness_table(args.csv))
        else:
            print(table(args.csv))
    except (ReportError, OSError) as exc:
        print(f"kexp-results: error: {exc}", file=sys.stderr)
        sys.exit(2)
    sys.exit(0)


if __name__ == "__main__":
    main()
