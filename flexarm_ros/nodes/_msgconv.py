"""Plain message dicts (what the cores emit and :class:`~flexarm_ros.bag.BagWriter` takes)
to rclpy message objects and back, for any ROS 2 message type, by walking the fields.

``to_msg("sensor_msgs/msg/JointState", d)`` sets every key of ``d`` recursively (nested
messages from dicts, sequences of messages from lists of dicts, numeric sequences from
lists or numpy arrays); ``to_dict(msg)`` gives plain dicts, lists, floats, ints, bools
and strings with exactly the keys of the type, so ``to_dict(to_msg(t, d)) == d`` for the
cores' messages (floats pass through C doubles unchanged: bit-identical).
"""

from __future__ import annotations

import array
import importlib
from functools import lru_cache

import numpy as np

__all__ = ["msg_class", "to_dict", "to_msg"]

_TYPECODES = {"double": "d", "float": "f", "int8": "b", "uint8": "B", "int16": "h",
              "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q"}


@lru_cache(maxsize=None)
def msg_class(msgtype: str):
    """The rclpy class of ``pkg/msg/Type`` (also accepts ``pkg/Type``)."""
    parts = msgtype.split("/")
    pkg, name = parts[0], parts[-1]
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _is_msg(ftype: str) -> bool:
    return "/" in ftype


@lru_cache(maxsize=None)
def _fields(cls) -> tuple:
    """(name, kind, element type) per field; kind: msg, msgseq, numseq, other."""
    out = []
    for name, ftype in cls.get_fields_and_field_types().items():
        base = ftype.split("<", 1)[1].rstrip(">").split(",")[0] if ftype.startswith(
            "sequence<") else ftype.split("[", 1)[0]
        if base.startswith("string") or base.startswith("wstring"):
            kind = "other"
        elif _is_msg(base):
            kind = "msgseq" if ftype != base else "msg"
        elif ftype != base:
            kind = "numseq"
        else:
            kind = "other"
        out.append((name, kind, base))
    return tuple(out)


def _fill(obj, data: dict):
    cls = type(obj)
    for name, kind, base in _fields(cls):
        if name not in data:
            continue
        value = data[name]
        if kind == "msg":
            _fill(getattr(obj, name), value)
        elif kind == "msgseq":
            ecls = msg_class(base)
            setattr(obj, name, [_fill(ecls(), v) for v in value])
        elif kind == "numseq":
            code = _TYPECODES.get(base)
            current = getattr(obj, name)
            if isinstance(current, array.array) and code is not None:
                setattr(obj, name, array.array(code, np.asarray(value).tolist()
                                               if isinstance(value, np.ndarray) else value))
            else:                                   # fixed-size array (numpy) or bool[]
                setattr(obj, name, np.asarray(value).tolist()
                        if isinstance(value, np.ndarray) else list(value))
        else:
            setattr(obj, name, value.item() if isinstance(value, np.generic) else value)
    return obj


def to_msg(msgtype: str, data: dict):
    """A new rclpy message of ``msgtype`` with the fields of ``data`` set."""
    return _fill(msg_class(msgtype)(), data)


def to_dict(msg) -> dict:
    """Plain-dict form of an rclpy message (every field of its type)."""
    out = {}
    for name, kind, _ in _fields(type(msg)):
        value = getattr(msg, name)
        if kind == "msg":
            out[name] = to_dict(value)
        elif kind == "msgseq":
            out[name] = [to_dict(v) for v in value]
        elif kind == "numseq":
            out[name] = value.tolist() if hasattr(value, "tolist") else list(value)
        else:
            out[name] = list(value) if isinstance(value, (list, tuple)) else value
    return out
