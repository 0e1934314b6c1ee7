"""The twin's ROS 2 nodes: thin rclpy adapters over :mod:`flexarm_ros.twin.cores`.

=================  ===========================  ==========================================
node (executable)  subscribes                   publishes
=================  ===========================  ==========================================
``simulator``      effort_controller/commands   /clock, joint_states, encoders/counts,
                                                accelerometers|strain|potentiometer/batch,
                                                tool/contact, tool/wrench,
                                                ground_truth/joint_states, ground_truth/tip
``controller``     joint_states, tool/contact,  motor_driver/commands
                   tool/wrench
``motor_driver``   motor_driver/commands,       effort_controller/commands,
                   ground_truth/joint_states    motor_driver/motor_states
``recorder``       all of the above             (an MCAP file)
``estimator``      joint_states,                estimator/joint_states, estimator/tip,
                   accelerometers/batch,        estimator/tip_deflections, estimator/nis,
                   motor_driver/commands        estimator/events (not part of a
                                                ``flexarm run`` graph: start it beside one)
=================  ===========================  ==========================================

Topic names are relative to the node namespace (``flexarm run`` uses ``/flexarm``),
``/clock`` is global; the contract is :mod:`flexarm_ros.twin.topics`. Every node takes
the parameters ``scene`` (YAML path or shipped name), ``mode`` (``lockstep``,
``realtime`` or ``fast``), ``duration``, ``recorders`` and the fidelity overrides ``rung``,
``refine``, ``integrator``, ``rtol``, ``atol``, ``dt``, ``no_foreshortening``, ``max_steps``
(:mod:`flexarm_ros.nodes.parameters`); ``<executable> --help`` lists them. ``flexarm run``
(:mod:`flexarm_ros.run`) starts the graph; :mod:`flexarm_ros.nodes.environment` sets the
ROS environment (importable without rclpy, like ``parameters``).
"""

__all__ = ["node_classes"]


def node_classes() -> dict:
    """{executable name: Node class} (imports rclpy)."""
    from flexarm_ros.nodes.controller import ControllerNode
    from flexarm_ros.nodes.motor_driver import MotorDriverNode
    from flexarm_ros.nodes.recorder import RecorderNode
    from flexarm_ros.nodes.simulator import SimulatorNode
    return {"simulator": SimulatorNode, "motor_driver": MotorDriverNode,
            "controller": ControllerNode, "recorder": RecorderNode}
