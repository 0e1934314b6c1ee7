#!/usr/bin/env python3
"""A joint-space position controller for the flexarm twin, written only against its topic
contract (docs/topic_contract.md): plain rclpy and standard messages, nothing of
flexarm_ros. Use it as the template of your own controller.

    flexarm run two_link_position --without controller            # terminal 1: the twin
    python examples/foreign_controller.py --ros-args -r __ns:=/flexarm \\
        -p target:="[0.66, 0.53]"                                 # terminal 2: this node

In: ``joint_states`` (sensor_msgs/JointState: encoder angles in rad; stamps in simulation
time). Out: ``motor_driver/commands`` (std_msgs/Float64MultiArray: one voltage per joint,
V). It answers every joint_states message with exactly one command: that is what the
twin's lockstep mode steps on; in realtime the motor driver holds the latest one. It
subscribes to joint_states only once its command publisher is matched with the motor
driver, so that its first answer cannot be lost.

Law, per joint i (the joint PD of seed 000 Eq. 5.16 through the static motor map of
Eq. 5.17, written out here so that nothing of the twin is imported):
    T_i = kp_i (q*_i − q_i) − kd_i ω_i                      joint torque wanted, N·m
    u_i = T_i / motor_gain_i + back_emf_i ω_i               voltage, saturated at ±supply
with ω_i the encoder rate (backward difference of the angles over the stamps, low-pass
filtered at ``velocity_filter_hz``), motor_gain = n·K_t/R (N·m/V) and back_emf = n·K_b
(V·s/rad) of the gearmotor. The defaults are the Maxon motors and gearboxes of the
seed 000 arm (``two_link_position``) and the gains its scene was tuned with: soft
joints, because stiff ones leave the arm's 0.25 Hz beam mode ringing.

Parameters (``-p name:=value``; a list gives one value per joint): ``target`` (rad; unset:
hold the first angles received), ``kp`` (N·m/rad, default [6, 8]), ``kd`` (N·m·s/rad,
default [5, 8]), ``motor_gain`` (N·m/V, default [5.131, 1.621]), ``back_emf`` (V·s/rad,
default [4.711, 6.089]), ``supply_voltage`` (V, default [24]), ``velocity_filter_hz``
(default 20), ``idle_exit_s`` (exit after this many seconds without joint states once
some have arrived; default 5, 0: never).
"""

import math
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

# reliable and volatile as the twin's topics; 1000 deep is plenty for a node that answers
# each state at once (lockstep loses no message)
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def _per_joint(value, n):
    values = list(value) if isinstance(value, (list, tuple)) else [float(value)]
    return [float(values[i if len(values) > 1 else 0]) for i in range(n)]


class ForeignController(Node):
    def __init__(self):
        super().__init__("my_controller")
        self.declare_parameter("target", Parameter.Type.DOUBLE_ARRAY)   # unset: hold
        self.declare_parameter("kp", [6.0, 8.0])
        self.declare_parameter("kd", [5.0, 8.0])
        self.declare_parameter("motor_gain", [156 * 0.0302 / 0.9182, 236 * 0.0258 / 3.757])
        self.declare_parameter("back_emf", [156 * 0.0302, 236 * 0.0258])
        self.declare_parameter("supply_voltage", [24.0])
        self.declare_parameter("velocity_filter_hz", 20.0)
        self.declare_parameter("idle_exit_s", 5.0)
        self.target = None
        self.last = None                  # (stamp s, angles, filtered rates)
        self.last_rx = None
        self.answered = 0
        self.pub = self.create_publisher(Float64MultiArray, "motor_driver/commands", QOS)
        # the states only once the motor driver's subscription is matched on this side: an
        # answer published before that is lost (volatile QoS), and lockstep waits for it
        self.sub = None
        self.matching = self.create_timer(0.05, self.subscribe_when_matched)

    def subscribe_when_matched(self):
        if self.sub is None and self.pub.get_subscription_count() >= 1:
            self.sub = self.create_subscription(JointState, "joint_states", self.on_state,
                                                QOS)
            self.matching.cancel()

    def on_state(self, msg):
        self.last_rx = time.monotonic()
        n = len(msg.position)
        t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        q = list(msg.position)
        if self.target is None:
            given = self.get_parameter("target").value
            self.target = _per_joint(list(given), n) if given is not None else list(q)
            self.get_logger().info(f"target {self.target} rad")
        p = {k: _per_joint(self.get_parameter(k).value, n)
             for k in ("kp", "kd", "motor_gain", "back_emf", "supply_voltage")}
        w = [0.0] * n
        if self.last is not None and t > self.last[0]:
            dt = t - self.last[0]
            tau = 1.0 / (2.0 * math.pi * self.get_parameter("velocity_filter_hz").value)
            a = dt / (tau + dt)
            w = [(1 - a) * self.last[2][i] + a * (q[i] - self.last[1][i]) / dt
                 for i in range(n)]
        self.last = (t, q, w)
        u = []
        for i in range(n):
            torque = p["kp"][i] * (self.target[i] - q[i]) - p["kd"][i] * w[i]
            v = torque / p["motor_gain"][i] + p["back_emf"][i] * w[i]
            u.append(max(-p["supply_voltage"][i], min(p["supply_voltage"][i], v)))
        out = Float64MultiArray()
        out.layout.dim = [MultiArrayDimension(label="joint", size=n, stride=n)]
        out.data = u
        self.pub.publish(out)
        self.answered += 1


def main():
    rclpy.init(args=sys.argv)
    node = ForeignController()
    idle = node.get_parameter("idle_exit_s").value
    node.get_logger().info("ready: answering joint_states on motor_driver/commands")
    try:
        while rclpy.ok():
            rclpy.spin_once(node, timeout_sec=0.1)
            if idle and node.last_rx is not None and time.monotonic() - node.last_rx > idle:
                break
    except (KeyboardInterrupt, ExternalShutdownException):    # Ctrl-C, SIGTERM
        pass
    except Exception:
        # a SIGTERM that shut the context down while a callback was publishing ("the
        # publisher's context is invalid") is a stop like the others; anything else is not
        if rclpy.ok():
            raise
    node.get_logger().info(f"answered {node.answered} joint states")
    node.destroy_node()
    if rclpy.ok():
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
