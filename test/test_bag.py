"""flexarm_ros.bag: rosbag2-compatible MCAP writing and damage-tolerant reading, no ROS."""

import dataclasses
import io
import math
import re
import subprocess
import sys

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from flexarm_ros.bag import (KNOWN_TYPES, BagError, BagWriter, CorruptChunkWarning, TruncatedBagWarning, iter_messages, read_bag, to_dict)
from flexarm_ros.bag import messages as m
from flexarm_ros.bag.msgdefs import TYPE_HASHES, full_text
from flexarm_ros.bag.writer import encode_cdr

try:  # rosbags (the [dev] extra) is the independent reference implementation
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader as Rosbag2Reader
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Rosbag2Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
except ImportError:  # pragma: no cover
    AnyReader = None

needs_rosbags = pytest.mark.skipif(AnyReader is None,
                                   reason="rosbags is not installed (pip install -e .[dev])")

T0 = 1_700_000_000_123_456_789
NAMES = ["shoulder", "elbow", "link1_mode1", "link1_mode2", "link2_mode1", "link2_mode2"]


def _marker(mtype, points):
    """A visualization_msgs/Marker dict with every field set, its texture and mesh too."""
    return {"header": m.header(T0, "world"), "ns": "links", "id": 1, "type": mtype,
            "action": 0,
            "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                     "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "scale": {"x": 0.02, "y": 0.0, "z": 0.0},
            "color": {"r": 0.25, "g": 0.5, "b": 1.0, "a": 1.0},
            "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
            "points": [{"x": float(x), "y": float(y), "z": 0.0} for x, y in points],
            "colors": [{"r": 1.0, "g": 0.0, "b": 0.0, "a": 0.5}] * len(points),
            "texture_resource": "", "texture": {"header": m.header(0, ""), "format": "",
                                                "data": [3]},
            "uv_coordinates": [{"u": 0.25, "v": 0.5}], "text": "arm",
            "mesh_resource": "", "mesh_file": {"filename": "", "data": []},
            "mesh_use_embedded_materials": True}


