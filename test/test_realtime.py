"""Realtime runs and the run summary (issue 13): every tick's messages reach the bag, the
summary's numbers agree with the bag and with each other, ground truth at a set rate
keeps the values of the every-tick run, and the nodes publish serialized CDR that the
bag keeps byte for byte. Speed itself is measured in ``bench/bench_realtime.py``, not
asserted here (shared machines)."""

from __future__ import annotations

import json
import math

import pytest
from mcap.reader import make_reader

from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.cli import main
from flexarm_ros.scene import load_scene
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cosim import cosimulate

NS = "/flexarm"
SIM_TOPICS = (T.CLOCK, T.JOINT_STATES, T.ENCODER_COUNTS, T.ACCEL_BATCH, T.TOOL_CONTACT,
              T.TOOL_WRENCH, T.GT_JOINT_STATES, T.GT_TIP, T.GT_COORDINATES)


def _run_json(capsys, *argv) -> dict:
    code = main(["run", *argv, "--quiet", "--json"])
    out = capsys.readouterr().out
    assert code == 0, out
    return json.loads(out)


def _check_summary(s: dict, ticks: int, gt_every: int = 10):
    """``gt_every``: ticks per ground_truth/tip and /coordinates message (realtime's
    default is 100 Hz at the 1 kHz control rate)."""
    assert s["ticks"] == ticks and s["sim_time_s"] == pytest.approx(ticks * 1e-3, abs=1e-9)
    assert 0 <= s["late_ticks"] <= s["ticks"]
    assert 0 <= s["lateness_p50_s"] <= s["lateness_p99_s"] <= s["lateness_max_s"]
    assert s["real_time_factor"] > 0
    assert s["late_policy"] == "slow" and s["skipped_ticks"] == 0
    # every message the simulator published is in the bag: none lost by the recorder
    rec, pub = s["recorded"], s["published"]
    for topic in SIM_TOPICS:
        want = ticks if topic == T.ACCEL_BATCH else ticks + 1   # no samples at t = 0
        if topic in (T.GT_TIP, T.GT_COORDINATES):
            want = ticks // gt_every + 1
        assert pub[T.resolve(NS, topic)] == want and rec[T.resolve(NS, topic)] == want, topic
    for topic in (T.COMMANDS, T.EFFORTS, T.MOTOR_STATES):
        assert rec[T.resolve(NS, topic)] in (ticks, ticks + 1), topic
    # arm_markers (built by the marker thread): the first tick at or after each 1/30 s
    markers = math.floor(ticks * 1e-3 * 30 + 1e-6) + 1
    assert pub[T.resolve(NS, T.ARM_MARKERS)] == rec[T.resolve(NS, T.ARM_MARKERS)] == markers
    assert s["rejected_commands"] == 0
    assert s["scheduling"] == "SCHED_OTHER (thread_priority 0)"      # the default
    # the CPU budget over the ticking: every process of the graph costs something, and
    # together no more than the machine's CPUs had in that time
    cpu = s["cpu_ms_per_tick"]
    assert cpu and all(v >= 0 for v in cpu.values())
    assert s["cpu_ms_per_tick_total"] == pytest.approx(sum(cpu.values()))
    assert s["cpu_share"] == pytest.approx(s["cpu_ms_per_tick_total"] * 1e-3 * ticks / (
        s["ticking_wall_time_s"] * s["cpus_available"]), rel=1e-6)
    assert 0 < s["cpu_share"] <= 1.02


def _granted(priority: int) -> str:
    """What this host's kernel gives a thread that asks for SCHED_FIFO ``priority``."""
    import threading
    from flexarm_ros.twin.pacing import realtime_scheduling
    out = []
    th = threading.Thread(target=lambda: out.append(realtime_scheduling(priority)[1]))
    th.start()
    th.join()
    return out[0]


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
@pytest.mark.parametrize("argv,gt_every,layout", [
    ([], 10, "one"), (["--ground-truth-rate", "0"], 1, "one"),
    (["--layout", "split"], 10, "split")])
def test_realtime_run_summary_agrees_with_its_bag(tmp_path, capsys, argv, gt_every, layout):
    """Every node in this process (the default), or the simulator in a process of its own
    joined to the others by a socket (``--layout split``): every message in the bag."""
    s = _run_json(capsys, "two_link_case1", "--mode", "realtime", "--duration", "0.5",
                  "--record", str(tmp_path / "rt.mcap"), *argv)
    _check_summary(s, 500, gt_every)
    assert s["layout"] == layout
    assert set(s["nodes"]) == {"simulator", "motor_driver", "controller", "recorder"}
    procs = ({"simulator", "motor_driver+controller+recorder"} if layout == "split" else
             {"simulator+motor_driver+controller+recorder"})
    assert procs <= set(s["cpu_ms_per_tick"]) and all(s["cpu_ms_per_tick"][p] > 0
                                                      for p in procs)
    if layout == "split":
        assert s["returncodes"] == {"simulator": 0}
    # the drives hold 0 until the controller's first command: when that came is reported
    with open(tmp_path / "rt.mcap", "rb") as f:
        first = next(make_reader(f).iter_messages(topics=[T.resolve(NS, T.COMMANDS)]))[2]
    assert s["first_command_s"] == pytest.approx(first.log_time * 1e-9)
    assert 0 <= s["first_command_s"] < 0.5
    # the real-time factor covers the ticking; the wall time includes start-up
    assert s["ticking_wall_time_s"] == pytest.approx(s["sim_time_s"] / s["real_time_factor"])
    assert s["ticking_wall_time_s"] < s["wall_time_s"]


