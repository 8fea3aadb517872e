"""``kexp --help`` (and ``-h``): what kexp is, its common commands, the presets and config groups (read from the
config folder when asked, so a new preset or option shows without an edit here), the other tools and where the
docs are, in one screen.  It imports nothing but the standard library (no numpy, no Hydra): it prints in a
fraction of a second.  Hydra's own help page stays one flag away: ``kexp --hydra-help``."""
from __future__ import annotations

import re
from pathlib import Path

HELP_FLAGS = ("--help", "-h")
HYDRA_HELP = "--hydra-help"   # becomes Hydra's --help
WIDTH = 100

TOOLS = (   # (command, one line); each also answers --help and --version
    ("kexp-diff", "compare two run logs or run folders (exit 0 equal, 1 different)"),
    ("kexp-render", "render a run log (run.mcap) into a Rerun recording (.rrd)"),
    ("kexp-report", "tabulate a sweep folder: report.csv, report.md and figures"),
    ("kexp-results", "results tables from sweeps: collect, table, compare, robustness, plants"),
    ("kexp-figures", "figures from logs and sweeps: paper, roa, theorem1"),
    ("kexp-compile", "compile the controller kernels into the cache now (about a minute, once)"),
)


def options(conf_dir: str | Path) -> dict[str, list[str]]:
    """Config group -> its options (the YAML files of ``conf_dir/<group>/``, sorted), groups sorted by name."""
    conf = Path(conf_dir)
    groups = {}
    for group in sorted(p for p in conf.iterdir() if p.is_dir() and not p.name.startswith((".", "_"))):
        names = sorted(f.stem for f in group.glob("*.yaml"))
        if names:
            groups[group.name] = names
    return groups


def defaults(conf_dir: str | Path) -> dict[str, str]:
    """Group -> its default option, from the ``defaults:`` list of ``conf_dir/config.yaml`` (lines
    ``  - group: option``; no YAML parser needed, none imported)."""
    try:
        text = (Path(conf_dir) / "config.yaml").read_text()
    except OSError:
        return {}
    return dict(re.findall(r"^\s*-\s*([A-Za-z_][\w]*)\s*:\s*([\w.-]+)", text, flags=re.M))


def _wrapped(label: str, words: list[str], indent: int) -> list[str]:
    """``label`` then ``words`` separated by spaces, wrapped at :data:`WIDTH` with continuation lines indented."""
    lines, line = [], label.ljust(indent)
    for word in words:
        if len(line) + len(word) + 1 > WIDTH and line.strip():
            lines.append(line.rstrip())
            line = " " * indent
        line += word + " "
    lines.append(line.rstrip())
    return lines


def page(conf_dir: str | Path, version: str) -> str:
    """The help page for the configs in ``conf_dir``."""
    groups = options(conf_dir)
    chosen = defaults(conf_dir)
    presets = groups.pop("experiment", [])
    lines = [
        f"kexp {version}: Koopman-based Lyapunov MPC from data, as a logged experiment framework.",
        "Each run learns a model from data, certifies a control Lyapunov function, runs the closed loop",
        "and logs it (summary.json, model.npz, run.mcap, run.rrd) into its own folder.",
        "",
        "Usage: kexp [group=option] [key=value] [+experiment=PRESET] [-m (a sweep)]",
        "  kexp                                  the default: Van der Pol, LMPC -> outputs/<date>/<time>/",
        "  kexp +experiment=pendulum             a preset (below)",
        "  kexp controller=lqr sim.T=5           choose an option of a group, set a value",
        "  kexp -m 'sim.x0=[0.5,0.5],[1,1]'      a sweep, one folder per job; then kexp-report <dir>",
        "  kexp --cfg job                        print the composed config, run nothing",
        "",
    ]
    lines += _wrapped("Presets (+experiment=NAME):", presets, 28)
    lines += ["", "Config groups (group=option; * the default):"]
    for group, names in groups.items():
        lines += _wrapped(f"  {group}", [n + ("*" if chosen.get(group) == n else "") for n in names], 17)
    lines += ["", "Other tools (each has --help and --version):"]
    lines += [f"  {name:<14} {text}" for name, text in TOOLS]
    lines += ["",
              "Docs: docs/index.md in the repository (start with README.md).",
              f"Hydra's own help and flags: kexp {HYDRA_HELP}; version: kexp --version"]
    return "\n".join(lines)


def wants_help(argv: list[str]) -> bool:
    """Whether the command line asks for kexp's help page (``--help`` or ``-h`` anywhere)."""
    return any(a in HELP_FLAGS for a in argv)


def hydra_argv(argv: list[str]) -> list[str]:
    """``argv`` with ``--hydra-help`` replaced by Hydra's ``--help``."""
    return ["--help" if a == HYDRA_HELP else a for a in argv]
