"""A faster batch check for Hydra's basic sweeper: one composition per job *structure*, not per job.

Before it launches a batch, Hydra's basic sweeper composes the config of every job of it in the parent process,
one after the other, to find composition errors early (``BasicSweeper.validate_batch_is_legal``); the launcher
then composes each job again where it runs.  With kexp's config one composition takes 0.2–0.5 s, so a 100-job
sweep spent 20–45 s composing before its first job started (``benchmarks/sweep.py``).

Jobs whose overrides differ only in the values of dotted keys (``sim.x0=…``, ``controller.lmpc.horizon=…``) have
the same defaults list, so composing one of them finds every error of the group choices, ``+``/``~`` overrides
and config files; the values themselves were checked against the typed schema before Hydra started
(``kexp.app.precheck._precheck_sweep``), and a value that is legal in type but not in range is reported by its own
job.  :func:`install` makes the basic sweeper check one job per structure (:func:`representatives`); the ``kexp``
command calls it before Hydra runs (Hydra accepts sweeper classes only from its ``hydra_plugins`` namespace, so
kexp changes the one method instead of shipping a plugin package).  A sweep over 100 initial conditions then
composes once in the parent.
"""
from __future__ import annotations

import copy
import os
import sys
import threading
import time
from typing import Sequence

from hydra._internal.config_loader_impl import ConfigLoaderImpl, get_overrides_dirname
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf, open_dict


def structure_of(override: str) -> str:
    """The part of an override string that decides the defaults list: the whole override for a group choice
    (a key without a dot, or with a '/') and for ``+``/``~`` overrides; only the key for a value of a dotted key."""
    key = override.split("=", 1)[0]
    if key.startswith(("+", "~")) or "." not in key or "/" in key:
        return override
    return key + "=<value>"


def representatives(batch: Sequence[Sequence[str]]) -> list[Sequence[str]]:
    """One job (its overrides) per distinct structure in ``batch``, in the order first seen."""
    seen: dict[tuple[str, ...], Sequence[str]] = {}
    for overrides in batch:
        seen.setdefault(tuple(structure_of(o) for o in overrides), overrides)
    return list(seen.values())


def install() -> None:
    """Make Hydra's basic sweeper check one job per structure of each batch (idempotent).  A job that does not
    compose (an unknown group option or preset, a bad ``+``/``~`` override) stops the sweep before any job starts
    with one line on stderr naming the job's overrides, and exit code 2, as a single run's bad input does (Hydra
    itself prints several lines and exits 1)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    if getattr(BasicSweeper.validate_batch_is_legal, "_kexp", False):
        return
    check_all = BasicSweeper.validate_batch_is_legal

    def validate_batch_is_legal(self, batch):
        from hydra.errors import HydraException
        from omegaconf.errors import OmegaConfBaseException

        from .precheck import composition_error_line, null_node_line
        for job in representatives(batch):
            try:
                check_all(self, [job])
                continue
            except (HydraException, OmegaConfBaseException) as exc:
                line = composition_error_line(exc)
            except AssertionError:   # OmegaConf's, for a key below a null node (kexp.app.precheck)
                line = null_node_line(list(job))
                if line is None:
                    raise
            choices = " ".join(o for o in job if structure_of(o) == o)   # what decided its composition
            print(f"kexp: error: {line} (the sweep's jobs with {choices}; no job started)", file=sys.stderr)
            sys.exit(2)

    validate_batch_is_legal._kexp = True
    BasicSweeper.validate_batch_is_legal = validate_batch_is_legal
    original_sweep = BasicSweeper.sweep

    def sweep(self, arguments):   # sweep.resume, a folder holding runs refused, the jobs' outcomes (kexp.app.resume)
        from .resume import sweep as resumable_sweep
        return resumable_sweep(original_sweep, self, arguments)

    BasicSweeper.sweep = sweep


# -- each job's composition in its worker -----------------------------------------------------------------------
# Where a job runs, Hydra composes its config again from the YAML files (ConfigLoaderImpl.load_sweep_config, 0.2–0.4 s
# for kexp's config).  The composition of a job depends on its overrides in two ways: the defaults list (group
# choices, + and ~ overrides: the job's structure) and the values of dotted keys applied afterwards.  A worker that has
# composed one job of a structure keeps that config; for the next job of the same structure it copies it and applies
# the new job's values and override lists the way Hydra's loader does (tests/test_sweeper.py: equal to Hydra's own
# composition, key for key).
_COMPOSED: dict = {}
COMPOSED_SIZE = 16


class StructureCachingConfigLoader(ConfigLoaderImpl):
    """Hydra's config loader whose ``load_sweep_config`` composes once per job structure in a process
    (:func:`compose_job`); a module-level class, so that the launcher's pickle of it names this module and a worker
    imports it."""

    def load_sweep_config(self, master_config, sweep_overrides):
        from . import conf  # noqa: F401 - kexp's schema in this process's ConfigStore (a worker's too)
        watch_parent()   # where a job runs in a child of the kexp process, it ends with the kexp process
        return compose_job(self, master_config, list(sweep_overrides))


def compose_job(loader, master_config, sweep_overrides: list[str]):
    """The config of one sweep job: Hydra's ``load_sweep_config``, from this process's earlier composition of a job
    with the same structure when there is one."""
    hydra_overrides = list(OmegaConf.to_container(master_config.hydra.overrides.hydra))
    overrides = hydra_overrides + sweep_overrides
    key = (str(master_config.hydra.job.config_name), tuple(structure_of(o) for o in overrides))
    base = _COMPOSED.get(key)
    if base is None:
        cfg = ConfigLoaderImpl.load_sweep_config(loader, master_config, sweep_overrides)
        _COMPOSED[key] = copy.deepcopy(cfg)
        while len(_COMPOSED) > COMPOSED_SIZE:
            _COMPOSED.pop(next(iter(_COMPOSED)))
        return cfg
    cfg = copy.deepcopy(base)
    parsed = OverridesParser.create().parse_overrides(overrides=overrides)
    values = [p for o, p in zip(overrides, parsed) if structure_of(o) != o]   # the dotted keys' values
    ConfigLoaderImpl._apply_overrides_to_config(values, cfg)
    app = [p for p in parsed if not p.is_hydra_override()]
    with open_dict(cfg.hydra):
        cfg.hydra.overrides.hydra = [p.input_line for p in parsed if p.is_hydra_override()]
        cfg.hydra.overrides.task = [p.input_line for p in app]
        dirname = cfg.hydra.job.config.override_dirname
        cfg.hydra.job.override_dirname = get_overrides_dirname(
            overrides=app, kv_sep=dirname.kv_sep, item_sep=dirname.item_sep, exclude_keys=dirname.exclude_keys)
        cfg.hydra.runtime.cwd = os.getcwd()
    OmegaConf.copy_cache(from_config=master_config, to_config=cfg)
    return cfg


def install_loader() -> None:
    """Make Hydra create its config loader as :class:`StructureCachingConfigLoader` (idempotent)."""
    import hydra._internal.hydra as hydra_core
    hydra_core.ConfigLoaderImpl = StructureCachingConfigLoader


# -- workers end with the kexp process ----------------------------------------------------------------------------
# A joblib sweep's loky workers (and the resource trackers, which live as long as a worker holds their pipe) are
# children of the kexp process, a submitit_local sweep's jobs its grandchildren.  Killed (SIGKILL, SIGTERM), it
# cannot stop them, and they went on for the whole sweep's work and stayed idle afterwards (~240 MB each).  Each of
# them runs a watchdog thread that ends its process (os._exit) as soon as the kexp process is gone, and a job that
# starts after it is gone (a submitit job still being spawned) ends at once.  The kexp process is named by host, pid
# and start time (a pid alone may be reused); a job on another host (a cluster node) is the scheduler's to end.
PARENT_ENV = "KEXP_SWEEP_PARENT"   # "host:pid:start time" of the kexp process, inherited by its workers
POLL_S = 0.5
_WATCHED: list[str] = []


def _proc_stat(pid: int) -> tuple[str, str] | None:
    """(state, start time) of process ``pid`` from /proc (Linux); None if there is no such process (or no /proc)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            text = f.read()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()   # after "pid (comm) ": state, ppid, …, starttime (22nd field)
    return fields[0], fields[19]


