"""The twin's wire bytes: the one CDR encoder (``encode_cdr``, used by the nodes'
``publish(bytes)`` and by the bags) against rclpy's own serializer for every message type
the twin publishes, on real twin messages and on edge cases.

rclpy's bytes differ from ours only in alignment padding (rmw leaves it uninitialized, we
write zeros) and in the trailing padding of a message whose size is not a multiple of 4
(std_msgs/Bool: 5 bytes from us, 8 from rclpy). So: every byte where the two differ is a
zero of ours (padding), lengths agree up to that trailing padding, and rclpy deserializes
our bytes to the original message exactly (floats bit for bit)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

pytest.importorskip("rclpy")

import flexarm_ros.nodes.common  # noqa: E402,F401  (loads rclpy's type support quietly)
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402

from flexarm_ros.bag import messages as msg  # noqa: E402
from flexarm_ros.bag.writer import encode_cdr  # noqa: E402
from flexarm_ros.nodes._msgconv import msg_class, to_dict, to_msg  # noqa: E402
from flexarm_ros.scene import load_scene  # noqa: E402
from flexarm_ros.twin import topics as T  # noqa: E402
from flexarm_ros.twin.cosim import Lockstep  # noqa: E402

BIG = 1.7976931348623157e308
TINY = 5e-324


def _same(a, b) -> bool:
    """Message dicts equal, floats compared bit for bit (so -0.0 ≠ 0.0)."""
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def _check(msgtype: str, data: dict):
    ours = encode_cdr(msgtype, data)
    # the nodes' path (compiled per type, no validation) gives the very same bytes
    assert encode_cdr(msgtype, data, validate=False) == ours, msgtype
    theirs = serialize_message(to_msg(msgtype, data))
    back = deserialize_message(ours, msg_class(msgtype))
    assert _same(to_dict(back), to_dict(to_msg(msgtype, data))), msgtype
    if _empty_float_sequence(data):
        # Fast-CDR aligns a zero-length float64 sequence to 8 bytes, we (as rosbags and
        # mcap_ros2) do not: both are read back the same (checked above)
        return
    n = len(ours)
    assert len(theirs) == n or (n % 4 and len(theirs) == n + 4 - n % 4), \
        (msgtype, n, len(theirs))
    diff = [i for i in range(n) if ours[i] != theirs[i]]
    assert all(ours[i] == 0 for i in diff), (msgtype, diff)


def _empty_float_sequence(data) -> bool:
    if isinstance(data, dict):
        return any(_empty_float_sequence(v) for v in data.values())
    if isinstance(data, np.ndarray):
        return data.size == 0 and data.dtype.kind == "f"
    if isinstance(data, list):
        return len(data) == 0
    return False


def _twin_messages():
    """(type, dict) of every topic of a running twin: simulator, controller, driver."""
    ls = Lockstep(load_scene("two_link_case1"))
    out = {}
    for _ in range(3):
        for m in ls.tick():
            out[m.topic] = (m.msgtype, m.data)
    return out


def test_every_topic_of_the_twin():
    msgs = _twin_messages()
    assert set(msgs) >= {T.CLOCK, T.JOINT_STATES, T.ENCODER_COUNTS, T.ACCEL_BATCH,
                         T.TOOL_CONTACT, T.TOOL_WRENCH, T.GT_JOINT_STATES, T.GT_TIP,
                         T.GT_COORDINATES, T.COMMANDS, T.EFFORTS, T.MOTOR_STATES}
    for topic, (tp, data) in msgs.items():
        _check(tp, data)


@pytest.mark.parametrize("case", [
    ("rosgraph_msgs/msg/Clock", msg.clock(0)),
    ("rosgraph_msgs/msg/Clock", msg.clock(2**31 * 10**9 - 1)),
    ("sensor_msgs/msg/JointState", msg.joint_state(1, [], [], [], [])),
    ("sensor_msgs/msg/JointState", msg.joint_state(123456789, ["a"], [BIG], [-TINY], [-0.0])),
    ("sensor_msgs/msg/JointState", msg.joint_state(7, ["gelenk_ä", "x" * 37, ""],
                                                   [1.0, -BIG, TINY], [0.5, 0.25, 3.0],
                                                   [math.pi, -math.e, 1e-300])),
    ("std_msgs/msg/Float64MultiArray", msg.float64_multiarray(np.zeros(0), ("joint",))),
    ("std_msgs/msg/Float64MultiArray", msg.float64_multiarray(np.array([[BIG, -BIG],
                                                                        [TINY, 0.0]]),
                                                              ("sample", "channel"))),
    ("std_msgs/msg/Int32MultiArray", msg.int32_multiarray(
        np.array([-2**31, 2**31 - 1, 0], dtype=np.int64), "joint")),
    ("std_msgs/msg/Int32MultiArray", msg.int32_multiarray(np.zeros(0, dtype=np.int64),
                                                          "joint")),
    ("std_msgs/msg/Bool", {"data": True}),
    ("std_msgs/msg/Bool", {"data": False}),
    ("geometry_msgs/msg/WrenchStamped", msg.wrench_stamped(5, "wall", (BIG, -TINY, 0.0),
                                                           (1.0, 2.0, 3.0))),
    ("geometry_msgs/msg/PointStamped", msg.point_stamped(9, "", (1e-3, -1e3, 0.0))),
    ("std_msgs/msg/String", {"data": ""}),
    ("std_msgs/msg/String", {"data": '{"topic": "/flexarm/x", "reason": "non-finite ü"}'}),
], ids=lambda c: c[0].split("/")[-1])
def test_edge_cases(case):
    _check(*case)


def test_a_raw_recorded_twin_bag_reads_the_same_with_mcap_ros2_and_rosbags(tmp_path):
    """Bytes written as received (BagWriter.write_raw) decode with the other readers to
    the values the twin published."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader

    from flexarm_ros.bag import BagWriter
    path = tmp_path / "raw.mcap"
    msgs = _twin_messages()
    with BagWriter(path) as w:
        for topic, (tp, data) in msgs.items():
            w.write_raw(T.resolve("/flexarm", topic), tp, encode_cdr(tp, data), 1000)
    seen = 0
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, decoded in reader.iter_decoded_messages():
            topic = channel.topic.removeprefix("/flexarm/")
            tp, data = msgs[topic if topic in msgs else channel.topic]
            if "position" in data:
                assert list(decoded.position) == list(data["position"])
            elif isinstance(data.get("data"), list):
                assert list(decoded.data) == list(data["data"])
            seen += 1
    assert seen == len(msgs)
    with AnyReader([path]) as reader:
        n = 0
        for conn, _, raw in reader.messages():
            decoded = reader.deserialize(raw, conn.msgtype)
            topic = conn.topic.removeprefix("/flexarm/")
            tp, data = msgs[topic if topic in msgs else conn.topic]
            if "position" in data:
                assert list(decoded.position) == list(data["position"])
            n += 1
    assert n == len(msgs)


