"""The intra-process bus of the one-process graph (flexarm_ros/nodes/intraprocess.py):
the same bag as DDS delivery, byte for byte; no DDS reader between the process's own
nodes; every message still on DDS while a foreign subscriber is there; bytes that are not a
message dropped with a count, nothing changed."""

import contextlib
import json
import time

import pytest
from mcap.reader import make_reader

pytest.importorskip("rclpy")

from flexarm_ros.twin import topics as T  # noqa: E402
from flexarm_ros.twin.validation import FOREIGN, NOT_CDR  # noqa: E402

NS = "/flexarm"


def _graph(**kw):
    from flexarm_ros.run import InProcessGraph
    return InProcessGraph(namespace=NS, **kw)


@contextlib.contextmanager
def _outside_node(g, name):
    """A node of a user's own (its own rclpy context) in NS on ``g``'s domain; on exit
    ``g`` closes, then that context shuts down."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    ctx = Context()
    rclpy.init(context=ctx, domain_id=g.context.get_domain_id())
    try:
        yield Node(name, namespace=NS, context=ctx)
    finally:
        g.close()
        rclpy.shutdown(context=ctx)


def _lockstep(path, intraprocess, duration=0.05):
    g = _graph(scene="two_link_case1", mode="lockstep", duration=duration, record=path,
               intraprocess=intraprocess)
    try:
        sim = g["simulator"]
        assert g.spin_until(lambda: sim.finished, 120)
        sim.finish(g.executor)
        assert g.spin_until(g.recorded_all, 30)
        dds_readers = {t: p.pub.get_subscription_count() if hasattr(p, "pub")
                       else p.get_subscription_count() for t, p in sim.pubs.items()}
    finally:
        g.close()
    out = {}
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(ch.topic, []).append((m.log_time, m.data))
    return out, dds_readers


@pytest.mark.ros
@pytest.mark.subprocess
def test_the_bus_records_the_same_bag_as_dds_byte_for_byte(tmp_path):
    """Lockstep two_link_case1, 50 ticks, all nodes in one process: with the bus and with
    DDS between the nodes, every topic holds the same messages at the same log times —
    and with the bus no DDS reader sits on the simulator's topics (the recorder, the
    driver and the controller take them from the bus)."""
    bus, readers_bus = _lockstep(tmp_path / "bus.mcap", True)
    dds, readers_dds = _lockstep(tmp_path / "dds.mcap", False)
    assert set(bus) == set(dds)
    for topic in dds:
        assert bus[topic] == dds[topic], topic
    assert len(bus[T.resolve(NS, T.JOINT_STATES)]) == 51
    assert set(readers_bus.values()) == {0}
    assert readers_dds[T.JOINT_STATES] == 2 and readers_dds[T.GT_JOINT_STATES] == 2


@pytest.mark.ros
@pytest.mark.subprocess
def test_a_foreign_subscriber_still_gets_every_message_on_dds(tmp_path):
    """A node in another DDS participant (another context) subscribing to joint_states
    receives the twin's messages while the twin's own nodes use the bus."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from flexarm_ros.nodes.common import QOS
    g = _graph(scene="two_link_case1", mode="lockstep", duration=0.05,
               record=tmp_path / "x.mcap")
    ctx = Context()
    rclpy.init(context=ctx, domain_id=g.context.get_domain_id())
    try:
        node = Node("echo", namespace=NS, context=ctx)
        got = []
        node.create_subscription(JointState, T.JOINT_STATES, got.append, QOS)
        pub = g["simulator"].pubs[T.JOINT_STATES]
        # matched before the graph spins (the twin starts on its first spin, and DDS
        # discovery needs no spinning): a reader that matched later would miss the start
        t0 = time.monotonic()
        while pub.pub.get_subscription_count() < 1 and time.monotonic() - t0 < 20:
            time.sleep(0.01)
        assert pub.pub.get_subscription_count() >= 1
        sim = g["simulator"]
        assert g.spin_until(lambda: sim.finished, 120)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        t0 = time.monotonic()
        while len(got) < 51 and time.monotonic() - t0 < 20:
            ex.spin_once(timeout_sec=0.05)
        ex.shutdown()
        assert len(got) == 51
        assert [m.header.stamp.nanosec for m in got[:3]] == [0, 1_000_000, 2_000_000]
    finally:
        g.close()
        rclpy.shutdown(context=ctx)


