"""The power electronics: :class:`~flexarm_ros.twin.cores.DriverCore` on ROS 2.

Subscribes (node-relative): ``motor_driver/commands`` (std_msgs/Float64MultiArray, V per
joint; A for a valve) and ``ground_truth/joint_states`` (the drive coordinates' angles
and rates, ``<link>_drive``, of the current tick). Publishes, once per tick:
``effort_controller/commands`` (N·m at the gearbox outputs, held by the simulator over
the next period; for a hydraulic joint the servovalve current, A above the null bias, to
the actuator the simulator integrates) and ``motor_driver/motor_states`` (motor-shaft
angle/speed, armature current or load pressure in ``effort``).

Commands are validated where they enter: a message is taken only from the topic's source
(the ``command_source`` node, ``controller``, when it is on the graph, else the first
publisher; :mod:`flexarm_ros.nodes._wire`) and only when it holds one finite value per
joint within the joint's command limit (V, A or N·m; :mod:`flexarm_ros.model.limits`).
Anything else is rejected (``rejected``, by reason in ``core.validator.counts``; a
throttled warning) and changes nothing: not the held command, not the pairing. States
are taken from the ``simulator`` only.

Time: the ground-truth stamp is the driver's time. ``lockstep`` pairs the k-th accepted
command with the k-th state (a FIFO of accepted commands: a rejected one never takes a
state's place). A Float64MultiArray carries no stamp, so a valid command beyond one per
state cannot be told from the next state's answer: it shifts the pairing from there on.
What the run shows of it is counted at the end (:attr:`extra_commands`: the accepted
commands beyond the states answered and the one the last state may have had) and said
at WARN level; ``realtime`` / ``fast`` take each accepted command when it arrives and
answer every state with the latest one (the source's latest wins). A command older than
``control.watchdog_s`` of simulated time gives 0 V / a closed valve (``tripped``), so a
dead controller lets the arm coast. With ``await_first_command`` (realtime and fast;
``flexarm run`` sets it where a controller of the user's is expected) the states are
subscribed once a command publisher is matched, as in lockstep, and no state is answered
before the first accepted command, which answers the newest one (the simulator's state at
t = 0, whose clock waits for that answer). The final log line gives the rejected
messages by topic and reason.
"""

from __future__ import annotations

import sys
from collections import deque

from rclpy.node import Node

from flexarm_ros.bag.cdr_fixed import CdrBuilder
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import DriverCore
import flexarm_ros.nodes.common as C
from flexarm_ros.nodes.diagnostics import attach as attach_diagnostics
from flexarm_ros.nodes._wire import Rejections, Source, reject_undecodable