def test_write_raw_refuses_bytes_that_are_not_little_endian_cdr(tmp_path):
    from flexarm_ros.bag import BagWriter
    with BagWriter(tmp_path / "x.mcap") as w:
        with pytest.raises(ValueError, match="little-endian CDR"):
            w.write_raw("/x", "std_msgs/msg/Bool", b"\x00\x00\x00\x00\x01", 0)
        with pytest.raises(ValueError, match="unknown message type"):
            w.write_raw("/x", "std_msgs/msg/Nope", b"\x00\x01\x00\x00\x01", 0)


# ----------------------------------------------------------- bytes without dicts
_BUILD_CASES = [
    ("clock", (0,)), ("clock", (2**31 * 10**9 - 1,)), ("clock", (-1,)),
    ("joint_state", (1, [], [], [], [])),
    ("joint_state", (123456789, ["a"], [BIG], [-TINY], [-0.0])),
    ("joint_state", (7, ["gelenk_ä", "x" * 37, ""], [1.0, -BIG, TINY], [0.5, 0.25, 3.0],
                     [math.pi, -math.e, 1e-300], "frame")),
    ("float64_multiarray", (np.zeros(0), ("joint",))),
    ("float64_multiarray", (np.array([[BIG, -BIG], [TINY, 0.0]]), ("sample", "channel"))),
    ("float64_multiarray", (np.arange(12.0).reshape(3, 4), ("sample", "channel"))),
    ("int32_multiarray", (np.array([-2**31, 2**31 - 1, 0], dtype=np.int64), "joint")),
    ("int32_multiarray", (np.zeros(0, dtype=np.int64), "joint")),
    ("boolean", (True,)), ("boolean", (False,)),
    ("wrench_stamped", (5, "wall", (BIG, -TINY, 0.0), (1.0, 2.0, 3.0))),
    ("point_stamped", (9, "", (1e-3, -1e3, 0.0))),
]
_TYPE_OF = {"clock": "rosgraph_msgs/msg/Clock", "joint_state": "sensor_msgs/msg/JointState",
            "float64_multiarray": "std_msgs/msg/Float64MultiArray",
            "int32_multiarray": "std_msgs/msg/Int32MultiArray", "boolean": "std_msgs/msg/Bool",
            "wrench_stamped": "geometry_msgs/msg/WrenchStamped",
            "point_stamped": "geometry_msgs/msg/PointStamped"}


