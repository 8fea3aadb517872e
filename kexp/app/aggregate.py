"""Reading a Hydra sweep of ``kexp`` runs into rows and groups, for ``kexp-report`` (:mod:`kexp.app.report`),
``kexp-results`` (:mod:`kexp.app.results`) and ``kexp-figures roa`` (:mod:`kexp.analysis.roa`).

:func:`aggregate` finds every job folder under the sweep folder (a folder with a ``summary.json`` or a
``.hydra/overrides.yaml``), reads its ``summary.json`` and the job's overrides, and returns one row per job.
A job that did not complete is never dropped: it gets a row with its ``reason`` (no summary.json, interrupted,
diverged, unreadable), and a job that the sweep planned (``multirun.yaml``, basic sweeper) but never started
gets a row too.  :func:`summarize` condenses the rows per group of identical overrides apart from ``sim.x0``
(runs, completed, errors, successes, median / worst cost, median solve time, worst p99 solve time).
"""
from __future__ import annotations

import json
import math
import os
import statistics
from pathlib import Path
from typing import Any, Iterable

from ..errors import KexpError

X0_KEY = "sim.x0"


class ReportError(KexpError):
    """The sweep folder is missing or holds no runs."""


# ---------------------------------------------------------------------------------------------------- overrides
def _parser():
    from hydra.core.override_parser.overrides_parser import OverridesParser
    return OverridesParser.create()


def _split_override(text: str) -> tuple[str, str]:
    """'sim.x0=[0.5,0.5]' -> ('sim.x0', '[0.5,0.5]'); the key keeps Hydra's +/++/~ prefix."""
    key, _, value = text.partition("=")
    return key.strip(), value.strip()


def _x0_from_override(value: str) -> list[float] | None:
    try:
        parsed = _parser().parse_override(f"{X0_KEY}={value}").value()
        return [float(v) for v in parsed]
    except Exception:  # not a list of numbers: leave the row's x0 empty
        return None


def _read_overrides(job: Path) -> list[str] | None:
    path = job / ".hydra" / "overrides.yaml"
    if not path.is_file():
        return None
    import yaml
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return [str(o) for o in data] if isinstance(data, list) else None


def _planned_jobs(sweep_root: Path) -> tuple[list[list[str]] | None, list[str]]:
    """The jobs ``multirun.yaml`` says the basic sweeper launched (their override lists) and the swept keys.
    (None, keys) when it cannot tell (another sweeper, a glob over a config group, ...)."""
    import yaml
    try:
        cfg = yaml.safe_load((sweep_root / "multirun.yaml").read_text()) or {}
        hydra_cfg = cfg.get("hydra") or {}
        task = list((hydra_cfg.get("overrides") or {}).get("task") or [])
        sweeper = hydra_cfg.get("sweeper") or {}
        params = [f"{k}={v}" for k, v in (sweeper.get("params") or {}).items()]
    except Exception:
        return None, []
    try:
        parsed = _parser().parse_overrides(params + [str(t) for t in task])
    except Exception:
        return None, []
    keys = [o.get_key_element() for o in parsed if o.is_sweep_override()]
    if not str(sweeper.get("_target_", "")).endswith("BasicSweeper"):
        return None, keys
    try:
        from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
        return BasicSweeper.split_arguments(parsed, None)[0], keys
    except Exception:
        return None, keys


# ---------------------------------------------------------------------------------------------- failure reasons
class _SubmititLogs:
    """Finds a failed job's submitit error stream: the ``*_submitted.pkl`` holding all of the job's override
    strings (matched exactly, as pickled strings) names the folder whose ``*_log.err`` tells what happened."""

    def __init__(self, sweep_root: Path):
        pkls = sorted((sweep_root / ".submitit").glob("*/*_submitted.pkl"))
        self.folders = [(p.parent, p.read_bytes()) for p in pkls]

    @staticmethod
    def _pickled(s: str) -> bytes:
        b = s.encode()
        return (b"\x8c" + bytes([len(b)]) + b) if len(b) < 256 else (b"X" + len(b).to_bytes(4, "little") + b)

    def reason(self, overrides: list[str]) -> str | None:
        if not overrides or not self.folders:
            return None
        needles = [self._pickled(o) for o in overrides]
        hits = [folder for folder, blob in self.folders if all(n in blob for n in needles)]
        if len(hits) != 1:
            return None
        for err in sorted(hits[0].glob("*_log.err")):
            lines = [ln.strip() for ln in err.read_text(errors="replace").splitlines() if ln.strip()]
            if lines:
                return f"{lines[-1][:300]} (from {err})"
        return None


def _last_log_line(job: Path) -> str | None:
    log = job / "main.log"
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return None
    return lines[-1][:300] if lines else None


# ------------------------------------------------------------------------------------------------------ rows
def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _short_verdict(cert: dict | None) -> str | None:
    if not cert:
        return None
    if cert.get("bounds_state") is False:   # V does not bound the state: whatever the decrease
        return "not in x"
    if cert.get("global_holds"):
        return "global"
    if cert.get("holds_on_samples"):
        return "samples"
    return "fails"


