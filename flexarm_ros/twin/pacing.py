"""Keeping the wall clock: the deadlines of a realtime twin and what it does when late.

The simulator of a ``realtime`` run steps tick n (n = 1, 2, ...) at the deadline
``t0 + n·T`` of a monotonic clock (T = the control period; t0 = the wall time of the
first published state). :class:`Pacer` sleeps to that absolute deadline — never to "now
plus a period", which drifts by the work of every tick — and measures each tick's
lateness (start − deadline). A tick that starts late is simply taken at once, so a late
stretch is caught up by running ticks back to back while the average work stays below T.

Past ``late_bound`` seconds of lateness, the policy decides (``late_policy``):

* ``"slow"`` (default): every tick is published; the deadlines are moved later by the
  lateness, so the twin's time falls behind the wall clock (real-time factor below 1).
  Counted as ``slowed_s``.
* ``"skip"``: the twin keeps the wall clock, as the bench's arm does. The ticks already
  due are stepped without publishing their hardware messages (sensor batches then carry
  the samples of the skipped ticks too, the last one at the message time), and the next
  published tick is the one whose deadline is now. Counted as ``skipped_ticks``. The
  plant integrates through the skipped ticks with the *held effort*: the driver's
  back-EMF feedback is open over them, so a long skip of a fast-moving DC drive can run
  away (measured: a 0.5 s stall at start-up made ``two_link_case1`` diverge) — use it
  with a bound of a few periods, where a held effort is what the bench would see.

The pacing thread can ask the kernel for realtime scheduling (``SCHED_FIFO`` at
``thread_priority`` 1..99; ros2_control's controller manager does so for its update loop
by default): a runnable process of normal priority can then not delay a deadline on the
simulator's CPU. It is off by default (:data:`THREAD_PRIORITY` 0), measured: on a
shared 2-core host a FIFO plant takes the CPU from the user's own controller — with the
example controller in its own process (``--processes``, an overloaded graph here) the
arm ended 3.5–26 % of its move off target under FIFO 50 against 0.2–1.2 % at normal
priority, while the gain was only the wake-up latency (p50 0.05 against 0.11 ms;
docs/decisions/0011-sched-fifo-is-opt-in.md). Where the kernel refuses (no ``CAP_SYS_NICE`` and
no ``RLIMIT_RTPRIO``), the thread runs at normal priority and the node warns once. The
run summary says which (``scheduling``). A FIFO thread never runs back to back for
longer than ``late_bound``: past it, either policy moves the next deadline a period
after now, so the thread sleeps again (and the kernel's realtime throttling keeps 5 % of
every second for the rest in any case).

Either way the run never drifts silently: the statistics (:class:`Lateness`) go into the
run summary, and the node warns when the bound is crossed.

No rclpy here: the clock and the sleep are injected, so the policy is tested with a fake
clock (``test/test_pacing.py``).
"""

from __future__ import annotations

import math
import os
import time
from typing import Callable

import numpy as np

from flexarm_ros.errors import InputError

LATE_POLICIES = ("skip", "slow")
#: the pacing thread's SCHED_FIFO priority by default: 0, normal scheduling (see above)
THREAD_PRIORITY = 0


