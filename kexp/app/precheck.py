"""The ``kexp`` command's checks before Hydra runs: a config that does not compose, a swept value that does not fit
the schema or a config file that is not YAML is one line on stderr and exit code 2 (Hydra itself prints several
lines, or a traceback, and exits 1)."""
from __future__ import annotations

import os
import sys

from .conf import CONF_DIR
from .schema import register as _register_schema


def composition_error_line(exc: BaseException) -> str:
    """One line for a config that does not compose: the key, the value and what went wrong, e.g.
    "controller.lmpc.horizon: Value 'abc' of type 'str' could not be converted to Integer (override
    controller.lmpc.horizon=abc)"."""
    cause, seen = exc, set()
    while cause is not None and not getattr(cause, "full_key", None) and id(cause) not in seen:
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    full_key = getattr(cause, "full_key", None)
    if cause is not None and full_key:
        import dataclasses
        detail = str(cause).splitlines()[0].strip()
        first = str(exc).splitlines()[0].strip()
        schema = getattr(cause, "object_type", None)
        if "not in" in detail and dataclasses.is_dataclass(schema):  # a misspelled key: list the valid ones
            detail += f"; valid keys: {sorted(f.name for f in dataclasses.fields(schema))}"
        return f"{full_key}: {detail} ({first[0].lower() + first[1:]})"[:500]
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    msg = " ".join(line for line in lines if not line.startswith(("See https", "Set the environment")))
    msg = msg.split(" Config search path:")[0]
    return (msg[:400] + " …") if len(msg) > 400 else (msg or type(exc).__name__)


def precheck(argv: list[str]) -> bool:
    """For a single run: compose the config first, so an unknown group option, preset or key, a value of the wrong
    type (the schema, kexp/app/schema.py), an interpolation that does not resolve or a bad override is one line and
    exit code 2 (Hydra itself prints several lines, or a traceback, and exits 1).  The command line is read with
    Hydra's own parser, so the overrides are checked with options among them too (``-cn NAME``, ``--config-dir D``,
    ``-m``); what only shows something (``--help``, ``--cfg``, ``--info``, …) and ``--config-path`` are Hydra's.
    Returns whether the command line runs a sweep (``-m``/``--multirun``, or an abbreviation, as Hydra reads it)."""
    args = _hydra_args(argv)
    if args is None:
        return False
    _check(args)
    return bool(args.multirun)


def _check(args) -> None:
    """:func:`precheck`'s checks of the command line ``args`` (Hydra's parsed namespace)."""
    if args.experimental_rerun:   # Hydra unpickles the file: a config from a stranger would run its code
        print(f"kexp: error: --experimental-rerun {args.experimental_rerun}: Hydra loads that file with pickle, which "
              "runs any code it holds; kexp does not accept it: re-run with the overrides in the run's "
              ".hydra/overrides.yaml instead", file=sys.stderr)
        sys.exit(2)
    if (args.help or args.hydra_help or args.cfg or args.info or args.shell_completion or args.config_path):
        return  # Hydra shows something, or finds the config relative to its own main: leave it to Hydra
    argv, config_name, multirun = list(args.overrides), args.config_name or "config", args.multirun
    if args.config_dir:
        if any(a.startswith(("hydra.searchpath=", "+hydra.searchpath=")) for a in argv):
            return  # both: leave it to Hydra
        # --config-dir D: Hydra adds D to the search path (after kexp's conf/); the same for this check
        argv.append(f"hydra.searchpath=[file://{os.path.abspath(args.config_dir)}]")
    _check_output_dir(argv, "hydra.sweep.dir" if multirun else "hydra.run.dir")
    if multirun:
        return _precheck_sweep(argv, config_name)
    _compose_or_exit(argv, config_name)


class _ArgumentError(Exception):
    pass


def _hydra_args(argv: list[str]):
    """``argv`` read by Hydra's own command-line parser (its namespace: overrides, multirun, config_name, …); None
    for ``--version`` (Hydra's to answer).  A command line it refuses is one line on stderr and exit code 2 (Hydra
    prints its usage, ten lines, and the error)."""
    if "--version" in argv:
        return None
    from hydra._internal.utils import get_args_parser
    parser = get_args_parser()

    def error(message):
        raise _ArgumentError(message)
    parser.error = error
    try:
        return parser.parse_args(argv)
    except _ArgumentError as exc:
        hint = "; give the options (-m, -cn NAME, …) before or after all the overrides" if "unrecognized" in str(
            exc) else ""
        print(f"kexp: error: {exc}{hint} (see kexp --help)", file=sys.stderr)
        sys.exit(2)