def _row(job: Path, root: Path, overrides: list[str] | None, summary: dict | None, reason: str | None,
         missing_status: str = "missing") -> dict:
    ov = overrides or []
    x0 = None
    for o in ov:
        k, v = _split_override(o)
        if k.lstrip("+~") == X0_KEY:
            x0 = _x0_from_override(v)
    row: dict[str, Any] = {
        "job": "." if job == root else job.relative_to(root).as_posix(), "path": str(job),
        "override_list": ov, "overrides": "", "system": None, "controller": None, "x0": x0,
        "status": None, "ok": False, "success": None, "final_error": None, "cost": None, "settling_time_s": None,
        "max_abs_u": None, "fallbacks": None, "solve_median_ms": None, "solve_p99_ms": None, "certificate": None,
        "certificate_verdict": None, "clf_status": None, "wall_time_s": None, "reason": reason or "",
        "inputs": None, "data_noise": None, "smoothing": None, "sim_noise": None, "mismatch": None,
        "estimator": None, "sim_noise_per_x0": None,
    }
    if summary is None:
        row["status"] = missing_status
        return row
    m = summary.get("metrics") or {}
    clf = summary.get("clf") or {}
    cert = clf.get("certificate") or {}
    status = summary.get("status")
    # a system=data run without a plant stops after identification and its certificate ("identified", data_only.py):
    # it completed what it set out to do, with no closed loop and so no success
    completed = bool(summary.get("completed")) and status in ("completed", "identified")
    settle = _num(m.get("settling_time"))
    if settle is None and "settling_time" in m and summary.get("completed"):
        settle = math.inf  # summary.json writes inf (never settled within tol) as null
    row.update({
        "system": summary.get("system"), "controller": summary.get("controller"),
        "x0": summary.get("x0") if isinstance(summary.get("x0"), list) else x0,
        "status": status,
        "ok": completed,
        "success": bool(m["success"]) if isinstance(m.get("success"), bool) else None,
        "final_error": _num(m.get("final_error")), "cost": _num(m.get("cost")), "settling_time_s": settle,
        "max_abs_u": _num(m.get("max_abs_u")), "fallbacks": m.get("fallbacks"),
        "solve_median_ms": None if _num(m.get("solve_time_median")) is None else m["solve_time_median"] * 1e3,
        "solve_p99_ms": None if _num(m.get("solve_time_p99")) is None else m["solve_time_p99"] * 1e3,
        "certificate": _short_verdict(cert), "certificate_verdict": cert.get("verdict"),
        "clf_status": clf.get("status"), "wall_time_s": _num(summary.get("wall_time_s")),
        **_conditions(summary),
    })
    if not completed:
        if status == "error":  # rejected or failed with a one-line reason (kexp writes it into summary.json)
            row["reason"] = f"error: {summary.get('message', '')}"
        elif not summary.get("completed"):
            row["reason"] = (f"interrupted: summary.json says status {status!r}, completed false "
                             "(the job crashed or was killed during the run)")
            row["status"] = "interrupted"
        else:
            row["reason"] = f"status {status!r}" + (f": {summary['message']}" if summary.get("message") else "")
    return row


def _relative(std, rms) -> float | None:
    """The largest σ_i / rms_i (a noise level as a fraction of the data's RMS); 0.0 for no noise."""
    if std is None:
        return 0.0
    if not rms or len(rms) != len(std):
        return None
    return float(max(s / r for s, r in zip(std, rms)))


def _conditions(summary: dict) -> dict:
    """What a run was perturbed by, from its summary: ``inputs`` (how B, b were identified: projection on the
    known G, or regression from forced data), ``data_noise`` and ``sim_noise`` (measurement noise on the data and
    in the closed loop, as the largest fraction of the data's RMS over the states), ``smoothing`` (the filter on
    the data before identification: 'none' or e.g. 'Savitzky–Golay, window 21, order 3') and ``mismatch`` ('' or e.g.
    'mu=1.2': the plant's parameters that differ from the data's system), ``estimator`` (identification.estimator:
    'ls' or 'iv') and ``sim_noise_per_x0`` (the closed loop's noise drawn per initial condition, sim.noise.per_x0)."""
    noise = summary.get("noise") or {}
    rms = noise.get("data_rms")
    mism = ((summary.get("plant") or {}).get("mismatch")) or {}
    return {"inputs": (summary.get("model") or {}).get("inputs", "projection"),
            "data_noise": _relative(noise.get("data_noise_std"), rms),
            "smoothing": noise.get("data_smoothing") or "none",
            "sim_noise": _relative(noise.get("sim_noise_std"), rms),
            "mismatch": ";".join(f"{k}={d['plant']:g}" for k, d in sorted(mism.items())),
            "estimator": (summary.get("model") or {}).get("estimator", "ls"),
            "sim_noise_per_x0": bool(noise.get("sim_noise_per_x0", False))}


def _job_folders(root: Path) -> list[Path]:
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        here = Path(dirpath)
        if "summary.json" in filenames or (here / ".hydra" / "overrides.yaml").is_file():
            found.append(here)
    return found


def _sort_key(job: str):
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in job.split("/")]


