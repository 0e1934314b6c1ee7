"""Decoding the CDR bytes of the messages the twin's nodes take, without rclpy's message
classes.

rclpy builds a message object per message (``deserialize_message``, or a subscription's
take): on the 2-core host that cost ~44 µs per JointState or Float64MultiArray, eight of
them per lockstep tick (cProfile, one-process graph,
docs/decisions/0008-an-intra-process-bus.md). These readers walk the same bytes with ``struct``
(little-endian XCDR1, the
rules in :mod:`flexarm_ros.bag.cdr_fixed`) into plain objects with the attribute paths
the nodes read (``m.data``, ``m.header.stamp.sec``, ``m.position``, ``m.wrench.force.x``,
…); float64 sequences come as tuples, names as lists of str. Tested against rclpy's
``serialize_message`` for every type here, empty sequences and extreme values included
(``test/test_cdr_read.py``).

Bytes that are not a message of the type (truncated, a count past the end, not UTF-8)
raise :class:`CdrError`; the subscription that reads them drops the message and says so
(:func:`flexarm_ros.nodes.common.subscription`).
"""

from __future__ import annotations

import struct
from types import SimpleNamespace

__all__ = ["CdrError", "READERS", "decode"]

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")


class CdrError(ValueError):
    """The bytes are not a CDR message of the expected type."""


class _Reader:
    __slots__ = ("b", "p", "end")

    def __init__(self, data: bytes):
        if len(data) < 4:
            raise CdrError(f"{len(data)} bytes: shorter than the CDR header")
        if data[1] != 1:
            raise CdrError(f"encapsulation {data[:2].hex()}: expected little-endian CDR "
                           "(00 01)")
        self.b, self.p, self.end = data, 4, len(data)

    def align(self, n: int) -> None:
        self.p += (-(self.p - 4)) % n

    def _need(self, n: int) -> None:
        if self.p + n > self.end:
            raise CdrError(f"truncated: {n} bytes needed at offset {self.p} of {self.end}")

    def u32(self) -> int:
        self.align(4)
        self._need(4)
        v = _U32.unpack_from(self.b, self.p)[0]
        self.p += 4
        return v

    def string(self) -> str:
        n = self.u32()
        if n == 0:
            return ""
        self._need(n)
        raw = self.b[self.p:self.p + n - 1]
        self.p += n
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CdrError(f"a string that is not UTF-8 ({exc})") from None

    def doubles(self, n: int) -> tuple:
        if n == 0:
            return ()
        self.align(8)
        self._need(8 * n)
        v = struct.unpack_from(f"<{n}d", self.b, self.p)
        self.p += 8 * n
        return v

    def double_seq(self) -> tuple:
        return self.doubles(self.u32())

    def stamp(self) -> SimpleNamespace:
        self.align(4)
        self._need(8)
        sec, nsec = _STAMP.unpack_from(self.b, self.p)
        self.p += 8
        return SimpleNamespace(sec=sec, nanosec=nsec)

    def header(self) -> SimpleNamespace:
        stamp = self.stamp()
        return SimpleNamespace(stamp=stamp, frame_id=self.string())


# The parts of a message that a publisher repeats unchanged (a Float64MultiArray's layout,
# a JointState's frame_id and joint names) are parsed once per distinct byte string and
# then recognised by comparing bytes: a prefix equal to one parsed before decodes to the
# same values and ends at the same offset. (cProfile of the one-process realtime graph:
# the layout's u32 and string reads were ~5 % of the tick, for 4 arrays per tick.)
_SEEN_MAX = 32
_LAYOUTS: dict = {}     # layout bytes (from offset 4) -> (layout, offset after it)
_NAMES: dict = {}       # bytes after the stamp through the names -> (frame_id, names, end)


def _float64_multiarray(data: bytes):
    for raw, (layout, p) in _LAYOUTS.items():
        if data.startswith(raw, 4):
            r = _Reader(data)
            r.p = p
            return SimpleNamespace(layout=layout, data=r.double_seq())
    r = _Reader(data)
    dims = []
    for _ in range(r.u32()):
        label = r.string()
        size, stride = r.u32(), r.u32()
        dims.append(SimpleNamespace(label=label, size=size, stride=stride))
    layout = SimpleNamespace(dim=dims, data_offset=r.u32())
    _remember(_LAYOUTS, bytes(data[4:r.p]), (layout, r.p))
    return SimpleNamespace(layout=layout, data=r.double_seq())


def _remember(seen: dict, key: bytes, value) -> None:
    if len(seen) >= _SEEN_MAX:
        seen.clear()
    seen[key] = value


def _joint_state(data: bytes):
    r = _Reader(data)
    stamp = r.stamp()
    for raw, (frame_id, names, p) in _NAMES.items():
        if data.startswith(raw, 12):
            r.p = p
            break
    else:
        frame_id = r.string()
        names = [r.string() for _ in range(r.u32())]
        _remember(_NAMES, bytes(data[12:r.p]), (frame_id, names, r.p))
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp, frame_id=frame_id),
                           name=list(names), position=r.double_seq(),
                           velocity=r.double_seq(), effort=r.double_seq())


def _bool(data: bytes):
    r = _Reader(data)
    r._need(1)
    return SimpleNamespace(data=data[4] != 0)


def _wrench_stamped(data: bytes):
    r = _Reader(data)
    header = r.header()
    f = r.doubles(3)
    t = r.doubles(3)
    wrench = SimpleNamespace(force=SimpleNamespace(x=f[0], y=f[1], z=f[2]),
                             torque=SimpleNamespace(x=t[0], y=t[1], z=t[2]))
    return SimpleNamespace(header=header, wrench=wrench)


READERS = {"std_msgs/msg/Float64MultiArray": _float64_multiarray,
           "sensor_msgs/msg/JointState": _joint_state,
           "std_msgs/msg/Bool": _bool,
           "geometry_msgs/msg/WrenchStamped": _wrench_stamped}
"""Type name → reader of its CDR bytes (the types the twin's nodes subscribe to)."""


def decode(msgtype: str, data: bytes):
    """The message in ``data`` as a plain object; :class:`CdrError` if it is not one."""
    try:
        return READERS[msgtype](data)
    except struct.error as exc:          # pragma: no cover - _need guards every read
        raise CdrError(str(exc)) from None