class Lateness:
    """Streaming statistics of tick lateness (s): count, ticks late by more than half a
    period (``late_ticks``), the maximum, and percentiles from a histogram of 1 µs..10 s in
    64 bins per decade (a percentile is reported to within 3.7 %, the bin width; exact
    below 1 µs, where it is 0). Memory is fixed however long the run."""

    BINS_PER_DECADE = 64
    LO, HI = 1e-6, 10.0

    def __init__(self, period: float):
        self.period = period
        n = int(round(math.log10(self.HI / self.LO) * self.BINS_PER_DECADE))
        self.edges = self.LO * 10.0 ** (np.arange(n + 1) / self.BINS_PER_DECADE)
        self.counts = np.zeros(n + 2, dtype=np.int64)   # [< LO, bins..., >= HI]
        self.ticks = 0
        self.late_ticks = 0
        self.max = 0.0

    def add(self, lateness: float) -> None:
        lateness = max(0.0, float(lateness))
        self.ticks += 1
        if lateness > 0.5 * self.period:
            self.late_ticks += 1
        if lateness > self.max:
            self.max = lateness
        self.counts[int(np.searchsorted(self.edges, lateness, side="right"))] += 1

    def percentile(self, p: float) -> float:
        """The lateness below which ``p`` % of the ticks started (the upper edge of the bin
        holding that rank; never above the maximum)."""
        if self.ticks == 0:
            return 0.0
        rank = math.ceil(p / 100.0 * self.ticks)
        i = int(np.searchsorted(np.cumsum(self.counts), max(rank, 1)))
        if i == 0:
            return 0.0
        upper = self.edges[i] if i < len(self.edges) else math.inf
        return float(min(upper, self.max))

    def summary(self) -> dict:
        return {"ticks": self.ticks, "late_ticks": self.late_ticks,
                "lateness_p50_s": self.percentile(50), "lateness_p99_s": self.percentile(99),
                "lateness_max_s": self.max}


REALTIME_GT_HZ = 100.0
"""The default rate of ``ground_truth/tip`` and ``ground_truth/coordinates`` in realtime:
analysis topics that no bench has, thinned so that the hardware topics keep the wall
clock (measured: docs/decisions/0007-realtime-on-two-cores.md)."""


def ground_truth_rate(rate: float, mode: str) -> float:
    """The ground-truth rate a simulator uses: ``rate`` when it is 0 (every tick) or
    positive; for the default -1, every tick (0) in lockstep and fast and
    :data:`REALTIME_GT_HZ` in realtime."""
    if isinstance(rate, (int, float)) and rate == -1:
        return REALTIME_GT_HZ if mode == "realtime" else 0.0
    return rate


def check_settings(period: float, late_policy: str = "slow", late_bound: float = 0.1,
                   ground_truth_rate_hz: float = 0.0,
                   thread_priority: int = THREAD_PRIORITY,
                   start_timeout_s: float = 0.0, marker_rate_hz: float = 30.0) -> None:
    """The simulator's pacing and publishing parameters, or an InputError naming the one
    that is wrong (the node, :func:`flexarm_ros.run.run` and ``flexarm run`` check with
    this one function)."""
    if isinstance(start_timeout_s, bool) or not (
            isinstance(start_timeout_s, (int, float)) and math.isfinite(start_timeout_s)
            and start_timeout_s >= 0):
        raise InputError(f"parameter start_timeout_s: got {start_timeout_s:g} s, expected a "
                         f"finite number >= 0 (0: wait for ever)"
                         if isinstance(start_timeout_s, (int, float)) else
                         f"parameter start_timeout_s: got {start_timeout_s!r}, expected a "
                         f"finite number >= 0 (0: wait for ever)")
    if isinstance(thread_priority, bool) or not isinstance(thread_priority, int) or not (
            0 <= thread_priority <= 99):
        raise InputError(f"parameter thread_priority: got {thread_priority!r}, expected an "
                         f"integer SCHED_FIFO priority 1..99, or 0 for normal scheduling")
    if late_policy not in LATE_POLICIES:
        raise InputError(f"parameter late_policy: got {late_policy!r}, expected one of "
                         f"{LATE_POLICIES}")
    if not (isinstance(late_bound, (int, float)) and math.isfinite(late_bound)
            and late_bound >= period):
        raise InputError(f"parameter late_bound: got {late_bound!r} s, expected a finite "
                         f"bound of at least one control period ({period:g} s)")
    rate = ground_truth_rate(ground_truth_rate_hz, "lockstep")
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate >= 0):
        raise InputError(f"parameter ground_truth_rate_hz: got {rate!r}, expected 0 (every "
                         f"tick), -1 (the mode's default) or a positive rate in Hz")
    if not (isinstance(marker_rate_hz, (int, float)) and math.isfinite(marker_rate_hz)
            and marker_rate_hz >= 0):
        shown = (f"{marker_rate_hz:g}" if isinstance(marker_rate_hz, (int, float))
                 else repr(marker_rate_hz))
        raise InputError(f"parameter marker_rate_hz: got {shown}, expected a finite rate "
                         f"≥ 0 Hz (0: no arm_markers)")