@pytest.mark.ros
@pytest.mark.subprocess
def test_bytes_that_are_not_a_message_change_nothing(tmp_path, capfd):
    """Garbage published raw on effort_controller/commands by a foreign node: the simulator
    refuses it as a second publisher's, counted with the other rejections (the run summary
    shows them), never a crash; the recorder puts it in diagnostics/rejected without rmw
    printing a deserialization error per message; the lockstep bag still equals the
    co-simulation on joint_states."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray
    from flexarm_ros.nodes.common import QOS
    from flexarm_ros.scene import load_scene
    from flexarm_ros.twin.cosim import cosimulate
    from flexarm_ros.bag.writer import encode_cdr
    path = tmp_path / "g.mcap"
    g = _graph(scene="two_link_case1", mode="lockstep", duration=0.05, record=path)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=g.context.get_domain_id())
    try:
        node = Node("garbage", namespace=NS, context=ctx)
        pub = node.create_publisher(Float64MultiArray, T.EFFORTS, QOS)
        sim = g["simulator"]
        # the simulator's DDS reader opens once the graph shows this second publisher
        assert g.spin_until(lambda: sim._effort_sub.dds is not None, 30)
        # both DDS readers matched — the simulator's and the recorder's, which records the
        # rejections (a full suite's load once let the junk go before the recorder's
        # reader matched: a late-joining volatile reader, 2 of 3 rejections in the bag)
        assert g.spin_until(lambda: pub.get_subscription_count() >= 2, 20)
        for junk in (b"\x00\x01\x00\x00\xff\xff\xff\x7f", b"\x00\x01", b"\x00\x01\x00\x00"):
            pub.publish(junk)
        assert g.spin_until(lambda: getattr(sim, "undecodable", 0) >= 3, 30)
        # and the recorder, which records them in diagnostics/rejected, has taken them
        rec = g["recorder"]
        assert g.spin_until(lambda: rec.rejections.total() >= 3, 30)
        assert g.spin_until(lambda: sim.finished, 120)
        sim.finish(g.executor)
        assert g.spin_until(g.recorded_all, 30)
    finally:
        g.close()
        rclpy.shutdown(context=ctx)
    assert sim.undecodable == 3 and sim.core.k == 50
    assert dict(sim.core.validator.counts) == {FOREIGN: 3}
    assert "exceeds remaining buffer" not in capfd.readouterr().err
    from flexarm_ros.bag import read_bag
    rej = [json.loads(m.data) for _, m in read_bag(path)[T.resolve(NS, T.REJECTED)]]
    assert [(r["topic"], r["reason"]) for r in rej] == [(T.resolve(NS, T.EFFORTS), FOREIGN)] * 3
    ref = [(m.t_ns, encode_cdr(m.msgtype, m.data))
           for m in cosimulate(load_scene("two_link_case1"), 0.05).topic(T.JOINT_STATES)]
    with open(path, "rb") as f:
        got = [(m.log_time, m.data) for _, ch, m in make_reader(f).iter_messages(
            log_time_order=False) if ch.topic == T.resolve(NS, T.JOINT_STATES)]
    assert got == ref


@pytest.mark.ros
def test_bytes_that_are_not_a_command_from_the_only_publisher_are_rejected(tmp_path):
    """Without the twin's controller, a node that sends only bytes that are not a
    Float64MultiArray on motor_driver/commands: the driver rejects each (``not a CDR
    message of its type``, counted with the other rejections; the junk never makes its
    publisher the topic's owner) and nothing steps — lockstep stays at tick 0."""
    from std_msgs.msg import Float64MultiArray
    from flexarm_ros.nodes.common import QOS
    g = _graph(scene="two_link_case1", mode="lockstep", duration=0.05, record=None,
               nodes=("simulator", "motor_driver"))
    with _outside_node(g, "junk_controller") as node:
        pub = node.create_publisher(Float64MultiArray, T.COMMANDS, QOS)
        assert g.spin_until(lambda: pub.get_subscription_count() >= 1, 30)
        for junk in (b"\x00\x01\x00\x00\xff\xff\xff\x7f", b"\x00\x01", b"\x00\x01\x00\x00"):
            pub.publish(junk)
        drv, sim = g["motor_driver"], g["simulator"]
        assert g.spin_until(lambda: getattr(drv, "undecodable", 0) >= 3, 30)
        assert not g.spin_until(lambda: sim.core.k > 0, 1.0)
    assert dict(drv.core.validator.counts) == {NOT_CDR: 3}
    assert drv.source.owner == set() and sim.core.k == 0


def test_an_unusable_profile_dir_is_named_and_does_not_stop_the_node(tmp_path, monkeypatch,
                                                                     capsys):
    """FLEXARM_PROFILE_DIR pointing at a file: a message naming the variable, the value and
    the expectation; the spinning runs unprofiled. A usable one gets the profile."""
    from flexarm_ros.nodes.common import PROFILE_ENV, profiled
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv(PROFILE_ENV, str(blocker / "prof"))
    with profiled("simulator") as p:
        sum(range(10))
    err = capsys.readouterr().err
    assert PROFILE_ENV in err and str(blocker / "prof") in err and "writable directory" in err
    assert p.path is None and p.prof is None
    monkeypatch.setenv(PROFILE_ENV, str(tmp_path / "prof"))
    with profiled("simulator"):
        sum(range(10))
    import pstats
    assert pstats.Stats(str(tmp_path / "prof" / "simulator.prof")).total_calls > 0


def test_a_publisher_announced_over_the_bridge_is_the_expected_source_before_dds_shows_it():
    """--layout split: the simulator's process announces each publisher (topic, GID, node,
    namespace) on the bridge; the other process's source rule takes it as the expected
    node's at once, with a DDS graph that does not show it yet. (Before session 11 the
    rule waited for discovery, 0.5 s per GID and topic, and the driver answered no state
    for ~6 s in about half of the split realtime runs.)"""
    import socket
    import threading
    from types import SimpleNamespace

    from flexarm_ros.nodes import _wire, intraprocess
    from flexarm_ros.nodes.bridge import Bridge

    topic, gid = f"{NS}/{T.JOINT_STATES}", bytes(range(24))
    class Pub:                                   # what the bridge reads of a BusPublisher
        node = SimpleNamespace(get_name=lambda: "simulator", get_namespace=lambda: NS)

    pub = Pub()
    pub.topic, pub.gid = topic, gid
    sim_bus = SimpleNamespace(subs={}, pubs={topic: [pub]}, guard=None)
    here = SimpleNamespace(subs={}, pubs={}, guard=SimpleNamespace(
        trigger_guard_condition=lambda: None))
    a, b = socket.socketpair()
    receiving = Bridge(here, b)
    sending = Bridge(sim_bus, a)                 # announces its publisher at once
    class Context:                               # a key of the bus table (weakly held)
        pass

    context = Context()
    bus = SimpleNamespace(bridge=receiving, pubs={})
    bus.local_publishers = lambda *a: intraprocess.Bus.local_publishers(bus, *a)
    intraprocess._BUSES[context] = bus
    dds_asked = threading.Event()

    class Driver:                                # a subscriber whose DDS graph is empty
        def __init__(self):
            self.context = context

        def get_namespace(self):
            return NS

        def get_publishers_info_by_topic(self, t):
            dds_asked.set()
            return []

        def count_publishers(self, t):
            return 0

    try:
        t0 = time.monotonic()
        while gid not in receiving.remote_names and time.monotonic() - t0 < 10:
            time.sleep(0.01)
        assert receiving.remote_names[gid] == ("simulator", NS)
        src = _wire.Source(Driver(), topic, expected="simulator")
        info = {"publisher_gid": {"data": gid}}
        assert src.verdict(info) is None
        assert src.trusted(info) and src.owner == {gid} and dds_asked.is_set()
        assert gid not in src._waited          # taken without waiting for discovery
        # another GID on the topic is a second publisher: refused
        assert src.verdict({"publisher_gid": {"data": bytes(24)}}) == "an unknown node"
    finally:
        del intraprocess._BUSES[context]
        sending.close()
        receiving.close()


def test_a_message_goes_on_dds_only_while_a_dds_reader_is_there(monkeypatch):
    """BusPublisher: with no DDS reader the message goes only to the in-process
    subscribers; a reader that appears is served from the next graph look-up on
    (GRAPH_POLL_S of wall time), and one that leaves stops it the same way."""
    from types import SimpleNamespace
    from flexarm_ros.nodes import intraprocess as ip
    clock = [100.0]
    monkeypatch.setattr(ip.time, "monotonic", lambda: clock[0])
    readers, sent = [0], []
    fake = SimpleNamespace(topic_name="/flexarm/joint_states", publish=sent.append,
                           get_subscription_count=lambda: readers[0])
    bus = SimpleNamespace(pubs={}, subs={}, bridge=None)
    pub = ip.BusPublisher(bus, None, fake)
    pub.publish(b"a")
    readers[0] = 1                        # a reader matches
    pub.publish(b"b")                     # not looked up yet
    clock[0] += ip.GRAPH_POLL_S
    pub.publish(b"c")
    pub.publish(b"d")
    readers[0] = 0
    clock[0] += ip.GRAPH_POLL_S
    pub.publish(b"e")
    assert sent == [b"c", b"d"]


def test_the_bus_keeps_each_subscriptions_qos_depth_and_counts_what_it_drops():
    """KEEP_LAST as DDS keeps it (issue 38: the bus's queue had been unbounded where the
    QoS said KEEP_LAST(depth)): a subscription of depth 3 that is not served while five
    messages arrive gets the newest three, in order, and counts two dropped; one of depth
    10 on the same topic gets all five; deliveries run in arrival order across topics; a
    post from another thread wakes the executor (rclpy's public Executor.wake)."""
    from types import SimpleNamespace
    from flexarm_ros.nodes import intraprocess as ip
    warned = []
    node = SimpleNamespace(get_logger=lambda: SimpleNamespace(warning=warned.append))
    bus = ip.Bus(None, [])
    woken = []
    bus.waker = lambda: woken.append(1)
    got = []
    a = ip.BusSubscription(bus, node, object, "/t", lambda m, i: got.append(("a", m)), True,
                           SimpleNamespace(depth=3), None)
    b = ip.BusSubscription(bus, node, object, "/t", lambda m, i: got.append(("b", m)), True,
                           SimpleNamespace(depth=10), None)
    c = ip.BusSubscription(bus, node, object, "/u", lambda m, i: got.append(("c", m)), True,
                           SimpleNamespace(depth=10), None)
    for k in range(5):
        bus.post("/t", bytes([k]), {})
    bus.post("/u", b"u", {})
    assert woken == [1]                   # the first post woke it; the queue was not empty
    assert (a.dropped, b.dropped, c.dropped) == (2, 0, 0) and len(warned) == 1
    assert "/t: 3 messages waiting (the QoS depth)" in warned[0]
    bus.deliver()
    assert [m for w, m in got if w == "a"] == [bytes([2]), bytes([3]), bytes([4])]
    assert [m for w, m in got if w == "b"] == [bytes([k]) for k in range(5)]
    assert got[-1] == ("c", b"u") and not bus.queue


def test_a_subscription_counts_matched_publishers_not_the_graphs():
    """BusSubscription.get_publisher_count means what rclpy's does: publishers matched
    with it. A foreign publisher the graph shows is not matched before the DDS reader is
    open (session 20: the lockstep simulator started on the graph's count and missed the
    first answer of an amplifier in another process)."""
    from types import SimpleNamespace
    from flexarm_ros.nodes import intraprocess as ip
    topic = f"{NS}/{T.EFFORTS}"
    node = SimpleNamespace(count_publishers=lambda t: 1)          # the graph shows one
    bus = SimpleNamespace(pubs={}, subs={}, bridge=None)
    sub = ip.BusSubscription(bus, node, object, topic, lambda m: None, True, None, None)
    assert sub.get_publisher_count() == 0                         # no reader yet
    sub.dds = SimpleNamespace(get_publisher_count=lambda: 1)
    assert sub.get_publisher_count() == 1                         # the reader matched it
    bus.pubs[topic] = ["a local driver", "and another"]
    assert sub.get_publisher_count() == 2                         # in-process ones count
    bus.bridge = SimpleNamespace(remote_publishers=lambda t: 1)
    assert sub.get_publisher_count() == 3                         # and bridged ones


@pytest.mark.ros
def test_lockstep_does_not_start_before_its_effort_input_is_matched():
    """Without the twin's driver, an outside node that reads ground_truth/joint_states but
    publishes no effort yet: the lockstep simulator does not publish its first state (it
    could not hear the answer) and names the missing input; the outside publisher's
    appearance starts it."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    from flexarm_ros.nodes.common import QOS
    g = _graph(scene="two_link_case1", mode="lockstep", duration=0.05, record=None,
               nodes=("simulator", "controller"))
    with _outside_node(g, "outside_amplifier") as node:
        node.create_subscription(JointState, T.GT_JOINT_STATES, lambda m: None, QOS)
        node.create_subscription(Float64MultiArray, T.COMMANDS, lambda m: None, QOS)
        sim = g["simulator"]
        sent = lambda: sum(sim.published.values())             # noqa: E731
        # the rest of the start condition is met: the simulator's ground truth has its
        # subscriber; only the effort input is missing
        assert g.spin_until(lambda: sim.pubs[T.GT_JOINT_STATES].get_subscription_count()
                            >= 1, 30)
        assert not g.spin_until(sent, 1.0)
        assert sim.ready.missing == [f"{NS}/{T.EFFORTS} (0/1 publishers matched: the motor "
                                     f"driver or an amplifier of yours)"], sim.ready.missing
        node.create_publisher(Float64MultiArray, T.EFFORTS, QOS)
        assert g.spin_until(sent, 30)
