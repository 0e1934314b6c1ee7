"""ROS 2 message definitions (``ros2msg`` text) for the types the twin records.

The texts are the ROS 2 Humble/Jazzy ``.msg`` files with comments stripped (field
names, types, array bounds, default values and constants are unchanged; Humble and Jazzy
agree on every field here, and on every constant but Marker's ``ARROW_STRIP``, Jazzy's).
:func:`full_text` concatenates a type with all its dependencies
exactly the way rosbag2's MCAP storage plugin does (``message_definition_cache.cpp``):

* the top-level text first, then for each dependency not seen before, in a depth-first
  walk whose children are visited in sorted order, ``"\\n"`` + a line of 80 ``=`` +
  ``"\\nMSG: <name>\\n"`` + the dependency's text;
* ``<name>`` is the type as spelled in the referencing field, made package-qualified
  (``std_msgs/Header``, ``geometry_msgs/Vector3``): this is what real rosbag2 bags
  contain, and what rosbags, Foxglove and ``mcap_ros2`` parse.

``TYPE_HASHES`` are the ROS 2 ``RIHS01`` type-description hashes (written by rosbag2
from Iron on as ``topic_type_hash`` / ``type_description_hash``); ``test/test_bag.py``
recomputes them from these texts with ``rosbags``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "DEFINITIONS",
    "KNOWN_TYPES",
    "PRIMITIVE_TYPES",
    "TYPE_HASHES",
    "Field",
    "fields",
    "full_text",
]

_SEPARATOR = "=" * 80

# Comment-stripped texts of the real .msg files (ros2/common_interfaces,
# ros2/rcl_interfaces), keyed by normalized name ``pkg/msg/Type``.
DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/msg/Duration": "int32 sec\nuint32 nanosec\n",
    "rosgraph_msgs/msg/Clock": "builtin_interfaces/Time clock\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/msg/Bool": "bool data\n",
    "std_msgs/msg/String": "string data\n",
    "std_msgs/msg/MultiArrayDimension": "string label\nuint32 size\nuint32 stride\n",
    "std_msgs/msg/MultiArrayLayout": "MultiArrayDimension[] dim\nuint32 data_offset\n",
    "std_msgs/msg/Float64MultiArray": "MultiArrayLayout  layout\nfloat64[]         data\n",
    "std_msgs/msg/Int32MultiArray": "MultiArrayLayout  layout\nint32[]           data\n",
    "sensor_msgs/msg/JointState": (
        "std_msgs/Header header\n\n"
        "string[] name\n"
        "float64[] position\n"
        "float64[] velocity\n"
        "float64[] effort\n"
    ),
    "sensor_msgs/msg/Imu": (
        "std_msgs/Header header\n\n"
        "geometry_msgs/Quaternion orientation\n"
        "float64[9] orientation_covariance\n\n"
        "geometry_msgs/Vector3 angular_velocity\n"
        "float64[9] angular_velocity_covariance\n\n"
        "geometry_msgs/Vector3 linear_acceleration\n"
        "float64[9] linear_acceleration_covariance\n"
    ),
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Wrench": "Vector3  force\nVector3  torque\n",
    "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    "geometry_msgs/msg/PointStamped": "std_msgs/Header header\nPoint point\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/msg/TransformStamped": (
        "std_msgs/Header header\n"
        "string child_frame_id\n"
        "Transform transform\n"
    ),
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "std_msgs/msg/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "sensor_msgs/msg/CompressedImage": (
        "std_msgs/Header header\n"
        "string format\n"
        "uint8[] data\n"
    ),
    "visualization_msgs/msg/UVCoordinate": "float32 u\nfloat32 v\n",
    "visualization_msgs/msg/MeshFile": "string filename\nuint8[] data\n",
    # Jazzy's text (Humble's lacks the constant ARROW_STRIP; the fields are the same)
    "visualization_msgs/msg/Marker": (
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\n"
        "int32 LINE_STRIP=4\nint32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\n"
        "int32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n"
        "int32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\n\n"
        "int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\n"
        "std_msgs/Header header\n"
        "string ns\n"
        "int32 id\n"
        "int32 type\n"
        "int32 action\n"
        "geometry_msgs/Pose pose\n"
        "geometry_msgs/Vector3 scale\n"
        "std_msgs/ColorRGBA color\n"
        "builtin_interfaces/Duration lifetime\n"
        "bool frame_locked\n\n"
        "geometry_msgs/Point[] points\n"
        "std_msgs/ColorRGBA[] colors\n\n"
        "string texture_resource\n"
        "sensor_msgs/CompressedImage texture\n"
        "UVCoordinate[] uv_coordinates\n\n"
        "string text\n\n"
        "string mesh_resource\n"
        "MeshFile mesh_file\n"
        "bool mesh_use_embedded_materials\n"
    ),
    "visualization_msgs/msg/MarkerArray": "Marker[] markers\n",
}

KNOWN_TYPES: tuple[str, ...] = tuple(sorted(DEFINITIONS))

# RIHS01 type-description hashes (identical in Humble's and Jazzy's definitions).
TYPE_HASHES: dict[str, str] = {
    "geometry_msgs/msg/Transform":
        "RIHS01_beb83fbe698636351461f6f35d1abb20010c43d55374d81bd041f1ba2581fddc",
    "geometry_msgs/msg/TransformStamped":
        "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
    "tf2_msgs/msg/TFMessage":
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "builtin_interfaces/msg/Duration":
        "RIHS01_e8d009f659816f758b75334ee1a9ca5b5c0b859843261f14c7f937349599d93b",
    "builtin_interfaces/msg/Time":
        "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "geometry_msgs/msg/Point":
        "RIHS01_6963084842a9b04494d6b2941d11444708d892da2f4b09843b9c43f42a7f6881",
    "geometry_msgs/msg/PointStamped":
        "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
    "geometry_msgs/msg/Quaternion":
        "RIHS01_8a765f66778c8ff7c8ab94afcc590a2ed5325a1d9a076ffff38fbce36f458684",
    "geometry_msgs/msg/Vector3":
        "RIHS01_cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
    "geometry_msgs/msg/Wrench":
        "RIHS01_018e8519d57c16adbe97c9fe1460ef21fec7e31bc541de3d653a35895677ce52",
    "geometry_msgs/msg/WrenchStamped":
        "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
    "rosgraph_msgs/msg/Clock":
        "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    "sensor_msgs/msg/Imu":
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "sensor_msgs/msg/JointState":
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "std_msgs/msg/Bool":
        "RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9",
    "std_msgs/msg/Float64MultiArray":
        "RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
    "std_msgs/msg/Header":
        "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "std_msgs/msg/Int32MultiArray":
        "RIHS01_84a7346323525d1b4dfca899df3820f245e54009dac5a6b69217d14fdefd1701",
    "std_msgs/msg/MultiArrayDimension":
        "RIHS01_5e773a60a4c7fc8a54985f307c7837aa2994252a126c301957a24e31282c9cbe",
    "std_msgs/msg/MultiArrayLayout":
        "RIHS01_4c66e6f78e740ac103a94cf63259f968e48c617e7699e829b63c21a5cb50dac6",
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "geometry_msgs/msg/Pose":
        "RIHS01_d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
    "std_msgs/msg/ColorRGBA":
        "RIHS01_77a7a5b9ae477306097665106e0413ba74440245b1f3d0c6d6405fe5c7813fe8",
    "sensor_msgs/msg/CompressedImage":
        "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a",
    "visualization_msgs/msg/UVCoordinate":
        "RIHS01_f27f7ed21fe360c6066944f856b801a0c0d1e94e815b6886444b42d90b196a26",
    "visualization_msgs/msg/MeshFile":
        "RIHS01_7710ece15a148fb7c9b546364cfb215bb06098087bd6394fe5b73a493508f8c4",
    "visualization_msgs/msg/Marker":
        "RIHS01_45b13ccf791f225962bf74e746f9644518855d783a6f42ba0cc14fde2b4f3ce0",
    "visualization_msgs/msg/MarkerArray":
        "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
}

PRIMITIVE_TYPES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string",
})

_CONSTANT_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_/]*\s+[A-Za-z][A-Za-z0-9_]*\s*=")
_FIELD_RE = re.compile(
    r"^(?P<type>[A-Za-z][A-Za-z0-9_/]*)(?:\[(?P<size>[0-9]*)\])?\s+(?P<name>[A-Za-z][A-Za-z0-9_]*)"
)


@dataclass(frozen=True)
class Field:
    """One field of a message.

    ``type`` is a primitive name or a normalized ``pkg/msg/Type``; ``array`` is
    ``None`` for a scalar, ``-1`` for an unbounded sequence, ``n`` for ``T[n]``.
    """

    name: str
    type: str
    array: int | None

    @property
    def is_primitive(self) -> bool:
        return self.type in PRIMITIVE_TYPES


def _normalize(ref: str, package: str) -> str:
    """``Vector3`` in geometry_msgs -> ``geometry_msgs/msg/Vector3``; keeps primitives."""
    if ref in PRIMITIVE_TYPES:
        return ref
    parts = ref.split("/")
    if len(parts) == 1:
        return f"{package}/msg/{ref}"
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return ref


def _qualified(ref: str, package: str) -> str:
    """The dependency name rosbag2 writes after ``MSG:``: as spelled, package-qualified."""
    return ref if "/" in ref else f"{package}/{ref}"


def _field_lines(msgtype: str):
    """The field lines of a definition (constants such as ``int32 ARROW=0`` skipped)."""
    for raw in DEFINITIONS[msgtype].splitlines():
        line = raw.split("#", 1)[0].strip()
        if line and not _CONSTANT_RE.match(line):
            m = _FIELD_RE.match(line)
            if m is None:  # pragma: no cover - guards edits of DEFINITIONS
                raise ValueError(f"cannot parse line {raw!r} of {msgtype}")
            yield m


def fields(msgtype: str) -> tuple[Field, ...]:
    """The fields of ``msgtype`` (a key of :data:`DEFINITIONS`), in order."""
    package = msgtype.split("/")[0]
    out = []
    for m in _field_lines(msgtype):
        size = m.group("size")
        array = None if size is None else (-1 if size == "" else int(size))
        out.append(Field(m.group("name"), _normalize(m.group("type"), package), array))
    return tuple(out)


def _dependencies(msgtype: str) -> list[str]:
    """Non-primitive field types as rosbag2 names them (sorted, unique)."""
    package = msgtype.split("/")[0]
    deps = {_qualified(m.group("type"), package) for m in _field_lines(msgtype)
            if m.group("type") not in PRIMITIVE_TYPES}
    return sorted(deps)


def full_text(msgtype: str) -> str:
    """Concatenated definition of ``msgtype`` and its dependencies, as rosbag2 writes it."""
    if msgtype not in DEFINITIONS:
        raise ValueError(
            f"unknown message type {msgtype!r}; known types: {', '.join(KNOWN_TYPES)}")
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:  # pragma: no cover - our definitions are acyclic
            raise RuntimeError(f"recursion too deep resolving {msgtype}")
        text = DEFINITIONS[name]
        for dep in _dependencies(name):
            if dep not in seen:
                seen.add(dep)
                text += f"\n{_SEPARATOR}\nMSG: {dep}\n" + append(_normalize(dep, ""), depth - 1)
        return text

    return append(msgtype, 50)
