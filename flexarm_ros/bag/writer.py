"""Write rosbag2-compatible MCAP files without ROS.

Contract
--------
:class:`BagWriter` produces a single ``.mcap`` file that ``ros2 bag info/play`` (MCAP
storage plugin), rosbags, Foxglove and the ``mcap`` tools read like a file recorded by
``ros2 bag record -s mcap``.  "rosbag2-compatible" means here:

* MCAP header profile ``ros2``; one Schema per message type, named ``pkg/msg/Type``,
  encoding ``ros2msg``, holding the full concatenated definition of
  :func:`flexarm_ros.bag.msgdefs.full_text` (dependencies appended the way rosbag2 does);
* one Channel per topic, message encoding ``cdr`` (little-endian CDR, byte-identical to
  what rosbags serializes), channel metadata ``offered_qos_profiles`` (a YAML string in
  the format of the chosen rosbag2 metadata version: reliable, volatile, keep_last,
  depth 10, infinite deadline/lifespan/lease) and ``topic_type_hash`` (RIHS01);
* chunked (zstd, else lz4, else uncompressed), with message indexes, chunk/metadata
  indexes, statistics and summary offsets, schemas and channels repeated in the summary,
  CRCs (written by :class:`~flexarm_ros.bag.mcap_file.McapFile`, whose per-message path
  is ~5× cheaper than ``mcap.writer.Writer``'s; read back with the ``mcap`` package);
* on :meth:`BagWriter.close`, a Metadata record named ``rosbag2`` whose key
  ``serialized_metadata`` is the YAML of rosbag2's ``BagMetadata`` (version,
  ``storage_identifier: mcap``, duration/starting time in ns, message counts per topic,
  topic metadata, empty compression fields, ``custom_data``, ``ros_distro``).

``rosbag2_version=9`` (default) is the Jazzy format (QoS enums as strings, the topic
QoS list embedded as YAML sequence).  ``rosbag2_version=8`` writes the Iron format (QoS
enums as integers, QoS list as a YAML string), which Humble's tools also parse.  A bare
``.mcap`` is read directly by Jazzy's ``ros2 bag`` and by rosbags; for Humble's
``ros2 bag play``, call :meth:`BagWriter.write_metadata_yaml` after closing so that the
file's directory becomes a rosbag2 bag directory (``metadata.yaml`` + ``.mcap``).

Serialization uses the validating CDR encoder :func:`encode_cdr` of this module (not
``mcap_ros2``'s, which silently fills missing fields with defaults and is slow on long
arrays); its output is byte-identical to rosbags' and ``mcap_ros2``'s serializers
(checked by ``test/test_bag.py``).

Validation: the message type must be one of :data:`~flexarm_ros.bag.msgdefs.KNOWN_TYPES`
(``ValueError`` listing them otherwise); every field of the definition must be present
and no other key (``ValueError`` naming topic, type and dotted field path); values are
type- and range-checked, fixed-size arrays must have their exact length.  Numpy arrays
and scalars are converted to Python lists/floats/ints.  NaN and inf are legal float64
values and are written unchanged.  Data are never altered: a JointState whose trailing
``effort`` (or a Float64MultiArray whose ``data``) is an empty float64 sequence is
written as is, although some CDR readers mishandle an empty float64 sequence at the very
end of a message (missing trailing alignment padding); build messages with
:func:`flexarm_ros.bag.messages.joint_state`, which always fills position, velocity and
effort to ``len(name)`` (NaN where unknown), to stay clear of them.

Crash behaviour
---------------
Output goes to a file opened in binary mode, written in chunks of about ``chunk_size``
bytes (uncompressed, default 256 kB); each completed chunk, and each metadata record, is
flushed to the operating system at once.  If the process is killed (SIGKILL, OOM) the
file ends after the last complete chunk: :func:`flexarm_ros.bag.reader.read_bag` then
recovers every message of the complete chunks with a
:class:`~flexarm_ros.bag.reader.TruncatedBagWarning`.  Lost are the messages of the
chunk being filled (at most ``chunk_size`` bytes of serialized messages; call
:meth:`BagWriter.flush` to close a chunk early), the ``rosbag2`` metadata record and the
summary section (indexes, statistics), so tools that need the summary (``ros2 bag
info``, ``mcap``'s indexed reader, rosbags) refuse the file until it is rewritten
complete by ``flexarm bag repair`` (:mod:`flexarm_ros.bag.repair`; ``flexarm run
--processes`` does that itself when its recorder process was killed).  Data are
flushed, not fsync'ed: a power loss can lose more.
"""

