"""The realtime pacer (:mod:`flexarm_ros.twin.pacing`) against a fake clock: deadlines are
absolute (no drift whatever the work per tick), late ticks are caught up, and past the
bound ``skip`` keeps the wall clock while ``slow`` keeps every tick; the lateness
statistics against exact order statistics."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from flexarm_ros.twin.pacing import Lateness, Pacer


class FakeClock:
    """A monotonic clock that advances only by sleeping or by the work done."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, dt):
        assert dt >= 0
        self.t += dt

    def work(self, dt):
        self.t += dt


T = 1e-3


def run(pacer, clock, works):
    """Step ticks whose work takes ``works[i]`` s; returns the wall time of each step."""
    pacer.start()
    starts, published = [], 0
    for w in works:
        steps = pacer.wait()
        starts.append(clock())
        published += 1
        clock.work(w * steps)
    return np.array(starts), published


def test_deadlines_are_absolute_so_the_work_never_drifts():
    clock = FakeClock()
    p = Pacer(T, clock=clock, sleep=clock.sleep)
    starts, _ = run(p, clock, [0.3e-3] * 1000)
    # tick n starts exactly at t0 + n·T (relative sleeping would drift by 0.3 ms per tick)
    np.testing.assert_allclose(starts - 100.0, T * np.arange(1, 1001), rtol=0, atol=1e-9)
    assert p.stats.late_ticks == 0 and p.stats.max < 1e-9


def test_a_late_stretch_is_caught_up_back_to_back():
    clock = FakeClock()
    p = Pacer(T, late_bound=0.05, clock=clock, sleep=clock.sleep)
    works = [0.2e-3] * 10 + [5e-3] + [0.2e-3] * 40      # one 5 ms hiccup
    starts, _ = run(p, clock, works)
    # the 4 ticks due during the hiccup start late, back to back; from then on on time
    late = starts - (100.0 + T * np.arange(1, len(works) + 1))
    assert np.all(late[:11] < 1e-9)
    assert late[11] == pytest.approx(4e-3, abs=1e-9)
    assert np.all(np.diff(late[11:16]) < 0)              # shrinking by 0.8 ms per tick
    assert np.all(late[17:] < 1e-9)
    assert p.stats.late_ticks == 5                        # 4.0, 3.2, 2.4, 1.6, 0.8 ms late
    assert p.skipped_ticks == 0 and p.slowed_s == 0.0


def test_skip_keeps_the_wall_clock_past_the_bound():
    clock = FakeClock()
    p = Pacer(T, late_bound=0.01, late_policy="skip", clock=clock, sleep=clock.sleep)
    p.start()
    p.wait()
    clock.work(0.0255)        # a 25.5 ms stall after tick 1: deadlines 2..26 have passed
    steps = p.wait()
    assert steps == 25 and p.skipped_ticks == 24          # 26 is published, 2..25 skipped
    # the next deadline lies in the future: the twin is back on the wall clock
    assert p.deadline(p.n + 1) > clock()
    sim_time = p.n * T
    assert sim_time == pytest.approx(clock() - 100.0, abs=T)


def test_slow_publishes_every_tick_and_falls_behind_by_the_lateness():
    clock = FakeClock()
    p = Pacer(T, late_bound=0.01, late_policy="slow", clock=clock, sleep=clock.sleep)
    p.start()
    p.wait()
    clock.work(0.0255)
    assert p.wait() == 1
    assert p.slowed_s == pytest.approx(0.0245, abs=1e-12)
    steps = [p.wait() for _ in range(100)]
    assert steps == [1] * 100
    # wall clock ran ahead of simulated time by exactly what was given up
    assert (clock() - 100.0) - p.n * T == pytest.approx(p.slowed_s, abs=1e-9)


def test_bad_settings_name_the_parameter():
    with pytest.raises(ValueError, match="late_policy: got 'drop'"):
        Pacer(T, late_policy="drop")
    with pytest.raises(ValueError, match="late_bound: got 0.0001 s"):
        Pacer(T, late_bound=1e-4)
    with pytest.raises(ValueError, match="late_bound: got nan"):
        Pacer(T, late_bound=math.nan)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lateness_percentiles_bracket_the_exact_order_statistics(seed):
    rng = np.random.default_rng(seed)
    x = np.concatenate([np.zeros(200), rng.lognormal(np.log(2e-4), 1.5, 5000)])
    st = Lateness(T)
    for v in x:
        st.add(v)
    assert st.ticks == len(x) and st.max == x.max()
    assert st.late_ticks == int(np.sum(x > T / 2))
    width = 10 ** (1 / Lateness.BINS_PER_DECADE)
    for p in (50, 90, 99, 99.9):
        exact = np.sort(x)[math.ceil(p / 100 * len(x)) - 1]
        got = st.percentile(p)
        assert exact <= got <= exact * width * (1 + 1e-12), (p, exact, got)
    assert st.percentile(1) == 0.0          # the zeros


