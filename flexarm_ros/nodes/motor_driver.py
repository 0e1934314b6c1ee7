"""The power electronics: :class:`~flexarm_ros.twin.cores.DriverCore` on ROS 2.

Subscribes (node-relative): ``motor_driver/commands`` (std_msgs/Float64MultiArray, V per
joint; A for a valve) and ``ground_truth/joint_states`` (the drive coordinates' angles
and rates, ``<link>_drive``, of the current tick). Publishes, once per tick:
``effort_controller/commands`` (N·m at the gearbox outputs, held by the simulator over
the next period) and ``motor_driver/motor_states`` (motor-shaft angle/speed, armature
current or load pressure in ``effort``).

Time: the ground-truth stamp is the driver's time. ``lockstep`` pairs the k-th command
with the k-th state (count-based FIFO); ``realtime`` / ``fast`` take each command when it
arrives and answer every state with the latest one. Commands with NaN/inf or the wrong
length are rejected (``rejected`` counts them, a throttled warning is logged) and never
reach the plant; a command older than ``control.watchdog_s`` of simulated time gives
0 V / a closed valve (``tripped``), so a dead controller lets the arm coast.
"""

from __future__ import annotations

import sys
from collections import deque

from rclpy.node import Node

from flexarm_ros.bag import messages as msg
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import DriverCore
from flexarm_ros.nodes import _common as C
from flexarm_ros.nodes._msgconv import to_msg


class MotorDriverNode(Node):
    """flexarm twin motor driver node: commands in, joint torques out (with watchdog)."""

    EXECUTABLE = "motor_driver"

    def __init__(self, **kwargs):
        super().__init__("motor_driver", **kwargs)
        self.p, scene, self.n_end = C.load(self, {})
        self.lockstep = self.p["mode"] == "lockstep"
        self.scene = scene
        self.core = DriverCore(scene)
        self.n = len(scene.links)
        self.period = 1.0 / scene.control.rate_hz
        self.sim_time = C.SimTime(scene)
        self.t = 0.0
        r = self.p["recorders"]
        self.pub_eff = C.publisher(self, T.TYPES[T.EFFORTS], T.EFFORTS)
        self.pub_ms = C.publisher(self, T.TYPES[T.MOTOR_STATES], T.MOTOR_STATES)
        self.ready = C.Barrier(self, [(self.pub_eff, 1 + r), (self.pub_ms, r)], r)
        self.commands, self.states = deque(), deque()
        C.subscription(self, T.TYPES[T.COMMANDS], T.COMMANDS, self._on_command)
        C.subscription(self, T.TYPES[T.GT_JOINT_STATES], T.GT_JOINT_STATES, self._on_state)
        self.published = {T.EFFORTS: 0, T.MOTOR_STATES: 0}
        self.timer = self.create_timer(0.01, self._drain)   # wall clock: the start barrier

    @property
    def rejected(self) -> int:
        return self.core.rejected

    def _accept(self, t, data):
        if not self.core.accept(t, data):
            self.get_logger().warning(
                f"rejected command {data!r} (expected {self.n} finite values); "
                f"{self.core.rejected} rejected so far", throttle_duration_sec=1.0)

    def _on_command(self, m):
        if self.lockstep:
            self.commands.append(list(m.data))
            self._drain()
        else:
            self._accept(self.t, list(m.data))

    def _on_state(self, m):
        self.states.append(m)
        self._drain()

    def _drain(self):
        if not self.ready():
            return
        self.timer.cancel()
        while self.states and (self.commands or not self.lockstep):
            gt = self.states.popleft()
            t_ns = C.stamp_ns(gt.header.stamp)
            if self.n_end is not None and C.tick_of(self.scene, t_ns) >= self.n_end:
                self.commands.clear()
                continue
            self.t = t = self.sim_time(t_ns)
            if self.lockstep:
                self._accept(t, self.commands.popleft())
            angles = list(gt.position[self.n:2 * self.n])
            rates = list(gt.velocity[self.n:2 * self.n])
            tau = self.core.update(t, self.period, rates)
            self.pub_eff.publish(to_msg(T.TYPES[T.EFFORTS],
                                        msg.float64_multiarray(tau, ("joint",))))
            self.pub_ms.publish(to_msg(T.TYPES[T.MOTOR_STATES],
                                       self.core.motor_states(t_ns, angles, rates)))
            self.published[T.EFFORTS] += 1
            self.published[T.MOTOR_STATES] += 1


def main(args=None):
    return C.node_main(MotorDriverNode, args)


if __name__ == "__main__":
    sys.exit(main())