def aggregate(sweep_dir: str | Path) -> list[dict]:
    """One row (a dict) per job under ``sweep_dir``: the CSV columns (``x0`` a list, times in ms / s, ``success``
    a bool or None) plus ``ok`` (completed without divergence), ``override_list`` (the job's overrides) and
    ``reason`` (why the job failed, '' when it did not).  Raises :class:`ReportError` if the folder does not exist
    or holds no job."""
    root = Path(sweep_dir)
    if not root.is_dir():
        raise ReportError(f"{sweep_dir}: no such folder")
    root = root.resolve()
    rows: list[dict] = []
    submitit: dict[Path, _SubmititLogs] = {}
    for job in _job_folders(root):
        overrides = _read_overrides(job)
        summary, reason, missing = None, None, "missing"
        spath = job / "summary.json"
        if spath.is_file():
            try:
                summary = json.loads(spath.read_text())
                if not isinstance(summary, dict):
                    raise ValueError("not a JSON object")
            except (OSError, ValueError) as exc:
                summary, reason = None, f"summary.json unreadable: {exc}"
                missing = "unreadable"
        else:
            reason = "no summary.json (the job crashed or was killed before its run started)"
            sweep_root = next((p for p in [job, *job.parents] if (p / ".submitit").is_dir()), None)
            hint = None
            if sweep_root is not None:
                logs = submitit.setdefault(sweep_root, _SubmititLogs(sweep_root))
                hint = logs.reason(overrides or [])
            hint = hint or _last_log_line(job)
            if hint:
                reason += f"; last error line: {hint}"
        rows.append(_row(job, root, overrides, summary, reason, missing))
    # jobs the basic sweeper planned but that never got a folder (the sweep stopped before them)
    swept: list[str] = []
    for mr in sorted(root.rglob("multirun.yaml")):
        sroot = mr.parent
        planned, keys = _planned_jobs(sroot)
        swept += [k for k in keys if k not in swept]
        mine = [r for r in rows if Path(r["path"]) == sroot or sroot in Path(r["path"]).parents]
        if planned is None or any(not r["override_list"] for r in mine):
            continue  # cannot match jobs to the plan (e.g. hydra.output_subdir=null)
        have = {tuple(sorted(r["override_list"])) for r in mine}
        for i, ov in enumerate(planned):
            if tuple(sorted(ov)) not in have:
                rows.append(_row(sroot, root, list(ov), None,
                                 "not started: no job folder (the sweep stopped before this job)", "not started"))
                rows[-1]["job"] = f"(not started #{i})" if sroot == root else \
                    f"{sroot.relative_to(root).as_posix()}/(not started #{i})"
                rows[-1]["path"] = ""
    if not rows:
        raise ReportError(f"{sweep_dir}: holds no runs (no summary.json nor .hydra/overrides.yaml below it)")
    _label(rows, swept)
    rows.sort(key=lambda r: _sort_key(r["job"]))
    return rows


def _label(rows: list[dict], swept: list[str]) -> None:
    """``overrides``: the job's values of the keys that vary across the jobs (or were swept)."""
    per_job = [dict(_split_override(o) for o in r["override_list"]) for r in rows]
    keys: list[str] = []
    for d in per_job:
        keys += [k for k in d if k not in keys]
    varying = [k for k in keys if k in swept or len({d.get(k) for d in per_job}) > 1]
    for r, d in zip(rows, per_job):
        r["overrides"] = " ".join(f"{k}={d[k]}" for k in varying if k in d)
        r["group"] = " ".join(f"{k}={d[k]}" for k in varying if k in d and k.lstrip("+~") != X0_KEY) or "(all)"
        r["_group_key"] = tuple(sorted((k, v) for k, v in d.items() if k.lstrip("+~") != X0_KEY))


# --------------------------------------------------------------------------------------------------- summary
def _median(xs: Iterable[float | None]) -> float | None:
    v = [x for x in xs if x is not None and not math.isnan(x)]
    return statistics.median(v) if v else None


def _max(xs: Iterable[float | None]) -> float | None:
    v = [x for x in xs if x is not None and not math.isnan(x)]
    return max(v) if v else None


def summarize(rows: list[dict]) -> list[dict]:
    """Per group of identical overrides apart from ``sim.x0``: runs, completed, errors (runs that stopped with an
    error, or never wrote a completed summary), successes (settled runs; an error counts as not settled), median / worst cost and median solve time over the runs that have them."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(r.get("_group_key", ()), []).append(r)
    out = []
    for members in groups.values():
        n = len(members)
        ok = sum(r["ok"] for r in members)
        succ = sum(bool(r["success"]) for r in members)
        out.append({
            "group": members[0].get("group", "(all)"), "runs": n, "completed": ok, "errors": n - ok,
            "successes": succ, "success_rate": succ / n,
            "cost_median": _median(r["cost"] for r in members), "cost_worst": _max(r["cost"] for r in members),
            "solve_median_ms": _median(r["solve_median_ms"] for r in members),
            "solve_p99_worst_ms": _max(r["solve_p99_ms"] for r in members),
        })
    return out
