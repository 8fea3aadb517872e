"""``kexp-report``: one table (and a few pictures) for a Hydra sweep of ``kexp`` runs.

    kexp --multirun hydra/launcher=joblib 'sim.x0=[0.5,0.5],[-0.5,0.5]' clf.gamma=1,2
    kexp-report multirun/2025-01-01/12-00-00            # writes report.csv, report.md, ... into that folder

The rows (one per job; a failed or never-started job keeps its row and its ``reason``) and their groups come from
:mod:`kexp.app.aggregate`; this module writes them as report.csv, report_summary.csv, report.md and PNG pictures
(with matplotlib), and is the command line.
"""
from __future__ import annotations

import csv
import functools
import json
import math
import sys
from pathlib import Path
from typing import Any

from ..analysis import roa
from ..cli import Parser
from .aggregate import ReportError, aggregate, summarize

CSV_NAME, MD_NAME, SUMMARY_CSV_NAME = "report.csv", "report.md", "report_summary.csv"
PICTURES = {"roa": "roa.png", "cost": "cost_hist.png", "solve_time": "solve_time_hist.png"}
CSV_COLUMNS = ["job", "overrides", "system", "controller", "x0", "status", "success", "final_error", "cost",
               "settling_time_s", "max_abs_u", "fallbacks", "solve_median_ms", "solve_p99_ms", "certificate",
               "certificate_verdict", "clf_status", "wall_time_s", "reason", "all_overrides", "path"]
