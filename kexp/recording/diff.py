"""Compare two run logs channel by channel, message by message, field by field, under a policy (policy.py).

``exact`` (default): numbers equal, or within ``atol + rtol·|b|`` entry by entry when tolerances are given.
``portable``: what must hold on any machine — discrete fields exact, numbers norm-wise within tolerances
justified by the computation's conditioning, the model compared by its eigenvalues and predictions.  Strings,
booleans and None always match exactly; lists must have the same length.  Wall-clock channels and fields are
ignored unless asked for.  The first divergence is the earliest in log time (channel order breaks ties).
"""
from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..cli import Parser, emit
from ..errors import ConfigError
from . import behaviour
from .policy import POLICIES, ChannelRule, Policy, make_policy
from .provenance import version_warnings
from .reader import LogError, RunLog, log_path, read_log
from .schema import CHANNELS, WALL_CLOCK_CHANNELS, WALL_CLOCK_FIELDS

_INDEX = re.compile(r"\[\d+\]")


@dataclass(frozen=True)
class Divergence:
    """Where two logs first differ: channel, message index, control step (if any), log time, field, values."""
    channel: str
    index: int              # message index on the channel
    step: int | None        # control step k where the message has one
    t: float                # log time in seconds
    field: str              # path inside the message, e.g. "u[0]" or "metrics.cost"
    a: object
    b: object
    note: str = ""          # the tolerance that was exceeded, for policies with one

    def describe(self) -> str:
        where = f"step {self.step}" if self.step is not None else f"message {self.index}"
        note = f" ({self.note})" if self.note else ""
        return (f"first divergence: channel {self.channel}, {where} (t = {self.t:.6g} s), field {self.field}: "
                f"{self.a!r} != {self.b!r}{note}")


@dataclass(frozen=True)
class DiffResult:
    """``equal``; the ``first`` divergence (None if equal); ``per_channel``: channel -> (messages compared,
    messages different); ``warnings`` (truncated files, different package versions); the ``policy`` name."""
    equal: bool
    first: Divergence | None
    per_channel: dict = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    policy: str = "exact"
    usage: dict = field(default_factory=dict)   # portable: channel -> largest |Δ|/tolerance seen (1 = at the bound)

    def report(self) -> str:
        lines = list(self.warnings)
        lines.append(f"logs are equal ({self.policy})" if self.equal else self.first.describe())
        for ch, (n, d) in sorted(self.per_channel.items()):
            lines.append(f"  {ch:<12} {n:>7} messages compared, {d:>6} different")
        return "\n".join(lines)


def _numeric(x) -> bool:
    return (isinstance(x, (int, float)) and not isinstance(x, bool)) or x is None


def _array(x) -> np.ndarray | None:
    """A number or a (nested) list of numbers/None as a float array (None -> NaN); None if it is not one."""
    if _numeric(x) and x is not None:
        return np.asarray(float(x))
    if isinstance(x, list) and x:
        flat, stack = [], [x]
        while stack:
            v = stack.pop()
            if isinstance(v, list):
                stack.extend(v)
            elif _numeric(v):
                flat.append(v)
            else:
                return None
        if any(v is not None for v in flat):
            try:
                return np.array(x, dtype=float)
            except (TypeError, ValueError):   # ragged
                return None
    return None


def _compare_exact(a, b, path, tol, ignore_fields):
    """Entry by entry: (field path, a, b, note) of the first difference, or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in ignore_fields:
                continue
            sub = f"{path}.{key}" if path else key
            if key not in a or key not in b:
                return sub, a.get(key, "<missing>"), b.get(key, "<missing>"), ""
            d = _compare_exact(a[key], b[key], sub, tol, ignore_fields)
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}.length", len(a), len(b), ""
        for i, (x, y) in enumerate(zip(a, b)):
            d = _compare_exact(x, y, f"{path}[{i}]", tol, ignore_fields)
            if d:
                return d
        return None
    if _numeric(a) and _numeric(b) and a is not None and b is not None:
        return None if abs(a - b) <= tol.bound(abs(b)) else (path, a, b, "")
    return None if a == b and type(a) is type(b) else (path, a, b, "")


def _scales(messages, ignore_fields) -> dict:
    """Largest magnitude of each numeric field (path without indices) over a channel's messages."""
    out: dict[str, float] = {}

    def walk(x, path):
        if isinstance(x, dict):
            for k, v in x.items():
                if k not in ignore_fields:
                    walk(v, f"{path}.{k}" if path else k)
            return
        arr = _array(x)
        if arr is not None:
            finite = np.abs(arr[np.isfinite(arr)])
            if finite.size:
                out[path] = max(out.get(path, 0.0), float(finite.max()))
        elif isinstance(x, list):
            for v in x:
                walk(v, path)
    for _, m in messages:
        walk(m, "")
    return out


