"""The node-side CDR readers (flexarm_ros.bag.cdr_read) against rclpy's serializer."""

import math
import random

import pytest

pytest.importorskip("rclpy")

from flexarm_ros.nodes import common  # noqa: E402,F401  (loads rosidl quietly first)
from rclpy.serialization import serialize_message  # noqa: E402

from flexarm_ros.bag.cdr_read import READERS, CdrError, decode  # noqa: E402
from flexarm_ros.nodes._msgconv import msg_class  # noqa: E402

EXTREMES = [0.0, -0.0, 1e-308, 5e-324, -1.7976931348623157e308, 1.7976931348623157e308,
            math.pi, -1.5]


def _arrays(rng):
    n = rng.choice([0, 1, 2, 3, 7, 16])
    return [rng.choice(EXTREMES) if rng.random() < 0.3 else rng.uniform(-1e3, 1e3)
            for _ in range(n)]


def _names(rng, n):
    return [rng.choice(["", "a", "link1_joint", "λ_ü", "x" * rng.randint(1, 9)])
            for _ in range(n)]


def _messages(rng):
    from builtin_interfaces.msg import Time
    F = msg_class("std_msgs/msg/Float64MultiArray")
    J = msg_class("sensor_msgs/msg/JointState")
    B = msg_class("std_msgs/msg/Bool")
    W = msg_class("geometry_msgs/msg/WrenchStamped")
    from std_msgs.msg import MultiArrayDimension
    f = F()
    f.data = _arrays(rng)
    f.layout.dim = [MultiArrayDimension(label=lab, size=rng.randint(0, 2**32 - 1),
                                        stride=rng.randint(0, 9))
                    for lab in _names(rng, rng.randint(0, 3))]
    f.layout.data_offset = rng.randint(0, 2**32 - 1)
    j = J()
    j.header.stamp = Time(sec=rng.randint(-2**31, 2**31 - 1), nanosec=rng.randint(0, 999999999))
    j.header.frame_id = rng.choice(["", "world", "wall_ü"])
    j.name = _names(rng, rng.randint(0, 5))
    j.position, j.velocity, j.effort = _arrays(rng), _arrays(rng), _arrays(rng)
    b = B(data=rng.random() < 0.5)
    w = W()
    w.header.stamp = Time(sec=rng.randint(0, 10**6), nanosec=rng.randint(0, 999999999))
    w.header.frame_id = rng.choice(["", "w", "wall", "abcdefg"])
    w.wrench.force.x, w.wrench.force.y, w.wrench.force.z = (rng.choice(EXTREMES)
                                                           for _ in range(3))
    w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = _arrays(rng)[:0] or \
        (rng.uniform(-1, 1), -0.0, 1e300)
    return {"std_msgs/msg/Float64MultiArray": f, "sensor_msgs/msg/JointState": j,
            "std_msgs/msg/Bool": b, "geometry_msgs/msg/WrenchStamped": w}


def _same(ours, theirs, path="m"):
    """Every field of rclpy's message equals ours (floats bit for bit, -0.0 kept)."""
    fields = getattr(theirs, "get_fields_and_field_types", None)
    if fields is not None:
        for name in fields():
            _same(getattr(ours, name), getattr(theirs, name), f"{path}.{name}")
        return
    if isinstance(theirs, (list, tuple)) or hasattr(theirs, "typecode"):
        theirs = list(theirs)
        assert len(ours) == len(theirs), path
        for k, (a, b) in enumerate(zip(ours, theirs)):
            _same(a, b, f"{path}[{k}]")
        return
    if isinstance(theirs, float):
        assert math.copysign(1, ours) == math.copysign(1, theirs) and ours == theirs, path
    else:
        assert ours == theirs, path


@pytest.mark.parametrize("seed", range(40))
def test_every_reader_gives_what_rclpy_serialized(seed):
    rng = random.Random(seed)
    for tp, m in _messages(rng).items():
        _same(decode(tp, serialize_message(m)), m)


def test_the_readers_cover_every_type_the_nodes_subscribe_to():
    from flexarm_ros.twin import topics as T
    taken = {T.TYPES[t] for t in (T.JOINT_STATES, T.TOOL_CONTACT, T.TOOL_WRENCH,
                                  T.GT_JOINT_STATES, T.COMMANDS, T.EFFORTS)}
    assert taken <= set(READERS)


#: payload offset of the first count or string length of each type (a value past the end)
_COUNT_AT = {"std_msgs/msg/Float64MultiArray": 4, "sensor_msgs/msg/JointState": 12,
             "geometry_msgs/msg/WrenchStamped": 12}


@pytest.mark.parametrize("tp", sorted(READERS))
def test_bytes_that_are_not_a_message_raise_cdr_error_never_anything_else(tp):
    """Every truncation of a valid message, a count or string length past the end, an
    unknown encapsulation, garbage: CdrError, never another exception or a message."""
    good = serialize_message(_messages(random.Random(3))[tp])
    # rmw pads a Bool to 8 bytes: its first 5 are the whole message
    end = 5 if tp == "std_msgs/msg/Bool" else len(good)
    cases = [good[:k] for k in range(end)] + [b"", b"\x00\x00\x00\x00" + good[4:]]
    if tp in _COUNT_AT:
        k = _COUNT_AT[tp]
        cases.append(good[:k] + b"\xff\xff\xff\x7f" + good[k + 4:])
    for data in cases:
        with pytest.raises(CdrError):
            decode(tp, data)


def test_repeated_layouts_and_names_decode_as_fresh_ones():
    """The readers recognise a Float64MultiArray layout or a JointState's names they parsed
    before by their bytes: messages that share them, or share only their start (a label
    one character longer, one more joint), still decode as rclpy serialized them."""
    from std_msgs.msg import MultiArrayDimension
    from builtin_interfaces.msg import Time
    F = msg_class("std_msgs/msg/Float64MultiArray")
    J = msg_class("sensor_msgs/msg/JointState")
    rng = random.Random(7)
    for k in range(200):
        f = F()
        f.layout.dim = [MultiArrayDimension(label=["joint", "joints", "j"][k % 3],
                                            size=k % 2 + 1, stride=1)]
        f.layout.data_offset = k % 4 // 2
        f.data = _arrays(rng)
        got = decode("std_msgs/msg/Float64MultiArray", serialize_message(f))
        assert got.data == tuple(f.data)
        assert [(d.label, d.size, d.stride) for d in got.layout.dim] == \
            [(d.label, d.size, d.stride) for d in f.layout.dim]
        assert got.layout.data_offset == f.layout.data_offset
        j = J()
        j.header.stamp = Time(sec=k, nanosec=rng.randint(0, 999999999))
        j.header.frame_id = ["", "world"][k % 2]
        j.name = ["l1_joint", "l2_joint", "l3_joint"][:1 + k % 3]
        j.position, j.velocity, j.effort = _arrays(rng), _arrays(rng), _arrays(rng)
        got = decode("sensor_msgs/msg/JointState", serialize_message(j))
        assert (got.header.stamp.sec, got.header.stamp.nanosec, got.header.frame_id) == \
            (k, j.header.stamp.nanosec, j.header.frame_id)
        assert got.name == list(j.name)
        assert (got.position, got.velocity, got.effort) == \
            (tuple(j.position), tuple(j.velocity), tuple(j.effort))
