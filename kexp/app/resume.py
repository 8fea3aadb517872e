"""A sweep's jobs in the ``kexp`` process: re-entering a sweep folder (``sweep.resume=true``) and the sweep's
verdict (its exit code).

Hydra's basic sweeper launches every job of the command line into ``hydra.sweep.dir/<subdir>`` and returns 0 however
its jobs ended.  :func:`sweep` (installed around ``BasicSweeper.sweep`` by :func:`kexp.app.sweeper.install`) adds:

* a sweep folder that holds runs already is refused before anything is written, one line and exit code 2, unless
  ``sweep.resume=true``;
* with ``sweep.resume=true`` each job is looked at before it is launched (:func:`classify`): a job whose folder holds
  its completed run (``summary.json`` with ``"completed": true``, status not ``error``, and the job's own
  ``config_hash``) is skipped with one line and its summary stays for the report; a folder that holds the run of
  another config is refused with one line (left as it is); a folder that holds an incomplete, failed or unreadable
  run is moved aside to the hidden ``.<name>.replaced-<n>`` (kexp-report does not read it) and the job runs again;
* every job's outcome is tallied (:data:`TALLY`): a job that stopped with an error (its summary says ``"status":
  "error"``, it wrote none, it raised, or it was refused) counts, and ``kexp`` exits 2 after the sweep with one
  line; a run that did not settle is a result, not an error.  A job that raised (a bug) has its traceback printed
  and the other jobs go on.

``sweep.resume`` itself is how the sweep is run, not what a job computes: it is dropped from the jobs' overrides
(their ``.hydra/overrides.yaml`` and the report's groups) and from the config hash.
"""
from __future__ import annotations

import copy
import json
import os
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from .run_folder import holds_run

RESUME_KEY = "sweep.resume"


@dataclass
class Tally:
    """The outcome of the sweep's jobs (numbers as Hydra's ``#<num>``)."""
    sweep_dir: Path
    resume: bool
    launched: list[int] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    refused: list[int] = field(default_factory=list)
    errors: list[int] = field(default_factory=list)   # launched jobs that stopped with an error, and refused ones

    @property
    def jobs(self) -> int:
        return len(self.launched) + len(self.skipped) + len(self.refused)

    def closing_lines(self) -> tuple[list[str], list[str]]:
        """(stdout lines, stderr lines) to print when the sweep is over."""
        out, err = [], []
        if self.skipped:
            out.append(f"kexp: {RESUME_KEY}: {len(self.skipped)} of {self.jobs} jobs were complete and skipped, "
                       f"{len(self.launched)} launched")
        if self.errors:
            err.append(f"kexp: {len(self.errors)} of {self.jobs} jobs stopped with an error; "
                       f"see kexp-report {self.sweep_dir}")
        return out, err


TALLY: Tally | None = None   # the last sweep of this process (the kexp command runs one)
PROGRESS = None              # its lines (kexp.app.sweep_progress.Progress), made when its first batch launches


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def folders_with_runs(sweep_dir: Path) -> list[Path]:
    """The folders below ``sweep_dir`` (hidden ones skipped, as kexp-report does) that hold a run."""
    found = []
    if not sweep_dir.is_dir():
        return found
    for dirpath, dirnames, _ in os.walk(sweep_dir):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        here = Path(dirpath)
        if here != sweep_dir and holds_run(here):
            found.append(here)
    return found


