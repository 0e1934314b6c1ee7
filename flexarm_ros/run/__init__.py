"""Start the twin's ROS 2 graph: simulator, motor driver, controller and (optionally) the
recorder, in one process (all nodes on one executor, the default) or one process per
node, for a duration or until Ctrl-C; always leaves a finalized MCAP when recording.

``flexarm run`` is :func:`run`; tests and benchmarks use :class:`InProcessGraph` and
:class:`ProcessGraph` directly to reach into a running graph (kill a node, publish a bad
command, read counters).

The scene is a YAML path or shipped name (default :data:`flexarm_ros.scene.DEFAULT_SCENE`);
``fidelity`` overrides (``Scene.with_fidelity`` keywords: rung, refine, integrator, rtol,
atol, dt, foreshortening) reach every node as the parameters of
:mod:`flexarm_ros.nodes.parameters`; ``sets`` (``flexarm run --set KEY=VALUE``: scene key
paths and values, :mod:`flexarm_ros.scene.overrides`) reach every node as its string
parameter ``set`` (JSON), which the node applies to the scene it loads before the fidelity
parameters — in every layout, whether the node runs in this process or in a child, it
builds the same modified scene, and nothing is left on disk (the recorder embeds the
modified scene in the bag and the sets in its ``flexarm_ros`` metadata).

Environment: :func:`flexarm_ros.nodes.environment.private_graph` (loopback-only discovery
and a private ``ROS_DOMAIN_ID``, each unless set) before rclpy initializes, inherited by
every child process.

The package, one job a module: :mod:`~flexarm_ros.run.graphs` starts the graph (the three
layouts, the nodes' parameters, the child processes), :mod:`~flexarm_ros.run.supervision`
runs it to its end (:func:`run`, the stop and how each node ended) and
:mod:`~flexarm_ros.run.result` holds what it came to (:class:`RunResult`, read from the
simulator's summary and the bag). Their public names are importable from here.
"""

from flexarm_ros.run.graphs import (DEFAULT_NAMESPACE, GRAPH_NODES, NODES, PR_SET_PDEATHSIG,
                                    InProcessGraph, ProcessGraph, SplitGraph, all_arrived,
                                    awaits, cpu_placement, die_with_parent, ros_arg,
                                    select_nodes)
from flexarm_ros.run.result import BUSY_SHARE, RunResult
from flexarm_ros.run.supervision import (ANSWERS_QUIET_S, ANSWERS_WAIT_S, LAYOUTS,
                                         TRANSPORTS, default_layout, ended_early,
                                         recover_killed_bag, run, run_with_view)

# the names the tests knew before the split (flexarm_ros/run.py), when these were private
_all_arrived, _ros_arg = all_arrived, ros_arg

__all__ = ["ANSWERS_QUIET_S", "ANSWERS_WAIT_S", "BUSY_SHARE", "DEFAULT_NAMESPACE",
           "GRAPH_NODES", "LAYOUTS", "NODES", "PR_SET_PDEATHSIG", "TRANSPORTS",
           "InProcessGraph", "ProcessGraph", "RunResult", "SplitGraph", "all_arrived",
           "awaits", "cpu_placement", "default_layout", "die_with_parent", "ended_early",
           "recover_killed_bag", "ros_arg", "run", "run_with_view", "select_nodes"]
