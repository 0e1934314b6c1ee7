"""Control laws of the twin, plain numpy (no rclpy): seed 000's joint PD law (Eq. 5.16) and
static motor voltage map (Eq. 5.17), rigid two-link kinematics with Newton–Raphson inverse
kinematics, and the sanding task. Components take time as an argument
(``update(t, dt, ...)``) and never read a clock; ROS nodes are thin adapters over them."""

from flexarm_ros.control.joint_pd import (EncoderVelocity, JointPD, JointPositionController, MotorVoltageMap)
from flexarm_ros.control.kinematics import IKResult, PlanarTwoLink
from flexarm_ros.control.sanding import SandingTask

__all__ = ["EncoderVelocity", "IKResult", "JointPD", "JointPositionController",
           "MotorVoltageMap", "PlanarTwoLink", "SandingTask"]
