"""The arm for robot_state_publisher and RViz2's RobotModel: the URDF published once on
``robot_description`` (std_msgs/String, reliable and transient local, as
robot_state_publisher publishes it, so a viewer started later still gets it) and the
URDF's joint values as ``robot_state/joint_states`` beside ``arm_markers``
(:mod:`flexarm_ros.twin.robot_description`)."""

from __future__ import annotations

import numpy as np

from flexarm_ros.bag import messages as M
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.robot_description import Description

JOINT_STATE = "sensor_msgs/msg/JointState"


class RobotState:
    """``robot_description`` of ``chain`` published by ``node`` now; :meth:`cdr` the
    joint values at coordinates q."""

    def __init__(self, node, chain):
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        self.description = Description(chain)
        self.urdf = self.description.urdf()
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub = node.create_publisher(String, T.ROBOT_DESCRIPTION, qos)
        self.pub.publish(String(data=self.urdf))
        self._zeros = np.zeros(len(self.description.movable))

    def cdr(self, t_ns: int, q) -> bytes:
        """``robot_state/joint_states`` at ``t_ns`` of the model's coordinates ``q``."""
        d = self.description
        return encode_cdr(JOINT_STATE, M.joint_state(t_ns, d.movable, d.positions(q),
                                                     self._zeros, self._zeros),
                          validate=False)
