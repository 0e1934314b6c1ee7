"""flexarm_ros: a ROS 2 digital twin of flexible-link robot arms.

The physics core (:mod:`flexarm_ros.model`) never imports rclpy; ROS nodes live in
:mod:`flexarm_ros.nodes` and are thin adapters over it.
"""

__version__ = "0.2.0"
