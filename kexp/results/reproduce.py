"""Does a committed results row still come out of today's code?  Re-run some of its initial conditions and
compare the new summaries with the committed ones, run by run.

    kexp-results sample results/pendulum_lmpc.csv 10        # 10 of the row's x0, as one Hydra list value
    kexp-results compare results/pendulum_lmpc.csv NEW.csv   # each run of NEW against the committed run

``results/reproduce.sh`` does both for any committed CSV, with the row's overrides from the script that made it.
A CSV keeps x0 to 10 significant digits; :func:`sample` gives the full-precision x0 the row scripts swept
(``np.random.default_rng(seed).uniform(low, high, (2, n))``, or per state for a box of n states,
:data:`GENERATORS`) wherever a CSV's x0 is one of theirs, so that a re-run starts where the committed run started,
bit for bit.  A run is known by its full x0 (x0_1 … x0_n).

What agrees (:func:`compare`): the discrete columns exactly (status, success, fallbacks and the conditions); cost
and max |u| to ``rtol`` of the committed value (default 1e-6: the portable golden policy's bound on a model's
prediction, README "Golden recordings"; the same machine and code reproduce them to the CSV's 10 digits); the
settling time to one control step (0.01 s: a run that creeps along the tolerance can cross it one step apart).  The
solve times are wall-clock and not compared.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import is_number
from .aggregate import ReportError
from .csvfiles import read_csv, x0_columns, x0_key

GENERATORS = ((42, -1.0, 1.0, 100), (42, -2.0, 2.0, 100), (43, -2.0, 2.0, 300),
              (42, (-0.6, -1.5), (0.6, 1.5), 100), (42, (-0.5, -0.6, 0.0, 0.0), (0.5, 0.6, 0.0, 0.0), 100))
"""(seed, low, high, n) of the x0 the row scripts sweep: results/robustness.sh, results/regions.sh and its --map,
results/plants.sh (Pendulum-v1's and InvertedPendulum-v5's boxes).
low and high are numbers (2 states) or one number per state (a box, :func:`generated_x0`): a plant row's box
(results/sweep_lib.sh x0_box) belongs here too, so that ``sample`` re-runs its full-precision x0."""
EXACT = ("status", "success", "fallbacks", "certificate", "controller", "inputs", "data_noise", "smoothing",
         "sim_noise", "mismatch")
RELATIVE = ("cost", "max_abs_u")
SETTLE_ATOL = 0.0101     # one control step of 0.01 s, and the CSV's rounding
SHOWN = 10               # runs that disagree listed in a report


def _bounds(name: str, v) -> np.ndarray:
    """``v`` (a number or one number per state) as a float vector; ReportError when it is not finite numbers."""
    vals = [v] if is_number(v) else list(v) if isinstance(v, (list, tuple, np.ndarray)) else [v]
    if not vals or not all(is_number(x) and math.isfinite(x) for x in vals):
        raise ReportError(f"{name} {v!r}: give finite numbers, one per state (or one number for both states of a "
                          "2-state system)")
    return np.array(vals, dtype=float)


def generated_x0(seed: int, low, high, n: int) -> list[tuple[float, ...]]:
    """The ``n`` x0 the row scripts sweep, as tuples of Python floats (results/sweep_lib.sh's x0_list and x0_box
    print them with :func:`hydra_list`).

    - ``low``, ``high`` numbers: 2 states, ``np.random.default_rng(seed).uniform(low, high, (2, n)).T`` (the
      built-in systems' rows, unchanged);
    - ``low``, ``high`` one number per state (a box, n_states >= 1): state i is drawn from [low_i, high_i), state by
      state as above (``uniform(low[:, None], high[:, None], (n_states, n)).T``: with equal bounds on all states
      the same numbers as the 2-state draws); low_i == high_i fixes state i (e.g. zero velocities).

    ReportError when the bounds are not finite numbers of one length, a low exceeds its high, or ``n`` < 1."""
    if not (is_number(n, integer=True) and n >= 1):
        raise ReportError(f"number of x0 {n!r}: give a whole number >= 1")
    if not is_number(seed, integer=True):
        raise ReportError(f"seed {seed!r}: give a whole number")
    lo, hi = _bounds("low", low), _bounds("high", high)
    if is_number(low) and is_number(high):
        lo, hi = np.repeat(lo, 2), np.repeat(hi, 2)
    if lo.size != hi.size:
        raise ReportError(f"low {lo.tolist()} and high {hi.tolist()}: one bound per state in each ({lo.size} and "
                          f"{hi.size} given)")
    if np.any(lo > hi):
        i = int(np.argmax(lo > hi))
        raise ReportError(f"state {i + 1}: low {lo[i]:g} > high {hi[i]:g}; give low <= high (equal fixes the state)")
    draws = np.random.default_rng(seed).uniform(lo[:, None], hi[:, None], (lo.size, n)).T
    return [tuple(float(v) for v in x) for x in draws]


def corner(name: str, text: str) -> list[float]:
    """A box corner given on the command line, 'L1,L2,…' (one number per state), as floats; ReportError naming
    the argument otherwise."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if not vals or not all(math.isfinite(v) for v in vals):
        raise ReportError(f"{name} {text!r}: give finite numbers, one per state, separated by commas "
                          "(e.g. -0.5,-0.2,0,0)")
    return vals


def _known_x0() -> dict:
    """{x0 as a CSV writes it (each entry %.10g): the full-precision x0} over :data:`GENERATORS`."""
    return {tuple(f"{v:.10g}" for v in x): x for gen in GENERATORS for x in generated_x0(*gen)}


def sample(path: str | Path, n: int) -> list[tuple[float, float]]:
    """``n`` x0 of a results CSV, evenly spaced over its rows (all of them if it has fewer), each the row
    scripts' full-precision x0 where the CSV's is one of theirs, else the CSV's own digits."""
    if not (is_number(n, integer=True) and n >= 1):
        raise ReportError(f"sample size {n!r}: give a whole number >= 1")
    rows = read_csv(path)
    cols = x0_columns(rows[0])
    idx = np.unique(np.linspace(0, len(rows) - 1, min(n, len(rows))).round().astype(int))
    known = _known_x0()
    out = []
    for i in idx:
        key = x0_key(rows[i], cols)
        if "" in key:
            raise ReportError(f"{path}: row {i + 2} has no x0; a run without one cannot be re-run")
        out.append(known.get(key, tuple(float(v) for v in key)))
    return out


def hydra_list(x0s) -> str:
    """x0s (each a sequence of n floats) as one Hydra list value (``sim.x0=...`` of a multirun), each float
    written exactly (repr): ``[a,b],[c,d]`` for 2 states."""
    return ",".join("[" + ",".join(repr(float(v)) for v in x) + "]" for x in x0s)


@dataclass(frozen=True)
class RunDiff:
    """One re-run against the committed run of the same x0: ``fields`` the columns that disagree, each
    (column, committed value, new value) as the CSVs hold them; empty when the run agrees."""
    x0: tuple[str, ...]
    fields: tuple[tuple[str, str, str], ...]

    @property
    def agrees(self) -> bool:
        return not self.fields


@dataclass(frozen=True)
class Comparison:
    """What ``compare`` found: one :class:`RunDiff` per new run, the largest relative cost difference over the
    runs whose costs were compared (nan when none), the tolerance used, and the columns one CSV lacked."""
    committed: str
    new: str
    runs: tuple[RunDiff, ...]
    worst_cost_rel: float
    rtol: float
    skipped: tuple[str, ...]

    @property
    def agrees(self) -> bool:
        return all(r.agrees for r in self.runs)

    def report(self) -> str:
        """A few lines: the verdict, then each run that disagrees and how."""
        n_ok = sum(r.agrees for r in self.runs)
        worst = "–" if math.isnan(self.worst_cost_rel) else f"{self.worst_cost_rel:.1e}"
        lines = [f"{self.committed}: {n_ok}/{len(self.runs)} re-run x0 agree with the committed runs "
                 f"(cost and max |u| to rtol {self.rtol:g}, worst cost difference {worst}; settling time to "
                 f"{SETTLE_ATOL:g} s; discrete columns exactly)"]
        if self.skipped:
            lines.append(f"  not compared (only in one CSV): {', '.join(self.skipped)}")
        differ = [r for r in self.runs if not r.agrees]
        for r in differ[:SHOWN]:
            what = "; ".join(f"{c} {a} -> {b}" for c, a, b in r.fields)
            lines.append(f"  x0 ({', '.join(r.x0)}): {what}")
        if len(differ) > SHOWN:
            lines.append(f"  … and {len(differ) - SHOWN} more runs that disagree")
        return "\n".join(lines)


def _float(v: str) -> float:
    return float(v) if v != "" else math.nan


def _differs(col: str, a: str, b: str, rtol: float) -> bool:
    if col in RELATIVE:
        fa, fb = _float(a), _float(b)
        if math.isnan(fa) or math.isnan(fb):
            return (a == "") != (b == "")
        return abs(fa - fb) > rtol * abs(fa)
    if col == "settling_time_s":
        fa, fb = _float(a), _float(b)
        if math.isinf(fa) or math.isinf(fb) or math.isnan(fa) or math.isnan(fb):
            return a != b
        return abs(fa - fb) > SETTLE_ATOL
    return a != b


def compare(committed: str | Path, new: str | Path, rtol: float = 1e-6) -> Comparison:
    """Each run of the ``new`` CSV against the ``committed`` run of the same x0 (to the CSVs' 10 digits):
    :class:`Comparison`.  ReportError when the two files' names (rows) differ, a new x0 is not among the
    committed ones, or ``rtol`` is not a finite number >= 0."""
    if not (is_number(rtol) and 0 <= rtol < math.inf):
        raise ReportError(f"--rtol {rtol!r}: give a finite number >= 0")
    if Path(committed).stem != Path(new).stem:
        raise ReportError(f"{committed} and {new}: rows of two names; compare a re-run of a row with the committed "
                          "row of the same <system>_<configuration>")
    old_rows, new_rows = read_csv(committed), read_csv(new)
    ocols, ncols = x0_columns(old_rows[0]), x0_columns(new_rows[0])
    if len(ocols) != len(ncols):
        raise ReportError(f"{committed} and {new}: runs of {len(ocols)} and {len(ncols)} states; compare a re-run "
                          "of a row with the committed row of the same system")
    old = {x0_key(r, ocols): r for r in old_rows}
    columns = EXACT + RELATIVE + ("settling_time_s",)
    shared = [c for c in columns if c in old_rows[0] and c in new_rows[0]]
    skipped = tuple(c for c in columns if (c in old_rows[0]) != (c in new_rows[0]))
    runs, worst = [], math.nan
    for r in new_rows:
        key = x0_key(r, ncols)
        if key not in old:
            raise ReportError(f"{new}: x0 ({', '.join(key)}) is not a run of {committed}; compare a re-run of "
                              "the committed row's x0 (kexp-results sample)")
        o = old[key]
        diffs = tuple((c, o[c], r[c]) for c in shared if _differs(c, o[c], r[c], rtol))
        runs.append(RunDiff(key, diffs))
        ca, cb = _float(o["cost"]), _float(r["cost"])
        if not (math.isnan(ca) or math.isnan(cb)) and ca != 0:
            rel = abs(ca - cb) / abs(ca)
            worst = rel if math.isnan(worst) else max(worst, rel)
    return Comparison(str(committed), str(new), tuple(runs), worst, float(rtol), skipped)
