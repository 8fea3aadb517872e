"""Real-time pacing of the closed loop (``sim.realtime=true``): each control step held to wall-clock Δ.

The clock starts at step 0.  Step k's work (measure, control, the plant's step) must end by its deadline; its
*lateness* is end − deadline in seconds (negative: the time it had to spare), a *miss* a lateness > 0.  After the
logging callback the loop sleeps until the deadline and starts the next step there, so consecutive steps start
Δ apart.  A miss is not caught up: the schedule is re-based at the late step's end (the next deadline is that end
+ Δ), so every step, the one after a miss included, gets a full Δ.  Keeping the absolute schedule instead would
run the steps after an overrun back to back, each shorter than Δ, to catch up: a hardware plant would then hold
inputs for less than the Δ the model was identified at.  The cost of re-basing: a run with misses takes longer
than n·Δ in wall-clock time, by the misses' lateness.  The time the logging callback takes after the end is
counted in the next step's budget (it starts late by that much), so no wall-clock time goes unaccounted.

Waiting: ``time.sleep`` until ``SPIN_S`` before the wake-up time, then polling ``time.perf_counter``: on a
loaded 2-core machine the median |period − Δ| at Δ = 10 ms was 9–16 µs with ``time.sleep`` alone and 3–8 µs
with the 1 ms busy-wait (benchmarks/realtime_jitter.py); the p99, ~4 ms there, is the machine's preemption,
which no wait removes (the miss count is for that).  The busy-wait costs up to ``SPIN_S`` of CPU per step.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

SPIN_S = 1e-3   # the last part of a wait spent polling the clock rather than asleep


@dataclass(frozen=True)
class RealtimeSummary:
    """How well a paced run kept its schedule (frozen; wall-clock numbers, they vary between repeats): ``dt`` the
    period Δ in s, ``steps`` the steps timed, ``misses`` the steps that ended past their deadline, the lateness
    (end − deadline, s; negative: time to spare) at its ``late_max`` (at step ``late_max_k``), ``late_p99`` and
    ``late_median``, and ``wall_s`` the wall-clock seconds from step 0's start to the end of the last step (of its
    wait, where the loop waited after it).
    ``to_dict()`` gives a plain dict."""

    dt: float
    steps: int
    misses: int
    late_max: float
    late_max_k: int
    late_p99: float
    late_median: float
    wall_s: float

    def to_dict(self) -> dict:
        return asdict(self)


class Pacer:
    """The wall clock of one paced run: :meth:`start` at step 0, :meth:`stamp` when a step's work ends (its
    lateness and miss), :meth:`wait` before the next step starts; :meth:`summary` at the end.  ``dt`` > 0 in s;
    ``spin`` the busy-wait at the end of each wait in s (None: ``SPIN_S``); ``clock`` and ``sleep`` are
    ``time.perf_counter`` and ``time.sleep`` (a test may pass others)."""

    def __init__(self, dt: float, *, spin: float | None = None, clock=time.perf_counter, sleep=time.sleep):
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"Pacer: dt={dt!r}, need a finite number > 0")
        self.dt, self._clock, self._sleep = float(dt), clock, sleep
        self.spin = float(SPIN_S if spin is None else spin)
        self._t0 = self._deadline = self._wake = self._end = None
        self.late: list[float] = []

    def start(self) -> None:
        """Step 0 starts now: its deadline is now + Δ."""
        self._t0 = self._clock()
        self._deadline = self._t0 + self.dt

    def stamp(self) -> tuple[float, bool]:
        """The current step's work has ended: returns its lateness (s, end − deadline) and whether it missed
        (lateness > 0), and sets the next deadline (the current one + Δ; after a miss, this end + Δ)."""
        if self._deadline is None:
            raise RuntimeError("Pacer.stamp before start")
        now = self._clock()
        late = now - self._deadline
        miss = late > 0
        self._wake = now if miss else self._deadline
        self._deadline = self._wake + self.dt
        self._end = now
        self.late.append(late)
        return late, miss

    def wait(self) -> None:
        """Hold until the next step's start (the last deadline; at once after a miss): asleep until ``spin`` s
        before it, then polling the clock."""
        until, clock, spin = self._wake, self._clock, self.spin
        if until is None:
            return
        left = until - clock()
        if left > spin:
            self._sleep(left - spin)
        now = clock()
        while now < until:
            now = clock()
        self._end = now

    def summary(self) -> RealtimeSummary:
        """The run's :class:`RealtimeSummary` (all zeros and ``late_max_k`` −1 before any step was stamped)."""
        late = np.asarray(self.late, dtype=float)
        if late.size == 0:
            return RealtimeSummary(dt=self.dt, steps=0, misses=0, late_max=0.0, late_max_k=-1, late_p99=0.0,
                                   late_median=0.0, wall_s=0.0)
        worst = int(np.argmax(late))
        return RealtimeSummary(dt=self.dt, steps=int(late.size), misses=int(np.sum(late > 0)),
                               late_max=float(late[worst]), late_max_k=worst,
                               late_p99=float(np.percentile(late, 99)), late_median=float(np.median(late)),
                               wall_s=float(self._end - self._t0))