def samples():
    """(topic, type, message) covering every known type, numpy input, NaN/inf, unicode."""
    nan, inf = float("nan"), float("inf")
    modes = np.arange(6.0).reshape(2, 3)
    modes[0, 1], modes[1, 2] = nan, -inf
    dim = {"label": "sample", "size": 2, "stride": 6}
    return [
        ("/clock", "rosgraph_msgs/msg/Clock", m.clock(T0)),
        ("/stamp", "builtin_interfaces/msg/Time", m.stamp(-1_500_000_000)),
        ("/duration", "builtin_interfaces/msg/Duration", {"sec": -3, "nanosec": 999_999_999}),
        ("/header", "std_msgs/msg/Header", m.header(T0, "wörld_frame")),
        ("/flag", "std_msgs/msg/Bool", {"data": True}),
        ("/scene", "std_msgs/msg/String", {"data": "scene: two_link\nE: 7.0e10  # Pa\n"}),
        ("/dim", "std_msgs/msg/MultiArrayDimension", dim),
        ("/layout", "std_msgs/msg/MultiArrayLayout", {"dim": [dim, dim], "data_offset": 0}),
        ("/modes", "std_msgs/msg/Float64MultiArray", m.float64_multiarray(modes, ("s", "q"))),
        ("/ids", "std_msgs/msg/Int32MultiArray",
         m.int32_multiarray(np.array([-(2**31), 0, 2**31 - 1]), "id")),
        ("/joint_states", "sensor_msgs/msg/JointState",
         m.joint_state(T0, NAMES, np.linspace(-1, 1, 6), np.ones(6), np.zeros(6), "base")),
        ("/imu", "sensor_msgs/msg/Imu", m.imu(T0, "tip_imu", [0.1, -0.2, 9.0], [0, 0, 9.81])),
        ("/quat", "geometry_msgs/msg/Quaternion", {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}),
        ("/vec", "geometry_msgs/msg/Vector3", {"x": 1.0, "y": nan, "z": inf}),
        ("/pt", "geometry_msgs/msg/Point", {"x": 1e-300, "y": -0.0, "z": 3.0}),
        ("/wrench", "geometry_msgs/msg/Wrench",
         {"force": {"x": 1.0, "y": 2.0, "z": 3.0}, "torque": {"x": 4.0, "y": 5.0, "z": 6.0}}),
        ("/tip_wrench", "geometry_msgs/msg/WrenchStamped",
         m.wrench_stamped(T0, "tip", np.array([1.0, 2.0, 3.0]), (0.1, 0.2, 0.3))),
        ("/tip", "geometry_msgs/msg/PointStamped", m.point_stamped(T0, "world", [0.5, 0, 1])),
        ("/pose", "geometry_msgs/msg/Pose",
         {"position": {"x": 1.0, "y": 2.0, "z": 3.0},
          "orientation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}}),
        ("/tf", "tf2_msgs/msg/TFMessage",
         m.tf_message(T0, [("world", "link1_hub", 0.0, 0.1, 0.5), ("a", "b", 1.0, 0.0, -3.0)])),
        ("/transform", "geometry_msgs/msg/TransformStamped",
         m.tf_message(T0, [("world", "tool", 1.0, 2.0, 0.25)])["transforms"][0]),
        ("/tr", "geometry_msgs/msg/Transform",
         {"translation": {"x": 1.0, "y": 2.0, "z": 0.0},
          "rotation": {"x": 0.0, "y": 0.0, "z": 0.6, "w": 0.8}}),
        ("/color", "std_msgs/msg/ColorRGBA", {"r": 0.5, "g": 0.25, "b": 1.0, "a": 0.125}),
        ("/image", "sensor_msgs/msg/CompressedImage",
         {"header": m.header(T0, "cam"), "format": "png", "data": [137, 80, 78, 71, 0, 255]}),
        ("/uv", "visualization_msgs/msg/UVCoordinate", {"u": 0.5, "v": -0.75}),
        ("/mesh", "visualization_msgs/msg/MeshFile", {"filename": "arm.stl", "data": [1, 2]}),
        ("/marker", "visualization_msgs/msg/Marker", _marker(4, [[0, 0], [0.5, 0.1]])),
        ("/markers", "visualization_msgs/msg/MarkerArray",
         {"markers": [_marker(4, [[0, 0], [0.5, 0.1], [1.0, 0.3]]), _marker(2, [])]}),
        # second messages on some topics
        ("/flag", "std_msgs/msg/Bool", {"data": np.bool_(False)}),
        ("/scene", "std_msgs/msg/String", {"data": ""}),
        ("/modes", "std_msgs/msg/Float64MultiArray", m.float64_multiarray([1.5, 2.5], ("q",))),
        ("/joint_states", "sensor_msgs/msg/JointState", m.joint_state(T0 + 1, NAMES[:2], [1, 2])),
        ("/imu", "sensor_msgs/msg/Imu",
         m.imu(T0 + 1, "tip_imu", [1, 2, 3], [4, 5, 6], [0, 0, 0.6, 0.8],
               angular_velocity_covariance=np.eye(3) * 1e-4,
               orientation_covariance=np.arange(9.0))),
    ]


def plain(value):
    """Input message -> plain python (numpy converted, tuples as lists)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def from_rosbags(value):
    """rosbags-decoded message -> plain python."""
    if dataclasses.is_dataclass(value):
        return {f.name: from_rosbags(getattr(value, f.name))
                for f in dataclasses.fields(value)
                if not f.name.startswith("__") and not f.name.isupper()}   # constants
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list):
        return [from_rosbags(v) for v in value]
    return value


def same(a, b):
    """Structural equality with NaN == NaN and -0.0 told apart from 0.0 (a uint8[] read
    as bytes equals its list of values)."""
    a, b = (list(v) if isinstance(v, bytes) else v for v in (a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return a == b and math.copysign(1, a) == math.copysign(1, b)
    return type(a) is type(b) and a == b


def write_samples(target, **kwargs):
    msgs = samples()
    with BagWriter(target, {"software": "flexarm_ros test"}, **kwargs) as w:
        w.add_metadata("scene", {"yaml": "links: 2\n", "name": "two_link"})
        for i, (topic, msgtype, msg) in enumerate(msgs):
            w.write(topic, msgtype, msg, T0 + 1000 * i, publish_time_ns=T0 + 1000 * i - 7)
    return w, msgs


def expected_by_topic(msgs):
    out = {}
    for i, (topic, _, msg) in enumerate(msgs):
        out.setdefault(topic, []).append((T0 + 1000 * i, plain(msg)))
    return out


def test_samples_cover_every_known_type():
    assert {t for _, t, _ in samples()} == set(KNOWN_TYPES)


# --- message definitions ------------------------------------------------------------


@needs_rosbags
@pytest.mark.parametrize("store", ["ROS2_HUMBLE", "ROS2_JAZZY"])
def test_msgdefs_match_the_real_ros2_definitions(store):
    real = get_typestore(getattr(Stores, store))
    for msgtype in KNOWN_TYPES:
        ours = get_typestore(Stores.EMPTY)
        ours.register(get_types_from_msg(full_text(msgtype), msgtype))
        consts, fields = ours.fielddefs[msgtype]
        assert fields == real.fielddefs[msgtype][1], msgtype
        if store == "ROS2_JAZZY" or msgtype != "visualization_msgs/msg/Marker":
            assert consts == real.fielddefs[msgtype][0], msgtype   # Humble: no ARROW_STRIP
        assert ours.hash_rihs01(msgtype) == real.hash_rihs01(msgtype) == TYPE_HASHES[msgtype]


def test_full_text_concatenates_dependencies_like_rosbag2():
    sep = "=" * 80
    text = full_text("sensor_msgs/msg/Imu")
    blocks = text.split(f"\n{sep}\nMSG: ")
    assert [b.split("\n", 1)[0] for b in blocks[1:]] == [
        "geometry_msgs/Quaternion", "geometry_msgs/Vector3", "std_msgs/Header",
        "builtin_interfaces/Time"]
    assert blocks[0].startswith("std_msgs/Header header\n")
    wrench = full_text("geometry_msgs/msg/WrenchStamped")
    assert wrench.count("MSG: geometry_msgs/Vector3\n") == 1  # each dependency once
    assert full_text("std_msgs/msg/Bool") == "bool data\n"


# --- round trips --------------------------------------------------------------------


@pytest.mark.parametrize("where", ["memory", "file"])
def test_round_trip_of_every_type(where, tmp_path):
    target = io.BytesIO() if where == "memory" else tmp_path / "run.mcap"
    _, msgs = write_samples(target)
    source = target.getvalue() if where == "memory" else target
    bag = read_bag(source)
    assert not bag.truncated and bag.profile == "ros2"
    want = expected_by_topic(msgs)
    assert bag.topics == list(want)
    for topic, expected in want.items():
        got = [(t, to_dict(msg)) for t, msg in bag[topic]]
        assert [t for t, _ in got] == [t for t, _ in expected]
        for (_, g), (_, e) in zip(got, expected):
            assert same(g, e), (topic, g, e)
    assert bag.types["/imu"] == "sensor_msgs/msg/Imu"
    assert bag.metadata["scene"] == {"yaml": "links: 2\n", "name": "two_link"}
    assert bag.metadata["flexarm_ros"] == {"software": "flexarm_ros test"}
    assert {x.log_time_ns - x.publish_time_ns for x in iter_messages(source)} == {7}


def test_iter_messages_filters_topics_in_file_order(tmp_path):
    path = tmp_path / "b.mcap"
    _, msgs = write_samples(path)
    got = list(iter_messages(path, topics=["/flag", "/imu"]))
    assert [(x.topic, x.msgtype) for x in got] == [
        (t, ty) for t, ty, _ in msgs if t in ("/flag", "/imu")]
    assert [x.message.data for x in iter_messages(path, "/flag")] == [True, False]


def test_writer_keeps_nan_and_empty_trailing_arrays_unchanged():
    buf = io.BytesIO()
    raw = {"header": m.header(5, ""), "name": ["a"], "position": [float("nan")],
           "velocity": [], "effort": []}
    with BagWriter(buf) as w:
        w.write("/joint_states", "sensor_msgs/msg/JointState", raw, 5)
        w.write("/joint_states", "sensor_msgs/msg/JointState", m.joint_state(6, ["a"], [1.0]), 6)
    (_, first), (_, second) = read_bag(buf.getvalue())["/joint_states"]
    assert same(to_dict(first), raw)
    assert same(to_dict(second)["effort"], [float("nan")])  # helper pads to len(name)
    assert same(to_dict(second)["velocity"], [float("nan")])


@needs_rosbags
def test_cdr_is_byte_identical_to_rosbags_and_mcap_ros2():
    from mcap_ros2._dynamic import serialize_dynamic

    typestore = get_typestore(Stores.ROS2_JAZZY)
    extra = [("/js", "sensor_msgs/msg/JointState",
              {"header": m.header(1, "abc"), "name": ["a"], "position": [1.0],
               "velocity": [], "effort": []}),
             ("/js", "sensor_msgs/msg/JointState", m.joint_state(0, [], [], [], []))]
    for _, msgtype, msg in samples() + extra:
        ours = encode_cdr(msgtype, msg)
        theirs = typestore.serialize_cdr(typestore.deserialize_cdr(ours, msgtype), msgtype)
        assert ours == theirs, msgtype
        assert ours == serialize_dynamic(msgtype, full_text(msgtype))[msgtype](plain(msg))


# --- compatibility with rosbags and the rosbag2 layout ------------------------------


@needs_rosbags
@pytest.mark.parametrize("version", [8, 9])
def test_rosbags_decodes_every_message(tmp_path, version):
    path = tmp_path / "bag" / "bag.mcap"
    path.parent.mkdir()
    w, msgs = write_samples(path, rosbag2_version=version)
    want = [(t, T0 + 1000 * i, plain(msg)) for i, (t, _, msg) in enumerate(msgs)]
    # 1. the bare .mcap file
    with AnyReader([path]) as reader:
        got = [(c.topic, ts, from_rosbags(reader.deserialize(raw, c.msgtype)))
               for c, ts, raw in reader.messages()]
    assert len(got) == len(want)
    for g, e in zip(got, want):
        assert g[:2] == e[:2] and same(g[2], e[2]), (g, e)
    # 2. a rosbag2 directory (metadata.yaml next to the file), as Humble expects
    assert w.write_metadata_yaml() == path.parent / "metadata.yaml"
    with Rosbag2Reader(path.parent) as reader:
        assert reader.message_count == len(msgs)
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
        assert {q.reliability.name for q in qos.values()} == {"RELIABLE"}
        assert {(q.history.name, q.depth, q.durability.name) for q in qos.values()} == {
            ("KEEP_LAST", 10, "VOLATILE")}
        typestore = get_typestore(Stores.ROS2_JAZZY)
        decoded = [from_rosbags(typestore.deserialize_cdr(raw, c.msgtype))
                   for c, _, raw in reader.messages()]
    assert all(same(d, e[2]) for d, e in zip(decoded, want))
    assert read_bag(path.parent).message_count == len(msgs)  # the directory form


def test_mcap_layout_is_rosbag2s(tmp_path):
    path = tmp_path / "run.mcap"
    w, msgs = write_samples(path, chunk_size=512)
    counts = {}
    for topic, _, _ in msgs:
        counts[topic] = counts.get(topic, 0) + 1
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == set(KNOWN_TYPES)
        for name, schema in schemas.items():
            assert schema.encoding == "ros2msg" and schema.data.decode() == full_text(name)
        assert len(summary.channels) == len(counts)
        for channel in summary.channels.values():
            assert channel.message_encoding == "cdr"
            qos = yaml.safe_load(channel.metadata["offered_qos_profiles"])
            assert qos[0]["reliability"] == "reliable" and qos[0]["durability"] == "volatile"
            assert qos[0]["history"] == "keep_last" and qos[0]["depth"] == 10
            assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        assert summary.statistics.message_count == len(msgs)
        assert len(summary.chunk_indexes) > 1
        assert all(c.compression == "zstd" and c.message_index_offsets
                   for c in summary.chunk_indexes)
        records = {r.name: r.metadata for r in reader.iter_metadata()}
    meta = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert meta == w.rosbag2_metadata
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["message_count"] == len(msgs)
    assert meta["starting_time"]["nanoseconds_since_epoch"] == T0
    assert meta["duration"]["nanoseconds"] == 1000 * (len(msgs) - 1)
    assert meta["compression_format"] == meta["compression_mode"] == ""
    assert meta["relative_file_paths"] == ["run.mcap"]
    assert meta["custom_data"] == {"software": "flexarm_ros test"}
    per_topic = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert {k: v["message_count"] for k, v in per_topic.items()} == counts
    js = per_topic["/joint_states"]["topic_metadata"]
    assert js["type"] == "sensor_msgs/msg/JointState" and js["serialization_format"] == "cdr"
    assert js["offered_qos_profiles"][0]["reliability"] == "reliable"
    assert records["scene"]["name"] == "two_link"


# --- foreign files ------------------------------------------------------------------


def test_reads_a_bag_written_by_plain_mcap_ros2_writer():
    from mcap_ros2.writer import Writer

    # different definition style: pkg/msg/Type after MSG:, comments kept
    text = ("# joint state\nstd_msgs/Header header\nstring[] name\nfloat64[] position\n"
            "float64[] velocity\nfloat64[] effort\n" + "=" * 80 +
            "\nMSG: std_msgs/msg/Header\n# hdr\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
            + "=" * 80 + "\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n")
    buf = io.BytesIO()
    writer = Writer(buf)
    js = writer.register_msgdef("sensor_msgs/msg/JointState", text)
    string = writer.register_msgdef("std_msgs/msg/String", "string data\n")
    for i in range(3):
        writer.write_message("/js", js, m.joint_state(i, ["a"], [float(i)], [0.0], [1.0]),
                             log_time=100 + i)
    writer.write_message("/note", string, {"data": "hi"}, log_time=200)
    writer.finish()
    bag = read_bag(buf.getvalue())
    assert [t for t, _ in bag["/js"]] == [100, 101, 102]
    assert [msg.position for _, msg in bag["/js"]] == [[0.0], [1.0], [2.0]]
    assert bag["/js"][2][1].header.stamp.nanosec == 2
    assert bag["/note"][0][1].data == "hi" and bag.types["/note"] == "std_msgs/msg/String"


@needs_rosbags
def test_reads_a_bag_written_by_rosbags(tmp_path):
    typestore = get_typestore(Stores.ROS2_JAZZY)
    JointState = typestore.types["sensor_msgs/msg/JointState"]
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    Wrench = typestore.types["geometry_msgs/msg/Wrench"]
    Vector3 = typestore.types["geometry_msgs/msg/Vector3"]
    with Rosbag2Writer(tmp_path / "foreign", version=9,
                       storage_plugin=StoragePlugin.MCAP) as writer:
        cjs = writer.add_connection("/js", JointState.__msgtype__, typestore=typestore)
        cw = writer.add_connection("/w", Wrench.__msgtype__, typestore=typestore)
        for i in range(4):
            msg = JointState(Header(Time(i, 5), "f"), ["j"], np.array([0.5 * i]),
                             np.array([1.0]), np.array([]))
            writer.write(cjs, 1000 + i, typestore.serialize_cdr(msg, JointState.__msgtype__))
        wrench = Wrench(Vector3(1.0, 2.0, 3.0), Vector3(-1.0, -2.0, float("nan")))
        writer.write(cw, 2000, typestore.serialize_cdr(wrench, Wrench.__msgtype__))
    bag = read_bag(tmp_path / "foreign" / "foreign.mcap")
    assert bag.profile == "ros2" and bag.rosbag2_metadata()["message_count"] == 5
    assert [(t, msg.position, msg.effort) for t, msg in bag["/js"]] == [
        (1000 + i, [0.5 * i], []) for i in range(4)]
    assert same(to_dict(bag["/w"][0][1]), plain({"force": {"x": 1.0, "y": 2.0, "z": 3.0},
                                                 "torque": {"x": -1.0, "y": -2.0,
                                                            "z": float("nan")}}))


# --- damaged files ------------------------------------------------------------------


def _many(target, n=400, **kwargs):
    msgs = [m.joint_state(T0 + i * 10**6, NAMES, np.sin(np.arange(6) + i), np.cos(np.arange(6) + i),
                          np.full(6, 0.1 * i)) for i in range(n)]
    w = BagWriter(target, chunk_size=4096, **kwargs)
    for i, msg in enumerate(msgs):
        w.write("/joint_states", "sensor_msgs/msg/JointState", msg, T0 + i * 10**6)
    return w, msgs


def _assert_prefix(recovered, msgs):
    assert len(recovered) <= len(msgs)
    for (t, got), i in zip(recovered, range(len(msgs))):
        assert t == T0 + i * 10**6
        assert same(to_dict(got), plain(msgs[i]))


def test_truncated_file_yields_the_complete_chunks_and_warns(tmp_path):
    path = tmp_path / "cut.mcap"
    w, msgs = _many(path)
    w.close()
    data = path.read_bytes()
    path.write_bytes(data[: int(0.6 * len(data))])
    with pytest.warns(TruncatedBagWarning,
                      match=re.escape(str(path)) + ": MCAP bag is truncated") as record:
        bag = read_bag(path)
    assert bag.truncated
    recovered = bag["/joint_states"]
    assert 0 < len(recovered) < len(msgs)
    _assert_prefix(recovered, msgs)
    assert f"recovered {len(recovered)} messages" in str(record[0].message)
    with pytest.warns(TruncatedBagWarning):
        streamed = list(iter_messages(path))
    assert len(streamed) == len(recovered)


@pytest.mark.parametrize("fraction", [0.0005, 0.003, 0.25, 0.5, 0.97, 0.9999])
def test_any_cut_gives_an_ordered_prefix(fraction):
    buf = io.BytesIO()
    w, msgs = _many(buf, n=200)
    w.close()
    data = buf.getvalue()
    with pytest.warns(TruncatedBagWarning, match="<bytes>"):
        bag = read_bag(data[: max(1, int(fraction * len(data)))])
    _assert_prefix(bag.messages.get("/joint_states", []), msgs)


def test_bag_of_a_killed_writer_is_readable_up_to_the_last_chunk(tmp_path):
    path = tmp_path / "live.mcap"
    w, msgs = _many(path, n=300)  # not closed: the file is what a SIGKILL would leave
    with pytest.warns(TruncatedBagWarning, match="without MCAP footer"):
        partial = read_bag(path)["/joint_states"]
    assert 0 < len(partial) < len(msgs)
    _assert_prefix(partial, msgs)
    w.flush()  # closes the open chunk
    with pytest.warns(TruncatedBagWarning):
        assert len(read_bag(path)["/joint_states"]) == len(msgs)
    w.close()
    assert len(read_bag(path)["/joint_states"]) == len(msgs)


def test_corrupted_chunk_is_skipped_and_reading_continues():
    """16 bytes overwritten inside a chunk: that chunk fails its CRC and is skipped (a
    CorruptChunkWarning, still a TruncatedBagWarning, names it and what it held); every
    message of the other chunks is read, in order. Truth: the chunk that holds the damaged
    bytes and its messages, from mcap's own reader on the intact file."""
    from mcap.records import Chunk as McapChunk, Message as McapMessage
    from mcap.stream_reader import StreamReader, breakup_chunk
    buf = io.BytesIO()
    w, msgs = _many(buf, n=200, compression="none")
    w.close()
    data = bytearray(buf.getvalue())
    mid = len(data) // 2
    summary = make_reader(io.BytesIO(bytes(data))).get_summary()
    hit = [c for c in summary.chunk_indexes
           if c.chunk_start_offset + 9 + 60 <= mid < c.chunk_start_offset + c.chunk_length - 16]
    assert len(hit) == 1                        # the damage lies inside one chunk's data
    chunks = [r for r in StreamReader(io.BytesIO(bytes(data)), emit_chunks=True).records
              if isinstance(r, McapChunk)]
    k = [c.chunk_start_offset for c in summary.chunk_indexes].index(hit[0].chunk_start_offset)
    lost = {r.log_time for r in breakup_chunk(chunks[k]) if isinstance(r, McapMessage)}
    assert 0 < len(lost) < len(msgs)
    data[mid:mid + 16] = b"\xff" * 16
    with pytest.warns(CorruptChunkWarning, match="damaged at byte .*crc validation failed"
                      f".*: {len(lost)} messages lost") as record:
        bag = read_bag(bytes(data))
    assert issubclass(record[0].category, TruncatedBagWarning)
    want = [(T0 + i * 10**6, plain(m)) for i, m in enumerate(msgs)
            if T0 + i * 10**6 not in lost]
    got = [(t, to_dict(m)) for t, m in bag["/joint_states"]]
    assert len(got) == len(want) == len(msgs) - len(lost)
    assert all(g[0] == e[0] and same(g[1], e[1]) for g, e in zip(got, want))
    assert bag.truncated and [(d.start, d.kind, d.lost_messages) for d in bag.damage] == [
        (hit[0].chunk_start_offset, "corrupt", len(lost))]


def test_empty_and_foreign_files_raise_bag_error(tmp_path):
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(BagError, match=re.escape(str(empty)) + ".*empty"):
        read_bag(empty)
    text = tmp_path / "notes.txt"
    text.write_text("just some notes\n")
    with pytest.raises(BagError, match=re.escape(str(text)) + ".*not an MCAP file"):
        read_bag(text)
    with pytest.raises(ValueError):  # BagError is a ValueError
        list(iter_messages(text))


# --- validation ---------------------------------------------------------------------


def test_unknown_message_type_is_refused():
    with BagWriter(io.BytesIO()) as w:
        with pytest.raises(ValueError, match=r"unknown message type 'std_msgs/msg/Float32'.*"
                                             r"known types: .*sensor_msgs/msg/JointState"):
            w.write("/x", "std_msgs/msg/Float32", {"data": 1.0}, 0)


@pytest.mark.parametrize("msg, field, problem", [
    ({"header": {"stamp": {"sec": 1}, "frame_id": ""}, "name": [], "position": [],
      "velocity": [], "effort": []}, "header.stamp.nanosec", "missing field"),
    ({"header": m.header(0), "name": ["a"], "position": [1.0], "velocity": [1.0]},
     "effort", "missing field"),
    ({**m.joint_state(0, ["a"]), "positon": [1.0]}, "positon", "unknown field"),
    ({**m.joint_state(0, ["a"]), "position": ["1.0"]}, "position[0]", "expected a number"),
    ({**m.joint_state(0, ["a"]), "position": np.zeros((1, 1))}, "position", "1-D array"),
    ({**m.joint_state(0, ["a"]), "header": {"stamp": {"sec": 2**31, "nanosec": 0},
                                            "frame_id": ""}}, "header.stamp.sec", "out of range"),
    ({**m.joint_state(0, ["a"]), "name": "a"}, "name", "expected a sequence"),
    ({**m.joint_state(0, ["a"]), "velocity": [True]}, "velocity[0]", "expected a number"),
    ({**m.joint_state(0, ["a"]), "effort": [[1.0]]}, "effort[0]", "expected a number"),
    ({**m.joint_state(0, ["a"]), "effort": [None]}, "effort[0]", "expected a number"),
    ({**m.joint_state(0, ["a"]), "name": [1]}, "name[0]", "expected a str"),
    ({**m.joint_state(0, ["a"]), "header": None}, "header", "expected a dict"),
])
def test_invalid_message_names_topic_type_and_field(msg, field, problem):
    with BagWriter(io.BytesIO()) as w:
        with pytest.raises(ValueError) as err:
            w.write("/joint_states", "sensor_msgs/msg/JointState", msg, 0)
    text = str(err.value)
    assert "topic '/joint_states' (sensor_msgs/msg/JointState)" in text
    assert f"field '{field}'" in text and problem in text


def test_fixed_size_arrays_and_writer_state_are_checked():
    with BagWriter(io.BytesIO()) as w:
        bad = m.imu(0, "f", [0, 0, 0], [0, 0, 0])
        bad["orientation_covariance"] = [0.0] * 8
        with pytest.raises(ValueError, match="orientation_covariance.*exactly 9"):
            w.write("/imu", "sensor_msgs/msg/Imu", bad, 0)
        w.write("/a", "std_msgs/msg/Bool", {"data": True}, 0)
        with pytest.raises(ValueError, match="already carries std_msgs/msg/Bool"):
            w.write("/a", "std_msgs/msg/String", {"data": "x"}, 1)
        with pytest.raises(ValueError, match="absolute ROS name"):
            w.write("relative", "std_msgs/msg/Bool", {"data": True}, 1)
        with pytest.raises(ValueError, match="log_time_ns"):
            w.write("/a", "std_msgs/msg/Bool", {"data": True}, 1.5)
        with pytest.raises(ValueError, match="reserved"):
            w.add_metadata("rosbag2", {"a": "b"})
        with pytest.raises(ValueError, match="str to str"):
            w.add_metadata("scene", {"links": 2})
    with pytest.raises(ValueError, match="closed"):
        w.write("/a", "std_msgs/msg/Bool", {"data": True}, 2)
    assert w.message_counts == {"/a": 1}


# --- helpers ------------------------------------------------------------------------


def test_message_helpers():
    assert m.stamp(-1) == {"sec": -1, "nanosec": 999_999_999}
    assert m.stamp(T0) == {"sec": 1_700_000_000, "nanosec": 123_456_789}
    layout = m.float64_multiarray(np.zeros((4, 3)), ("sample", "channel"))["layout"]
    assert layout == {"dim": [{"label": "sample", "size": 4, "stride": 12},
                              {"label": "channel", "size": 3, "stride": 3}], "data_offset": 0}
    arr = np.arange(12.0).reshape(4, 3)
    msg = m.float64_multiarray(arr, ("sample", "channel"))
    stride = msg["layout"]["dim"][1]["stride"]
    assert msg["data"][stride * 2 + 1] == arr[2, 1]
    with pytest.raises(ValueError, match="labels"):
        m.float64_multiarray(arr, ("sample",))
    js = m.joint_state(0, ["a", "b"], position=[1, 2])
    assert len(js["velocity"]) == len(js["effort"]) == 2 and math.isnan(js["effort"][1])
    with pytest.raises(ValueError, match="expected 2 values"):
        m.joint_state(0, ["a", "b"], position=[1, 2, 3])
    no_orientation = m.imu(0, "imu", [0, 0, 1], [0, 0, 9.81])
    assert no_orientation["orientation_covariance"][0] == -1.0
    assert no_orientation["orientation"] == {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}
    assert no_orientation["angular_velocity_covariance"] == [0.0] * 9  # unknown covariance
    gyro_only = m.imu(0, "imu", angular_velocity=[0, 0, 1])
    assert gyro_only["linear_acceleration_covariance"][0] == -1.0
    assert m.int32_multiarray([1, 2], "id")["layout"]["dim"] == [
        {"label": "id", "size": 2, "stride": 2}]


@pytest.mark.subprocess
def test_bag_package_imports_without_rclpy():
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "import flexarm_ros.bag, flexarm_ros.bag.reader, flexarm_ros.bag.writer\n"
            "assert 'rclpy' not in [k for k, v in sys.modules.items() if v is not None]\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_uint8_sequences_are_written_from_bytes_as_the_readers_give_them():
    """A message read back from a bag carries uint8[] as bytes (a CompressedImage's data,
    a Marker's texture.data): writing it again encodes the same CDR as from a list (the
    golden bag's arm_markers, rewritten by test_bag_export, failed on it)."""
    from flexarm_ros.bag.writer import encode_cdr
    base = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "f"}, "format": "png"}
    as_list = encode_cdr("sensor_msgs/msg/CompressedImage", {**base, "data": [0, 7, 255]})
    for raw in (b"\x00\x07\xff", bytearray(b"\x00\x07\xff"), memoryview(b"\x00\x07\xff")):
        assert encode_cdr("sensor_msgs/msg/CompressedImage", {**base, "data": raw}) == as_list
