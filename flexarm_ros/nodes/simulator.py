"""The plant node: :class:`~flexarm_ros.twin.cores.SimulatorCore` on ROS 2.

Publishes (node-relative, reliable keep_last 1000): ``/clock``, ``joint_states``,
``encoders/counts``, ``accelerometers/batch`` / ``strain/batch`` /
``potentiometer/batch`` (scenes with such sensors), ``tool/contact`` and ``tool/wrench``
(scenes with a wall), ``ground_truth/joint_states``, ``ground_truth/tip``, ``ground_truth/coordinates`` — the state of
one control tick, in that order — and ``arm_markers`` (the deformed arm for RViz2 and
Foxglove, :mod:`flexarm_ros.nodes.markers`) at ``marker_rate_hz`` of simulation time. Subscribes: ``effort_controller/commands`` (N·m per
joint — for a hydraulic joint the servovalve current, A above the null bias, to the
actuator the plant integrates — held over the next control period).

Efforts are validated where they enter: a message is taken only from the topic's source
(the ``command_source`` node, ``motor_driver``, when it is on the graph, else the first
publisher; :mod:`flexarm_ros.nodes._wire`) and only when it holds one finite value per
joint within the joint's torque limit (a servovalve's rated current;
:mod:`flexarm_ros.model.limits`). Anything else is
rejected: counted by reason, logged (throttled), and it changes nothing — it neither
steps the plant nor replaces the held torque.

Time modes (parameter ``mode``):

* ``lockstep``: publishes tick k, then steps on the first accepted effort after it (no
  timer): deterministic, equal to ``cosimulate``. Every accepted message from the source
  steps one period (the source is the tick); rejected ones and a second publisher's never
  do, so a hostile publisher cannot change a lockstep run.
* ``realtime``: a loop in its own thread steps at absolute deadlines of the monotonic
  clock with the latest accepted effort (zero-order hold; the source's latest message
  wins): :class:`~flexarm_ros.twin.pacing.Pacer`, not an rclpy timer (a timer loses ticks
  under load and drifts). Late ticks are caught up back to back; past ``late_bound``
  seconds ``late_policy`` decides: ``skip`` keeps the wall clock (the ticks due are
  stepped, only the last is published), ``slow`` publishes every tick and lets the twin
  fall behind the wall clock. The lateness statistics (late ticks, p50/p99/max) are
  logged every few seconds and at the end, and kept in ``pacing`` for the run summary.
* ``fast``: steps as fast as the executor allows with the latest accepted effort;
  ``/clock`` is the only time (run the other nodes with ``use_sim_time``).

A diverging plant stops the node like ``flexarm simulate``: nothing of the diverged state
is published, ``diverged`` holds the :class:`~flexarm_ros.errors.SimulationDiverged`
(what, when, what to change), and the node's process exits with status 3 printing it once.
The final log line gives the simulated time, ticks, real-time factor and the rejected
efforts by reason.

Every message is published as serialized CDR built straight from the core's values
(:class:`flexarm_ros.bag.cdr_fixed.CdrBuilder`: a byte template per message shape,
byte-identical to :func:`flexarm_ros.bag.writer.encode_cdr` of the core's message dicts):
no rclpy message objects and no dicts on the hot path. The analysis-only
topics ``ground_truth/tip`` and ``ground_truth/coordinates`` go out every tick in
``lockstep`` and ``fast``, at 100 Hz in ``realtime`` (at 1 kHz on two cores the budget
does not allow every tick: docs/decisions/0007-realtime-on-two-cores.md), or at
``ground_truth_rate_hz`` when set
(``ground_truth/joint_states`` is the driver's input and goes out every tick).

Publishing starts once what the twin needs is matched: the driver on
``ground_truth/joint_states``, in ``lockstep`` a controller on ``joint_states`` (the twin
steps on its answers, so the first state must reach it; in every mode with
``controllers`` = 1, as ``flexarm run`` sets it when it starts the twin's controller),
and with ``recorders`` the
recorder on every topic; in ``lockstep`` also a publisher matched with its own
``effort_controller/commands`` subscription (the answer to the first state must reach
it) — nothing else (a user's controller need not read
``tool/contact``). A wait longer than a few seconds is logged at WARN level with what is
missing. With ``await_first_effort`` (realtime and fast; ``flexarm run`` sets it where a
controller or driver of the user's is expected) the start is lockstep's and the clock
starts at the first effort answering the state at t = 0 (a WARN after 3 s, ``stalled``
after ``stall_timeout_s``).
With a finite ``duration`` the node stops after the state at that time (and its process
exits); ``progress`` prints the simulated time on stderr.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque

import numpy as np
from rclpy.node import Node

from flexarm_ros.bag.cdr_fixed import CdrBuilder
from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.io.progress import ProgressLine
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import SimulatorCore
from flexarm_ros.twin.pacing import (REALTIME_GT_HZ, THREAD_PRIORITY, Pacer, check_settings,
                                     ground_truth_rate, name_thread, realtime_scheduling)
import flexarm_ros.nodes.common as C
from flexarm_ros.nodes.markers import ArmMarkers
from flexarm_ros.nodes.robot_state import RobotState
from flexarm_ros.nodes.intraprocess import bus_of
from flexarm_ros.nodes.diagnostics import attach as attach_diagnostics
from flexarm_ros.nodes._wire import UNKNOWN, Rejections, Source, reject_undecodable


#: s between the simulator's looks for another twin in its namespace and domain
ALONE_CHECK_S = 0.25


class SimulatorNode(Node):
    """flexarm twin simulator node: plant, sensors, contact and /clock."""

    EXECUTABLE = "simulator"
    PARAMS = {"progress": (False, "print the simulated time on stderr"),
              "command_source": (T.SOURCE[T.EFFORTS], "node whose efforts are taken while "
                                 "it is on the graph ('': the first publisher)"),
              "late_policy": ("slow", "realtime, past late_bound: 'slow' publishes every "
                              "tick and falls behind the wall clock; 'skip' keeps the wall "
                              "clock (due ticks stepped with the held effort, the last "
                              "published)"),
              "late_bound": (0.1, "realtime: s of lateness before late_policy acts"),
              "thread_priority": (THREAD_PRIORITY, "realtime: SCHED_FIFO priority of the "
                                  "pacing thread (1..99; 0, the default: normal "
                                  "scheduling, which leaves a controller on the same "
                                  "host its share); refused by the kernel, the thread "
                                  "runs at normal priority and the node warns"),
              "effort_lag": (3, "realtime: the most ticks the plant runs ahead of the "
                             "efforts (the source answers every joint state, as the twin's "
                             "driver does) before it waits for the next one (at most "
                             "control.watchdog_s); -1: never waits (an effort source on "
                             "its own timer)"),
              "summary_file": ("", "write the final run summary (JSON) here when the node "
                               "stops ('': none)"),
              "controllers": (-1, "controllers on joint_states the first state waits for "
                                  "(-1: 1 in lockstep, where the twin steps on their answers, "
                                  "else 0; flexarm run sets 1 when it starts its controller)"),
              "stall_timeout_s": (30.0, "lockstep (and the first effort awaited): s "
                                  "without an effort after a published state before the "
                                  "run ends as stalled (0: waits for ever); after 3 s a "
                                  "WARN says what the twin waits for"),
              "await_first_effort": (False, "realtime and fast: start the clock at the "
                                     "first effort answering the first state, as lockstep "
                                     "does, and wait for a controller on joint_states and "
                                     "an effort publisher first (flexarm run sets it where "
                                     "a controller or driver of the user's is expected)"),
              "start_timeout_s": (0.0, "s to wait for the start condition (the driver, "
                                  "in lockstep a controller, the recorder) before the run "
                                  "ends as stalled without a tick (0: waits for ever, as a "
                                  "bench waits for its controller); after 3 s a WARN says "
                                  "what the twin waits for"),
              "ground_truth_rate_hz": (-1.0, "rate of ground_truth/tip and "
                                       "ground_truth/coordinates (0: every tick; -1: "
                                       f"every tick, in realtime {REALTIME_GT_HZ:g} Hz)"),
              "marker_rate_hz": (30.0, "rate of arm_markers (visualization_msgs/"
                                 "MarkerArray of the deformed arm for RViz2 and Foxglove) "
                                 "in simulation time: the first tick at or after each "
                                 "1/rate (0: none)"),
              "marker_force_scale": (0.0, "arm_markers: contact force arrow length in m "
                                     "per N (0: the largest force so far draws 0.25 of "
                                     "the arm's reach)")}

    def __init__(self, **kwargs):
        super().__init__("simulator", **kwargs)
        self.p, scene, self.n_end = C.load(self, self.PARAMS)
        self.mode = self.p["mode"]
        # the work budget of a finite run, checked here too (a node started on its own)
        self.core = SimulatorCore(scene, None if self.n_end is None else
                                  self.n_end / scene.twin_control.rate_hz)
        plant = self.core.plant
        asked = plant.chain.fidelity.integrator
        if asked != plant.integrator:       # batch-only integrators: said, not ignored
            self.get_logger().warning(
                f"fidelity.integrator {asked!r} applies to batch runs (flexarm simulate); "
                f"the twin's plant steps {plant.integrator}"
                + (" (the contact stepper's)" if asked == "rkn4" else "")
                + f" at {plant.h:.3g} s")
        self.period = self.core.period
        check_settings(self.period, self.p["late_policy"], self.p["late_bound"],
                       ground_truth_rate(self.p["ground_truth_rate_hz"], self.mode),
                       self.p["thread_priority"], self.p["start_timeout_s"],
                       self.p["marker_rate_hz"])
        pubs = {}                                   # outputs() at k = 0 changes nothing
        for topic in [o[0] for o in self.core.outputs()] + list(self.core.groups):
            pubs[topic] = C.publisher(self, T.TYPES[topic], topic)
        self.marker_rate = float(self.p["marker_rate_hz"])   # checked with the pacing below
        self.markers = None                     # the arm for RViz2 / Foxglove
        self._marker_slot = -1                  # the last 1/rate slot drawn
        self._marker_cv = threading.Condition()     # realtime: to the marker thread
        self._marker_states = deque(maxlen=self.MARKER_QUEUE)
        self._marker_thread = None
        if self.marker_rate > 0:
            self.markers = ArmMarkers(scene, plant.chain,
                                      force_scale=float(self.p["marker_force_scale"]))
            pubs[T.ARM_MARKERS] = C.publisher(self, T.TYPES[T.ARM_MARKERS], T.ARM_MARKERS)
            self.robot = RobotState(self, plant.chain)     # robot_description, once
            pubs[T.ROBOT_JOINT_STATES] = C.publisher(self, T.TYPES[T.ROBOT_JOINT_STATES],
                                                     T.ROBOT_JOINT_STATES)
        self.pubs = pubs
        self._cdr = CdrBuilder()
        sub = C.subscription(self, T.TYPES[T.EFFORTS], T.EFFORTS, self._on_effort, plain=True,
                             undecodable=lambda data, info, exc: reject_undecodable(
                                 self, self.core.validator, self.source, "effort", data, exc,
                                 info))
        self._effort_sub = sub
        self.source = Source(self, sub.topic_name, self.p["command_source"] or None)
        self.rejections = Rejections(self)
        attach_diagnostics(self)               # /diagnostics at 1 Hz
        self.diverged: SimulationDiverged | None = None
        self.stalled: str | None = None         # lockstep: why the run ended without effort
        self.conflict: str | None = None        # another twin in this namespace and domain
        self.twin_seen: str | None = None       # a newer twin appeared (it stops itself)
        self._alone = self.create_timer(ALONE_CHECK_S, self._check_alone)
        self._watch = None                      # lockstep: the stall watchdog's timer
        self._progress_wall = time.monotonic()  # when the last state went out
        r = self.p["recorders"]
        # the start condition is what the twin needs: the driver (it answers every
        # ground-truth state), in lockstep a controller on joint_states (ours or a user's:
        # the first state must not be lost, the twin steps on the answers), and with
        # recording the recorder on every topic; nobody else (a user's controller need not
        # read tool/contact or tool/wrench)
        lockstep = self.mode == "lockstep"
        # realtime and fast with a controller or driver of the user's: start as lockstep
        # does (a controller on joint_states, a matched effort publisher), and the clock
        # at the answer to the first state
        self.awaits = bool(self.p["await_first_effort"]) and not lockstep
        gated = lockstep or self.awaits
        self._awaiting = None                   # WaitWarning: the first state out, no answer
        self.first_answer_s = None              # how long the first answer took (awaited)

        def own_controller():
            """1 while the twin's own controller (which pairs contact and wrench with each
            state in lockstep) or a not yet resolved node reads joint_states, else 0."""
            if not lockstep or T.JOINT_STATES not in pubs:
                return 0
            ns = self.get_namespace()
            return int(any(name == UNKNOWN or (name == "controller" and nns == ns)
                           for name, nns in C.subscriber_names(self, pubs[T.JOINT_STATES])))
        def driver():
            """Whom ground_truth/joint_states waits for; in lockstep the driver subscribes
            once a controller publishes commands, so a command publisher of another type
            (which DDS never connects) is named here too."""
            if not lockstep:
                return "the motor driver"
            return ("the motor driver, which in lockstep subscribes once a controller "
                    "publishes on motor_driver/commands" + C.other_types(
                        self, T.resolve(self.get_namespace(), T.COMMANDS),
                        T.TYPES[T.COMMANDS]))
        needs = {T.GT_JOINT_STATES: (1, driver),
                 T.JOINT_STATES: (int(gated) if self.p["controllers"] < 0 else
                                  int(self.p["controllers"]), "a controller"),
                 T.TOOL_CONTACT: (own_controller, "the twin's controller"),
                 T.TOOL_WRENCH: (own_controller, "the twin's controller")}
        self.ready = C.Barrier(self, [
            (p, (lambda f=needs[t][0]: r + f()) if callable(needs.get(t, (0,))[0]) else
             r + needs.get(t, (0,))[0], needs.get(t, (0, "the recorder"))[1])
            for t, p in pubs.items()], r,
            inputs=[(sub, "the motor driver or an amplifier of yours")] if gated else [])
        self.published = {t: 0 for t in pubs}
        self.torque = np.zeros(len(scene.links))
        self.finished = self.started = False
        self.accepted = {T.EFFORTS: 0}              # valid efforts from the source, started
        self.t_wall0 = self.t_wall_end = None
        self.cpu0 = self.cpu_end = None             # this process's CPU time at both ends
        self._last_report = self._last_log = 0.0
        self._line = ProgressLine(0)
        rate = ground_truth_rate(self.p["ground_truth_rate_hz"], self.mode)
        self.scheduling = None                      # realtime: what the pacing thread got
        self.pacer = Pacer(self.period, self.p["late_bound"], self.p["late_policy"])
        self.gt_every = max(1, int(round(scene.twin_control.rate_hz / rate))) if rate else 1
        self._thread = None
        self._bus = bus_of(self.context)
        # realtime: the plant waits for the effort answering a recent state, so an
        # overloaded graph slows the twin (late ticks) instead of leaving the plant to
        # run on a stale effort (measured: 100 ticks of lag make two_link_case1 diverge)
        self._answer = threading.Condition()
        self.published_k = -1                   # the newest state published
        self.answered = -1                      # accepted efforts − 1: the state answered
        self.waited_ticks = 0                   # steps that waited for an effort
        self.stale_ticks = 0                    # steps taken after the wait timed out
        self._silent_at = None                  # answered when a wait timed out
        # wall-clock timer: polls the start barrier; then lockstep steps on efforts,
        # realtime in its pacing thread, fast whenever the executor is free
        self.timer = self.create_timer(0.0 if self.mode == "fast" else 0.001,
                                       self._on_timer)

    # ---------------------------------------------------------------------------- ticks
    @property
    def overruns(self) -> int:
        """Ticks that started more than half a period after their deadline (realtime)."""
        return self.pacer.stats.late_ticks

    def _publish_state(self):
        gt = self.core.k % self.gt_every == 0
        for topic, tp, data in self.core.outputs(ground_truth=gt, build=self._cdr):
            self.pubs[topic].publish(data)
            self.published[topic] += 1
        if self.markers is not None:
            self._publish_markers()
        self.published_k = self.core.k
        self._progress_wall = time.monotonic()
        if self.n_end is not None and self.core.k >= self.n_end:
            self.halt()

    def _publish_markers(self):
        """``arm_markers`` at the first published tick at or after each 1/marker_rate_hz
        of simulation time (the tick's state, its stamp). In lockstep and fast the tick
        builds and publishes them; in realtime the pacing thread only takes the state
        (a copy of q) and the marker thread builds and publishes the array (~0.5 ms of
        Python that would otherwise delay the next tick; with the GIL's switch interval
        at a tenth of a period the pacer preempts it). The recorder logs them at their
        stamp, the tick's time."""
        t_ns = int(round(self.core.t * 1e9))
        slot = math.floor(t_ns * self.marker_rate / 1e9 + 1e-6)
        if slot <= self._marker_slot:
            return
        self._marker_slot = slot
        state = self.core.view_state()
        if self.mode != "realtime" or threading.current_thread() is not self._thread:
            self._send_markers(state)
            return
        with self._marker_cv:
            self._marker_states.append(state)   # beyond MARKER_QUEUE: the oldest dropped
            if self._marker_thread is None:
                self._marker_thread = threading.Thread(target=self._marker_loop,
                                                       name="arm-markers", daemon=True)
                self._marker_thread.start()
            self._marker_cv.notify()

    def _send_markers(self, state):
        t_ns, q, contact, fn, ft = state
        self.pubs[T.ARM_MARKERS].publish(self.markers.cdr(t_ns, q, contact, fn, ft))
        self.published[T.ARM_MARKERS] += 1
        values = self.robot.values(q)          # once for robot_state and the live /tf
        self.pubs[T.ROBOT_JOINT_STATES].publish(self.robot.cdr(t_ns, values))
        self.published[T.ROBOT_JOINT_STATES] += 1
        self.robot.publish_tf(t_ns, values)

    def _marker_loop(self):
        """Realtime: build and publish the arrays the pacing thread hands over, until the
        node has halted and the last one is out."""
        try:
            while True:
                with self._marker_cv:
                    self._marker_cv.wait_for(lambda: self._marker_states or self.finished)
                    if not self._marker_states:
                        return
                    state = self._marker_states.popleft()
                self._send_markers(state)
        except BaseException as exc:            # never die silently in a thread
            self.get_logger().error(f"arm_markers thread stopped: {exc!r}")

    def halt(self):
        """Stop stepping (end of the run, or Ctrl-C): no more states are published."""
        if not self.finished:
            self.finished = True
            self.t_wall_end = time.monotonic()
            self.cpu_end = time.process_time()
            self.timer.cancel()
            self._alone.cancel()
            if self._watch is not None:
                self._watch.cancel()
            if self._thread is not None and self._thread is not threading.current_thread():
                self._thread.join()
            if self._marker_thread is not None:     # the last array out, then it ends
                with self._marker_cv:
                    self._marker_cv.notify()
                self._marker_thread.join(timeout=5.0)
            self.report(final=True)
            self._write_summary()

    def _step(self, tau, ticks=1):
        """Hold ``tau`` over ``ticks`` control periods; publish the state reached."""
        self.torque = tau
        try:
            for _ in range(ticks):
                self.core.step(tau)
                if self.n_end is not None and self.core.k >= self.n_end:
                    break
        except SimulationDiverged as exc:        # nothing of the diverged state goes out
            self.diverged = exc
            self.halt()
            return
        self._publish_state()
        if self._bus is not None and threading.current_thread() is self._thread:
            self._bus.deliver_all()              # one process: the tick's answers, here
        self.report()

    STALL_WARN_S = 3.0
    MARKER_QUEUE = 30        # realtime: arrays waiting for the marker thread (1 s at 30 Hz)

    def _start_timeout(self):
        """Not started: past ``start_timeout_s`` (> 0) the run ends as stalled, naming what
        it waited for (exit status 3, the bag keeps its metadata)."""
        limit = float(self.p["start_timeout_s"])
        if self.finished or not limit > 0:
            return
        waited = time.monotonic() - self.ready.since
        if waited >= limit:
            self._end_stalled(f"not started within start_timeout_s = {limit:g} s: waiting "
                              f"for " + ", ".join(self.ready.missing or
                                                  ["its start condition"]))

    def _end_stalled(self, why: str) -> None:
        """The run ends as stalled (exit status 3), saying ``why`` once."""
        self.stalled = why
        self.get_logger().error(why)
        self.halt()

    def _watchdog(self):
        """Lockstep: the twin steps only on an effort answering its last state, so a lost
        or never-sent answer would stop it for good. After STALL_WARN_S without one, a
        WARN names the tick and the chain of answers the twin waits for (every 5 s);
        after ``stall_timeout_s`` the run ends as stalled (the bag keeps what it holds,
        the summary and `flexarm run` say why, exit status 3)."""
        if self.finished:
            return
        waited = time.monotonic() - self._progress_wall
        if waited < self.STALL_WARN_S:
            self._stall_said = 0.0
            return
        what = (f"no effort on {self.source.topic} for {waited:.0f} s after the state of "
                f"tick {self.core.k} (t = {self.core.t:.6g} s): lockstep steps on the motor "
                f"driver's answer to each joint_states, which answers the controller's "
                f"command on motor_driver/commands (check that a controller runs in this "
                f"namespace and publishes there, and the driver runs)")
        limit = float(self.p["stall_timeout_s"])
        if limit > 0 and waited >= limit:
            self._end_stalled(f"lockstep stalled: {what}; ended after stall_timeout_s = "
                              f"{limit:g} s")
        elif waited - getattr(self, "_stall_said", 0.0) >= 5.0 or not getattr(
                self, "_stall_said", 0.0):
            self._stall_said = waited
            self.get_logger().warning(f"waiting: {what}")

    def _await_effort(self, k_min: int, timeout: float) -> None:
        """Take the efforts queued, then wait until one answered state ``k_min`` or newer
        (at most ``timeout`` s). After a wait timed out the source counts as silent and is
        not waited for until it speaks again (any new effort): a dead driver must not
        cost every tick a timeout, and a driver that stalled once must not leave the
        plant running ahead of its answers for good (measured: one 50 ms stall at
        start-up, then the plant ran unbounded ahead and two_link_case1 diverged at
        t = 0.94 s)."""
        self._poll_efforts(0.0)
        if self._silent_at is not None and self.answered > self._silent_at:
            self._silent_at = None                      # it spoke: bound the lag again
        if self.answered >= k_min or self._silent_at is not None:
            return
        self.waited_ticks += 1
        end = time.monotonic() + timeout
        while self.answered < k_min and not self.finished:
            left = end - time.monotonic()
            if left <= 0:
                self.stale_ticks += 1
                self._silent_at = self.answered
                return
            self._poll_efforts(min(left, 0.005))

    def _poll_efforts(self, wait_s: float) -> None:
        """Realtime, in the pacing thread: wait up to ``wait_s`` for an effort. The
        executor's thread takes it (``_on_effort``, which notifies this condition): by
        the bus in one process (or the pacing thread itself, running its tick's
        deliveries), by DDS in another layout. (Until session 22 the pacing thread took a
        DDS effort itself on a wait set of its own: rclpy's private bindings, issue 38.)"""
        if wait_s > 0:
            with self._answer:
                answered = self.answered
                self._answer.wait_for(lambda: self.answered != answered, wait_s)

    def _pace(self):
        """The realtime loop (its own thread): sleep to each tick's deadline, step with the
        latest accepted effort, publish."""
        try:
            lag = int(self.p["effort_lag"])
            wait_s = self.core.scene.twin_control.watchdog_s
            if self._bus is not None:
                self._bus.self_delivering.add(threading.current_thread())
            # the kernel's name comes after the policy: a thread that ps -L / chrt -p show
            # as flexarm-pacer already runs under the scheduling the summary names
            granted, self.scheduling = realtime_scheduling(self.p["thread_priority"])
            name_thread("flexarm-pacer")
            if not granted and self.p["thread_priority"]:
                self.get_logger().warning(f"realtime pacing thread: {self.scheduling}; "
                                          f"other processes can delay its ticks")
            with C.profiled("simulator-pacer"):
                while not self.finished:
                    ticks = self.pacer.wait()
                    if self.finished:
                        break
                    if lag >= 0:
                        self._await_effort(self.published_k - lag, wait_s)
                    self._step(self.torque, ticks)
        except BaseException as exc:            # never die silently in a thread
            self.get_logger().error(f"realtime loop stopped: {exc!r}")
            self.halt()
            raise

    @property
    def rejected(self) -> int:
        return self.core.validator.rejected

    def _on_effort(self, msg, info):
        """Validated where it enters: taken (held, and in lockstep stepped on) only when
        it comes from the source and passes the validator; else counted and logged."""
        data = msg.data
        v = self.core.validator
        why = v.reason(data)
        who = self.source.verdict(info, valid=why is None)
        if who is not None:
            v.refuse(self.source.reason)
            self.rejections.refused(self.source, "effort", data, who)
            return
        if why is not None:
            v.check(data)
            self.rejections.invalid(self.source.topic, "effort", data, why, v.expectation())
            return
        tau = np.array(data, float)
        if self.started:
            # the recorder takes these too (same validation, reliable QoS): the graph's
            # end waits until it has them all, including an outside node's last effort
            self.accepted[T.EFFORTS] += 1
        if self.mode != "lockstep":
            with self._answer:
                self.torque = tau
                self.answered += 1          # the source answers every state, in order
                self._answer.notify()
        elif self.started and not self.finished:
            self._step(tau)

    def _check_alone(self):
        """Every ALONE_CHECK_S: a twin in this namespace and domain that started before
        this run ends it (exit 3): this run slipped past its start condition before
        discovery showed the other, and their messages would mix (a graph query, ~10 µs).
        A newer twin is refused by its own start condition and left to stop itself."""
        if self.finished or self.conflict:
            return
        other = C.other_twin(self)               # one graph query while alone
        if other is None:
            return
        older = C.other_twin(self, older_only=True) if self.started else other
        if older:
            self.conflict = f"stopped {self.where()}: {older}" if self.started else (
                f"not started: {older}")
            self.get_logger().error(self.conflict)
            self.halt()
        elif self.twin_seen is None:             # a newer twin: it stops itself
            self.twin_seen = (f"{self.where()}: a newer {other[len('another '):]}; it "
                              f"stops itself, and this run takes none of its messages "
                              f"(refused as 'another run', counted in rejected)")
            self.get_logger().warning(self.twin_seen)

    def _on_timer(self):
        if not self.started:
            if not self.ready():
                if self.conflict:                # the start condition found another twin
                    self.halt()
                    return
                self._start_timeout()
                return
            self.started, self.t_wall0 = True, time.monotonic()
            self.cpu0 = time.process_time()
            self._last_log = self.t_wall0
            self._publish_state()
            if self.awaits and not self.finished:
                self._awaiting = C.WaitWarning(self.STALL_WARN_S)
                if self.mode == "fast":             # poll, do not spin, while it waits
                    self.timer.cancel()
                    self.timer = self.create_timer(0.001, self._on_timer)
                return
            self._start_clock()
            return
        if self._awaiting is not None:
            if not self._first_answer():
                return
            self.first_answer_s = time.monotonic() - self._awaiting.since
            self._awaiting = None
            self.t_wall0 = time.monotonic()         # the clock starts at the answer
            self.cpu0 = time.process_time()
            self._last_log = self.t_wall0
            if self.mode == "fast":
                self.timer.cancel()
                self.timer = self.create_timer(0.0, self._on_timer)
            self._start_clock()
            if self.mode == "realtime":
                return
        if self.finished:
            return
        self._step(self.torque)

    def _start_clock(self):
        """Once the first state is out (and, awaited, answered): lockstep's watchdog, or
        realtime's pacing thread; fast steps on the timer."""
        if self.mode != "fast":
            self.timer.cancel()
        if self.mode == "lockstep" and not self.finished:
            self._watch = self.create_timer(0.5, self._watchdog)
        if self.mode == "realtime" and not self.finished:
            # the pacing thread must get the GIL soon after its deadline: Python's
            # default switch interval (5 ms) would hand it over 5 ticks late
            sys.setswitchinterval(min(sys.getswitchinterval(), self.period / 10))
            self.pacer.start(self.t_wall0)
            self._thread = threading.Thread(target=self._pace, name="realtime-pacer",
                                            daemon=True)
            self._thread.start()

    def _first_answer(self) -> bool:
        """await_first_effort: True once an effort answered the first state; else a WARN
        after STALL_WARN_S (every 5 s) and, past ``stall_timeout_s``, the run ends as
        stalled (exit 3) with what it waited for."""
        if self.answered >= 0:
            return True
        if self.finished:
            return False
        waited = time.monotonic() - self._awaiting.since
        if waited < self.STALL_WARN_S:
            return False
        what = (f"no effort on {self.source.topic} for {waited:.0f} s after the first state "
                f"(t = 0): {self.mode} with a controller or driver of yours starts its "
                f"clock at the answer to the first joint_states (await_first_effort), as "
                f"lockstep does (check that your controller runs in this namespace and "
                f"publishes on motor_driver/commands, or your amplifier on "
                f"{self.source.topic})")
        limit = float(self.p["stall_timeout_s"])
        if limit > 0 and waited >= limit:
            self._end_stalled(f"not started: {what}; ended after stall_timeout_s = "
                              f"{limit:g} s")
        elif self._awaiting.due():
            self.get_logger().warning(f"waiting: {what}")
        return False

    def finish(self, executor):
        """Called by main() when the node is stopped: halts, and waits for the pacing
        thread (which may be the one that halted, still writing the summary)."""
        self.halt()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()

    # --------------------------------------------------------------------------- report
    def summary(self) -> dict:
        """The run as numbers: simulated time, ticks, real-time factor, pacing (realtime:
        late ticks, lateness p50/p99/max, skipped ticks / time behind), the waits for
        efforts, messages published per topic, rejected efforts by reason."""
        out = {"mode": self.mode, "integrator": self.core.plant.integrator,
               "step_s": self.core.plant.h, "sim_time_s": self.core.t, "ticks": self.core.k,
               "real_time_factor": self.rtf(), "published": dict(self.published),
               "accepted": dict(self.accepted),
               "rejected_efforts": dict(self.core.validator.counts),
               "diverged": str(self.diverged) if self.diverged else None,
               "stalled": self.stalled,
               "await_first_effort": self.awaits, "first_answer_s": self.first_answer_s,
               "conflict": self.conflict, "twin_seen": self.twin_seen,
               "end_s": None if self.n_end is None else self.n_end * self.period,
               "stopped_by": getattr(self, "stopped_by", None),
               # the ticking on the system-wide monotonic clock, and this process's CPU
               # over it (the run's per-process CPU budget: twin/cpu_load.py)
               "ticking_monotonic_s": ([self.t_wall0, self.t_wall_end]
                                       if None not in (self.t_wall0, self.t_wall_end)
                                       else None),
               "process_cpu_s": (self.cpu_end - self.cpu0 if self.cpu_end is not None
                                 and self.cpu0 is not None else None)}
        if self.mode == "realtime":
            out.update(self.pacer.summary())
            out.update({"scheduling": self.scheduling, "effort_waits": self.waited_ticks,
                        "effort_wait_timeouts": self.stale_ticks})
        return out

    def where(self) -> str:
        """How far the run got, for a message: 'at t = 2.198 s of 3 s'."""
        return f"at t = {self.core.t:.6g} s" + (
            "" if self.n_end is None else f" of {self.n_end * self.period:.6g} s")

    def _write_summary(self):
        path = self.p["summary_file"]
        if path:
            import json
            try:
                with open(path, "w") as f:
                    json.dump(self.summary(), f)
            except OSError as exc:
                self.get_logger().error(f"summary_file: cannot write {path!r}: {exc}")

    def diagnostic_values(self) -> dict:
        """/diagnostics: simulated time, ticks, real-time factor, late ticks (realtime),
        rejected efforts; an error when the plant diverged or the run stalled."""
        out = {"mode": self.mode, "sim_time_s": self.core.t, "ticks": self.core.k,
               "real_time_factor": self.rtf()}
        if self.mode == "realtime":
            out["late_ticks"] = self.pacer.stats.late_ticks
        if self.diverged or self.stalled:
            out["error"] = f"diverged: {self.diverged}" if self.diverged else "stalled"
        return out

    def rtf(self) -> float:
        if self.t_wall0 is None:
            return 0.0
        wall = (self.t_wall_end or time.monotonic()) - self.t_wall0
        return self.core.t / wall if wall > 0 else math.inf

    def report(self, final=False):
        if self.finished and not final:
            return
        now = time.monotonic()
        if self.p["progress"] and (final or now - self._last_report > 0.2):
            end = "" if self.n_end is None else f" / {self.n_end * self.period:.3f}"
            self._line.show(f"  t = {self.core.t:.3f}{end} s  (real-time factor "
                            f"{self.rtf():.3g}" + (f", {self.overruns} late ticks"
                                                   if self.mode == "realtime" else "") + ")",
                            final=final)
            self._last_report = now
        if final or (self.mode != "lockstep" and now - self._last_log > 5.0):
            self._last_log = now
            pace = ""
            if self.mode == "realtime":
                st = self.pacer.summary()
                pace = (f", {st['late_ticks']} of {st['ticks']} ticks late (lateness p50 "
                        f"{st['lateness_p50_s'] * 1e3:.3g} ms, p99 "
                        f"{st['lateness_p99_s'] * 1e3:.3g} ms, max "
                        f"{st['lateness_max_s'] * 1e3:.2f} ms)")
                if st["skipped_ticks"] or st["slowed_s"]:
                    n = self.pacer.crossings
                    pace += (f"; late beyond {st['late_bound_s']:g} s {n} "
                             f"time{'' if n == 1 else 's'}: "
                             + (f"{st['skipped_ticks']} ticks stepped without "
                                f"publishing (late_policy skip)"
                                if st["skipped_ticks"] else
                                f"{st['slowed_s']:.3f} s behind the wall clock "
                                f"(late_policy slow)"))
            log = self.get_logger().warning if (self.mode == "realtime" and
                                                self.pacer.crossings) else \
                self.get_logger().info
            log(f"{self.mode}{'' if final else ' (running)'}: {self.core.t:.3f} s simulated, "
                f"{self.core.k} ticks, real-time "
                f"factor {self.rtf():.3g}{pace}; {T.EFFORTS}: "
                f"{self.core.validator.summary()}" + ("; diverged" if self.diverged else ""))


def main(args=None):
    return C.node_main(SimulatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
