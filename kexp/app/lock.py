"""Which locked environment a run used: the sha256 of the repository's ``requirements.lock`` and whether the
installed package versions are the ones it pins (README, Set-up)."""
from __future__ import annotations

import hashlib
import re
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

LOCK_NAME = "requirements.lock"
REPO = Path(__file__).resolve().parents[2]     # the checkout; site-packages for an installed wheel (no lock there)
_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)")


@dataclass(frozen=True)
class LockInfo:
    file: str | None        # the lock file's name, None when there is none
    sha256: str | None      # of its bytes
    matches: bool | None    # every pinned package installed at its pinned version; None without a lock
    note: str               # why there is no lock, or which pins differ ("" when they all match)

    def to_dict(self) -> dict:
        return asdict(self)


def pins(text: str) -> dict[str, str]:
    """``name==version`` lines of a requirements file (hash and comment lines skipped), names normalised."""
    out = {}
    for line in text.splitlines():
        m = _PIN.match(line.strip())
        if m:
            out[_normalise(m.group(1))] = m.group(2)
    return out


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


@lru_cache(maxsize=None)
def installed_version(name: str) -> str | None:
    """The installed version of package ``name`` (None: not installed), looked up once per process: a metadata
    lookup scans site-packages (0.17 s per run for the lock's pins and the run's provenance, under cProfile), and the
    installed versions do not change while a process runs."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def lock_info(path: str | Path | None = None) -> LockInfo:
    """The lock at ``path`` (default: ``requirements.lock`` at the top of the repository) against this environment."""
    path = Path(path) if path is not None else REPO / LOCK_NAME
    if not path.is_file():
        return LockInfo(None, None, None, f"no {path.name} beside the kexp package (an installed wheel?): "
                                          "versions not checked against a lock")
    data = path.read_bytes()
    wanted = pins(data.decode("utf-8", errors="replace"))
    differ = [(name, ver, installed_version(name)) for name, ver in sorted(wanted.items())]
    differ = [(n, v, got) for n, v, got in differ if got != v]
    note = ""
    if differ:
        shown = "; ".join(f"{n} {v} locked, {got or 'not'} installed" for n, v, got in differ[:5])
        note = f"{len(differ)} of {len(wanted)} pins differ: {shown}" + (" ..." if len(differ) > 5 else "")
    return LockInfo(path.name, hashlib.sha256(data).hexdigest(), not differ, note)
