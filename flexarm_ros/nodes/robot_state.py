"""The arm for robot_state_publisher and RViz2's RobotModel: the URDF published once on
``robot_description`` (std_msgs/String, reliable and transient local, as
robot_state_publisher publishes it, so a viewer started later still gets it) and the
URDF's joint values as ``robot_state/joint_states`` beside ``arm_markers``
(:mod:`flexarm_ros.twin.robot_description`). Where the ``tf2_msgs`` Python package
imports (a ROS installation), also ``/tf_static`` once (transient local) and ``/tf`` with
each ``robot_state/joint_states``; where it does not (PyPI has no tf2_msgs), one INFO line
says so and names robot_state_publisher and the bag's /tf."""

from __future__ import annotations

import numpy as np

from flexarm_ros.bag import messages as M
from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.robot_description import Description

JOINT_STATE = "sensor_msgs/msg/JointState"


class RobotState:
    """``robot_description`` of ``chain`` published by ``node`` now; :meth:`values` the
    joint values at coordinates q, :meth:`cdr` and :meth:`publish_tf` their messages."""

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
        self.tf = self.tf_static = None
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            node.get_logger().info(
                "/tf: not published live (the tf2_msgs Python package does not import); "
                "robot_state_publisher with robot_state/joint_states gives it, and the "
                "recorder writes /tf into the bag")
            return
        self._tf_type = TFMessage
        self.tf = node.create_publisher(TFMessage, T.TF, 100)
        self.tf_static = node.create_publisher(TFMessage, T.TF_STATIC, qos)
        self.tf_static.publish(self._message(0, self.description.fixed()))

    def _message(self, t_ns: int, transforms):
        """A TFMessage object of (parent, child, x, y, yaw) transforms."""
        from rclpy.serialization import deserialize_message
        return deserialize_message(encode_cdr("tf2_msgs/msg/TFMessage",
                                              M.tf_message(t_ns, transforms)),
                                   self._tf_type)

    def publish_tf(self, t_ns: int, values) -> None:
        """Live ``/tf`` of the movable joints at their ``values`` (:meth:`values`; where
        tf2_msgs imports)."""
        if self.tf is None:
            return
        self.tf.publish(self._message(t_ns, self.description.moving(values)))

    def values(self, q) -> np.ndarray:
        """The URDF's movable joint values at the model's coordinates ``q``."""
        return self.description.positions(q)

    def cdr(self, t_ns: int, values) -> bytes:
        """``robot_state/joint_states`` at ``t_ns`` of the joint ``values``."""
        return encode_cdr(JOINT_STATE, M.joint_state(t_ns, self.description.movable, values,
                                                     self._zeros, self._zeros),
                          validate=False)