def _compare_normwise(a, b, path, rule: ChannelRule, scales, ignore_fields, usage):
    """Field by field against the field's norm over the channel: (path, a, b, note) or None.  ``usage`` (a
    one-item list) keeps the largest |Δ|/bound seen."""
    bare = _INDEX.sub("", path)
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            sub = f"{path}.{key}" if path else key
            if key in ignore_fields or rule.tol_for(_INDEX.sub("", sub)) is None:
                continue
            if key not in a or key not in b:
                return sub, a.get(key, "<missing>"), b.get(key, "<missing>"), ""
            d = _compare_normwise(a[key], b[key], sub, rule, scales, ignore_fields, usage)
            if d:
                return d
        return None
    tol = rule.tol_for(bare)
    if tol is None:
        return None
    xa, xb = _array(a), _array(b)
    if xa is not None and xb is not None:
        if xa.shape != xb.shape:
            return f"{path}.shape", list(xa.shape), list(xb.shape), ""
        nan_a, nan_b = np.isnan(xa), np.isnan(xb)
        if (nan_a != nan_b).any():
            i = np.unravel_index(int(np.argmax(nan_a != nan_b)), xa.shape)
            return path + "".join(f"[{j}]" for j in i), _item(a, i), _item(b, i), "null on one side only"
        diff = np.where(nan_a, 0.0, np.abs(xa - xb))
        bound = tol.bound(scales.get(bare, 0.0))
        if diff.size:
            usage[0] = max(usage[0], float(diff.max()) / bound if bound > 0 else (0.0 if diff.max() == 0 else np.inf))
        if diff.size and diff.max() > bound:
            i = np.unravel_index(int(np.argmax(diff)), diff.shape)
            return (path + "".join(f"[{j}]" for j in i), _item(a, i), _item(b, i),
                    f"|Δ| = {diff.max():.3g} > {tol.atol:g} + {tol.rtol:g}·{scales.get(bare, 0.0):.3g}")
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path}.length", len(a), len(b), ""
        for i, (x, y) in enumerate(zip(a, b)):
            d = _compare_normwise(x, y, f"{path}[{i}]", rule, scales, ignore_fields, usage)
            if d:
                return d
        return None
    return None if a == b and type(a) is type(b) else (path, a, b, "")


def _item(x, index):
    for j in index:
        x = x[j]
    return x


def _derived(la: RunLog, lb: RunLog, rule: ChannelRule, usage):
    """The model compared by what it does: (field, a, b, note) of the first failing check, or None."""
    tol = rule.default
    ma, mb = la.one("/model"), lb.one("/model")
    if "eigenvalues" in rule.derived and ma and mb:
        ea, eb = behaviour.eigenvalues(ma), behaviour.eigenvalues(mb)
        dist, i = behaviour.set_distance(ea, eb)
        scale = float(np.abs(eb).max()) if eb.size else 0.0
        usage[0] = max(usage[0], dist / tol.bound(scale) if tol.bound(scale) > 0 else 0.0)
        if dist > tol.bound(scale):
            a = [ea.real[i], ea.imag[i]] if i >= 0 else ea.size
            return ("eigenvalues (as a set)", a, eb.size if i < 0 else "nearest further away",
                    f"distance {dist:.3g} > {tol.atol:g} + {tol.rtol:g}·{scale:.3g}")
    if "prediction" in rule.derived:
        preds = behaviour.model_predictions(la, lb)
        if preds is not None:
            pa, pb = preds
            diff = np.abs(pa - pb)
            scale = float(np.nanmax(np.abs(pb))) if np.isfinite(pb).any() else 0.0
            bad = ~np.isfinite(diff) | (diff > tol.bound(scale))
            if tol.bound(scale) > 0 and np.isfinite(diff).all():
                usage[0] = max(usage[0], float(diff.max()) / tol.bound(scale))
            if bad.any():
                t, j = np.unravel_index(int(np.argmax(bad)), diff.shape)
                return (f"prediction x̂[{t}][{j}] (from x0 under the logged inputs)", float(pa[t, j]),
                        float(pb[t, j]), f"|Δ| = {diff[t, j]:.3g} > {tol.atol:g} + {tol.rtol:g}·{scale:.3g}")
    return None