def _check_output_dir(argv: list[str], key: str) -> None:
    """The run's (or sweep's) folder, ``key``=DIR on the command line (else ``outputs/`` or ``multirun/`` in the
    current folder), must be a folder kexp can create and write: else one line and exit code 2 (Hydra creates it
    later, with a traceback).  Nothing is created here: the folder, if it exists, or its nearest existing parent
    is checked.  A value with an interpolation (``${now:…}``) is Hydra's to resolve: its fixed prefix is checked."""
    import os
    import tempfile
    from pathlib import Path
    given = [a.split("=", 1)[1] for a in argv if "=" in a and a.split("=", 1)[0].lstrip("+") == key]
    shown = given[-1] if given else ("multirun" if key == "hydra.sweep.dir" else "outputs")
    path = Path(shown.split("${", 1)[0] or ".").absolute()
    while not path.exists() and not path.is_symlink() and path != path.parent:
        path = path.parent
    problem = None
    if not path.is_dir():
        problem = f"{str(path)!r} is not a folder"
    else:
        try:   # a folder made and removed at once: os.access says yes to root even where nothing can be made
            os.rmdir(tempfile.mkdtemp(prefix=".kexp-check-", dir=path))
        except OSError as exc:
            problem = f"cannot create a folder in {str(path)!r} ({exc.strerror or type(exc).__name__})"
    if problem:
        print(f"kexp: error: {key}={shown}: {problem}; give a folder you can write", file=sys.stderr)
        sys.exit(2)


def _compose_or_exit(overrides: list[str], config_name: str = "config") -> None:
    """Compose the config ``config_name`` with ``overrides`` (a single run); a preset or group file that is not
    YAML, any other composition error, or an interpolation that does not resolve (``${oc.env:UNSET}``,
    ``${nope.x}``; ``${hydra:…}`` ones are Hydra's to resolve later) is one line on stderr and exit code 2."""
    from hydra import compose, initialize_config_dir

    def compose_it():
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=overrides)
        line = unresolved_line(cfg)
        if line:
            print(f"kexp: error: {line}", file=sys.stderr)
            sys.exit(2)
    _one_line_or_exit(compose_it, overrides=overrides)


def unresolved_line(cfg) -> str | None:
    """One line for the first interpolation of ``cfg`` (composed, without its ``hydra`` node) that does not
    resolve (:func:`interpolation_error_line`), None if all do; those that use ``${hydra:…}`` are left out (Hydra
    sets what they refer to when the run starts)."""
    from omegaconf import DictConfig, ListConfig, OmegaConf
    from omegaconf.errors import InterpolationResolutionError

    def walk(node, prefix):
        keys = list(node.keys()) if isinstance(node, DictConfig) else range(len(node))
        for key in keys:
            child = node._get_node(key)
            path = f"{prefix}[{key}]" if isinstance(node, ListConfig) else f"{prefix}{'.' if prefix else ''}{key}"
            if OmegaConf.is_interpolation(node, key):
                if "hydra" in str(child._value()):
                    continue
                try:
                    child._dereference_node()
                except InterpolationResolutionError as exc:
                    return interpolation_error_line(exc, str(child._value()), path)
                except Exception:  # noqa: BLE001 - anything else is the run's to report
                    continue
            elif isinstance(child, (DictConfig, ListConfig)) and not child._is_none() and not child._is_missing():
                found = walk(child, path)
                if found:
                    return found
        return None
    return walk(cfg, "")


def interpolation_error_line(exc: BaseException, raw: str | None = None, key: str | None = None) -> str:
    """One line for an interpolation that does not resolve (``raw``: the value as written), e.g.
    "sim.T=${oc.env:UNSET}: Environment variable 'UNSET' not found; set the variable, or give a default:
    ${oc.env:NAME,value}" (``key``: the key's path, when ``exc`` does not say)."""
    key = key or getattr(exc, "full_key", None) or "a key"
    if raw is None:
        try:
            raw = exc.child_node._value()
        except Exception:  # noqa: BLE001 - the value is shown only when it can be found
            raw = None
    raw = raw if isinstance(raw, str) else None
    detail = str(exc).splitlines()[0].strip().removeprefix("KeyError raised while resolving interpolation: ")
    fix = ("set the variable, or give a default: ${oc.env:NAME,value}" if "Environment variable" in detail
           else "interpolate a key that exists, or give a value")
    return f"{key}{'=' + raw if raw else ''}: {detail.strip(chr(34))}; {fix}"


