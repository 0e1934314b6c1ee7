"""The twin's nodes answer their parameter services as any rclpy node does (issue 38).

A twin runs in a child process (``flexarm run``, realtime, in each layout — one, split,
processes; in one process also with every message by DDS, ``--transport dds``, and in
lockstep, whose cascade of deliveries never empties the intra-process bus); this process
is a plain ROS 2 user with rclpy's own service clients — what ``ros2 param list/get/set/
describe`` sends. Every node lists its parameters, gives their values (the scene the twin
runs), describes them (read-only, with a description), and refuses a set with the reason
(the twin takes its parameters at start), leaving the value as it was.
"""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

rclpy = pytest.importorskip("rclpy")
import flexarm_ros.nodes.common  # noqa: E402,F401  (loads message support quietly)
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from rcl_interfaces.srv import (DescribeParameters, GetParameters,  # noqa: E402
                                ListParameters, SetParameters)

from flexarm_ros.nodes.environment import child_environment  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.subprocess, pytest.mark.heavy]

NS = "/param_test"
NODES = ("simulator", "motor_driver", "controller")


def _call(node, executor, srv_type, name, request, timeout=30.0):
    client = node.create_client(srv_type, name)
    try:
        deadline = time.monotonic() + timeout
        while not client.wait_for_service(timeout_sec=0.5):
            assert time.monotonic() < deadline, f"{name}: no service within {timeout} s"
        future = client.call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), f"{name}: no answer within {timeout} s"
        return future.result()
    finally:
        node.destroy_client(client)


@pytest.fixture(params=["one", "split", "processes", "one-dds", "one-lockstep"])
def twin(request):
    """A twin long enough for the queries: realtime in the given layout (and transport),
    or lockstep in one process."""
    lockstep = request.param == "one-lockstep"
    argv = [sys.executable, "-m", "flexarm_ros.cli", "run", "two_link_position",
            "--mode", "lockstep" if lockstep else "realtime",
            "--duration", "100000" if lockstep else "60", "--no-record", "--quiet",
            "--namespace", NS]
    if request.param == "processes":
        argv.append("--processes")
    if request.param == "split":
        argv += ["--layout", "split"]
    if request.param == "one-dds":
        argv += ["--transport", "dds"]
    proc = subprocess.Popen(argv, env=child_environment(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    yield request.param
    proc.terminate()
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate(timeout=10)


def test_every_node_answers_list_get_describe_and_refuses_a_set(twin):
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("param_client", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    states = []
    node.create_subscription(JointState, f"{NS}/joint_states",
                             lambda m: states.append(m.header.stamp.sec * 10**9 +
                                                     m.header.stamp.nanosec), 10)
    try:
        # the queries go to a twin that is ticking (in lockstep the bus's cascade of
        # deliveries never empties: the executor must still serve the services)
        deadline = time.monotonic() + 60
        while not states:
            assert time.monotonic() < deadline, (twin, "no joint state within 60 s")
            executor.spin_once(timeout_sec=0.1)
        ticking_at = states[-1]
        for name in NODES:
            base = f"{NS}/{name}"
            listed = _call(node, executor, ListParameters, f"{base}/list_parameters",
                           ListParameters.Request()).result.names
            assert "scene" in listed and "use_sim_time" in listed, (twin, name, listed)

            got = _call(node, executor, GetParameters, f"{base}/get_parameters",
                        GetParameters.Request(names=["scene", "mode"])).values
            assert got[0].type == ParameterType.PARAMETER_STRING
            assert got[0].string_value == "two_link_position", (twin, name)
            mode = "lockstep" if twin == "one-lockstep" else "realtime"
            assert got[1].string_value == mode, (twin, name)

            described = _call(node, executor, DescribeParameters, f"{base}/describe_parameters",
                              DescribeParameters.Request(names=["scene"])).descriptors
            assert described[0].read_only and described[0].description, (twin, name)

            bad = Parameter(name="scene", value=ParameterValue(
                type=ParameterType.PARAMETER_STRING, string_value="link"))
            result = _call(node, executor, SetParameters, f"{base}/set_parameters",
                           SetParameters.Request(parameters=[bad])).results[0]
            assert not result.successful and "read-only" in result.reason, (twin, name)
            again = _call(node, executor, GetParameters, f"{base}/get_parameters",
                          GetParameters.Request(names=["scene"])).values[0]
            assert again.string_value == "two_link_position", (twin, name)
        n = len(states)
        deadline = time.monotonic() + 10
        while len(states) == n and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert states[-1] > ticking_at, (twin, "the twin stopped ticking during the queries")
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
