"""Read a kexp run log, including what a truncated file (a killed run) still holds."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import KexpError
from .mcap_read import Cut, iter_messages


class LogError(KexpError, OSError):
    """The file is missing or not an MCAP log at all."""


@dataclass
class RunLog:
    """A run log read into memory by :func:`read_log`: ``channels`` maps a topic (e.g. '/step') to its
    (log_time_ns, message dict) pairs in log-time order; ``truncated`` and ``warning`` say whether the file was
    cut short.  ``messages(topic)`` -> the message dicts ([] for an absent topic), ``one(topic)`` -> the first
    (or None), ``completed`` -> the run wrote its final /summary with ``completed`` true."""

    path: Path
    channels: dict = field(default_factory=dict)   # topic -> list of (log_time_ns, message dict)
    truncated: bool = False
    warning: str = ""

    def messages(self, topic: str) -> list[dict]:
        return [m for _, m in self.channels.get(topic, [])]

    def one(self, topic: str) -> dict | None:
        msgs = self.messages(topic)
        return msgs[0] if msgs else None

    @property
    def completed(self) -> bool:
        s = self.one("/summary")
        return bool(s and s.get("completed"))


RUN_LOG = "run.mcap"   # the log a kexp run writes into its folder (logging.mcap)


def log_path(source: str | Path) -> Path:
    """The run log a command was given (kexp-diff, kexp-figures, the pytest plugin): ``source`` itself when it is
    not a folder (an .mcap file; :func:`read_log` says what is wrong with anything else), else the :data:`RUN_LOG`
    of that run folder.  A folder without one raises :class:`LogError` in one line."""
    path = Path(source)
    if not path.is_dir():
        return path
    log = path / RUN_LOG
    if not log.is_file():
        raise LogError(f"no run log at {log} (pass a run folder holding {RUN_LOG}, or an .mcap file; a run with "
                       "logging.mcap=false writes none)")
    return log


def read_log(path: str | Path) -> RunLog:
    """Messages of every channel in log-time order.  A file cut short (killed writer) yields what its complete
    chunks hold, with ``truncated=True`` and a warning; a file that is not MCAP, or one past the decompression
    limits of :mod:`kexp.recording.mcap_read` (a chunk over 64 MiB, all chunks over 64× the file's size + 1 MiB,
    a chunk that decompresses past its declared size), raises :class:`LogError` before that much is
    decompressed."""
    path = Path(path)
    if not path.exists():
        raise LogError(f"log {path} does not exist")
    if not path.is_file():
        raise LogError(f"{path} is not a file; pass the run.mcap inside a run folder")
    log = RunLog(path=path)
    with open(path, "rb") as f:
        try:
            for topic, log_time, data in iter_messages(f, str(path)):
                log.channels.setdefault(topic, []).append((log_time, json.loads(data)))
        except LogError:
            raise
        except Exception as exc:  # noqa: BLE001 - any decode error at the tail means a cut file
            reason = str(exc) if isinstance(exc, Cut) else type(exc).__name__
            log.truncated = True
            log.warning = (f"{path.name} is truncated ({reason}); read up to the last complete chunk "
                           f"({sum(len(v) for v in log.channels.values())} messages)")
    for topic in log.channels:
        log.channels[topic].sort(key=lambda tm: tm[0])
    if not log.truncated and not log.completed:
        log.warning = f"{path.name} has no completed /summary: the run did not finish"
    return log