SUMMARY_COLUMNS = ["group", "runs", "completed", "errors", "successes", "success_rate", "cost_median", "cost_worst",
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


def errors(n: int) -> str:
    """"1 error", "3 errors": runs that stopped with an error (kexp.app.sweep_progress's words)."""
    return f"{n} error{'' if n == 1 else 's'}"


def rate(successes: int, n: int) -> str:
    return f"{successes}/{n} ({100.0 * successes / n:.0f} %)" if n else "0/0"


def write_markdown(rows: list[dict], groups: list[dict], path: Path, sweep_dir: Path,
                   pictures: dict[str, str] | None, picture_note: str | None) -> None:
    n = len(rows)
    ok = sum(r["ok"] for r in rows)
    succ = sum(bool(r["success"]) for r in rows)
    with_error = [r for r in rows if not r["ok"]]
    lines = [f"# kexp sweep report: {sweep_dir}", "",
             f"**{n} runs**: {ok} completed, {errors(len(with_error))}; settled {rate(succ, n)} "
             "(a run that stopped with an error counts as not settled).", "",
             "## Summary (per group of identical overrides apart from `sim.x0`)", "",
             "| group | runs | errors | settled | median cost | worst cost | median solve [ms] | worst p99 [ms] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for g in groups:
        lines.append(f"| {_md_cell(g['group'])} | {g['runs']} | {g['errors']} | {rate(g['successes'], g['runs'])} "
                     f"| {_fmt(g['cost_median'])} | {_fmt(g['cost_worst'])} | {_fmt(g['solve_median_ms'], '.3f')} "
                     f"| {_fmt(g['solve_p99_worst_ms'], '.3f')} |")
    lines += ["", f"## Runs that stopped with an error ({len(with_error)})", ""]
    if with_error:
        lines += [f"- `{_md_cell(r['job'])}` {_md_cell(r['overrides'])}: {_md_cell(r['reason'])}" for r in with_error]
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
              "state of the region only, `fails` = neither, `not in x` = V does not bound the state (a decrease of V "
              "does not keep it in the region; full verdicts in report.csv).", "", "## Pictures", ""]
    if pictures:
        titles = {"roa": "Success over the initial conditions (estimate of the region of attraction)",
                  "cost": "Cost of the successful runs", "solve_time": "Solve-time distribution"}
        for key, name in pictures.items():
            lines += [f"![{titles[key]}]({name})", ""]
    if picture_note:
        lines += [picture_note, ""]
    path.write_text("\n".join(lines).rstrip() + "\n")


NOT_SETTLED = roa.NOT_SETTLED
KINDS = (("settled", dict(marker="o", color="tab:green")), (NOT_SETTLED, dict(marker="o", color="tab:orange")),
         ("unsettled", dict(marker="o", color="tab:red")), ("diverged", dict(marker="x", color="tab:red")),
         ("error", dict(marker="x", color="0.5")))
EDGE = dict(edgecolor="white", linewidth=1.5)   # histogram bars: adjacent bins of one run each stay apart
RUG_BELOW = 10                                 # fewer values than this: a rug of the values under the histogram


def sim_settings(row: dict) -> tuple[float | None, float | None]:
    """(T, tol) of a job (``sim.T``, ``sim.tol``: success is ‖x(T) − x_eq‖ < tol), as kexp.analysis.roa reads
    them; None where the job folder tells neither."""
    return _sim_settings(row.get("path") or "")


@functools.lru_cache(maxsize=None)
def _sim_settings(path: str) -> tuple[float | None, float | None]:
    sim = roa.sim_settings(Path(path)) if path else {}
    return sim.get("T"), sim.get("tol")


def _kind(row: dict) -> str:
    """kexp.analysis.roa's kind of a run (settled, unsettled near, unsettled, diverged), a job that did not
    complete an error."""
    if not row["ok"] and row["status"] != "diverged":
        return "error"
    return roa.run_kind(row, sim_settings(row)[1])


def _state_names(members: list[dict], n: int) -> list[str]:
    """As kexp.analysis.roa: the state names the group's first log records (/model), else the built-in system's,
    else x1 … xn."""
    for r in members:
        mcap = Path(r["path"]) / "run.mcap" if r.get("path") else None
        if mcap is None or not mcap.is_file():
            continue
        try:
            from ..recording.reader import read_log
            logged = (read_log(mcap).one("/model") or {}).get("state_names")
        except Exception:   # a damaged log: the names are a label, the report still gets written
            logged = None
        if logged and len(logged) == n:
            return [str(x) for x in logged]
        break
    return roa.fallback_state_names(members, n)


def success_rule(members: list[dict]) -> str:
    """kexp.analysis.roa's success rule over the runs' settings, e.g. 'success: ‖x(T) − x_eq‖ < 0.01 at T = 5 s'
    (several values: joined with '/')."""
    return roa.success_rule([dict(zip(("T", "tol"), sim_settings(r))) for r in members])


def _group_title(label: str, members: list[dict]) -> str:
    """What a group is: its system and controller, and its overrides apart from sim.x0 (or 'all N runs')."""
    what = ", ".join(x for key in ("system", "controller")
                     for x in dict.fromkeys(r[key] for r in members if r.get(key)))
    which = f"all {len(members)} runs of the sweep" if label == "(all)" else \
        (label if len(label) < 60 else label[:57] + "...")
    return f"{what}: {which}" if what else which


def _roa_picture(rows: list[dict], labels: list[str], by_group: dict, out_dir: Path) -> bool:
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    with_x0 = [lab for lab in labels if any(r["x0"] for r in by_group[lab])]
    if not with_x0:
        return False
    shown = with_x0[:12]
    ncols = min(len(shown), 3)
    nrows = math.ceil(len(shown) / ncols)
    fig = Figure(figsize=(4.8 * ncols, 4.6 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax, lab in zip(axes, shown):
        members = by_group[lab]
        n = max(len(r["x0"]) for r in members if r["x0"])
        names = _state_names(members, n)
        for name, style in KINDS:
            pts = [(r["x0"][0], r["x0"][1] if len(r["x0"]) > 1 else 0.0)
                   for r in members if r["x0"] and _kind(r) == name]
            if pts:
                ax.scatter(*zip(*pts), label=f"{name} ({len(pts)})", s=36, **style)
        note = f"\nprojection onto ({names[0]}, {names[1]}) of {n} states" if n > 2 else ""  # not the whole x0
        ax.set_title(f"{_group_title(lab, members)}{note}\n{success_rule(members)}", fontsize=9)
        ax.set_xlabel(f"{names[0]}(0)")
        ax.set_ylabel(f"{names[1]}(0)" if n > 1 else "")
        ax.grid(True, alpha=0.3)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    for ax in axes[len(shown):]:
        ax.set_visible(False)
    fig.suptitle(f"success over the initial conditions: {len(rows)} runs" +
                 (f" (first {len(shown)} of {len(with_x0)} groups)" if len(with_x0) > len(shown) else ""))
    fig.savefig(out_dir / PICTURES["roa"], dpi=100)
    return True


def _hist(ax, values: dict[str, list[float]], title: str, xlabel: str) -> bool:
    """One histogram per group (white bar edges) and, for fewer than RUG_BELOW values, a rug of the values."""
    import numpy as np
    from matplotlib.ticker import MaxNLocator
    every = [v for vs in values.values() for v in vs]
    if not every:
        return False
    bins = np.histogram_bin_edges(every, bins=min(30, max(5, len(every) // 2)))
    for i, (lab, v) in enumerate((lab, v) for lab, v in values.items() if v):
        color = f"C{i}"
        ax.hist(v, bins=bins, alpha=0.6 if len(values) > 1 else 0.9, label=lab[:40], color=color, **EDGE)
        if len(every) < RUG_BELOW:
            ax.plot(v, [0.04] * len(v), "|", color="k" if len(values) == 1 else color, ms=12, mew=1.2,
                    transform=ax.get_xaxis_transform())   # x in data, y a little above the axis
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("runs")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    if len(values) > 1:
        ax.legend(fontsize=7)
    return True


def write_pictures(rows: list[dict], groups: list[dict], out_dir: Path) -> dict[str, str]:
    """roa.png, cost_hist.png (successful runs only), solve_time_hist.png; raises ImportError when matplotlib is
    missing."""
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    written: dict[str, str] = {}
    labels = [g["group"] for g in groups]
    by_group = {lab: [r for r in rows if r.get("group", "(all)") == lab] for lab in labels}
    if _roa_picture(rows, labels, by_group, out_dir):
        written["roa"] = PICTURES["roa"]

    def values(key, keep=lambda r: True):
        return {lab: [r[key] for r in by_group[lab] if keep(r) and r[key] is not None and math.isfinite(r[key])]
                for lab in labels[:8]}

    # cost: a failed run's J (cut at T, or of a run that left) is not comparable with a successful one's
    fig = Figure(figsize=(6, 4), layout="constrained")
    ax = fig.subplots()
    cost = values("cost", lambda r: bool(r["success"]))
    k = sum(map(len, cost.values()))
    if not _hist(ax, cost, f"cost J of the {k} successful runs (of {len(rows)})", "J"):
        ax.set_axis_off()
        ax.set_title(f"cost J of the 0 successful runs (of {len(rows)})")
        ax.text(0.5, 0.5, f"no run succeeded (0 of {len(rows)}):\nno cost to compare\n{success_rule(rows)}",
                ha="center", va="center", transform=ax.transAxes)
    fig.savefig(out_dir / PICTURES["cost"], dpi=100)
    written["cost"] = PICTURES["cost"]
    fig = Figure(figsize=(10, 4), layout="constrained")
    a, b = fig.subplots(1, 2)
    med, p99 = values("solve_median_ms"), values("solve_p99_ms")
    if _hist(a, med, f"median solve time per run ({sum(map(len, med.values()))} runs)", "ms") | \
            _hist(b, p99, f"p99 solve time per run ({sum(map(len, p99.values()))} runs)", "ms"):
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
    print(f"kexp-report: {n} runs: {ok} completed, {errors(n - ok)}; settled "
          f"{rate(sum(bool(r['success']) for r in rows), n)}")
    for r in [r for r in rows if not r["ok"]][:20]:
        print(f"  error: {r['job']} {r['overrides']}: {r['reason']}")
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