@pytest.mark.subprocess
def test_realtime_run_in_processes_reports_the_same_summary(tmp_path, capsys):
    s = _run_json(capsys, "two_link_case1", "--mode", "realtime", "--duration", "0.5",
                  "--processes", "--record", str(tmp_path / "rt.mcap"))
    _check_summary(s, 500)
    assert set(s["nodes"]) == {"simulator", "motor_driver", "controller", "recorder"}
    assert s["returncodes"] == dict.fromkeys(s["nodes"], 0)
    assert all(s["cpu_ms_per_tick"][n] > 0 for n in s["nodes"])     # a process each
    # realtime in processes pins the simulator alone on a CPU, the other nodes elsewhere
    import os
    if len(os.sched_getaffinity(0)) >= 2:
        cpus = s["cpus"]
        assert set(cpus) == set(s["nodes"])
        sim = set(cpus["simulator"])
        assert len(sim) == 1 and all(not sim & set(c) for n, c in cpus.items()
                                     if n != "simulator")


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_ground_truth_at_a_set_rate_keeps_the_values_of_every_tick(tmp_path, capsys):
    """ground_truth/tip and ground_truth/coordinates every 10th tick (100 Hz of 1 kHz):
    their messages are the co-simulation's at those ticks, byte for byte; every other
    topic (ground_truth/joint_states, the driver's input, included) is unchanged."""
    path = tmp_path / "gt.mcap"
    s = _run_json(capsys, "two_link_case1", "--duration", "0.1", "--ground-truth-rate", "100",
                  "--record", str(path))
    ref = cosimulate(load_scene("two_link_case1"), 0.1)
    raw = {}
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(log_time_order=False):
            raw.setdefault(ch.topic, []).append((m.log_time, m.data))
    for topic in {m.topic for m in ref.messages}:
        want = [(m.t_ns, encode_cdr(m.msgtype, m.data)) for m in ref.topic(topic)]
        if topic in (T.GT_TIP, T.GT_COORDINATES):
            want = [w for w in want if round(w[0] / 1e6) % 10 == 0]
            assert len(want) == 11
        assert raw[T.resolve(NS, topic)] == want, topic
    assert s["recorded"][T.resolve(NS, T.GT_TIP)] == 11


@pytest.mark.ros
def test_the_pacing_thread_runs_under_the_scheduling_the_summary_names(tmp_path, capsys):
    """The kernel's own answer for the pacing thread (sched_getscheduler of its thread id,
    polled while it runs in this process, once the kernel knows it as ``flexarm-pacer``:
    the name comes after the policy is set), with ``--thread-priority 50`` and at the
    default (0: normal scheduling)."""
    import os
    import threading
    if not hasattr(os, "sched_getscheduler"):
        pytest.skip("no SCHED_FIFO here")
    for argv, want in ((["--thread-priority", "50"], os.SCHED_FIFO
                        if _granted(50) == "SCHED_FIFO 50" else os.SCHED_OTHER),
                       ([], os.SCHED_OTHER)):
        seen, done = set(), threading.Event()

        def watch():
            while not done.is_set():
                for th in threading.enumerate():
                    if th.name == "realtime-pacer" and th.native_id is not None:
                        try:
                            with open(f"/proc/self/task/{th.native_id}/comm") as f:
                                if f.read().strip() != "flexarm-pacer":
                                    continue        # started, its policy not yet set
                            seen.add(os.sched_getscheduler(th.native_id))
                        except OSError:             # ended between the calls
                            pass
                done.wait(0.01)
        w = threading.Thread(target=watch)
        w.start()
        try:
            s = _run_json(capsys, "link", "--mode", "realtime", "--duration", "0.3",
                          "--no-record", *argv)
        finally:
            done.set()
            w.join()
        assert seen == {want}, (argv, seen)
        assert s["scheduling"] == (_granted(50) if argv else
                                   "SCHED_OTHER (thread_priority 0)")


@pytest.mark.parametrize("argv,key", [(["--late-bound", "0"], "--late-bound: got 0.0 s"),
                                      (["--thread-priority", "100"],
                                       "--thread-priority: got 100, expected an integer "
                                       "SCHED_FIFO priority 1..99"),
                                      (["--ground-truth-rate", "-5"],
                                       "--ground-truth-rate: got -5.0"),
                                      (["--marker-rate", "-1"],
                                       "--marker-rate: got -1, expected a finite rate ≥ 0 Hz"),
                                      (["--marker-rate", "nan"],
                                       "--marker-rate: got nan, expected a finite rate")])
