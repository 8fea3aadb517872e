"""``kexp-report``: one table (and a few pictures) for a Hydra sweep of ``kexp`` runs.

    kexp --multirun hydra/launcher=joblib 'sim.x0=[0.5,0.5],[-0.5,0.5]' clf.gamma=1,2
    kexp-report multirun/2025-01-01/12-00-00            # writes report.csv, report.md, ... into that folder

The rows (one per job; a failed or never-started job keeps its row and its ``reason``) and their groups come from
:mod:`kexp.app.aggregate`; this module writes them as report.csv, report_summary.csv, report.md and PNG pictures
(with matplotlib), and is the command line.
"""
from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

from ..cli import Parser
from .aggregate import ReportError, aggregate, summarize

CSV_NAME, MD_NAME, SUMMARY_CSV_NAME = "report.csv", "report.md", "report_summary.csv"
PICTURES = {"roa": "roa.png", "cost": "cost_hist.png", "solve_time": "solve_time_hist.png"}
CSV_COLUMNS = ["job", "overrides", "system", "controller", "x0", "status", "success", "final_error", "cost",
               "settling_time_s", "max_abs_u", "fallbacks", "solve_median_ms", "solve_p99_ms", "certificate",
               "certificate_verdict", "clf_status", "wall_time_s", "reason", "all_overrides", "path"]
SUMMARY_COLUMNS = ["group", "runs", "completed", "failed", "successes", "success_rate", "cost_median", "cost_worst",
                   "solve_median_ms", "solve_p99_worst_ms"]
NO_MATPLOTLIB = "pictures skipped: matplotlib is not installed (pip install matplotlib)"