def test_thread_priority_is_checked_with_its_name():
    from flexarm_ros.errors import InputError
    from flexarm_ros.twin.pacing import check_settings
    for bad in (-1, 100, 2.5, True, "50"):
        with pytest.raises(InputError, match=r"parameter thread_priority: got .*expected an "
                                             r"integer SCHED_FIFO priority 1\.\.99, or 0"):
            check_settings(1e-3, thread_priority=bad)
    check_settings(1e-3, thread_priority=0)
    check_settings(1e-3, thread_priority=99)


def test_the_start_timeout_is_checked_with_its_name():
    from flexarm_ros.errors import InputError
    from flexarm_ros.twin.pacing import check_settings
    for bad in (-1.0, math.nan, math.inf, "5", True):
        with pytest.raises(InputError, match=r"parameter start_timeout_s: got .*expected a "
                                             r"finite number >= 0"):
            check_settings(1e-3, start_timeout_s=bad)
    check_settings(1e-3, start_timeout_s=0.0)
    check_settings(1e-3, start_timeout_s=5)


def test_the_marker_rate_is_checked_with_its_name():
    """One rule for marker_rate_hz, where the node, run() and `flexarm run` check it."""
    from flexarm_ros.errors import InputError
    from flexarm_ros.run import run
    from flexarm_ros.twin.pacing import check_settings
    for bad in (-1.0, math.nan, math.inf, "30"):
        with pytest.raises(InputError, match=r"parameter marker_rate_hz: got .*expected a "
                                             r"finite rate ≥ 0 Hz \(0: no arm_markers\)"):
            check_settings(1e-3, marker_rate_hz=bad)
    check_settings(1e-3, marker_rate_hz=0.0)
    check_settings(1e-3, marker_rate_hz=30)
    with pytest.raises(InputError, match=r"parameter marker_rate_hz: got -1"):
        run("link", duration=0.01, record=None, progress=False,     # before any node starts
            simulator={"marker_rate_hz": -1.0})


def _in_a_thread(fn):
    import threading
    out = {}
    th = threading.Thread(target=lambda: out.update(value=fn()))
    th.start()
    th.join()
    return out["value"]


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="no SCHED_FIFO here")
def test_realtime_scheduling_applies_to_the_calling_thread_only():
    """What the kernel reports back (sched_getscheduler) is the truth: the thread that
    asked runs SCHED_FIFO at the priority (where the kernel grants it), the caller's own
    thread keeps its policy."""
    from flexarm_ros.twin.pacing import realtime_scheduling
    before = os.sched_getscheduler(0)

    def ask():
        granted, how = realtime_scheduling(7)
        return granted, how, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority

    granted, how, policy, prio = _in_a_thread(ask)
    if granted:
        assert (how, policy, prio) == ("SCHED_FIFO 7", os.SCHED_FIFO, 7)
    else:                                   # a host that refuses: the thread is unchanged
        assert how.startswith("SCHED_OTHER (SCHED_FIFO 7 refused: ") and policy == before
    assert os.sched_getscheduler(0) == before
    granted, how, policy, _ = _in_a_thread(lambda: (*realtime_scheduling(0),
                                                    os.sched_getscheduler(0), None))
    assert (granted, how, policy) == (False, "SCHED_OTHER (thread_priority 0)", before)


def test_a_refused_priority_says_why_and_how_to_grant_it(monkeypatch):
    from flexarm_ros.twin import pacing

    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", refuse, raising=False)
    monkeypatch.setattr(os, "SCHED_FIFO", 1, raising=False)
    monkeypatch.setattr(os, "sched_param", lambda p: p, raising=False)
    granted, how = pacing.realtime_scheduling(50)
    assert not granted
    assert how.startswith("SCHED_OTHER (SCHED_FIFO 50 refused: Operation not permitted; ")
    assert "ulimit -r 50" in how and "thread_priority 0" in how


def test_the_summary_line_tells_asked_from_refused():
    from flexarm_ros.twin.pacing import short_scheduling
    assert short_scheduling("SCHED_FIFO 50") == "SCHED_FIFO 50"
    assert short_scheduling("SCHED_OTHER (thread_priority 0)") == "SCHED_OTHER"
    assert short_scheduling("SCHED_OTHER (SCHED_FIFO 50 refused: Operation not permitted; "
                            "grant it ...)") == "SCHED_OTHER (SCHED_FIFO refused)"


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="Linux only")
def test_the_pacing_thread_is_named_for_the_kernel():
    import threading
    from flexarm_ros.twin.pacing import name_thread
    got = []

    def run():
        name_thread("flexarm-pacer-and-more")
        with open(f"/proc/self/task/{threading.get_native_id()}/comm") as f:
            got.append(f.read().strip())
    th = threading.Thread(target=run)
    th.start()
    th.join()
    assert got == ["flexarm-pacer-a"]           # the kernel keeps 15 bytes
