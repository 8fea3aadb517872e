"""Run folders: one run per folder, never shared, never overwritten.

A run's files (``summary.json``, ``model.npz``, ``run.mcap``, ``run.rrd`` and Hydra's ``.hydra/``) go into a folder
that the run has *claimed* before anything is written into it:

* a folder named with a time stamp (``${now:…}`` in ``hydra.run.dir``: the default ``outputs/<date>/<time>``, whose
  resolution is one second) is made by the run itself with an exclusive ``mkdir``; if the name is taken (another
  run started in the same second, or an earlier one), the run takes ``<name>-1``, ``<name>-2``, … (the first that
  ``mkdir`` creates) and says so in one line (:func:`claim_run_folder`);
* a folder named without a time stamp is the user's: if it holds a run (:func:`holds_run`) the run is refused in
  one line, exit code 2, and nothing in it is touched;
* every run folder's ``.hydra/`` is made with an exclusive ``mkdir`` before Hydra writes into it (a sweep job's
  folder ``sweep.dir/<num>`` too, in whatever process the launcher runs it): a folder whose ``.hydra/`` exists, or
  that holds a run, is refused (:func:`install`), and the run's own files are created exclusively besides
  (kexp.app.experiment, kexp.recording.writer).

:func:`holds_run` and :func:`completed` are what a resume of a sweep needs to skip the jobs already done.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from ..errors import KexpError

RUN_FILES = ("summary.json", "model.npz", "run.mcap", "run.rrd")   # what a kexp run writes into its folder
HYDRA_RECORD = ".hydra"                                             # Hydra's record of the run (hydra.output_subdir)
MAX_SUFFIX = 999


class RunFolderError(KexpError):
    """The run's folder holds another run (or cannot be claimed): nothing was written into it."""


def run_files(folder: str | Path) -> list[str]:
    """The names of :data:`RUN_FILES` present in ``folder`` (as files, folders or links, even broken ones)."""
    folder = Path(folder)
    return [name for name in RUN_FILES if os.path.lexists(folder / name)]


def holds_run(folder: str | Path) -> bool:
    """Whether ``folder`` holds a run: one of its files (:data:`RUN_FILES`) or Hydra's record of one (``.hydra``),
    whatever state that run is in (completed, failed, killed, running).  A missing folder holds none."""
    return bool(run_files(folder)) or os.path.lexists(Path(folder) / HYDRA_RECORD)


def completed(folder: str | Path) -> bool:
    """Whether ``folder``'s summary.json says its run completed (``"completed": true``); False when there is no
    readable summary."""
    try:
        return json.loads((Path(folder) / "summary.json").read_text()).get("completed") is True
    except (OSError, ValueError, AttributeError):
        return False


def describe(folder: str | Path) -> str:
    """What of a run ``folder`` holds, for a message: e.g. "summary.json, run.mcap" or ".hydra"."""
    names = run_files(folder)
    return ", ".join(names) if names else HYDRA_RECORD


def is_generated(pattern: str) -> bool:
    """Whether a run folder's pattern (``hydra.run.dir`` before resolution) names a new folder per run: it holds a
    time stamp (``${now:…}``), as the default ``outputs/${now:%Y-%m-%d}/${now:%H-%M-%S}`` does."""
    return "${now:" in pattern.replace(" ", "")


def claim_run_folder(path: str | Path, generated: bool) -> tuple[Path, str | None]:
    """Claim the folder for a single run at ``path``: (the folder, a one-line note or None).

    ``generated`` (a time-stamped name): the folder is made with an exclusive ``mkdir``; when it exists, the first of
    ``path-1``, ``path-2``, … that ``mkdir`` creates (two runs started in the same second never share one), with a
    note saying so.  Otherwise the user's folder is used, made if missing; one that holds a run raises
    :class:`RunFolderError` and is left as it is.  OSError: a folder that cannot be made."""
    path = Path(path)
    if not generated:
        if holds_run(path):
            raise RunFolderError(f"hydra.run.dir={path} holds a run already ({describe(path)}); kexp never "
                                 "overwrites a run: give another folder, or leave hydra.run.dir unset for a new "
                                 "time-stamped one")
        path.mkdir(parents=True, exist_ok=True)
        return path, None
    path.parent.mkdir(parents=True, exist_ok=True)
    for i in range(MAX_SUFFIX + 1):
        candidate = path if i == 0 else path.with_name(f"{path.name}-{i}")
        try:
            os.mkdir(candidate)
        except FileExistsError:
            continue
        note = None if i == 0 else f"note: {path} is taken by another run; this run's folder is {candidate}"
        return candidate, note
    raise RunFolderError(f"{path} and {path.name}-1 … -{MAX_SUFFIX} are all taken; give hydra.run.dir")


