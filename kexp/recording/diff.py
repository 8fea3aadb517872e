"""Compare two run logs channel by channel, message by message, field by field.

Numbers are equal when |a − b| ≤ atol + rtol·|b|; strings, booleans and None must match exactly; lists must
have the same length.  Wall-clock channels and fields are ignored unless asked for.  The first divergence is
the earliest in log time (channel order breaks ties).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

from .provenance import version_warnings
from .reader import LogError, RunLog, read_log
from .schema import CHANNELS, WALL_CLOCK_CHANNELS, WALL_CLOCK_FIELDS


@dataclass(frozen=True)
class Divergence:
    channel: str
    index: int              # message index on the channel
    step: int | None        # control step k where the message has one
    t: float                # log time in seconds
    field: str              # path inside the message, e.g. "u[0]" or "metrics.cost"
    a: object
    b: object

    def describe(self) -> str:
        where = f"step {self.step}" if self.step is not None else f"message {self.index}"
        return (f"first divergence: channel {self.channel}, {where} (t = {self.t:.6g} s), field {self.field}: "
                f"{self.a!r} != {self.b!r}")


@dataclass(frozen=True)
class DiffResult:
    equal: bool
    first: Divergence | None
    per_channel: dict = field(default_factory=dict)   # channel -> (compared, different)
    warnings: tuple[str, ...] = ()

    def report(self) -> str:
        lines = list(self.warnings)
        lines.append("logs are equal" if self.equal else self.first.describe())
        for ch, (n, d) in sorted(self.per_channel.items()):
            lines.append(f"  {ch:<12} {n:>7} messages compared, {d:>6} different")
        return "\n".join(lines)


def _compare(a, b, path, atol, rtol, ignore_fields):
    """Return (field path, a, b) of the first difference, or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in ignore_fields:
                continue
            sub = f"{path}.{key}" if path else key
            if key not in a or key not in b:
                return sub, a.get(key, "<missing>"), b.get(key, "<missing>")
            d = _compare(a[key], b[key], sub, atol, rtol, ignore_fields)
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}.length", len(a), len(b)
        for i, (x, y) in enumerate(zip(a, b)):
            d = _compare(x, y, f"{path}[{i}]", atol, rtol, ignore_fields)
            if d:
                return d
        return None
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool) and not isinstance(b, bool):
        return None if abs(a - b) <= atol + rtol * abs(b) else (path, a, b)
    return None if a == b and type(a) is type(b) else (path, a, b)


def diff_logs(a: RunLog | str | Path, b: RunLog | str | Path, *, atol: float = 0.0, rtol: float = 0.0,
              include_wall_clock: bool = False) -> DiffResult:
    la = a if isinstance(a, RunLog) else read_log(a)
    lb = b if isinstance(b, RunLog) else read_log(b)
    warnings = tuple(w for w in (la.warning, lb.warning) if w) + tuple(version_warnings(la, lb))
    ignore_ch = () if include_wall_clock else WALL_CLOCK_CHANNELS
    ignore_fields = () if include_wall_clock else WALL_CLOCK_FIELDS
    order = {name: i for i, name in enumerate(CHANNELS)}
    topics = sorted((set(la.channels) | set(lb.channels)) - set(ignore_ch), key=lambda c: (order.get(c, 99), c))
    first, per = None, {}
    for ch in topics:
        ma, mb = la.channels.get(ch, []), lb.channels.get(ch, [])
        n = min(len(ma), len(mb))
        diffs = 0
        cand = None
        for i in range(n):
            (ta, xa), (tb, xb) = ma[i], mb[i]
            d = ("log_time", ta, tb) if ta != tb else _compare(xa, xb, "", atol, rtol, ignore_fields)
            if d:
                diffs += 1
                if cand is None:
                    step = xa.get("k") if isinstance(xa, dict) else None
                    cand = Divergence(ch, i, step, ta / 1e9, d[0], d[1], d[2])
        if len(ma) != len(mb):
            diffs += abs(len(ma) - len(mb))
            if cand is None:
                t = (ma[n][0] if len(ma) > n else mb[n][0]) / 1e9
                cand = Divergence(ch, n, None, t, "message count", len(ma), len(mb))
        per[ch] = (n, diffs)
        if cand is not None and (first is None or cand.t < first.t):
            first = cand
    return DiffResult(equal=first is None, first=first, per_channel=per, warnings=warnings)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="kexp-diff", description="Compare two kexp run logs (MCAP). "
                                "Exit 0: equal, 1: different, 2: unreadable.")
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--atol", type=float, default=0.0, help="absolute tolerance for numbers (default 0)")
    p.add_argument("--rtol", type=float, default=0.0, help="relative tolerance for numbers (default 0)")
    p.add_argument("--include-wall-clock", action="store_true",
                   help="also compare wall-clock channels/fields (solve times, versions)")
    args = p.parse_args(argv)
    try:
        res = diff_logs(args.a, args.b, atol=args.atol, rtol=args.rtol, include_wall_clock=args.include_wall_clock)
    except LogError as exc:
        print(f"kexp-diff: error: {exc}", file=sys.stderr)
        return 2
    for w in res.warnings:
        print(f"kexp-diff: warning: {w}", file=sys.stderr)
    print("\n".join(res.report().splitlines()[len(res.warnings):]))
    return 0 if res.equal else 1


def main_exit() -> None:
    sys.exit(main())


if __name__ == "__main__":
    main_exit()