def _summary(folder: Path) -> dict | None:
    try:
        data = json.loads((folder / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def classify(folder: Path, config_hash: str | None) -> tuple[str, str]:
    """What a resumed sweep does with the job whose folder is ``folder`` and whose config hash is ``config_hash``:
    ("launch", "") for a folder without a run, ("skip", why), ("refuse", why) for another config's run, or
    ("replace", what the folder holds) for an incomplete, failed or unreadable run."""
    if not holds_run(folder):
        return "launch", ""
    summary = _summary(folder)
    recorded = summary.get("config_hash") if summary else None
    if recorded and config_hash and recorded != config_hash:
        return "refuse", (f"{folder} holds the run of another config (config_hash {recorded}; this job's is "
                          f"{config_hash}); left as it is: run the changed sweep into another hydra.sweep.dir")
    if summary and summary.get("completed") is True and summary.get("status") != "error" and recorded:
        return "skip", f"its folder holds its completed run (status {summary.get('status')}, config_hash {recorded})"
    if summary is None:
        state = "a run without a readable summary.json"
    elif summary.get("status") == "error":
        state = "a run that stopped with an error"
    else:
        state = f"an incomplete run (status {summary.get('status')!r})"
    return "replace", state


def move_aside(folder: Path) -> Path:
    """Rename ``folder`` to the first free hidden ``.<name>.replaced-<n>`` beside it (nothing is deleted)."""
    for n in range(1, 10_000):
        aside = folder.with_name(f".{folder.name}.replaced-{n}")
        if not os.path.lexists(aside):
            os.rename(folder, aside)
            return aside
    raise OSError(f"{folder}: no free name to move it aside")


def job_folder_and_hash(sweeper, overrides: Sequence[str], num: int) -> tuple[Path, str | None]:
    """The folder job ``num`` with ``overrides`` will run in and its config hash, composed as the launcher and the
    job compose them (``hash`` None when the config does not give one: the job will say why)."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf, open_dict, read_write

    from ..errors import KexpError
    from .experiment import config_dict, config_hash
    cfg = sweeper.hydra_context.config_loader.load_sweep_config(sweeper.config, list(overrides))
    with open_dict(cfg):
        cfg.hydra.job.id = f"{cfg.hydra.job.name}_{num}"
        cfg.hydra.job.num = num
    hc = HydraConfig.instance()
    previous = hc.cfg
    hc.set_config(cfg)
    try:
        folder = Path(str(OmegaConf.select(cfg, "hydra.sweep.dir"))) / str(OmegaConf.select(cfg, "hydra.sweep.subdir"))
        task = copy.deepcopy(cfg)
        with read_write(task), open_dict(task):
            del task["hydra"]
        try:
            chash = config_hash(config_dict(task))
        except (KexpError, ValueError):
            chash = None
    finally:
        hc.cfg = previous
    return folder.absolute(), chash


def _output_dir(ret) -> Path | None:
    from omegaconf import OmegaConf
    try:
        out = OmegaConf.select(ret.hydra_cfg, "hydra.runtime.output_dir")
    except Exception:   # noqa: BLE001 - a return without its Hydra config
        return None
    return Path(str(out)) if out else None


def _tally_launched(tally: Tally, rets: list, first: int) -> None:
    """Count the launched jobs' outcomes; a job that raised (a bug) gets its traceback printed and a completed
    return, so that the sweep goes on to its next batch instead of stopping there."""
    from hydra.core.utils import JobStatus
    for num, ret in enumerate(rets, start=first):
        tally.launched.append(num)
        if ret.status == JobStatus.FAILED:
            exc = ret._return_value
            print(f"kexp: internal error in job #{num} ({_output_dir(ret)}):", file=sys.stderr)
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
            ret.status, ret._return_value = JobStatus.COMPLETED, None
            tally.errors.append(num)
            continue
        folder = _output_dir(ret)
        summary = _summary(folder) if folder is not None else None
        if summary is None or summary.get("status") == "error":
            tally.errors.append(num)


def _done(overrides: Sequence[str], folder: Path):
    """A completed JobReturn for a job that was not launched (skipped or refused)."""
    from hydra.core.utils import JobReturn, JobStatus
    ret = JobReturn(overrides=list(overrides), working_dir=str(folder), task_name="kexp")
    ret.status = JobStatus.COMPLETED
    return ret


def launch(sweeper, launch_batch, batch: Sequence[Sequence[str]], initial_job_idx: int, check: bool) -> list:
    """The launcher's ``launch(batch, initial_job_idx)`` with the jobs of a resumed sweep looked at first
    (``check``: the sweep folder held runs when the sweep started); the jobs to run are launched in runs of
    consecutive numbers, so that each keeps its number and folder."""
    global PROGRESS
    from .sweep_progress import Progress, workers_of
    tally = TALLY
    if PROGRESS is None:
        jobs = [job for b in (getattr(sweeper, "overrides", None) or [batch]) for job in b]
        PROGRESS = Progress(tally.sweep_dir, jobs, workers_of(sweeper.config.hydra.launcher))
        print(PROGRESS.launch_line(), flush=True)
    progress = PROGRESS
    kinds = ["launch"] * len(batch)
    folders: list[Path | None] = [None] * len(batch)
    if check:
        for i, overrides in enumerate(batch):
            num = initial_job_idx + i
            folder, chash = job_folder_and_hash(sweeper, overrides, num)
            folders[i] = folder
            kind, why = classify(folder, chash)
            if kind == "skip":
                print(f"#{num} skipped ({RESUME_KEY}): {why}; {folder}", flush=True)
                tally.skipped.append(num)
                progress.skip()
            elif kind == "refuse":
                print(f"kexp: error: {why} (job #{num})", file=sys.stderr, flush=True)
                tally.refused.append(num)
                tally.errors.append(num)
            elif kind == "replace":
                try:
                    aside = move_aside(folder)
                except OSError as exc:   # left as it is: the job is not run over it
                    kind = "refuse"
                    print(f"kexp: error: {folder} holds {why} and cannot be moved aside ({exc.strerror or exc}); "
                          f"left as it is (job #{num})", file=sys.stderr, flush=True)
                    tally.refused.append(num)
                    tally.errors.append(num)
                else:
                    print(f"#{num} runs again ({RESUME_KEY}): its folder held {why}, moved to {aside}", flush=True)
            kinds[i] = kind if kind in ("skip", "refuse") else "launch"
    results: list = [None] * len(batch)
    i = 0
    while i < len(batch):
        if kinds[i] != "launch":
            results[i] = _done(batch[i], folders[i])
            i += 1
            continue
        j = i
        while j < len(batch) and kinds[j] == "launch":
            j += 1
        with progress:   # a [k/N] line per job as it ends
            rets = list(launch_batch(batch[i:j], initial_job_idx=initial_job_idx + i))
        progress.finish([(initial_job_idx + i + n, _output_dir(r)) for n, r in enumerate(rets)])
        _tally_launched(tally, rets, initial_job_idx + i)
        results[i:j] = rets
        i = j
    return results


def sweep(original, sweeper, arguments: list[str]):
    """``BasicSweeper.sweep`` (``original``) with ``sweep.resume`` taken out of the jobs' overrides, a sweep folder
    that holds runs refused unless resumed, and the jobs' outcomes tallied in :data:`TALLY`."""
    global TALLY, PROGRESS
    import logging

    from omegaconf import OmegaConf, open_dict, read_write
    for name in ("hydra._internal.core_plugins.basic_launcher", "hydra_plugins"):   # its "#i : overrides" lines:
        logging.getLogger(name).setLevel(logging.WARNING)                          # kexp's launch line says it
    config = sweeper.config
    resume = bool(OmegaConf.select(config, RESUME_KEY, default=False))
    task = [str(o) for o in config.hydra.overrides.task]
    if any(_key(o) == RESUME_KEY for o in task):   # multirun.yaml records the sweep as the jobs see it
        from hydra._internal.config_loader_impl import get_overrides_dirname
        from hydra.core.override_parser.overrides_parser import OverridesParser
        task = [o for o in task if _key(o) != RESUME_KEY]
        with read_write(config.hydra), open_dict(config.hydra):
            config.hydra.overrides.task = task
            dirname = config.hydra.job.config.override_dirname
            config.hydra.job.override_dirname = get_overrides_dirname(
                overrides=OverridesParser.create().parse_overrides(overrides=task), kv_sep=dirname.kv_sep,
                item_sep=dirname.item_sep, exclude_keys=dirname.exclude_keys)
    arguments = [a for a in arguments if _key(a) != RESUME_KEY]
    sweep_dir = Path(str(config.hydra.sweep.dir)).absolute()
    held = folders_with_runs(sweep_dir)
    if held and not resume:
        names = ", ".join(str(p.relative_to(sweep_dir)) for p in held[:5]) + (" …" if len(held) > 5 else "")
        print(f"kexp: error: hydra.sweep.dir={sweep_dir} holds runs already ({len(held)}: {names}); kexp never "
              f"overwrites a run: add {RESUME_KEY}=true to skip the completed jobs and run the others, or give "
              "another hydra.sweep.dir (nothing was changed)", file=sys.stderr)
        sys.exit(2)
    TALLY, PROGRESS = Tally(sweep_dir, resume), None
    launcher = sweeper.launcher
    launch_batch = launcher.launch
    launcher.launch = lambda batch, initial_job_idx: launch(sweeper, launch_batch, batch, initial_job_idx,
                                                            bool(held))
    try:
        return original(sweeper, arguments)
    finally:
        del launcher.launch   # the instance attribute: the class's method again