def diff_logs(a: RunLog | str | Path, b: RunLog | str | Path, *, atol: float = 0.0, rtol: float = 0.0,
              include_wall_clock: bool = False, policy: str | Policy = "exact") -> DiffResult:
    """Compare log ``a`` with log ``b`` (RunLog, or paths: .mcap files or run folders, :func:`log_path`).  ``policy``: "exact" (with optional entry-wise
    ``atol``/``rtol``), "portable" (the cross-machine policy of policy.py), or a Policy."""
    pol = policy if isinstance(policy, Policy) else make_policy(policy, rtol=rtol, atol=atol)
    la = a if isinstance(a, RunLog) else read_log(log_path(a))
    lb = b if isinstance(b, RunLog) else read_log(log_path(b))
    for log in (la, lb):   # two such logs were "equal": no verdict can come from nothing
        if not any(log.channels.values()):
            raise LogError(f"{log.path} holds no message ({log.warning or 'an empty log'}): nothing to compare")
    # the file's own warning names it by its name; two logs are often both run.mcap: say which, by its path
    warnings = tuple(f"{side} ({log.path}): {log.warning}" for side, log in (("a", la), ("b", lb))
                     if log.warning) + tuple(version_warnings(la, lb))
    ignore_ch = () if include_wall_clock else WALL_CLOCK_CHANNELS
    ignore_fields = () if include_wall_clock else WALL_CLOCK_FIELDS
    order = {name: i for i, name in enumerate(CHANNELS)}
    topics = sorted((set(la.channels) | set(lb.channels)) - set(ignore_ch), key=lambda c: (order.get(c, 99), c))
    first, per, usage = None, {}, {}
    for ch in topics:
        ma, mb = la.channels.get(ch, []), lb.channels.get(ch, [])
        rule = pol.rule(ch)
        scales = _scales(mb, ignore_fields) if pol.normwise else {}
        n = min(len(ma), len(mb))
        diffs = 0
        cand = None
        used = [0.0]
        for i in range(n):
            (ta, xa), (tb, xb) = ma[i], mb[i]
            if ta != tb:
                d = ("log_time", ta, tb, "")
            elif pol.normwise:
                d = _compare_normwise(xa, xb, "", rule, scales, ignore_fields, used)
            else:
                d = _compare_exact(xa, xb, "", rule.default, ignore_fields)
            if d is None and i == 0 and rule.derived:
                d = _derived(la, lb, rule, used)
            if d:
                diffs += 1
                if cand is None:
                    step = xa.get("k") if isinstance(xa, dict) else None
                    cand = Divergence(ch, i, step, ta / 1e9, *d)
        if len(ma) != len(mb):
            diffs += abs(len(ma) - len(mb))
            if cand is None:
                t = (ma[n][0] if len(ma) > n else mb[n][0]) / 1e9
                cand = Divergence(ch, n, None, t, "message count", len(ma), len(mb))
        per[ch] = (n, diffs)
        if pol.normwise:
            usage[ch] = used[0]
        if cand is not None and (first is None or cand.t < first.t):
            first = cand
    return DiffResult(equal=first is None, first=first, per_channel=per, warnings=warnings, policy=pol.name,
                      usage=usage)


def main(argv=None) -> int:
    p = Parser(prog="kexp-diff", description="Compare two kexp run logs (MCAP), each given as its .mcap file or its "
               "run folder. Exit 0: equal, 1: different, 2: unreadable or bad arguments.")
    p.add_argument("a", help="a run.mcap, or a run folder holding one")
    p.add_argument("b", help="a run.mcap, or a run folder holding one")
    p.add_argument("--policy", choices=POLICIES, default="exact",
                   help="exact (default): every number equal, or within --atol/--rtol entry by entry; portable: "
                        "what holds across machines (README, 'Golden recordings')")
    p.add_argument("--atol", type=float, default=0.0, help="absolute tolerance for numbers (exact policy; default 0)")
    p.add_argument("--rtol", type=float, default=0.0, help="relative tolerance for numbers (exact policy; default 0)")
    p.add_argument("--include-wall-clock", action="store_true",
                   help="also compare wall-clock channels/fields (solve times, versions)")
    args = p.parse_args(argv)
    try:
        res = diff_logs(args.a, args.b, atol=args.atol, rtol=args.rtol, include_wall_clock=args.include_wall_clock,
                        policy=args.policy)
    except (LogError, ConfigError) as exc:
        print(f"kexp-diff: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:   # a file that exists but cannot be read (permissions, a device)
        print(f"kexp-diff: error: cannot read {exc.filename or 'a log'}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    for w in res.warnings:
        print(f"kexp-diff: warning: {w}", file=sys.stderr)
    emit("\n".join(res.report().splitlines()[len(res.warnings):]))
    return 0 if res.equal else 1


def main_exit() -> None:
    sys.exit(main())


if __name__ == "__main__":
    main_exit()