def mark_parent() -> None:
    """In the kexp process: let its workers know which process to end with."""
    import socket
    st = _proc_stat(os.getpid())
    os.environ[PARENT_ENV] = f"{socket.gethostname()}:{os.getpid()}:{st[1] if st else ''}"


def watch_parent() -> bool:
    """Start (once per process) the thread that ends this process when the kexp process that started the sweep is
    gone (exited, a zombie, or its pid taken by another process), in a process the sweep started on this host; if it
    is gone already, end now.  Without /proc only a direct child watches (for being re-parented).  Returns whether
    this process is watched."""
    import socket
    if _WATCHED:
        return True
    try:
        host, pid_text, start = os.environ.get(PARENT_ENV, "").rsplit(":", 2)
        parent = int(pid_text)
    except ValueError:
        return False
    if host != socket.gethostname() or parent == os.getpid():
        return False
    if not start and os.getppid() != parent:
        return False
    _WATCHED.append(os.environ[PARENT_ENV])

    def gone() -> bool:
        if not start:
            return os.getppid() != parent
        st = _proc_stat(parent)
        return st is None or st[0] in "ZX" or st[1] != start

    if gone():
        print(f"kexp: the sweep's kexp process (pid {parent}) is gone: this job does not start", file=sys.stderr,
              flush=True)
        os._exit(3)

    def watch():
        while not gone():
            time.sleep(POLL_S)
        os._exit(3)   # the kexp process is gone: nobody waits for this job's result

    threading.Thread(target=watch, name="kexp-parent-watch", daemon=True).start()
    return True


class workers_end_with_parent:
    """Context for the kexp process (``sweep``: it runs a sweep): every loky worker joblib starts runs
    :func:`watch_parent` when it starts (an initializer; idle workers too), every sweep job when it starts (any
    launcher: :class:`StructureCachingConfigLoader`)."""

    def __init__(self, sweep: bool = True):
        self.sweep = sweep

    def __enter__(self):
        mark_parent()
        self._config = None
        if not self.sweep:
            return self
        try:
            from joblib import parallel_config
        except ImportError:   # no joblib: the jobs' own call suffices
            return self
        self._config = parallel_config(backend="loky", initializer=watch_parent)
        self._config.__enter__()
        return self

    def __exit__(self, *exc):
        if self._config is not None:
            self._config.__exit__(*exc)
        return False