from __future__ import annotations

import copy
import numbers
import os
import struct
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import LIBRARY_IDENTIFIER as _MCAP_LIBRARY

from flexarm_ros.version import __version__
import flexarm_ros.bag.msgdefs as msgdefs
from flexarm_ros.bag.mcap_file import McapFile

__all__ = ["BagWriter", "DEFAULT_QOS", "INFO_METADATA_NAME", "ROSBAG2_METADATA_NAME",
           "encode_cdr", "rosbag2_bag_metadata"]

ROSBAG2_METADATA_NAME = "rosbag2"
"""Name of the MCAP Metadata record holding rosbag2's serialized ``BagMetadata``."""

INFO_METADATA_NAME = "flexarm_ros"
"""Name of the Metadata record holding ``BagWriter(path, metadata=...)``."""

_INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE

DEFAULT_QOS: dict[str, Any] = {
    "history": "keep_last",
    "depth": 10,
    "reliability": "reliable",
    "durability": "volatile",
    "deadline": dict(_INFINITE),
    "lifespan": dict(_INFINITE),
    "liveliness": "automatic",
    "liveliness_lease_duration": dict(_INFINITE),
    "avoid_ros_namespace_conventions": False,
}
"""The QoS profile recorded as offered for every topic (rosbag2 >= 9 spelling)."""

# rmw enum values, for rosbag2 metadata version 8 (Humble/Iron style integers).
_QOS_ENUMS_V8 = {
    "history": {"system_default": 0, "keep_last": 1, "keep_all": 2, "unknown": 3},
    "reliability": {"system_default": 0, "reliable": 1, "best_effort": 2, "unknown": 3},
    "durability": {"system_default": 0, "transient_local": 1, "volatile": 2, "unknown": 3},
    "liveliness": {"system_default": 0, "automatic": 1, "manual_by_topic": 3, "unknown": 4},
}


def default_compression() -> str:
    try:
        import zstandard  # noqa: F401

        return "zstd"
    except ImportError:
        pass
    try:
        import lz4.frame  # noqa: F401

        return "lz4"
    except ImportError:
        return ""


def _qos_yaml(version: int, depth: int = 10) -> list[dict[str, Any]]:
    qos = copy.deepcopy(DEFAULT_QOS)
    qos["depth"] = depth
    if version < 9:
        for key, table in _QOS_ENUMS_V8.items():
            qos[key] = table[qos[key]]
    return [qos]


