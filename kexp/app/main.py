"""The ``kexp`` command: a thin Hydra main around :func:`kexp.app.experiment.run`, after the command line's checks
(kexp.app.precheck).  Importing it stays light (Hydra's decorator, no numpy, no experiment code): ``kexp --help``
and ``--version`` print before anything heavy is imported (kexp.app.help)."""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from ..errors import KexpError
from . import run_folder
from .confdir import CONF_DIR

run_folder.install()   # here, not only in main(): a joblib worker imports this module to unpickle the task


def run(cfg, out_dir, **kwargs):
    """:func:`kexp.app.experiment.run`, imported at its first call (the experiment code imports numpy, scipy and
    the controllers: ``kexp --help`` does not wait for them)."""
    from .experiment import run as run_experiment
    return run_experiment(cfg, out_dir, **kwargs)


@hydra.main(config_path=CONF_DIR, config_name="config", version_base="1.3")
def _hydra_main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    hc = HydraConfig.get()
    out_dir = Path(hc.runtime.output_dir)
    sweep_job = hc.mode == RunMode.MULTIRUN
    try:
        refused = run_folder.refusal(out_dir)   # its folder holds another run: nothing was written there
        if refused is not None:
            raise refused
        if sweep_job:  # its warnings only: the kexp process prints its [k/N] line when it ends (resume.PROGRESS)
            run(cfg, out_dir, echo=_warnings_only, auto_progress=False)
        else:
            run(cfg, out_dir)
    except KexpError as exc:  # bad input or a failed stage: one line, no traceback
        print(f"kexp: error: {exc}" + (f" (job #{hc.job.num}: {out_dir})" if sweep_job else ""), file=sys.stderr)
        if not isinstance(exc, run_folder.RunFolderError):   # another run's folder is never written to
            _error_summary(out_dir, exc)
        if not sweep_job:
            sys.exit(2)  # a single run: exit code 2; in a sweep the other jobs go on, the report counts this one
    except Exception as exc:  # a bug: its traceback is Hydra's to show, but the summary says the run failed
        _error_summary(out_dir, exc, internal=True)
        raise


def _error_summary(out_dir: Path, exc: BaseException, internal: bool = False) -> None:
    """summary.json of a run that stopped with ``exc`` ("status": "error"; not "running", which kexp-report
    reads as a killed run); ``internal``: an unexpected exception, a bug to report with its traceback.  A summary
    the run wrote already keeps what it holds: a completed run's metrics and status stay, the error is added
    ("error"); a running one's keys stay besides the error's.  Replaced whole or not at all (a full disk leaves
    the previous summary)."""
    from .faults import write_json
    message = f"internal error: {type(exc).__name__}: {exc}" if internal else str(exc)
    error = {"message": message, "error_type": type(exc).__name__}
    path = out_dir / "summary.json"
    try:
        try:
            before = json.loads(path.read_text())
        except FileNotFoundError:
            before = None
        except (OSError, ValueError):
            return   # unreadable (a folder, say): left as it is
        if not isinstance(before, dict):
            summary = {"status": "error", "completed": False, **error}
        elif before.get("completed") is True:
            summary = {**before, "error": error}
        else:
            summary = {**before, "status": "error", "completed": False, **error}
        write_json(path, summary)
    except OSError:
        pass   # the folder itself failed: the error printed is what the user gets


def _warnings_only(line: str) -> None:
    if line.startswith("warning:"):
        print(line, flush=True)


def main() -> None:
    from .. import __version__
    from . import help as kexp_help
    if sys.argv[1:] == ["--version"]:  # Hydra's own --version prints Hydra's
        print(f"kexp {__version__}")
        return
    if kexp_help.wants_help(sys.argv[1:]):   # kexp's page, not Hydra's (kexp --hydra-help for that)
        print(kexp_help.page(CONF_DIR, __version__))
        return
    sys.argv[1:] = kexp_help.hydra_argv(sys.argv[1:])
    from .conf import CONF_DIR as _registered  # noqa: F401 - kexp's schema in Hydra's ConfigStore
    from .precheck import precheck
    sweep = precheck(sys.argv[1:])   # run_folder.install() ran when this module was imported
    from .sweeper import install, install_loader, workers_end_with_parent
    install()   # a sweep's batch check composes one job per structure, not every job (kexp/app/sweeper.py)
    install_loader()   # and each worker composes once per structure too
    with workers_end_with_parent(sweep):   # a sweep's worker processes end when this process is killed
        _hydra_main()
    _sweep_verdict()


def _sweep_verdict() -> None:
    """After a sweep (kexp.app.resume): the closing lines, and exit code 2 if any job stopped with an error."""
    from . import resume
    tally = resume.TALLY
    if tally is None:
        return
    out, err = tally.closing_lines()
    if resume.PROGRESS is not None:
        out.append(resume.PROGRESS.closing_line())
    for line in out:
        print(line, flush=True)
    for line in err:
        print(line, file=sys.stderr, flush=True)
    if tally.errors:
        sys.exit(2)


if __name__ == "__main__":
    import numpy as np
    np.set_printoptions(precision=4)
    main()