def name_thread(name: str) -> None:
    """Give the calling thread ``name`` (≤ 15 bytes) as the kernel knows it, for ``ps -L``,
    ``top -H`` and ``chrt -p`` (Python 3.11 names its threads for itself only). Linux
    ``prctl(PR_SET_NAME)``; a no-op elsewhere."""
    try:
        import ctypes
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return
    PR_SET_NAME = 15                # linux/prctl.h
    prctl(PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)


def short_scheduling(how: str) -> str:
    """:func:`realtime_scheduling`'s text for a summary line: the policy and, for normal
    scheduling, whether it was asked for or refused."""
    if how.startswith("SCHED_OTHER (SCHED_FIFO"):
        return "SCHED_OTHER (SCHED_FIFO refused)"
    if how.startswith("SCHED_OTHER (thread_priority 0)"):
        return "SCHED_OTHER"
    return how.split(" (")[0]


def realtime_scheduling(priority: int) -> tuple[bool, str]:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` (1..99; 0: leave it).
    Returns (granted, what the thread runs under — or why not, and how to grant it).
    Linux applies ``sched_setscheduler(0, ...)`` to the calling thread only."""
    if priority == 0:
        return False, "SCHED_OTHER (thread_priority 0)"
    if not hasattr(os, "sched_setscheduler"):
        return False, "SCHED_OTHER (this platform has no SCHED_FIFO)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return False, (f"SCHED_OTHER (SCHED_FIFO {priority} refused: "
                       f"{exc.strerror or exc}; grant it with CAP_SYS_NICE or an rtprio "
                       f"limit, e.g. 'ulimit -r {priority}' or rtprio in "
                       f"/etc/security/limits.conf; thread_priority 0 (flexarm run "
                       f"--thread-priority 0) stops asking)")
    return True, f"SCHED_FIFO {priority}"


class Pacer:
    """Absolute deadlines on a monotonic clock for ticks of ``period`` s.

    ``start()`` at the first published state (tick 0); then ``wait()`` before each step
    returns how many ticks to step now: 1, or with ``skip`` past ``late_bound`` more
    (only the last of them is published). ``clock`` and ``sleep`` default to
    :func:`time.monotonic` and :func:`time.sleep`."""

    def __init__(self, period: float, late_bound: float = 0.1, late_policy: str = "slow",
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        check_settings(period, late_policy, late_bound)
        self.period = period
        self.bound = late_bound
        self.policy = late_policy
        self.clock, self.sleep = clock, sleep
        self.t0 = None
        self.n = 0                      # ticks whose deadline has been served
        self.stats = Lateness(period)
        self.skipped_ticks = 0
        self.slowed_s = 0.0
        self.crossings = 0              # times the bound was crossed

    def start(self, now: float | None = None) -> None:
        self.t0 = self.clock() if now is None else now
        self.n = 0

    def deadline(self, n: int) -> float:
        return self.t0 + n * self.period

    def wait(self) -> int:
        """Sleep until the next tick's deadline; return the number of ticks to step."""
        due = self.deadline(self.n + 1)
        now = self.clock()
        if now < due:
            self.sleep(due - now)
            now = self.clock()
        late = now - due
        self.stats.add(late)
        steps = 1
        if late > self.bound:
            self.crossings += 1
            behind = int(late // self.period)          # deadlines already passed
            if self.policy == "skip":
                steps += behind
                self.skipped_ticks += behind
            else:
                self.t0 += late
                self.slowed_s += late
        self.n += steps
        return steps

    def summary(self) -> dict:
        out = self.stats.summary()
        out.update({"late_policy": self.policy, "late_bound_s": self.bound,
                    "skipped_ticks": self.skipped_ticks, "slowed_s": self.slowed_s})
        return out
