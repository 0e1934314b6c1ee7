"""The lean executor of the twin's nodes (:mod:`flexarm_ros.nodes.executor`) against what
rclpy's own executor delivers: every message, in order per topic, to message, raw and
MessageInfo callbacks; timers at their period; a node destroyed by a callback or removed
between spins never called again."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from std_msgs.msg import Float64MultiArray, Int32  # noqa: E402

from flexarm_ros.nodes.common import QOS  # noqa: E402
from flexarm_ros.nodes.executor import TwinExecutor  # noqa: E402


@pytest.fixture
def ctx():
    c = Context()
    rclpy.init(context=c)
    yield c
    rclpy.shutdown(context=c)


def _received(ctx, executor_cls, n=500):
    """Publish ``n`` messages on two topics from one node while spinning another with
    three kinds of callbacks; what each callback saw, in order."""
    pub_node = rclpy.create_node("pub", context=ctx)
    sub_node = rclpy.create_node("sub", context=ctx)
    got = {"obj": [], "info": [], "raw": [], "b": []}
    sub_node.create_subscription(Int32, "a", lambda m: got["obj"].append(m.data), QOS)
    sub_node.create_subscription(Int32, "a", lambda m, info: got["info"].append(
        (m.data, info["publication_sequence_number"] if isinstance(info, dict) else None)),
        QOS)
    sub_node.create_subscription(Int32, "a", lambda m, info: got["raw"].append(
        deserialize_message(m, Int32).data), QOS, raw=True)
    sub_node.create_subscription(Float64MultiArray, "b",
                                 lambda m: got["b"].append(list(m.data)), QOS)
    pa = pub_node.create_publisher(Int32, "a", QOS)
    pb = pub_node.create_publisher(Float64MultiArray, "b", QOS)
    exe = executor_cls(context=ctx)
    exe.add_node(sub_node)
    t0 = time.monotonic()
    while pa.get_subscription_count() < 3 or pb.get_subscription_count() < 1:
        exe.spin_once(timeout_sec=0.01)
        assert time.monotonic() - t0 < 30
    for i in range(n):
        pa.publish(Int32(data=i))
        pb.publish(Float64MultiArray(data=[float(i), -float(i)]))
        if i % 50 == 0:
            exe.spin_once(timeout_sec=0.0)
    t0 = time.monotonic()
    while min(len(v) for v in got.values()) < n and time.monotonic() - t0 < 30:
        exe.spin_once(timeout_sec=0.01)
    exe.shutdown()
    sub_node.destroy_node()
    pub_node.destroy_node()
    return got


@pytest.mark.ros
def test_every_message_in_order_to_every_kind_of_callback(ctx):
    got = _received(ctx, TwinExecutor)
    ref = list(range(500))
    assert got["obj"] == ref and got["raw"] == ref
    assert [d for d, _ in got["info"]] == ref
    seq = [s for _, s in got["info"]]
    assert seq == sorted(seq) and len(set(seq)) == 500      # the publisher's sequence
    assert got["b"] == [[float(i), -float(i)] for i in range(500)]


@pytest.mark.ros
def test_the_same_as_rclpys_executor(ctx):
    ours = _received(ctx, TwinExecutor, 200)
    c2 = Context()
    rclpy.init(context=c2)
    try:
        theirs = _received(c2, SingleThreadedExecutor, 200)
    finally:
        rclpy.shutdown(context=c2)
    assert ours["obj"] == theirs["obj"] and ours["b"] == theirs["b"]
    assert ours["raw"] == theirs["raw"]


@pytest.mark.ros
def test_timers_fire_at_their_period_and_stop_when_cancelled(ctx):
    node = rclpy.create_node("t", context=ctx)
    calls = []
    timer = node.create_timer(0.01, lambda: calls.append(time.monotonic()))
    exe = TwinExecutor(ctx)
    exe.add_node(node)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.5:
        exe.spin_once(timeout_sec=0.05)
    n = len(calls)
    assert 25 <= n <= 51                    # 50 periods; a loaded machine may miss some
    timer.cancel()
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.1:
        exe.spin_once(timeout_sec=0.02)
    assert len(calls) == n
    node.destroy_node()


@pytest.mark.ros
def test_a_node_destroyed_by_a_callback_is_not_called_again(ctx):
    pub_node = rclpy.create_node("p", context=ctx)
    node = rclpy.create_node("victim", context=ctx)
    seen = []

    def cb(m):
        seen.append(m.data)
        node.destroy_node()                 # what a crashing node amounts to

    node.create_subscription(Int32, "x", cb, QOS)
    pub = pub_node.create_publisher(Int32, "x", QOS)
    exe = TwinExecutor(ctx)
    exe.add_node(node)
    t0 = time.monotonic()
    while pub.get_subscription_count() < 1 and time.monotonic() - t0 < 30:
        exe.spin_once(timeout_sec=0.01)
    for i in range(5):
        pub.publish(Int32(data=i))
    t0 = time.monotonic()
    while not seen and time.monotonic() - t0 < 10:
        exe.spin_once(timeout_sec=0.01)
    exe.remove_node(node)
    for _ in range(5):
        exe.spin_once(timeout_sec=0.01)
    assert seen == [0]
    pub_node.destroy_node()