class MotorDriverNode(Node):
    """flexarm twin motor driver node: commands in, joint torques out (with watchdog)."""

    EXECUTABLE = "motor_driver"
    PARAMS = {"command_source": (T.SOURCE[T.COMMANDS], "node whose commands are taken while "
                                 "it is on the graph ('': the first publisher)"),
              "await_first_command": (False, "realtime and fast: subscribe to the states "
                                      "once a command publisher is matched and answer no "
                                      "state before the first accepted command, which then "
                                      "answers the newest (the simulator's first) state, as "
                                      "in lockstep (flexarm run sets it where a controller "
                                      "of the user's is expected)")}

    def __init__(self, **kwargs):
        super().__init__("motor_driver", **kwargs)
        self.p, scene, self.n_end = C.load(self, self.PARAMS)
        self.lockstep = self.p["mode"] == "lockstep"
        self.awaits = bool(self.p["await_first_command"]) and not self.lockstep
        self.scene = scene
        self.core = DriverCore(scene)
        self.n = len(scene.links)
        self.period = 1.0 / scene.twin_control.rate_hz
        self.sim_time = C.SimTime(scene)
        self.t = 0.0
        r = self.p["recorders"]
        self.pub_eff = C.publisher(self, T.TYPES[T.EFFORTS], T.EFFORTS)
        self.pub_ms = C.publisher(self, T.TYPES[T.MOTOR_STATES], T.MOTOR_STATES)
        self.ready = C.Barrier(self, [(self.pub_eff, 1 + r, "the simulator"),
                                      (self.pub_ms, r, "the recorder")], r)
        self.commands, self.states = deque(), deque()
        self._cdr = CdrBuilder()                # wire bytes from templates, as the simulator's
        self._cmd_sub = sub = C.subscription(self, T.TYPES[T.COMMANDS], T.COMMANDS,
                                             self._on_command, plain=True,
                                             undecodable=self._undecodable_command)
        self.source = Source(self, sub.topic_name, self.p["command_source"] or None)
        # lockstep: the states are subscribed (and so the simulator, which waits for this
        # subscriber, starts) only once a controller's command publisher is matched with
        # the command subscription: a controller that answers the first state before the
        # match would lose that answer, and lockstep would wait for it (seen with a
        # foreign controller under load; the twin's own controller waits for the match
        # itself, a foreign one cannot know to)
        self._state_sub = None
        self.state_source = None
        self._wait_warning = C.WaitWarning(self.WARN_AFTER_S)
        if not (self.lockstep or self.awaits):
            self._subscribe_states()
        self.rejections = Rejections(self)
        attach_diagnostics(self)               # /diagnostics at 1 Hz
        self.published = {T.EFFORTS: 0, T.MOTOR_STATES: 0}
        self.accepted = {T.COMMANDS: 0}
        self.paired = 0                         # lockstep: states answered with a command
        # lockstep: states that found a command already waiting (an extra put the queue
        # ahead; the controller's own answers to the last states are then still on their
        # way when the twin ends: flexarm_ros.run.supervision._await_last_answers)
        self.ran_ahead = 0
        self._started = False                   # the start barrier passed
        # the start barrier, on the wall clock: with use_sim_time (fast mode) a timer on
        # the node's clock would wait for the /clock that only the start brings
        self.timer = self.create_timer(0.01, self._drain, clock=C.wall_clock())

    @property
    def rejected(self) -> int:
        return self.core.rejected

    def _undecodable_command(self, data, info, exc) -> None:
        """Bytes on the command topic that are not a Float64MultiArray: refused or
        rejected and counted like any rejected command, never taken."""
        reject_undecodable(self, self.core.validator, self.source, "command", data, exc,
                           info)

    def _on_command(self, m, info):
        """Validated where it enters; only an accepted command is queued (lockstep) or
        held (realtime, fast)."""
        data = m.data
        v = self.core.validator
        why = v.reason(data)
        who = self.source.verdict(info, valid=why is None)
        if who is not None:
            v.refuse(self.source.reason)
            self.rejections.refused(self.source, "command", data, who)
            return
        if why is not None:
            v.check(data)
            self.rejections.invalid(self.source.topic, "command", data, why, v.expectation())
            return
        self.accepted[T.COMMANDS] += 1      # the recorder takes them too (run's end waits)
        if self.lockstep:
            self.commands.append(list(data))
            self._drain()
        else:
            self.core.accept(self.t, list(data))
            if self.awaits and self.accepted[T.COMMANDS] == 1:
                self._drain()                   # the first command answers the held state

    def _on_state(self, m, info):
        who = self.state_source.verdict(info)
        if who is not None:
            self.rejections.refused(self.state_source, "a state", None, who)
            return
        if self.lockstep and self.commands and not self.states:
            self.ran_ahead += 1
        self.states.append(m)
        self._drain()

    @property
    def extra_commands(self) -> int | None:
        """Lockstep: accepted commands beyond one per state answered, less the one the
        last state may have had (a lower bound of the extra commands a controller sent);
        None in realtime and fast, where the latest command wins by design."""
        if not self.lockstep:
            return None
        return max(0, self.accepted[T.COMMANDS] - self.paired - 1)

    def finish(self, executor=None):
        """The final log line: what was published and what was rejected (and, lockstep,
        a warning when more commands came than states to answer)."""
        extra = self.extra_commands
        if extra:
            self.get_logger().warning(
                f"lockstep: {extra} command(s) on {self._cmd_sub.topic_name} beyond one per "
                f"state ({self.accepted[T.COMMANDS]} accepted for {self.paired} states "
                f"answered, one more allowed for the last state's answer): the "
                f"k-th command answers the k-th state, so from the first extra on each state "
                f"took an earlier command. Publish exactly one command per joint_states "
                f"message")
        self.get_logger().info(f"{self.published[T.EFFORTS]} efforts published; "
                               f"{T.COMMANDS}: {self.core.validator.summary()}"
                               + (f"; {self.rejections.summary()}"
                                  if self.state_source is not None and
                                  self.rejections.total(self.state_source.topic) else "")
                               + (f"; torque held at the limit in {self.core.held} periods"
                                  if self.core.held else ""))

    WARN_AFTER_S = 3.0

    def _subscribe_states(self):
        self._state_sub = C.subscription(self, T.TYPES[T.GT_JOINT_STATES], T.GT_JOINT_STATES,
                                         self._on_state, plain=True)
        self.state_source = Source(self, self._state_sub.topic_name,
                                   T.SOURCE[T.GT_JOINT_STATES])

    def _drain(self):
        if self._state_sub is None:
            if self._cmd_sub.get_publisher_count() < 1:
                waited = self._wait_warning.due()
                if waited:
                    self.get_logger().warning(
                        f"not started after {waited:.0f} s: waiting for a publisher on "
                        f"{self._cmd_sub.topic_name} (a controller; "
                        + ("lockstep steps on its answers" if self.lockstep else
                           "the twin's clock starts at its first command")
                        + C.other_types(self, self._cmd_sub.topic_name,
                                        T.TYPES[T.COMMANDS]) + ")")
                return
            self._subscribe_states()
        if not self._started:
            if not self.ready():
                return
            self.timer.cancel()
            self._started = True
        if self.awaits and not self.accepted[T.COMMANDS]:
            while len(self.states) > 1:         # no answer before the first command; the
                self.states.popleft()           # newest state waits for it
            return
        while self.states and (self.commands or not self.lockstep):
            gt = self.states.popleft()
            t_ns = C.stamp_ns(gt.header.stamp)
            if self.n_end is not None and C.tick_of(self.scene, t_ns) >= self.n_end:
                self.commands.clear()
                continue
            self.t = t = self.sim_time(t_ns)
            if self.lockstep:
                self.core.accept(t, self.commands.popleft())
                self.paired += 1
            angles = list(gt.position[self.n:2 * self.n])
            rates = list(gt.velocity[self.n:2 * self.n])
            tau = self.core.update(t, self.period, rates, list(gt.effort[self.n:2 * self.n]))
            self.pub_eff.publish(self._cdr.float64_multiarray(tau, ("joint",)))
            self.pub_ms.publish(self.core.motor_states(t_ns, angles, rates, build=self._cdr))
            self.published[T.EFFORTS] += 1
            self.published[T.MOTOR_STATES] += 1


def main(args=None):
    return C.node_main(MotorDriverNode, args)


if __name__ == "__main__":
    sys.exit(main())