@pytest.mark.parametrize("case", _BUILD_CASES, ids=lambda c: c[0])
def test_the_fixed_shape_builder_gives_the_encoders_bytes(case):
    """bag.cdr_fixed.CdrBuilder (the simulator's wire path: templates per shape, numbers
    packed in) = encode_cdr of the messages module's dict, byte for byte — twice through
    the same builder, so a cached template serves a second message too."""
    from flexarm_ros.bag.cdr_fixed import CdrBuilder
    fn, args = case
    b = CdrBuilder()
    want = encode_cdr(_TYPE_OF[fn], getattr(msg, fn)(*args))
    assert getattr(b, fn)(*args) == want
    assert getattr(b, fn)(*args) == want


@pytest.mark.heavy
def test_the_simulators_wire_bytes_equal_the_encoded_dicts_through_an_impact():
    """The simulator core's outputs built as CDR bytes (what the node publishes) against
    the same outputs built as dicts and encoded by encode_cdr (itself checked against
    rclpy above), tick by tick through free flight, the impact and sliding: two cores
    stepped alike (outputs() advances the rate estimate and empties the batches)."""
    from flexarm_ros.bag.cdr_fixed import CdrBuilder
    from flexarm_ros.twin.cores import SimulatorCore
    sc = load_scene("two_link_case1")
    a, b = SimulatorCore(sc), SimulatorCore(sc)
    build = CdrBuilder()
    tau = np.array([7.0, 2.0])
    seen = set()
    for k in range(1900):
        if k % 3 == 0 or k > 1350:          # every tick around the impact (t ≈ 1.41 s)
            gt = k % 2 == 0
            da = a.outputs(ground_truth=gt)
            db = b.outputs(ground_truth=gt, build=build)
            assert [o[0] for o in da] == [o[0] for o in db]
            for (topic, tp, data), (_, _, raw) in zip(da, db):
                assert raw == encode_cdr(tp, data), (k, topic)
                seen.add(topic)
        a.step(tau)
        b.step(tau)
    assert a.plant.stepper.impacts, "the comparison must go through an impact"
    assert seen >= {T.CLOCK, T.JOINT_STATES, T.ENCODER_COUNTS, T.ACCEL_BATCH, T.TOOL_CONTACT,
                    T.TOOL_WRENCH, T.GT_JOINT_STATES, T.GT_TIP, T.GT_COORDINATES}