# -- Hydra's side ---------------------------------------------------------------------------------------------
_REFUSED: dict[str, KexpError] = {}   # a run folder (absolute) -> why the run in it must not start


def refusal(out_dir: str | Path) -> KexpError | None:
    """Why the run (or sweep job) whose folder is ``out_dir`` must not start — its folder holds another run, or
    Hydra's record could not be written — as found before Hydra wrote into it (:func:`install`); None if it may.
    Taken once."""
    return _REFUSED.pop(os.path.abspath(out_dir), None)


def _claim_record(save_config):
    """Hydra's ``_save_config`` (which writes ``.hydra/config.yaml``, ``hydra.yaml``, ``overrides.yaml`` in turn),
    claiming the run's folder at its first file: ``.hydra`` made with an exclusive mkdir, in a folder that holds
    no run; else nothing is written and :func:`refusal` says why."""
    def saved(cfg, filename, output_dir):
        from hydra.core.hydra_config import HydraConfig
        folder = os.path.abspath(HydraConfig.get().runtime.output_dir)
        if filename == "config.yaml":   # the first of the three
            record = Path(output_dir)
            try:
                if run_files(folder):
                    raise FileExistsError
                record.parent.mkdir(parents=True, exist_ok=True)
                record.mkdir()
            except FileExistsError:
                _REFUSED[folder] = RunFolderError(f"{folder} holds a run already ({describe(folder)}); kexp never "
                                                  "overwrites a run: nothing was written there")
            except OSError as exc:
                _REFUSED[folder] = RunFolderError(f"cannot write Hydra's record {record}: {os_error_text(exc)}")
        if folder in _REFUSED:
            return
        try:
            save_config(cfg, filename, output_dir)
        except OSError as exc:
            _REFUSED[folder] = RunFolderError(f"cannot write Hydra's record {Path(output_dir) / filename}: "
                                              f"{os_error_text(exc)}")
    saved._kexp = True
    return saved


def _claim_then_run(run_job):
    """Hydra's ``run_job`` for a single run (``hydra.run.dir``): the folder claimed first
    (:func:`claim_run_folder`) and ``hydra.run.dir`` set to it; a folder that holds a run is one line on stderr and
    exit code 2, nothing written."""
    def claimed(*args, **kwargs):
        config = kwargs.get("config")
        if kwargs.get("job_dir_key") == "hydra.run.dir" and config is not None:
            from hydra.core.hydra_config import HydraConfig
            from omegaconf import OmegaConf, open_dict, read_write
            HydraConfig.instance().set_config(config)   # as run_job does: ${hydra:…} in the pattern resolves
            pattern = str(OmegaConf.to_container(config.hydra.run, resolve=False).get("dir"))
            path = str(OmegaConf.select(config, "hydra.run.dir"))
            try:
                folder, note = claim_run_folder(path, is_generated(pattern))
            except RunFolderError as exc:
                print(f"kexp: error: {exc}", file=sys.stderr)
                sys.exit(2)
            except OSError as exc:
                print(f"kexp: error: hydra.run.dir={path}: cannot make the folder: {os_error_text(exc)}",
                      file=sys.stderr)
                sys.exit(2)
            if note:
                print(note, flush=True)
            with read_write(config.hydra), open_dict(config.hydra):
                config.hydra.run.dir = str(folder)
        return run_job(*args, **kwargs)
    claimed._kexp = True
    return claimed


def install() -> None:
    """Make Hydra claim each run folder before it writes into it (idempotent): a single run's folder in this
    process (:func:`claim_run_folder`), and every run's and sweep job's ``.hydra`` record, in the process where the
    job runs (the ``kexp`` command's module calls this when it is imported, so a joblib worker that unpickles the
    task does too)."""
    import hydra._internal.hydra as hydra_core
    import hydra.core.utils as hydra_utils
    if not getattr(hydra_utils._save_config, "_kexp", False):
        hydra_utils._save_config = _claim_record(hydra_utils._save_config)
    if not getattr(hydra_core.run_job, "_kexp", False):
        hydra_core.run_job = _claim_then_run(hydra_core.run_job)


def os_error_text(exc: OSError) -> str:
    """An OSError in a few words, e.g. "No space left on device (ENOSPC)" or "Is a directory (EISDIR): '…/x'"."""
    import errno
    name = errno.errorcode.get(exc.errno or 0)
    text = exc.strerror or str(exc) or type(exc).__name__
    where = f": {str(exc.filename)!r}" if exc.filename else ""
    return f"{text}{f' ({name})' if name else ''}{where}"
