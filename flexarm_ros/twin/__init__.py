"""The ROS twin's pieces without middleware: simulator, motor driver and controller cores
(:mod:`cores`), the topic contract (:mod:`topics`) and the in-process co-simulation that
wires them in lockstep (:mod:`cosim`). The ROS nodes in :mod:`flexarm_ros.nodes` adapt
these objects to rclpy."""
