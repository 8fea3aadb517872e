"""What a sweep says while it runs, in the ``kexp`` process: one launch line, a ``[k/N]`` line per job as it ends
(in the order the jobs end, with an ETA), and a closing line pointing to ``kexp-report``.

The jobs run wherever the launcher puts them (this process, joblib's workers, submitit's); each writes its
``summary.json`` when it ends.  :class:`Progress` watches the sweep folder from a thread of the ``kexp`` process
(every :data:`POLL_S` seconds) and prints a line for each job whose summary says it ended; when the launcher
returns, a last look prints the jobs not seen yet (a job that wrote no summary is an error).

One word per outcome, everywhere (sweep lines, kexp-report, the single run's result line):

* ``settled``: the run completed and reached the target set (``metrics.success``);
* ``unsettled``: the run completed but did not reach it (not an error: a result);
* ``error``: the run stopped with an error (its summary says ``"status": "error"``, or it wrote none);
* ``identified``: a ``system=data`` run without a plant, which stops after the certificate (no closed loop).
"""
from __future__ import annotations

import json
import math
import os
import re
import sys
import threading
import time
from pathlib import Path
from typing import Sequence

SETTLED, UNSETTLED, ERROR, IDENTIFIED = "settled", "unsettled", "error", "identified"
POLL_S = 0.25
OVERRIDES_WIDTH = 60   # characters of a job's overrides in its line
_FLOAT = re.compile(r"(?<![\w.])[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?(?![\w.])")


def verdict(summary: dict | None) -> str:
    """The outcome word of a run from its summary.json (None: the run wrote none, an error)."""
    if not isinstance(summary, dict) or summary.get("status") == "error" or summary.get("completed") is not True:
        return ERROR
    metrics = summary.get("metrics")
    if not isinstance(metrics, dict):
        return IDENTIFIED
    return SETTLED if metrics.get("success") is True else UNSETTLED


def ended(summary: dict | None) -> bool:
    """Whether a summary.json says its run ended (completed, or stopped with an error), not that it is running."""
    return isinstance(summary, dict) and (summary.get("completed") is True or summary.get("status") == "error")


def round_floats(text: str, digits: int = 4) -> str:
    """``text`` with every decimal number in it written with ``digits`` significant digits (integers stay)."""
    def short(m: re.Match) -> str:
        s = m.group(0)
        if re.fullmatch(r"[-+]?\d+", s):
            return s
        return f"{float(s):.{digits}g}"
    return _FLOAT.sub(short, text)


def shorten(overrides: Sequence[str], varying: set[str] | None = None, width: int = OVERRIDES_WIDTH) -> str:
    """A job's overrides for its line: only those whose key takes several values in the sweep (``varying``: the
    keys; None: all), floats to 4 significant digits, cut at ``width`` characters with '…'."""
    shown = [o for o in overrides if varying is None or o.split("=", 1)[0] in varying] or list(overrides)
    text = " ".join(round_floats(o) for o in shown)
    return text if len(text) <= width else text[:width - 1] + "…"


def varying_keys(jobs: Sequence[Sequence[str]]) -> set[str] | None:
    """The override keys whose value differs between ``jobs`` (None when there is one job: show them all)."""
    if len(jobs) < 2:
        return None
    given = [dict(o.partition("=")[::2] for o in job) for job in jobs]
    keys = {k for job in given for k in job}
    return {k for k in keys if len({job.get(k) for job in given}) > 1}


def duration(seconds: float) -> str:
    """A duration for a person: "8 s", "3 min 20 s", "2 h 05 min"."""
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def outcome_text(summary: dict | None) -> str:
    """The few numbers (or the error) that follow a job's word in its line."""
    word = verdict(summary)
    if summary is None:
        return "no summary.json"
    if word == ERROR:
        error = summary.get("error") if isinstance(summary.get("error"), dict) else summary
        message = str(error.get("message") or f"no final summary (status {summary.get('status')})")
        return message if len(message) <= 120 else message[:119] + "…"
    if word == IDENTIFIED:
        clf = summary.get("clf") or {}
        return f"k = {(summary.get('model') or {}).get('k')}, CLF {clf.get('status')} (no plant: no closed loop)"
    m = summary["metrics"]
    settle = m.get("settling_time")
    settle = "inf" if settle is None or not math.isfinite(settle) else f"{settle:.2f} s"
    status = summary.get("status")
    return ((f"{status}, " if status not in (None, "completed") else "")
            + f"‖x(T)‖ = {m.get('final_error', float('nan')):.2e}, J = {m.get('cost', float('nan')):.4g}, "
              f"settling {settle}")