class _NoAliasDumper(yaml.SafeDumper):
    """Never emit YAML anchors/aliases (rosbag2 metadata is plain YAML)."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def dump_yaml(data: Any) -> str:
    return yaml.dump(data, Dumper=_NoAliasDumper, sort_keys=False, width=2**31 - 1,
                     default_flow_style=False, allow_unicode=True).rstrip("\n")


class _Sink:
    """File proxy for the MCAP writer: remembers whether anything was written."""

    def __init__(self, stream: IO[bytes]):
        self.stream = stream
        self.dirty = False

    def write(self, data: bytes) -> int:
        self.dirty = True
        return self.stream.write(data)

    def tell(self) -> int:
        return self.stream.tell()

    def flush(self) -> None:
        self.dirty = False
        flush = getattr(self.stream, "flush", None)
        if flush is not None:
            flush()


class _Invalid(ValueError):
    """Internal: a field value failed validation (path relative to the message)."""

    def __init__(self, path: str, problem: str):
        super().__init__(path, problem)
        self.path = path
        self.problem = problem


# -- validating CDR encoder -------------------------------------------------------------
#
# Plain little-endian CDR (XCDR1, encapsulation 00 01 00 00) as written by rmw and by
# rosbags: primitives aligned to their size relative to the end of the 4-byte
# encapsulation header, strings as uint32 length (with NUL) + bytes + NUL, sequences as
# uint32 count + elements, fixed arrays as elements only, nested messages inline.  As in
# rosbags and mcap_ros2 (and Fast-CDR 2), an empty sequence adds no element alignment.
# test_bag.py checks byte identity with rosbags' and mcap_ros2's serializers.

_CDR_HEADER = b"\x00\x01\x00\x00"
_STRUCTS = {name: struct.Struct("<" + code) for name, code in {
    "float64": "d", "float32": "f", "int8": "b", "uint8": "B", "byte": "B", "char": "b",
    "int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
    "bool": "?"}.items()}
_DTYPES = {"float64": "<f8", "float32": "<f4", "int8": "<i1", "uint8": "<u1", "byte": "<u1",
           "char": "<i1", "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4",
           "int64": "<i8", "uint64": "<u8", "bool": "?"}
_UINT32 = _STRUCTS["uint32"]
_INT_RANGES = {
    "byte": (0, 2**8 - 1), "char": (-(2**7), 2**7 - 1),
    "int8": (-(2**7), 2**7 - 1), "uint8": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1), "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1), "uint64": (0, 2**64 - 1),
}
_FLOAT_TYPES = ("float32", "float64")


def _align(buf: bytearray, size: int) -> None:
    pad = -(len(buf) - 4) % size
    if pad:
        buf += b"\x00" * pad


def _join(path: str, name: str) -> str:
    return f"{path}.{name}" if path else name


def _check_scalar(ftype: str, value: Any, path: str) -> Any:
    """Validated Python value of a primitive field."""
    if ftype in _FLOAT_TYPES:
        if type(value) is float:
            return value
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise _Invalid(path, f"expected a number for {ftype}, got {type(value).__name__}")
        return float(value)
    if ftype in _INT_RANGES:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            raise _Invalid(path, f"expected an integer for {ftype}, got {type(value).__name__}")
        lo, hi = _INT_RANGES[ftype]
        value = int(value)
        if not lo <= value <= hi:
            raise _Invalid(path, f"{value} is out of range for {ftype} [{lo}, {hi}]")
        return value
    if ftype == "bool":
        if not isinstance(value, (bool, np.bool_)):
            raise _Invalid(path, f"expected a bool, got {type(value).__name__}")
        return bool(value)
    if ftype == "string":
        if not isinstance(value, str):
            raise _Invalid(path, f"expected a str, got {type(value).__name__}")
        return value
    raise _Invalid(path, f"unsupported primitive type {ftype}")  # pragma: no cover


def _put_string(buf: bytearray, value: str) -> None:
    data = value.encode("utf-8")
    _align(buf, 4)
    buf += _UINT32.pack(len(data) + 1)
    buf += data
    buf += b"\x00"


def _put_scalar(buf: bytearray, ftype: str, value: Any, path: str) -> None:
    value = _check_scalar(ftype, value, path)
    if ftype == "string":
        _put_string(buf, value)
        return
    packer = _STRUCTS[ftype]
    if packer.size > 1:
        _align(buf, packer.size)
    buf += packer.pack(value)


def _kind_ok(ftype: str, kind: str) -> bool:
    if ftype in _FLOAT_TYPES:
        return kind in "fiu"
    if ftype in _INT_RANGES:
        return kind in "iu"
    return kind == "b"  # bool


def _numeric_array(ftype: str, value: Any, path: str) -> np.ndarray:
    """Validated 1-D little-endian array of a numeric/bool sequence field."""
    if isinstance(value, np.ndarray):
        arr = value
    elif isinstance(value, (bytes, bytearray, memoryview)) and ftype in ("uint8", "byte"):
        # how the bag readers give uint8[] back (e.g. a Marker's texture.data): re-writing
        # a message read from a bag must not fail on it
        arr = np.frombuffer(bytes(value), np.uint8)
    elif isinstance(value, (list, tuple)):
        if not value:
            return np.zeros(0, _DTYPES[ftype])
        try:
            arr = np.asarray(value)
        except (ValueError, TypeError):  # ragged nesting
            arr = None
        if arr is None or arr.ndim != 1 or not _kind_ok(ftype, arr.dtype.kind):
            # element by element: names the first offending element, or builds the
            # array when numpy merely picked an unusual dtype (huge ints -> object)
            arr = np.array([_check_scalar(ftype, v, f"{path}[{i}]")
                            for i, v in enumerate(value)], dtype=_DTYPES[ftype])
    else:
        raise _Invalid(path, f"expected a sequence for {ftype}[], got {type(value).__name__}")
    if arr.ndim != 1:
        raise _Invalid(path, f"expected a 1-D array, got shape {arr.shape}")
    if not _kind_ok(ftype, arr.dtype.kind):
        raise _Invalid(path, f"expected {ftype} values, got an array of dtype {arr.dtype}")
    if ftype in _INT_RANGES and arr.size:
        lo, hi = _INT_RANGES[ftype]
        if int(arr.min()) < lo or int(arr.max()) > hi:
            raise _Invalid(path, f"values out of range for {ftype} [{lo}, {hi}]")
    return arr.astype(_DTYPES[ftype], copy=False)


def _put_message(buf: bytearray, msgtype: str, msg: Any, path: str) -> None:
    if not isinstance(msg, Mapping):
        raise _Invalid(path or "<message>",
                       f"expected a dict for {msgtype}, got {type(msg).__name__}")
    spec = _FIELDS[msgtype]
    for field in spec:
        try:
            value = msg[field.name]
        except KeyError:
            raise _Invalid(_join(path, field.name), "missing field") from None
        if field.array is None:
            if field.is_primitive:
                _put_scalar(buf, field.type, value, _join(path, field.name))
            else:
                _put_message(buf, field.type, value, _join(path, field.name))
            continue
        fpath = _join(path, field.name)
        if field.is_primitive and field.type != "string":
            arr = _numeric_array(field.type, value, fpath)
            count = arr.shape[0]
            if field.array >= 0 and count != field.array:
                raise _Invalid(fpath, f"expected exactly {field.array} elements, got {count}")
            if field.array < 0:
                _align(buf, 4)
                buf += _UINT32.pack(count)
            if count:
                _align(buf, arr.dtype.itemsize)
                buf += arr.tobytes()
            continue
        if isinstance(value, np.ndarray) and field.type == "string":
            value = value.tolist()
        if not isinstance(value, (list, tuple)):
            raise _Invalid(fpath, f"expected a sequence for {field.type}[], "
                                  f"got {type(value).__name__}")
        if field.array >= 0 and len(value) != field.array:
            raise _Invalid(fpath, f"expected exactly {field.array} elements, got {len(value)}")
        if field.array < 0:
            _align(buf, 4)
            buf += _UINT32.pack(len(value))
        for i, item in enumerate(value):
            if field.type == "string":
                _put_string(buf, _check_scalar("string", item, f"{fpath}[{i}]"))
            else:
                _put_message(buf, field.type, item, f"{fpath}[{i}]")
    if len(msg) != len(spec):
        names = {f.name for f in spec}
        extra = next(k for k in msg if k not in names)
        raise _Invalid(_join(path, str(extra)),
                       f"unknown field (fields of {msgtype}: "
                       f"{', '.join(f.name for f in spec)})")


def _compile(msgtype: str):
    """A serializer of ``msgtype`` without validation: ``put(buf, msg)`` appends the
    fields, the alignment computed as :func:`_put_message` does (each primitive aligned
    to its size relative to the byte after the 4-byte header; an empty sequence aligns
    nothing beyond its count). Built once per type from the same field definitions."""
    steps = []
    for field in _FIELDS[msgtype]:
        name, ftype, n = field.name, field.type, field.array
        if n is None:
            if ftype == "string":
                steps.append(lambda buf, m, k=name: _put_string(buf, m[k]))
            elif field.is_primitive:
                packer = _STRUCTS[ftype]
                size = packer.size

                def scalar(buf, m, k=name, pack=packer.pack, size=size):
                    if size > 1:
                        pad = -(len(buf) - 4) % size
                        if pad:
                            buf += b"\x00" * pad
                    buf += pack(m[k])
                steps.append(scalar)
            else:
                sub = _compiled(ftype)
                steps.append(lambda buf, m, k=name, sub=sub: sub(buf, m[k]))
        elif ftype == "string" or not field.is_primitive:
            def sequence(buf, m, k=name, n=n,
                         put=_put_string if ftype == "string" else _compiled(ftype)):
                values = m[k]
                if n < 0:
                    _align(buf, 4)
                    buf += _UINT32.pack(len(values))
                for v in values:
                    put(buf, v)
            steps.append(sequence)
        else:
            dtype = np.dtype(_DTYPES[ftype])

            def numbers_(buf, m, k=name, n=n, dtype=dtype):
                arr = np.asarray(m[k], dtype=dtype)
                if n < 0:
                    pad = -(len(buf) - 4) % 4
                    if pad:
                        buf += b"\x00" * pad
                    buf += _UINT32.pack(arr.shape[0])
                if arr.shape[0]:
                    pad = -(len(buf) - 4) % dtype.itemsize
                    if pad:
                        buf += b"\x00" * pad
                    buf += arr.tobytes()
            steps.append(numbers_)
    steps = tuple(steps)

    def put(buf, m):
        for step in steps:
            step(buf, m)
    return put


_PLANS: dict = {}


def _compiled(msgtype: str):
    plan = _PLANS.get(msgtype)
    if plan is None:
        plan = _PLANS[msgtype] = _compile(msgtype)
    return plan


def encode_cdr(msgtype: str, msg: Mapping[str, Any], validate: bool = True) -> bytes:
    """Validate ``msg`` (a plain dict) against ``msgtype`` and serialize it to CDR.

    Raises ``ValueError`` naming the dotted field path of the first problem. With
    ``validate=False`` the fields are serialized by a plan compiled once per type, without
    the checks (missing or extra keys, types, ranges, lengths): the path of the twin's
    nodes, whose messages are built by :mod:`flexarm_ros.bag.messages` (byte-identical to
    the validated path: ``test/test_cdr_wire.py``), several times faster.
    """
    if not validate:
        buf = bytearray(_CDR_HEADER)
        _compiled(msgtype)(buf, msg)
        return bytes(buf)
    if msgtype not in _FIELDS:
        raise ValueError(f"unknown message type {msgtype!r}; "
                         f"known types: {', '.join(msgdefs.KNOWN_TYPES)}")
    buf = bytearray(_CDR_HEADER)
    try:
        _put_message(buf, msgtype, msg, "")
    except _Invalid as err:
        raise ValueError(f"field {err.path!r}: {err.problem}") from None
    return bytes(buf)


_FIELDS = {t: msgdefs.fields(t) for t in msgdefs.KNOWN_TYPES}


def _check_time(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer number of nanoseconds, "
                         f"got {type(value).__name__}")
    value = int(value)
    if not 0 <= value < 2**64:
        raise ValueError(f"{name} must be in [0, 2**64) ns, got {value}")
    return value


def _times(log_time_ns: Any, publish_time_ns: Any) -> tuple[int, int]:
    """Checked (log time, publish time) of a message; the publish time defaults to the
    log time."""
    log_time_ns = _check_time("log_time_ns", log_time_ns)
    return log_time_ns, (log_time_ns if publish_time_ns is None
                         else _check_time("publish_time_ns", publish_time_ns))


def _check_str_dict(what: str, data: Any) -> dict[str, str]:
    if not isinstance(data, Mapping):
        raise ValueError(f"{what} must be a dict[str, str], got {type(data).__name__}")
    for k, v in data.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise ValueError(f"{what} must map str to str; entry {k!r}: {v!r} does not")
    return dict(data)


def rosbag2_bag_metadata(version: int, topics: list[tuple], start_ns: int | None,
                         end_ns: int | None, files: list[str],
                         custom_data: Mapping[str, str] | None,
                         ros_distro: str = "") -> dict[str, Any]:
    """rosbag2's ``BagMetadata`` (what the ``rosbag2`` Metadata record serializes).

    ``topics``: ``(name, type, serialization format, offered QoS list, type description
    hash, message count)`` per topic; the QoS list is embedded as a YAML sequence for
    ``version`` >= 9 and as a YAML string before.  ``start_ns``/``end_ns``: the first and
    last log time (``None`` without messages)."""
    start = start_ns or 0
    duration = 0 if start_ns is None or end_ns is None else end_ns - start_ns
    total = sum(t[5] for t in topics)
    entries = []
    for name, msgtype, fmt, qos, type_hash, count in topics:
        entries.append({
            "topic_metadata": {
                "name": name,
                "type": msgtype,
                "serialization_format": fmt,
                "offered_qos_profiles": qos if version >= 9 else dump_yaml(qos),
                "type_description_hash": type_hash,
            },
            "message_count": count,
        })
    return {
        "version": version,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total,
        "topics_with_message_count": entries,
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": list(files),
        "files": [{"path": f, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": total}
                  for f in files],
        "custom_data": dict(custom_data or {}) or None,
        "ros_distro": ros_distro,
    }


class BagWriter:
    """Write ROS 2 messages given as plain dicts into a rosbag2-compatible MCAP file.

    ``BagWriter(path_or_stream, metadata=None, *, chunk_size=256 * 1024,
    compression="auto", rosbag2_version=9, qos_depth=10)``

    ``path_or_stream`` is a file path (created or overwritten) or a writable binary
    stream such as :class:`io.BytesIO` (left open by :meth:`close`).  ``metadata``
    (``dict[str, str]``) is written at once as an MCAP Metadata record named
    :data:`INFO_METADATA_NAME` and is also stored as rosbag2 ``custom_data``.
    ``compression`` is ``"auto"`` (zstd, else lz4, else none), ``"zstd"``, ``"lz4"`` or
    ``"none"``.  ``qos_depth`` is the keep_last depth recorded as the offered QoS of every
    topic (the recorder passes the twin's publishers' depth, 1000).  Topics must be absolute ROS names (``/joint_states``); a topic keeps the
    type of its first message.  Thread-safe; use as a context manager or call
    :meth:`close`.
    """

    def __init__(self, path_or_stream: str | os.PathLike | IO[bytes],
                 metadata: Mapping[str, str] | None = None, *,
                 chunk_size: int = 256 * 1024, compression: str = "auto",
                 rosbag2_version: int = 9, qos_depth: int = 10):
        if rosbag2_version not in (8, 9):
            raise ValueError(f"rosbag2_version must be 8 or 9, got {rosbag2_version!r}")
        if not isinstance(chunk_size, int) or chunk_size <= 0:
            raise ValueError(f"chunk_size must be a positive int, got {chunk_size!r}")
        compressions = {"auto": None, "zstd": "zstd", "lz4": "lz4", "none": ""}
        if compression not in compressions:
            raise ValueError(f"compression must be one of {sorted(compressions)}, "
                             f"got {compression!r}")
        if not isinstance(qos_depth, int) or isinstance(qos_depth, bool) or qos_depth < 1:
            raise ValueError(f"qos_depth must be a positive int, got {qos_depth!r}")
        self._qos_depth = qos_depth
        info = _check_str_dict("metadata", metadata or {})
        self._lock = threading.RLock()
        self._rosbag2_version = rosbag2_version
        self._custom_data = info
        self._closed = False
        self._owns_stream = isinstance(path_or_stream, (str, os.PathLike))
        if self._owns_stream:
            self.path: Path | None = Path(path_or_stream)
            stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        else:
            if not hasattr(path_or_stream, "write"):
                raise TypeError("BagWriter needs a path or a writable binary stream, "
                                f"got {type(path_or_stream).__name__}")
            self.path = None
            stream = path_or_stream  # type: ignore[assignment]
        self._sink = _Sink(stream)
        try:
            codec = compressions[compression]
            self._writer = McapFile(
                self._sink, Profile.ROS2, f"flexarm_ros/{__version__}; {_MCAP_LIBRARY}",
                chunk_size=chunk_size,
                compression=default_compression() if codec is None else codec)
            if info:
                self._writer.add_metadata(INFO_METADATA_NAME, info)
            self._sink.flush()
        except BaseException:
            if self._owns_stream:
                stream.close()
            raise
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, msgtype)
        self._counts: dict[str, int] = {}
        self.rosbag2_metadata: dict[str, Any] | None = None
        """rosbag2 ``BagMetadata`` as written by :meth:`close` (``None`` before)."""

    # -- context manager -------------------------------------------------------------
    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def message_counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        with self._lock:
            return dict(self._counts)

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError("BagWriter is closed")

    # -- writing ---------------------------------------------------------------------
    def _channel(self, topic: str, msgtype: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise ValueError(f"topic {topic!r} already carries {known[1]}, "
                                 f"cannot write a {msgtype} on it")
            return known[0]
        if msgtype not in msgdefs.DEFINITIONS:
            raise ValueError(f"unknown message type {msgtype!r} for topic {topic!r}; "
                             f"known types: {', '.join(msgdefs.KNOWN_TYPES)}")
        if not isinstance(topic, str) or not topic.startswith("/") or topic == "/":
            raise ValueError(f"topic must be an absolute ROS name like '/joint_states', "
                             f"got {topic!r}")
        schema_id = self._schema_ids.get(msgtype)
        if schema_id is None:
            text = msgdefs.full_text(msgtype)
            schema_id = self._writer.register_schema(msgtype, SchemaEncoding.ROS2,
                                                     text.encode())
            self._schema_ids[msgtype] = schema_id
        qos = _qos_yaml(self._rosbag2_version, self._qos_depth)
        channel_id = self._writer.register_channel(
            topic=topic, message_encoding=MessageEncoding.CDR, schema_id=schema_id,
            metadata={"offered_qos_profiles": dump_yaml(qos),
                      "topic_type_hash": msgdefs.TYPE_HASHES.get(msgtype, "")})
        self._channels[topic] = (channel_id, msgtype)
        self._counts[topic] = 0
        return channel_id

    def write(self, topic: str, msgtype: str, msg: Mapping[str, Any], log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Validate ``msg`` against ``msgtype``, serialize it to CDR and append it.

        ``log_time_ns`` is the receive/record time (rosbag2's ``recv_timestamp``, the
        MCAP log time); ``publish_time_ns`` defaults to it.
        """
        with self._lock:
            self._check_open()
            log_time_ns, publish_time_ns = _times(log_time_ns, publish_time_ns)
            if msgtype not in msgdefs.DEFINITIONS:
                raise ValueError(f"unknown message type {msgtype!r} for topic {topic!r}; "
                                 f"known types: {', '.join(msgdefs.KNOWN_TYPES)}")
            try:
                data = encode_cdr(msgtype, msg)
            except ValueError as err:
                raise ValueError(f"cannot write to topic {topic!r} ({msgtype}): {err}") from None
            self._append(topic, msgtype, data, log_time_ns, publish_time_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, log_time_ns: int,
                  publish_time_ns: int | None = None) -> None:
        """Append an already serialized message (little-endian CDR with its 4-byte
        encapsulation header, as a raw rclpy subscription receives it) unchanged: the
        recorder's fast path. Only the header is checked; the bytes are the caller's
        responsibility (the twin's nodes publish :func:`encode_cdr` output)."""
        with self._lock:
            self._check_open()
            if type(log_time_ns) is not int or not 0 <= log_time_ns < 2**64 or \
                    publish_time_ns is not None:
                log_time_ns, publish_time_ns = _times(log_time_ns, publish_time_ns)
            else:
                publish_time_ns = log_time_ns
            if type(data) is not bytes:
                if not isinstance(data, (bytearray, memoryview)):
                    data = None
                else:
                    data = bytes(data)
            if data is None or data[:2] != _CDR_HEADER[:2] or len(data) < 4:
                raise ValueError(f"cannot write to topic {topic!r} ({msgtype}): expected "
                                 f"little-endian CDR bytes starting with "
                                 f"{_CDR_HEADER.hex()}, got "
                                 f"{bytes(data[:4]).hex() if data else data!r}")
            known = self._channels.get(topic)
            if known is None or known[1] != msgtype:      # a new topic, or a wrong type
                if msgtype not in msgdefs.DEFINITIONS:
                    raise ValueError(f"unknown message type {msgtype!r} for topic "
                                     f"{topic!r}; known types: "
                                     f"{', '.join(msgdefs.KNOWN_TYPES)}")
            self._append(topic, msgtype, data, log_time_ns, publish_time_ns)

    def _append(self, topic, msgtype, data: bytes, log_time_ns, publish_time_ns) -> None:
        """Add one serialized message (the lock is held)."""
        known = self._channels.get(topic)
        channel_id = (known[0] if known is not None and known[1] == msgtype else
                      self._channel(topic, msgtype))
        n = self._counts[topic]
        self._writer.add_message(channel_id, log_time_ns, data, publish_time_ns, n % 2**32)
        self._counts[topic] = n + 1
        if self._sink.dirty:  # a chunk was completed: hand it to the OS now
            self._sink.flush()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write an MCAP Metadata record now (scene YAML, versions, built model, ...).

        ``name`` must not be ``"rosbag2"`` (written by :meth:`close`).
        """
        with self._lock:
            self._check_open()
            if not isinstance(name, str) or not name:
                raise ValueError(f"metadata name must be a non-empty str, got {name!r}")
            if name == ROSBAG2_METADATA_NAME:
                raise ValueError(f"metadata name {name!r} is reserved for the rosbag2 record")
            self._writer.add_metadata(name, _check_str_dict(f"metadata {name!r}", data))
            self._sink.flush()

    def flush(self) -> None:
        """Close the chunk being filled (if any) and flush it to the operating system.

        Bounds what a kill can lose to the messages written after this call.
        """
        with self._lock:
            self._check_open()
            self._writer.flush()
            self._sink.flush()

    # -- closing ---------------------------------------------------------------------
    def _bag_metadata(self) -> dict[str, Any]:
        qos = _qos_yaml(self._rosbag2_version, self._qos_depth)
        topics = [(topic, msgtype, "cdr", qos, msgdefs.TYPE_HASHES.get(msgtype, ""),
                   self._counts[topic]) for topic, (_, msgtype) in self._channels.items()]
        return rosbag2_bag_metadata(
            self._rosbag2_version, topics, *self._writer.time_range(),
            [self.path.name] if self.path is not None else [], self._custom_data,
            os.environ.get("ROS_DISTRO", ""))

    def close(self) -> None:
        """Write the rosbag2 metadata record, the summary and the footer; idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self.rosbag2_metadata = self._bag_metadata()
                self._writer.add_metadata(
                    ROSBAG2_METADATA_NAME,
                    {"serialized_metadata": dump_yaml(self.rosbag2_metadata)})
                self._writer.finish()
                self._sink.flush()
            finally:
                if self._owns_stream:
                    self._sink.stream.close()

    def write_metadata_yaml(self) -> Path:
        """Write ``metadata.yaml`` next to the closed ``.mcap`` file; returns its path.

        The directory holding the file then is a rosbag2 bag directory (what Humble's
        ``ros2 bag play <dir>`` and ``rosbags.rosbag2.Reader(<dir>)`` expect).  It must
        contain only this bag.
        """
        with self._lock:
            if self.path is None:
                raise ValueError("write_metadata_yaml needs a BagWriter opened on a path")
            if not self._closed or self.rosbag2_metadata is None:
                raise ValueError("write_metadata_yaml: close the BagWriter first")
            out = self.path.parent / "metadata.yaml"
            out.write_text(dump_yaml({"rosbag2_bagfile_information": self.rosbag2_metadata})
                           + "\n", encoding="utf-8")
            return out

