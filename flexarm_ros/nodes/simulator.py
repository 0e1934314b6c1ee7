"""The plant node: :class:`~flexarm_ros.twin.cores.SimulatorCore` on ROS 2.

Publishes (node-relative, reliable keep_last 1000): ``/clock``, ``joint_states``,
``encoders/counts``, ``accelerometers/batch`` / ``strain/batch`` /
``potentiometer/batch`` (scenes with such sensors), ``tool/contact`` and ``tool/wrench``
(scenes with a wall), ``ground_truth/joint_states``, ``ground_truth/tip`` — the state of
one control tick, in that order. Subscribes: ``effort_controller/commands`` (N·m per
joint, held over the next control period).

Efforts are validated where they enter: a message is taken only from the topic's source
(the ``command_source`` node, ``motor_driver``, when it is on the graph, else the first
publisher; :mod:`flexarm_ros.nodes._wire`) and only when it holds one finite value per
joint within the joint's torque limit (:mod:`flexarm_ros.model.limits`). Anything else is
rejected: counted by reason, logged (throttled), and it changes nothing — it neither
steps the plant nor replaces the held torque.

Time modes (parameter ``mode``):

* ``lockstep``: publishes tick k, then steps on the first accepted effort after it (no
  timer): deterministic, equal to ``cosimulate``. Every accepted message from the source
  steps one period (the source is the tick); rejected ones and a second publisher's never
  do, so a hostile publisher cannot change a lockstep run.
* ``realtime``: a wall-clock timer at the control period steps with the latest accepted
  effort (zero-order hold; the source's latest message wins); the real-time factor and
  overruns (ticks that started more than one period late) are logged every few seconds
  and at the end.
* ``fast``: steps as fast as the executor allows with the latest accepted effort;
  ``/clock`` is the only time (run the other nodes with ``use_sim_time``).

A diverging plant stops the node like ``flexarm simulate``: nothing of the diverged state
is published, ``diverged`` holds the :class:`~flexarm_ros.errors.SimulationDiverged`
(what, when, what to change), and the node's process exits with status 3 printing it once.
The final log line gives the simulated time, ticks, real-time factor and the rejected
efforts by reason.

Publishing starts once every topic is matched (``recorders`` + the controller/driver).
With a finite ``duration`` the node stops after the state at that time (and its process
exits); ``progress`` prints the simulated time on stderr.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from rclpy.node import Node

from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import SimulatorCore
from flexarm_ros.twin.validation import FOREIGN
from flexarm_ros.nodes import _common as C
from flexarm_ros.nodes._msgconv import to_msg
from flexarm_ros.nodes._wire import Rejections, Source


class SimulatorNode(Node):
    """flexarm twin simulator node: plant, sensors, contact and /clock."""

    EXECUTABLE = "simulator"
    PARAMS = {"progress": (False, "print the simulated time on stderr"),
              "command_source": (T.SOURCE[T.EFFORTS], "node whose efforts are taken while "
                                 "it is on the graph ('': the first publisher)")}

    def __init__(self, **kwargs):
        super().__init__("simulator", **kwargs)
        self.p, scene, self.n_end = C.load(self, self.PARAMS)
        self.mode = self.p["mode"]
        # the work budget of a finite run, checked here too (a node started on its own)
        self.core = SimulatorCore(scene, None if self.n_end is None else
                                  self.n_end / scene.control.rate_hz)
        self.period = self.core.period
        pubs = {}                                   # outputs() at k = 0 changes nothing
        for topic in [o[0] for o in self.core.outputs()] + list(self.core.groups):
            pubs[topic] = C.publisher(self, T.TYPES[topic], topic)
        self.pubs = pubs
        sub = C.subscription(self, T.TYPES[T.EFFORTS], T.EFFORTS, self._on_effort)
        self.source = Source(self, sub.topic_name, self.p["command_source"] or None)
        self.rejections = Rejections(self)
        self.diverged: SimulationDiverged | None = None
        r = self.p["recorders"]
        to_nodes = (T.JOINT_STATES, T.TOOL_CONTACT, T.TOOL_WRENCH, T.GT_JOINT_STATES)
        self.ready = C.Barrier(self, [(p, r + (t in to_nodes)) for t, p in pubs.items()], r)
        self.published = {t: 0 for t in pubs}
        self.torque = np.zeros(len(scene.links))
        self.finished = self.started = False
        self.overruns = 0
        self.t_wall0 = self.t_wall_end = None
        self._last_report = self._last_log = 0.0
        # wall-clock timer: lockstep polls the start barrier (then efforts drive the
        # steps), realtime paces the steps, fast steps whenever the executor is free
        period = {"lockstep": 0.001, "realtime": self.period, "fast": 0.0}[self.mode]
        self.timer = self.create_timer(period, self._on_timer)

    # ---------------------------------------------------------------------------- ticks
    def _publish_state(self):
        for topic, tp, data in self.core.outputs():
            self.pubs[topic].publish(to_msg(tp, data))
            self.published[topic] += 1
        if self.n_end is not None and self.core.k >= self.n_end:
            self.halt()

    def halt(self):
        """Stop stepping (end of the run, or Ctrl-C): no more states are published."""
        if not self.finished:
            self.finished = True
            self.t_wall_end = time.monotonic()
            self.timer.cancel()
            self.report(final=True)

    def _step(self, tau):
        self.torque = tau
        try:
            self.core.step(tau)
        except SimulationDiverged as exc:        # nothing of the diverged state goes out
            self.diverged = exc
            self.halt()
            return
        self._publish_state()
        self.report()

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
            v.refuse(FOREIGN)
            self.rejections.refused(self.source.topic, "effort", data, who,
                                    self.source.expected)
            return
        if why is not None:
            v.check(data)
            self.rejections.invalid(self.source.topic, "effort", data, why, v.expectation())
            return
        tau = np.array(data, float)
        if self.mode != "lockstep":
            self.torque = tau
        elif self.started and not self.finished:
            self._step(tau)

    def _on_timer(self):
        if not self.started:
            if not self.ready():
                return
            self.started, self.t_wall0 = True, time.monotonic()
            self._last_log = self.t_wall0
            self._publish_state()
            if self.mode == "lockstep":
                self.timer.cancel()
            return
        if self.finished:
            return
        if self.mode == "realtime":
            due = (time.monotonic() - self.t_wall0) / self.period
            if due - self.core.k > 2.0:             # started more than a period late
                self.overruns += 1
        self._step(self.torque)

    def finish(self, executor):
        """Called by main() when the node is stopped."""
        self.halt()

    # --------------------------------------------------------------------------- report
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
            print(f"\r  t = {self.core.t:.3f}{end} s  (real-time factor {self.rtf():.3g}"
                  + (f", {self.overruns} overruns" if self.mode == "realtime" else "") + ")",
                  end="\n" if final else "", file=sys.stderr, flush=True)
            self._last_report = now
        if final or (self.mode != "lockstep" and now - self._last_log > 5.0):
            self._last_log = now
            self.get_logger().info(f"{self.mode}: {self.core.t:.3f} s simulated, "
                                   f"{self.core.k} ticks, real-time factor {self.rtf():.3g}, "
                                   f"{self.overruns} overruns; {T.EFFORTS}: "
                                   f"{self.core.validator.summary()}"
                                   + ("; diverged" if self.diverged else ""))


def main(args=None):
    return C.node_main(SimulatorNode, args)


if __name__ == "__main__":
    sys.exit(main())