def read_summary(folder: Path) -> dict | None:
    try:
        data = json.loads((Path(folder) / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _overrides_of(folder: Path) -> tuple[str, ...] | None:
    """The overrides Hydra recorded for the job in ``folder`` (``.hydra/overrides.yaml``, a YAML list of strings)."""
    try:
        import yaml
        data = yaml.safe_load((folder / ".hydra" / "overrides.yaml").read_text())
    except Exception:   # noqa: BLE001 - not written yet, or unreadable: the job is found by its number instead
        return None
    return tuple(str(o) for o in data) if isinstance(data, list) else None


class Progress:
    """The lines of one sweep: ``jobs`` (every job's overrides, in job-number order) into ``sweep_dir``."""

    def __init__(self, sweep_dir: Path, jobs: Sequence[Sequence[str]], workers: int | None = None, out=None,
                 clock=time.monotonic):
        self.sweep_dir = Path(sweep_dir)
        self.jobs = [tuple(j) for j in jobs]
        self.workers = workers
        self.out = out or sys.stdout
        self.clock = clock
        self.varying = varying_keys(self.jobs)
        self.numbers = {}
        for num, job in enumerate(self.jobs):
            self.numbers.setdefault(job, num)
        self.before = set(self._ended_folders())   # a resumed sweep's finished runs are not this sweep's lines
        self.done: dict[int, str] = {}             # job number -> its word
        self.skipped = 0
        self.started = None
        self._seen: set[str] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None

    @property
    def total(self) -> int:
        return len(self.jobs)

    def launch_line(self) -> str:
        workers = f" ({self.workers} worker{'s' if self.workers != 1 else ''})" if self.workers else ""
        return f"kexp: sweep of {self.total} job{'s' if self.total != 1 else ''}{workers} -> {self.sweep_dir}"

    def _ended_folders(self):
        if not self.sweep_dir.is_dir():
            return
        for dirpath, dirnames, filenames in os.walk(self.sweep_dir):
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            if "summary.json" in filenames and ended(read_summary(Path(dirpath))):
                try:
                    st = os.stat(os.path.join(dirpath, "summary.json"))
                except OSError:
                    continue
                yield os.path.abspath(dirpath), (st.st_ino, st.st_mtime_ns)

    def _emit(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def job_line(self, num: int | None, folder: Path, summary: dict | None) -> str:
        """The ``[k/N]`` line of the job that just ended (call once per job: it counts)."""
        word = verdict(summary)
        if num is not None:
            self.done[num] = word
        k = len(self.done) + self.skipped
        elapsed = self.clock() - (self.started if self.started is not None else self.clock())
        ran = len(self.done)
        left = self.total - k
        when = (f"ETA {duration(elapsed / ran * left)}" if left > 0 and ran else f"{duration(elapsed)} in all")
        overrides = shorten(self.jobs[num], self.varying) if num is not None else str(folder)
        label = f"#{num}" if num is not None else ""
        return f"[{k}/{self.total}] {word:<10} {label} {overrides}: {outcome_text(summary)}; {when}"

    def skip(self, n: int = 1) -> None:
        """``n`` jobs a resumed sweep skipped (complete already): they count as done."""
        self.skipped += n

    def scan(self) -> None:
        """Print a line for each job that ended since the last look, in the order their summaries were written."""
        with self._lock:
            new = []
            for folder, stamp in self._ended_folders():
                if (folder, stamp) in self.before or folder in self._seen:
                    continue
                new.append((stamp[1], folder))
            for _, folder in sorted(new):
                overrides = _overrides_of(Path(folder))
                num = self.numbers.get(overrides) if overrides is not None else None
                if num is None:
                    name = os.path.basename(folder)   # hydra.sweep.subdir's default: the job's number
                    num = int(name) if name.isdigit() and int(name) < self.total else None
                if num is None or num in self.done:
                    continue   # not (yet) a job of this sweep as far as can be told
                self._seen.add(folder)
                self._emit(self.job_line(num, Path(folder), read_summary(Path(folder))))

    def finish(self, returned: Sequence[tuple[int, Path | None]]) -> None:
        """After the launcher returned the jobs ``returned`` ((number, folder)): a last look, then a line for
        each job not seen (from its summary, or an error without one)."""
        self.scan()
        with self._lock:
            for num, folder in returned:
                if num in self.done:
                    continue
                summary = read_summary(folder) if folder is not None else None
                if folder is not None:
                    self._seen.add(os.path.abspath(folder))
                self._emit(self.job_line(num, folder or self.sweep_dir, summary))

    def closing_line(self) -> str:
        words = list(self.done.values())
        n_err = words.count(ERROR)
        finished = len(words) - n_err + self.skipped
        parts = [f"{words.count(w)} {w}" for w in (SETTLED, UNSETTLED, IDENTIFIED) if words.count(w)]
        if self.skipped:
            parts.append(f"{self.skipped} skipped (complete already)")
        elapsed = self.clock() - self.started if self.started is not None else 0.0
        return (f"kexp: sweep done in {duration(elapsed)}: {finished}/{self.total} completed"
                f"{' (' + ', '.join(parts) + ')' if parts else ''}, {n_err} error{'s' if n_err != 1 else ''}; "
                f"kexp-report {self.sweep_dir}")

    # -- the watching thread --------------------------------------------------------------------------------------
    def __enter__(self):
        if self.started is None:
            self.started = self.clock()
        self._stop.clear()
        self._thread = threading.Thread(target=self._watch, name="kexp-sweep-progress", daemon=True)
        self._thread.start()
        return self

    def _watch(self):
        while not self._stop.wait(POLL_S):
            try:
                self.scan()
            except Exception:   # noqa: BLE001 - the lines are a courtesy: a failed look never stops the sweep
                pass

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        return False


def workers_of(launcher_cfg) -> int | None:
    """How many jobs the launcher runs at once, when the config says (joblib's n_jobs, Hydra's basic launcher: 1)."""
    try:
        target = str(launcher_cfg.get("_target_", ""))
        if target.endswith("BasicLauncher"):
            return 1
        n = launcher_cfg.get("n_jobs")
        if n is None:
            return None
        n = int(n)
        return n if n > 0 else max(1, (os.cpu_count() or 1) + 1 + n)
    except (AttributeError, TypeError, ValueError):
        return None
