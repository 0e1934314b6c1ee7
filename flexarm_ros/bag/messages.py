"""Constructors of plain-dict ROS 2 messages for :meth:`BagWriter.write`.

Every function returns a dict holding every field of its type (what the writer
requires), with numpy input converted to Python floats/ints.  Times are integer
nanoseconds; ``stamp`` splits them the ROS way (``nanosec`` in ``[0, 1e9)``, ``sec``
floored, so negative times are legal down to the int32 limit).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "boolean",
    "clock",
    "float64_multiarray",
    "header",
    "imu",
    "int32_multiarray",
    "joint_state",
    "point_stamped",
    "stamp",
    "wrench_stamped",
]


def stamp(t_ns: int) -> dict[str, int]:
    """``builtin_interfaces/msg/Time`` of ``t_ns`` nanoseconds."""
    if isinstance(t_ns, (bool, np.bool_)) or not isinstance(t_ns, numbers.Integral):
        raise TypeError(f"stamp: t_ns must be an integer (ns), got {type(t_ns).__name__}")
    sec, nanosec = divmod(int(t_ns), 1_000_000_000)
    if not -(2**31) <= sec < 2**31:
        raise ValueError(f"stamp: {t_ns} ns does not fit builtin_interfaces/Time (int32 sec)")
    return {"sec": sec, "nanosec": nanosec}


def header(t_ns: int, frame_id: str = "") -> dict[str, Any]:
    """``std_msgs/msg/Header``."""
    return {"stamp": stamp(t_ns), "frame_id": str(frame_id)}


def clock(t_ns: int) -> dict[str, Any]:
    """``rosgraph_msgs/msg/Clock`` (the ``/clock`` topic of simulated time)."""
    return {"clock": stamp(t_ns)}


def boolean(value: Any) -> dict[str, bool]:
    """``std_msgs/msg/Bool``."""
    return {"data": bool(value)}


def _floats(values: Any, what: str, length: int | None = None) -> list[float]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{what}: expected a 1-D sequence, got shape {arr.shape}")
    if length is not None and arr.shape[0] != length:
        raise ValueError(f"{what}: expected {length} values, got {arr.shape[0]}")
    return arr.tolist()


def _vector3(xyz: Any, what: str) -> dict[str, float]:
    x, y, z = _floats(xyz, what, 3)
    return {"x": x, "y": y, "z": z}


def joint_state(t_ns: int, names: Sequence[str], position: Any = None, velocity: Any = None,
                effort: Any = None, frame_id: str = "") -> dict[str, Any]:
    """``sensor_msgs/msg/JointState`` with position, velocity and effort all of ``len(names)``.

    A quantity given as ``None`` is filled with NaN instead of being left empty: an empty
    float64 sequence at the end of a message (``effort``) trips some CDR readers, and
    equal lengths keep the message easy to index.  Lengths are checked.
    """
    names = [str(n) for n in names]
    n = len(names)
    out = {"header": header(t_ns, frame_id), "name": names}
    for key, values in (("position", position), ("velocity", velocity), ("effort", effort)):
        out[key] = ([float("nan")] * n if values is None
                    else _floats(values, f"joint_state.{key}", n))
    return out


def tf_message(t_ns: int, transforms) -> dict[str, Any]:
    """``tf2_msgs/msg/TFMessage`` of planar transforms ``(parent, child, x, y, yaw)``:
    translation (x, y, 0) m, rotation yaw rad about z (quaternion (0, 0, sin ½yaw,
    cos ½yaw)), each stamped ``t_ns``."""
    out = []
    for parent, child, x, y, yaw in transforms:
        out.append({"header": header(t_ns, str(parent)), "child_frame_id": str(child),
                    "transform": {"translation": {"x": float(x), "y": float(y), "z": 0.0},
                                  "rotation": {"x": 0.0, "y": 0.0,
                                               "z": math.sin(0.5 * float(yaw)),
                                               "w": math.cos(0.5 * float(yaw))}}})
    return {"transforms": out}


def float64_multiarray(data: Any, labels: Sequence[str]) -> dict[str, Any]:
    """``std_msgs/msg/Float64MultiArray`` of a 1-D or 2-D array, row-major.

    A 2-D ``data`` is ``[sample, channel]`` (shape ``(n, m)``), e.g.
    ``labels=("sample", "mode")``: ``dim[0] = {label: labels[0], size: n, stride: n*m}``,
    ``dim[1] = {label: labels[1], size: m, stride: m}``, ``data`` flattened in C order,
    so ``value[i, j] = data[dim[1].stride * i + j]`` (the std_msgs MultiArrayLayout rule,
    ``data_offset = 0``).  A 1-D ``data`` of length ``n`` has one dim ``{labels[0], n, n}``.
    ``labels`` must have one entry per dimension.
    """
    arr = np.asarray(data, dtype=np.float64)
    labels = tuple(str(label) for label in labels)
    if arr.ndim not in (1, 2):
        raise ValueError(f"float64_multiarray: data must be 1-D or 2-D, got shape {arr.shape}")
    if len(labels) != arr.ndim:
        raise ValueError(f"float64_multiarray: {arr.ndim}-D data needs {arr.ndim} labels, "
                         f"got {labels!r}")
    return {"layout": _layout(arr.shape, labels), "data": arr.ravel(order="C").tolist()}


def _layout(shape: tuple[int, ...], labels: tuple[str, ...]) -> dict[str, Any]:
    dims = [{"label": label, "size": int(shape[i]), "stride": int(math.prod(shape[i:]))}
            for i, label in enumerate(labels)]
    return {"dim": dims, "data_offset": 0}


def int32_multiarray(data: Any, label: str) -> dict[str, Any]:
    """``std_msgs/msg/Int32MultiArray`` of a 1-D integer array (one dim ``label``)."""
    arr = np.asarray(data)
    if arr.ndim != 1:
        raise ValueError(f"int32_multiarray: data must be 1-D, got shape {arr.shape}")
    if arr.size and arr.dtype.kind not in "iub":
        raise ValueError(f"int32_multiarray: data must be integers, got dtype {arr.dtype}")
    values = [int(v) for v in arr.tolist()]
    if values and (min(values) < -(2**31) or max(values) >= 2**31):
        raise ValueError("int32_multiarray: values out of int32 range")
    return {"layout": _layout(arr.shape, (str(label),)), "data": values}


def wrench_stamped(t_ns: int, frame: str, force_xyz: Any, torque_xyz: Any) -> dict[str, Any]:
    """``geometry_msgs/msg/WrenchStamped`` (force in N, torque in N m, in ``frame``)."""
    return {"header": header(t_ns, frame),
            "wrench": {"force": _vector3(force_xyz, "wrench_stamped.force"),
                       "torque": _vector3(torque_xyz, "wrench_stamped.torque")}}


def point_stamped(t_ns: int, frame: str, xyz: Any) -> dict[str, Any]:
    """``geometry_msgs/msg/PointStamped`` (metres, in ``frame``)."""
    return {"header": header(t_ns, frame), "point": _vector3(xyz, "point_stamped.point")}


def _covariance(cov: Any, what: str) -> list[float]:
    arr = np.asarray(cov, dtype=np.float64)
    if arr.shape == (3, 3):
        arr = arr.ravel(order="C")
    return _floats(arr, what, 9)


_NO_ESTIMATE = [-1.0] + [0.0] * 8


def imu(t_ns: int, frame: str, angular_velocity: Any = None, linear_acceleration: Any = None,
        orientation_xyzw: Any = None, *, angular_velocity_covariance: Any = None,
        linear_acceleration_covariance: Any = None,
        orientation_covariance: Any = None) -> dict[str, Any]:
    """``sensor_msgs/msg/Imu`` following the conventions of Imu.msg and REP 145.

    A quantity given as ``None`` has no estimate: its vector is zero (the orientation is
    the identity quaternion ``(0, 0, 0, 1)``) and element 0 of its covariance is ``-1``,
    which tells consumers to ignore it (typically ``orientation_covariance[0] = -1`` for a
    gyro/accelerometer-only IMU).  A quantity that is given but whose covariance is
    ``None`` gets the all-zero covariance, which Imu.msg defines as "covariance unknown"
    (``-1`` would mark the measurement itself as absent).  Covariances are 3x3 or 9
    values, row-major about x, y, z.  Units: rad/s, m/s^2.
    """
    def part(value, cov, what):
        if value is None:
            if cov is not None:
                raise ValueError(f"imu: {what}_covariance given without {what}")
            return None, list(_NO_ESTIMATE)
        return value, [0.0] * 9 if cov is None else _covariance(cov, f"imu.{what}_covariance")

    w, w_cov = part(angular_velocity, angular_velocity_covariance, "angular_velocity")
    a, a_cov = part(linear_acceleration, linear_acceleration_covariance, "linear_acceleration")
    q, q_cov = part(orientation_xyzw, orientation_covariance, "orientation")
    if q is None:
        quat = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    else:
        x, y, z, qw = _floats(q, "imu.orientation_xyzw", 4)
        quat = {"x": x, "y": y, "z": z, "w": qw}
    return {
        "header": header(t_ns, frame),
        "orientation": quat,
        "orientation_covariance": q_cov,
        "angular_velocity": _vector3([0.0] * 3 if w is None else w, "imu.angular_velocity"),
        "angular_velocity_covariance": w_cov,
        "linear_acceleration": _vector3([0.0] * 3 if a is None else a,
                                        "imu.linear_acceleration"),
        "linear_acceleration_covariance": a_cov,
    }