def _compose_master_or_exit(overrides: list[str], config_name: str = "config") -> None:
    """A sweep's first step in Hydra: its master config, composed with every override the way Hydra composes it
    for a multirun (a swept group choice is left out, a swept value not applied).  What fails there fails the
    whole sweep before any job, in Hydra with several lines or a traceback (a config file that is not YAML):
    here one line and exit code 2.  Each job's own composition is checked by the sweeper's batch check
    (kexp.app.sweeper.install)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path
    from hydra.core.utils import JobRuntime
    from hydra.types import RunMode
    JobRuntime.instance().set("name", "kexp")
    loader = ConfigLoaderImpl(config_search_path=create_config_search_path(CONF_DIR))
    _one_line_or_exit(lambda: loader.load_configuration(config_name, overrides=overrides,
                                                        run_mode=RunMode.MULTIRUN),
                      " (no job started)", overrides=overrides)


def _one_line_or_exit(compose_it, suffix: str = "", overrides: list[str] = ()) -> None:
    """Run ``compose_it``; a config file that is not YAML, a composition error, or one of ``overrides`` setting a
    key below a node that is null in this config, is one line on stderr (with ``suffix``; a YAML error names the
    file and where) and exit code 2."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException
    from yaml import YAMLError
    try:
        compose_it()
    except YAMLError as exc:  # a preset or group file that is not YAML
        print(f"kexp: error: {yaml_error_line(exc)}", file=sys.stderr)
        sys.exit(2)
    except (HydraException, OmegaConfBaseException, ValueError) as exc:
        print(f"kexp: error: {composition_error_line(exc)}{suffix}", file=sys.stderr)
        sys.exit(2)
    except AssertionError:   # OmegaConf's "Unexpected type for root: NoneType", raised through Hydra as it is
        line = null_node_line(overrides)
        if line is None:
            raise
        print(f"kexp: error: {line}{suffix}", file=sys.stderr)
        sys.exit(2)


def null_node_line(overrides) -> str | None:
    """One line for the first of ``overrides`` that sets a key below a node that is null in the config composed
    with the group choices alone, e.g. controller.lmpc.horizon=20 with controller=lqr (whose controller.lmpc is
    null); None if there is none."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path
    from hydra.types import RunMode
    from omegaconf import OmegaConf
    keys = [(o, o.split("=", 1)[0].lstrip("+~")) for o in overrides if "=" in o]
    choices = [o for o, k in keys if "." not in k or k.startswith("hydra.")]
    try:   # Hydra's loader, not compose(): inside a sweep Hydra is already initialised
        loader = ConfigLoaderImpl(config_search_path=create_config_search_path(CONF_DIR))
        cfg = loader.load_configuration("config", overrides=choices, run_mode=RunMode.RUN)
    except Exception:   # noqa: BLE001 — the caller re-raises the original error
        return None
    for o, key in keys:
        parts = key.split(".")
        for i in range(1, len(parts)):
            parent = ".".join(parts[:i])
            if OmegaConf.select(cfg, parent, default="<missing>") is None:
                group = parts[0]
                kind = OmegaConf.select(cfg, f"{group}.kind", default=None)
                which = f" (this {group} is kind {kind!r})" if kind else ""
                return (f"{o}: {parent} is null in this config{which}, so it has no keys to set; drop the override, "
                        f"or choose a {group} that has {parent}")
    return None


def yaml_error_line(exc: BaseException) -> str:
    """One line for a config file that does not parse, e.g. "/home/me/conf/experiment/mine.yaml: not valid YAML:
    expected ',' or ']', but got ':' (line 2, column 6)"."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    name = getattr(mark, "name", None) or "a config file"
    return f"{name}: not valid YAML: {problem}{where}"


def _precheck_sweep(overrides: list[str], config_name: str = "config") -> None:
    """For a multirun: Hydra composes every job's config before it launches any, and one value of the wrong type
    or a misspelled key stops the whole sweep with a many-line message.  Check each swept value against the schema
    first (microseconds each, no composition) and say which one in one line, exit code 2; then compose the sweep's
    master config as Hydra will (:func:`_compose_master_or_exit`).  A swept group choice that does not compose is
    reported in one line by the sweeper's batch check (kexp.app.sweeper.install); value errors (ranges,
    u_min < u_max) are reported per job."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except HydraException:
        return  # a syntax error: Hydra's own message names it
    from .schema import filled
    schema = filled(_register_schema())
    for ov in parsed:
        key = ov.key_or_group
        if ov.is_add() or ov.is_delete() or key.startswith("hydra") or "." not in key:
            continue
        values = list(ov.sweep_iterator()) if ov.is_sweep_override() else [ov.value()]
        for value in values:
            try:
                OmegaConf.update(schema, key, value, merge=True)
            except (OmegaConfBaseException, AssertionError) as exc:
                if not isinstance(exc, OmegaConfBaseException):
                    continue  # not a schema path (e.g. inside a free-form mapping): Hydra decides
                wrapped = HydraException(f"Sweep value {key}={value!r} does not fit the config schema")
                wrapped.__cause__ = exc
                print(f"kexp: error: {composition_error_line(wrapped)}", file=sys.stderr)
                sys.exit(2)
    _compose_master_or_exit(overrides, config_name)
