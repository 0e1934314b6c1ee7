"""CDR bytes of the twin's own messages straight from their values, without a message
dict: a builder with the functions of :mod:`flexarm_ros.bag.messages` (same arguments)
that returns serialized CDR (little-endian XCDR1, the 4-byte encapsulation header first)
instead of a dict.

Every message the simulator publishes has a fixed shape for a run (the same joint names,
frame ids, array shapes tick after tick), so its bytes are a template — strings, sequence
lengths and padding encoded once per shape — into which each tick packs its numbers at
known offsets (``struct.pack_into``). The result is byte-identical to
``encode_cdr(type, messages.<fn>(…))``, which is itself tested against rclpy's
``serialize_message`` (``test/test_cdr_wire.py``); the simulator node publishes these
bytes (one dict and one plan walk less per message on its tick).

CDR rules used (OMG CDR, ROS 2's rmw serialization): a primitive is aligned to its size
from the start of the payload (after the header); a string is a uint32 length counting
its terminating NUL, the bytes and the NUL; a sequence is a uint32 count and its
elements; a bool is one byte.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

__all__ = ["CdrBuilder"]

_HEADER = b"\x00\x01\x00\x00"


class _Template:
    """Bytes under construction with the payload offset of every numeric slot."""

    def __init__(self):
        self.buf = bytearray(_HEADER)

    @property
    def offset(self) -> int:                     # payload offset (after the header)
        return len(self.buf) - len(_HEADER)

    def align(self, n: int) -> None:
        self.buf += b"\x00" * ((-self.offset) % n)

    def slot(self, code: str, count: int = 1) -> int:
        """Room for ``count`` values of struct ``code`` (aligned); its buffer index."""
        size = struct.calcsize("<" + code)
        if count == 0:                   # an empty sequence: no padding after its count
            return len(self.buf)
        self.align(size)
        at = len(self.buf)
        self.buf += b"\x00" * (size * count)
        return at

    def u32(self, value: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", value)

    def string(self, text: str) -> None:
        data = text.encode("utf-8")
        self.u32(len(data) + 1)
        self.buf += data + b"\x00"

    def stamp(self) -> int:
        """A builtin_interfaces/Time slot (int32 sec, uint32 nanosec)."""
        at = self.slot("i")
        self.slot("I")
        return at

    def header(self, frame_id: str) -> int:
        at = self.stamp()
        self.string(frame_id)
        return at

    def layout(self, shape: tuple, labels: tuple) -> None:
        """std_msgs/MultiArrayLayout of a row-major array (as messages._layout)."""
        self.u32(len(labels))
        for i, label in enumerate(labels):
            self.string(str(label))
            self.u32(int(shape[i]))
            stride = 1
            for s in shape[i:]:
                stride *= int(s)
            self.u32(stride)
        self.u32(0)                              # data_offset


_STAMP = struct.Struct("<iI")


def _sec_nsec(t_ns: int) -> tuple:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    if not -(2**31) <= sec < 2**31:
        raise ValueError(f"stamp: {t_ns} ns does not fit builtin_interfaces/Time (int32 sec)")
    return sec, nsec


class CdrBuilder:
    """The :mod:`messages` constructors the simulator uses, returning CDR bytes; templates
    are cached per shape (joint names, frame id, array shape)."""

    def __init__(self):
        self._cache: dict = {}

    def _template(self, key, make):
        t = self._cache.get(key)
        if t is None:
            t = self._cache[key] = make()
        return t

    # ------------------------------------------------------------------ messages
    def clock(self, t_ns: int) -> bytes:
        """rosgraph_msgs/msg/Clock."""
        def make():
            tp = _Template()
            at = tp.stamp()
            return bytes(tp.buf), at
        buf, at = self._template(("clock",), make)
        out = bytearray(buf)
        _STAMP.pack_into(out, at, *_sec_nsec(t_ns))
        return bytes(out)

    def joint_state(self, t_ns: int, names: Sequence[str], position, velocity, effort,
                    frame_id: str = "") -> bytes:
        """sensor_msgs/msg/JointState (position, velocity, effort each of len(names))."""
        names = tuple(names)
        n = len(names)

        def make():
            tp = _Template()
            st = tp.header(frame_id)
            tp.u32(n)
            for nm in names:
                tp.string(str(nm))
            slots = []
            for _ in range(3):
                tp.u32(n)
                slots.append(tp.slot("d", n))
            return bytes(tp.buf), st, slots, struct.Struct(f"<{n}d")

        buf, st, slots, vec = self._template(("joint_state", frame_id, names), make)
        out = bytearray(buf)
        _STAMP.pack_into(out, st, *_sec_nsec(t_ns))
        for at, values in zip(slots, (position, velocity, effort)):
            vals = np.asarray(values, dtype=np.float64).tolist()
            if not isinstance(vals, list) or len(vals) != n:
                raise ValueError(f"joint_state: expected {n} values, got {values!r}")
            vec.pack_into(out, at, *vals)
        return bytes(out)

    def int32_multiarray(self, data, label: str) -> bytes:
        """std_msgs/msg/Int32MultiArray of a 1-D integer array."""
        arr = np.asarray(data)
        if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "iub"):
            raise ValueError(f"int32_multiarray: expected 1-D integers, got {arr.dtype} "
                             f"shape {arr.shape}")
        n = arr.shape[0]

        def make():
            tp = _Template()
            tp.layout((n,), (str(label),))
            tp.u32(n)
            at = tp.slot("i", n)
            return bytes(tp.buf), at, struct.Struct(f"<{n}i")

        buf, at, vec = self._template(("int32", str(label), n), make)
        out = bytearray(buf)
        vec.pack_into(out, at, *arr.tolist())       # struct.error beyond int32
        return bytes(out)

    def float64_multiarray(self, data, labels: Sequence[str]) -> bytes:
        """std_msgs/msg/Float64MultiArray of a 1-D or 2-D array, row-major."""
        arr = np.asarray(data, dtype=np.float64)
        labels = tuple(str(lb) for lb in labels)
        if arr.ndim not in (1, 2) or len(labels) != arr.ndim:
            raise ValueError(f"float64_multiarray: shape {arr.shape} with labels {labels!r}")
        shape = arr.shape

        def make():
            tp = _Template()
            tp.layout(shape, labels)
            tp.u32(arr.size)
            at = tp.slot("d", arr.size)
            return bytes(tp.buf), at, struct.Struct(f"<{arr.size}d")

        buf, at, vec = self._template(("float64", labels, shape), make)
        out = bytearray(buf)
        vec.pack_into(out, at, *arr.ravel(order="C").tolist())
        return bytes(out)

    def boolean(self, value) -> bytes:
        """std_msgs/msg/Bool."""
        return _HEADER + (b"\x01" if value else b"\x00")

    def wrench_stamped(self, t_ns: int, frame: str, force_xyz, torque_xyz) -> bytes:
        """geometry_msgs/msg/WrenchStamped."""
        return self._stamped_doubles(t_ns, frame, _VEC6, (*force_xyz, *torque_xyz))

    def point_stamped(self, t_ns: int, frame: str, xyz) -> bytes:
        """geometry_msgs/msg/PointStamped."""
        return self._stamped_doubles(t_ns, frame, _VEC3, xyz)

    def _stamped_doubles(self, t_ns: int, frame: str, vec: struct.Struct, values) -> bytes:
        """A header then a fixed block of doubles (the geometry_msgs *Stamped types here)."""
        n = vec.size // 8

        def make():
            tp = _Template()
            st = tp.header(frame)
            at = tp.slot("d", n)
            return bytes(tp.buf), st, at

        buf, st, at = self._template(("stamped", frame, n), make)
        out = bytearray(buf)
        _STAMP.pack_into(out, st, *_sec_nsec(t_ns))
        vec.pack_into(out, at, *(float(v) for v in values))
        return bytes(out)


_VEC3 = struct.Struct("<3d")
_VEC6 = struct.Struct("<6d")