def test_bad_pacing_settings_are_one_line(tmp_path, capsys, argv, key):
    code = main(["run", "link", "--mode", "realtime", "--duration", "0.1", "--no-record",
                 "--quiet", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and key in err[0], err


def test_cpu_placement_puts_the_simulator_alone():
    from flexarm_ros.run import cpu_placement
    names = ["simulator", "motor_driver", "controller", "recorder"]
    p = cpu_placement(names, cpus={0, 1})
    assert p["simulator"] == {1} and all(p[n] == {0} for n in names[1:])
    p = cpu_placement(names, cpus={2, 5, 7})
    assert p["simulator"] == {7} and p["recorder"] == {2, 5}
    assert cpu_placement(names, cpus={3}) == {}              # one CPU: nothing to separate
    assert cpu_placement(["recorder"], cpus={0, 1}) == {}


def test_realtime_in_processes_on_few_cpus_is_told_it_falls_behind():
    """Decision 0031: five processes need ~2.2 ms of CPU per 1 ms tick on 2 cores; the run
    says so before it starts, and nothing where the layout keeps the clock."""
    from flexarm_ros.run.supervision import PROCESSES_REALTIME_CPUS, layout_note
    note = layout_note("processes", "realtime", 2)
    assert "2 CPUs" in note and "0031" in note and "--layout one" in note
    assert layout_note("processes", "realtime", PROCESSES_REALTIME_CPUS) is None
    for layout, mode in (("processes", "lockstep"), ("processes", "fast"),
                         ("one", "realtime"), ("split", "realtime")):
        assert layout_note(layout, mode, 1) is None


def test_a_stalled_effort_source_is_waited_for_again_once_it_speaks():
    """The realtime plant's bound on running ahead of the efforts: after one timed-out
    wait the source counts as silent (no wait per tick while it is dead), but the first
    new effort restores the bound; before, the plant ran unbounded ahead after a single
    start-up stall and two_link_case1 diverged (t = 0.94 s)."""
    import time
    import flexarm_ros.nodes.common  # noqa: F401  (rclpy import order)
    from flexarm_ros.nodes.simulator import SimulatorNode
    sim = SimulatorNode.__new__(SimulatorNode)          # the wait's state, no ROS
    sim.finished = False
    sim.answered, sim._silent_at, sim.waited_ticks, sim.stale_ticks = -1, None, 0, 0
    arrivals = []                      # (after this many s of waiting, answered becomes)
    waited = [0.0]

    def poll(wait_s):                  # the subscription: efforts arrive as scheduled
        time.sleep(wait_s)
        waited[0] += wait_s
        while arrivals and waited[0] >= arrivals[0][0]:
            sim.answered = arrivals.pop(0)[1]
    sim._poll_efforts = poll
    sim._await_effort(0, 0.02)                           # nothing answers: times out
    assert (sim.waited_ticks, sim.stale_ticks, sim._silent_at) == (1, 1, -1)
    sim._await_effort(5, 0.02)                           # silent: no further wait
    assert sim.waited_ticks == 1
    sim.answered = 0                                     # it speaks again
    sim._await_effort(5, 0.02)                           # the bound holds again: waits
    assert (sim.waited_ticks, sim.stale_ticks) == (2, 2)
    sim._silent_at, waited[0] = None, 0.0
    arrivals.append((0.01, 5))
    sim._await_effort(5, 5.0)                            # an answer ends the wait early
    assert (sim.waited_ticks, sim.stale_ticks, sim.answered) == (3, 2, 5)
    assert waited[0] < 1.0


_LAZY_KERNELS = """
import sys
from numba.core import dispatcher
loaded = []
orig = dispatcher.Dispatcher._compile_for_args
def record(self, *a, **k):
    loaded.append(self.py_func.__module__ + "." + self.py_func.__name__)
    return orig(self, *a, **k)
dispatcher.Dispatcher._compile_for_args = record
from flexarm_ros.scene import load_scene
from flexarm_ros.twin.cosim import Lockstep
ls = Lockstep(load_scene("two_link_case1"))
before = list(loaded)
loaded.clear()
for _ in range(2200):                      # through the wall strike near t = 2.12 s
    ls.tick()
print(len(ls.sim.plant.stepper.impacts), bool(before), ",".join(loaded) or "none")
"""


@pytest.mark.heavy
@pytest.mark.subprocess
def test_no_kernel_is_loaded_or_compiled_after_start_up_not_even_at_the_impact():
    """A realtime tick must not stop to load or compile a numba function: the simulator
    core's start-up loads every kernel a tick can call, including those only an impact
    calls (before session 11 the impact tick of two_link_case1 loaded
    ``sensors.table`` from the cache, 30–37 ms, and compiled it for ~11 s on a fresh
    machine). Run in a fresh interpreter, where nothing else has loaded them."""
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", _LAZY_KERNELS], capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    impacts, started_with_kernels, after = out.stdout.split()
    assert int(impacts) >= 1 and started_with_kernels == "True"
    assert after == "none", f"loaded or compiled after start-up: {after}"