# ------------------------------------------------------------------------------------------------------ output
def _csv_value(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "inf" if math.isinf(v) else repr(v)
    if isinstance(v, (list, tuple)):
        return json.dumps(v)
    return str(v)


def write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow([_csv_value(" ".join(r["override_list"]) if c == "all_overrides" else r.get(c))
                        for c in CSV_COLUMNS])


def write_summary_csv(groups: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(SUMMARY_COLUMNS)
        for g in groups:
            w.writerow([_csv_value(g[c]) for c in SUMMARY_COLUMNS])


def _fmt(v: Any, spec: str = ".4g") -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "never" if math.isinf(v) else format(v, spec)
    if isinstance(v, list):
        return "[" + ", ".join(format(x, "g") if isinstance(x, (int, float)) else str(x) for x in v) + "]"
    return str(v)


def _md_cell(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def rate(successes: int, n: int) -> str:
    return f"{successes}/{n} ({100.0 * successes / n:.0f} %)" if n else "0/0"


def write_markdown(rows: list[dict], groups: list[dict], path: Path, sweep_dir: Path,
                   pictures: dict[str, str] | None, picture_note: str | None) -> None:
    n = len(rows)
    ok = sum(r["ok"] for r in rows)
    succ = sum(bool(r["success"]) for r in rows)
    failed = [r for r in rows if not r["ok"]]
    lines = [f"# kexp sweep report: {sweep_dir}", "",
             f"**{n} runs**: {ok} completed, {len(failed)} failed; success {rate(succ, n)} "
             "(a failed run counts as no success).", "",
             "## Summary (per group of identical overrides apart from `sim.x0`)", "",
             "| group | runs | failed | success | median cost | worst cost | median solve [ms] | worst p99 [ms] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for g in groups:
        lines.append(f"| {_md_cell(g['group'])} | {g['runs']} | {g['failed']} | {rate(g['successes'], g['runs'])} "
                     f"| {_fmt(g['cost_median'])} | {_fmt(g['cost_worst'])} | {_fmt(g['solve_median_ms'], '.3f')} "
                     f"| {_fmt(g['solve_p99_worst_ms'], '.3f')} |")
    lines += ["", f"## Failed runs ({len(failed)})", ""]
    if failed:
        lines += [f"- `{_md_cell(r['job'])}` {_md_cell(r['overrides'])}: {_md_cell(r['reason'])}" for r in failed]
    else:
        lines.append("none")
    lines += ["", "## Runs", "",
              "| job | overrides | system | controller | x0 | status | success | cost | settling [s] | max abs u "
              "| fallbacks | solve median [ms] | solve p99 [ms] | certificate |",
              "|---|---|---|---|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        lines.append("| " + " | ".join(_md_cell(x) for x in [
            r["job"], r["overrides"] or "–", _fmt(r["system"]), _fmt(r["controller"]), _fmt(r["x0"]),
            _fmt(r["status"]), _fmt(r["success"]), _fmt(r["cost"]), _fmt(r["settling_time_s"], ".3g"),
            _fmt(r["max_abs_u"]), _fmt(r["fallbacks"]), _fmt(r["solve_median_ms"], ".3f"),
            _fmt(r["solve_p99_ms"], ".3f"), _fmt(r["certificate"])]) + " |")
    lines += ["", "certificate: `global` = Proposition 1 holds globally, `samples` = h decreases V at every sampled "
              "state of the region only, `fails` = neither (full verdicts in report.csv).", "", "## Pictures", ""]
    if pictures:
        titles = {"roa": "Success over the initial conditions (estimate of the region of attraction)",
                  "cost": "Cost distribution", "solve_time": "Solve-time distribution"}
        for key, name in pictures.items():
            lines += [f"![{titles[key]}]({name})", ""]
    if picture_note:
        lines += [picture_note, ""]
    path.write_text("\n".join(lines).rstrip() + "\n")


def write_pictures(rows: list[dict], groups: list[dict], out_dir: Path) -> dict[str, str]:
    """roa.png, cost_hist.png, solve_time_hist.png; raises ImportError when matplotlib is missing."""
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    written: dict[str, str] = {}
    labels = [g["group"] for g in groups]
    by_group = {lab: [r for r in rows if r.get("group", "(all)") == lab] for lab in labels}
    with_x0 = [lab for lab in labels if any(r["x0"] for r in by_group[lab])]
    if with_x0:
        shown = with_x0[:12]
        ncols = min(len(shown), 3)
        nrows = math.ceil(len(shown) / ncols)
        fig = Figure(figsize=(4.2 * ncols, 4.0 * nrows), layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
        kinds = [("success", dict(marker="o", color="tab:green")), ("no success", dict(marker="o", color="tab:red")),
                 ("diverged", dict(marker="x", color="tab:red")), ("failed job", dict(marker="x", color="0.5"))]
        for ax, lab in zip(axes, shown):
            for name, style in kinds:
                pts = []
                for r in by_group[lab]:
                    if not r["x0"]:
                        continue
                    kind = ("success" if r["success"] else "no success") if r["ok"] else \
                        ("diverged" if r["status"] == "diverged" else "failed job")
                    if kind == name:
                        pts.append((r["x0"][0], r["x0"][1] if len(r["x0"]) > 1 else 0.0))
                if pts:
                    ax.scatter(*zip(*pts), label=name, s=36, **style)
            n = max(len(r["x0"]) for r in by_group[lab] if r["x0"])
            note = f"\nprojection onto (x1, x2) of {n} states" if n > 2 else ""  # say so: not the whole x0
            ax.set_title((lab if len(lab) < 60 else lab[:57] + "...") + note, fontsize=9)
            ax.set_xlabel("x1(0)")
            ax.set_ylabel("x2(0)")
            ax.grid(True, alpha=0.3)
            ax.set_aspect("equal", adjustable="datalim")
            ax.legend(fontsize=8)
        for ax in axes[len(shown):]:
            ax.set_visible(False)
        fig.suptitle("success over the initial conditions" +
                     (f" (first {len(shown)} of {len(with_x0)} groups)" if len(with_x0) > len(shown) else ""))
        fig.savefig(out_dir / PICTURES["roa"], dpi=100)
        written["roa"] = PICTURES["roa"]

    def hist(ax, key, title, xlabel):
        import numpy as np
        values = {lab: [r[key] for r in by_group[lab] if r[key] is not None and math.isfinite(r[key])]
                  for lab in labels[:8]}
        every = [v for vs in values.values() for v in vs]
        if not every:
            return False
        bins = np.histogram_bin_edges(every, bins=min(30, max(5, len(every) // 2)))
        drawn = False
        for lab, v in values.items():
            if v:
                ax.hist(v, bins=bins, alpha=0.6 if len(labels) > 1 else 0.9, label=lab[:40])
                drawn = True
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("runs")
        from matplotlib.ticker import MaxNLocator
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        if drawn and len(labels) > 1:
            ax.legend(fontsize=7)
        return drawn

    fig = Figure(figsize=(6, 4), layout="constrained")
    if hist(fig.subplots(), "cost", "cost J per run", "J"):
        fig.savefig(out_dir / PICTURES["cost"], dpi=100)
        written["cost"] = PICTURES["cost"]
    fig = Figure(figsize=(10, 4), layout="constrained")
    a, b = fig.subplots(1, 2)
    if hist(a, "solve_median_ms", "median solve time per run", "ms") | hist(b, "solve_p99_ms", "p99 solve time per run",
                                                                             "ms"):
        fig.savefig(out_dir / PICTURES["solve_time"], dpi=100)
        written["solve_time"] = PICTURES["solve_time"]
    return written


def report(sweep_dir: str | Path, out_dir: str | Path | None = None, *, pictures: bool = True) -> dict:
    """aggregate + write report.csv, report_summary.csv, report.md and the pictures into ``out_dir`` (default:
    the sweep folder).  Returns {'rows', 'groups', 'files', 'picture_note'}."""
    rows = aggregate(sweep_dir)
    groups = summarize(rows)
    out = Path(out_dir) if out_dir is not None else Path(sweep_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / CSV_NAME, out / SUMMARY_CSV_NAME, out / MD_NAME]
    write_csv(rows, files[0])
    write_summary_csv(groups, files[1])
    written, note = {}, None
    if pictures:
        try:
            written = write_pictures(rows, groups, out)
        except ImportError:
            note = NO_MATPLOTLIB
    write_markdown(rows, groups, files[2], Path(sweep_dir).resolve(), written, note)
    files += [out / name for name in written.values()]
    return {"rows": rows, "groups": groups, "files": files, "picture_note": note}


def _main(argv) -> int:
    p = Parser(prog="kexp-report", description="Tabulate a sweep of kexp runs (kexp --multirun): "
                                "report.csv, report_summary.csv, report.md and PNG pictures (with matplotlib).")
    p.add_argument("sweep_dir", help="the sweep folder (e.g. multirun/<date>/<time>), searched recursively")
    p.add_argument("-o", "--out", dest="out_dir", default=None, help="output folder (default: the sweep folder)")
    p.add_argument("--no-pictures", action="store_true", help="skip the PNG pictures")
    args = p.parse_args(argv)
    if Path(args.sweep_dir).is_file():
        print(f"kexp-report: error: {args.sweep_dir} is a file; give the sweep folder (e.g. multirun/<date>/<time>)",
              file=sys.stderr)
        return 2
    if args.out_dir is not None and Path(args.out_dir).exists() and not Path(args.out_dir).is_dir():
        print(f"kexp-report: error: -o {args.out_dir} is a file; give a folder", file=sys.stderr)
        return 2
    try:
        res = report(args.sweep_dir, args.out_dir, pictures=not args.no_pictures)
    except ReportError as exc:
        print(f"kexp-report: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:   # an output folder that cannot be made or written (-o a file, a read-only place)
        print(f"kexp-report: error: cannot write the report: {exc.filename}: {exc.strerror or exc}; give a folder "
              "you can write with -o", file=sys.stderr)
        return 2
    rows = res["rows"]
    n, ok = len(rows), sum(r["ok"] for r in rows)
    print(f"kexp-report: {n} runs, {ok} completed, {n - ok} failed; success "
          f"{rate(sum(bool(r['success']) for r in rows), n)}")
    for r in [r for r in rows if not r["ok"]][:20]:
        print(f"  failed: {r['job']} {r['overrides']}: {r['reason']}")
    if n - ok > 20:
        print(f"  ... and {n - ok - 20} more (see report.md)")
    if res["picture_note"]:
        print(f"kexp-report: {res['picture_note']}", file=sys.stderr)
    print("wrote " + ", ".join(str(f) for f in res["files"]))
    return 0


def main(argv=None) -> None:
    sys.exit(_main(argv))


if __name__ == "__main__":
    main()
