"""Plumbing shared by the twin's nodes, one job a module, importable from here as
``flexarm_ros.nodes.common`` (the nodes use it as ``C``):

- :mod:`~flexarm_ros.nodes.endpoints`: QoS, publishers and subscriptions (imported first:
  it loads rclpy's message support quietly);
- :mod:`~flexarm_ros.nodes.scene_time`: parameters, the scene they load, and the mapping
  from a message stamp to the simulator's float time;
- :mod:`~flexarm_ros.nodes.startup`: the start barrier and the clock it waits on;
- :mod:`~flexarm_ros.nodes.run_enclave`: the run a node belongs to, and another twin;
- :mod:`~flexarm_ros.nodes.lifecycle`: the ``main()`` of every node (``--help``, rclpy
  init, spin, clean shutdown on Ctrl-C / SIGTERM), its executor and its exit."""

from flexarm_ros.nodes.endpoints import (DEPTH, QOS, other_types, publisher,
                                         subscriber_names, subscription)
from flexarm_ros.nodes.lifecycle import (PROFILE_ENV, ShutdownGuard, StopFlag, make_executor,
                                         node_main, profiled, stopped_from_outside,
                                         tell_the_run)
from flexarm_ros.nodes.run_enclave import (RUN_ENCLAVE_PREFIX, TWIN_NODES, new_run_enclave,
                                           other_twin)
from flexarm_ros.nodes.scene_time import SimTime, declare, load, stamp_ns, tick_of
from flexarm_ros.nodes.startup import (DISCOVERY_SETTLE_S, GRAPH, Barrier, WaitWarning,
                                       wall_clock)

__all__ = ["DEPTH", "DISCOVERY_SETTLE_S", "GRAPH", "PROFILE_ENV", "QOS", "RUN_ENCLAVE_PREFIX",
           "TWIN_NODES", "Barrier", "ShutdownGuard", "SimTime", "StopFlag", "WaitWarning",
           "declare", "load", "make_executor", "new_run_enclave", "node_main", "other_twin",
           "other_types", "profiled", "publisher", "stamp_ns", "stopped_from_outside",
           "subscriber_names", "subscription", "tell_the_run", "tick_of", "wall_clock"]
