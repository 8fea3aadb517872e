"""Golden recordings: short runs (2 s) of the paper's experiments, committed as MCAP in ``recordings/`` and
re-run by the tests, which diff the new logs against them.

Regenerate (after an intended change of behaviour) with:  ``python -m kexp.app.golden``
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

from ..cli import Parser

GOLDEN = {
    "paper_vanderpol": ["+experiment=paper_vanderpol"],
    "paper_pendulum": ["+experiment=paper_pendulum"],
}
COMMON = ["sim.T=2.0", "logging.rrd=false", "logging.progress=false", "logging.prediction_every=20",
          "cache.enabled=false"]
RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


def compose(name: str):
    from hydra import compose as _compose
    from hydra import initialize_config_dir

    from .conf import CONF_DIR
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return _compose(config_name="config", overrides=GOLDEN[name] + COMMON)


def record(name: str, out: Path) -> Path:
    """Run golden experiment ``name`` and copy its log to ``out`` (a .mcap path)."""
    from .experiment import run
    with tempfile.TemporaryDirectory() as tmp:
        run(compose(name), tmp, echo=lambda *_: None)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(tmp) / "run.mcap", out)
    return out


def main(argv=None) -> int:
    p = Parser(prog="python -m kexp.app.golden", description=__doc__.splitlines()[0])
    p.add_argument("names", nargs="*", default=sorted(GOLDEN), help=f"which ones (default all: {sorted(GOLDEN)})")
    p.add_argument("-o", "--out", default=str(RECORDINGS), help="folder (default: the repository's recordings/)")
    args = p.parse_args(argv)
    for name in args.names:
        if name not in GOLDEN:
            print(f"golden: error: unknown recording {name!r}; valid: {sorted(GOLDEN)}", file=sys.stderr)
            return 2
    out = Path(args.out)
    try:   # before any run: a folder that cannot be made failed only after the first recording's 3 s
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"golden: error: -o {args.out}: cannot make the folder ({exc.strerror or exc}); give a folder you can "
              "write", file=sys.stderr)
        return 2
    for name in args.names:
        path = record(name, out / f"{name}.mcap")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
