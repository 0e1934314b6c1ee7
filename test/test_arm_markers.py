"""``arm_markers``: the deformed arm as visualization_msgs/MarkerArray for RViz2 and
Foxglove (flexarm_ros/nodes/markers.py), live from the simulator and in the bag.

The truth the markers are checked against is independent of the marker code: the batch
co-simulation's ``ground_truth/tip`` (the plant's compiled kernel frames) at the same
stamps, and the bag read with the standard readers (rosbags, mcap_ros2)."""

import math

import numpy as np
import pytest
from mcap.reader import make_reader

from flexarm_ros.bag.writer import encode_cdr
from flexarm_ros.model import Chain
from flexarm_ros.scene import load_scene
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cosim import cosimulate

NS = "/flexarm"
SCENE = "two_link_case1"
DURATION = 0.3
MARKERS = f"{NS}/{T.ARM_MARKERS}"
LINE_STRIP, LINE_LIST, SPHERE, ARROW, DELETE = 4, 5, 2, 0, 2


def _run(path, **simulator):
    from flexarm_ros.run import run
    res = run(SCENE, DURATION, "lockstep", record=path, namespace=NS, progress=False,
              simulator=simulator or None)
    assert not res.interrupted and res.ticks == round(DURATION * 1000)
    return res


def _rosbags(path):
    """{topic: [(log time, message)]} decoded by rosbags from the bag's own schemas."""
    from rosbags.highlevel import AnyReader
    out = {}
    with AnyReader([path]) as reader:
        for c, t, raw in reader.messages():
            out.setdefault(c.topic, []).append((t, reader.deserialize(raw, c.msgtype)))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same lockstep run with markers at the default 30 Hz and with them off."""
    d = tmp_path_factory.mktemp("markers")
    on, off = d / "on.mcap", d / "off.mcap"
    res_on = _run(on)
    res_off = _run(off, marker_rate_hz=0.0)
    return on, off, res_on, res_off


@pytest.fixture(scope="module")
def truth():
    """{t_ns: (x, y)} of the co-simulation's ground_truth/tip."""
    ref = cosimulate(load_scene(SCENE), DURATION)
    return {m.t_ns: (m.data["point"]["x"], m.data["point"]["y"])
            for m in ref.topic(T.GT_TIP)}


# ------------------------------------------------------------------ live, in the bag
@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_last_centerline_point_is_the_ground_truth_tip(runs, truth):
    on = runs[0]
    msgs = _rosbags(on)[MARKERS]
    assert msgs
    n_links = len(load_scene(SCENE).links)
    worst = 0.0
    for t, ma in msgs:
        stamp = ma.markers[0].header.stamp
        assert stamp.sec * 1_000_000_000 + stamp.nanosec == t     # stamped with sim time
        links = [m for m in ma.markers if m.ns == "links"]
        assert [m.id for m in links] == list(range(n_links))
        assert all(m.type == LINE_STRIP and m.header.frame_id == "world" and len(m.points)
                   >= 5 for m in links)
        tip = links[-1].points[-1]
        x, y = truth[t]
        worst = max(worst, math.hypot(tip.x - x, tip.y - y))
        # the links join: link k's root is at most a hub radius from link k-1's tip frame
        assert links[0].points[0].z == 0.0
    assert worst < 1e-9, worst
    print(f"\nworst |marker tip - ground truth tip| over {len(msgs)} arrays: {worst:.3g} m")


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_markers_come_at_the_configured_rate_and_stable_ids(runs):
    on, _, res, _ = runs
    msgs = _rosbags(on)[MARKERS]
    t = np.array([t for t, _ in msgs])
    # the first tick at or after each 1/30 s: 0, 34, 67, 100, ... ms; 0.3 s -> 10 arrays
    expected = [math.ceil(k / 30 * 1000 - 1e-9) * 1_000_000 for k in range(10)]
    assert t.tolist() == expected
    assert res.recorded[MARKERS] == 10
    ids = {tuple((m.ns, m.id, m.type) for m in ma.markers) for _, ma in msgs}
    assert len(ids) == 1                                   # the same markers every time
    kinds = dict(((ns, i), tp) for ns, i, tp in next(iter(ids)))
    assert kinds[("wall", 0)] == LINE_LIST and kinds[("tool", 0)] == SPHERE
    assert kinds[("hubs", 0)] == SPHERE and ("contact_force", 0) in kinds
    # out of contact (two_link_case1 touches its wall later): the arrow is deleted
    assert all(m.action == DELETE for _, ma in msgs for m in ma.markers
               if m.ns == "contact_force")


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_rate_zero_publishes_none_and_markers_change_nothing_else(runs):
    on, off, res_on, res_off = runs
    assert MARKERS not in (res_off.recorded or {})

    def raw(path):
        out = {}
        with open(path, "rb") as f:
            for _, ch, m in make_reader(f).iter_messages(log_time_order=False):
                out.setdefault(ch.topic, []).append((m.log_time, m.data))
        return out
    a, b = raw(on), raw(off)
    # with the markers go the URDF's joint values and the /tf made of them (the URDF
    # itself and /tf_static are in both)
    robot = {t for t in a if t.endswith("/robot_state/joint_states")} | {"/tf"}
    assert MARKERS not in b and set(a) - set(b) == {MARKERS} | robot, set(a) - set(b)
    assert any(t.endswith("/robot_description") for t in b) and "/tf_static" in b
    for topic in b:                                         # the twin is unchanged
        assert a[topic] == b[topic], topic


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_the_bag_schema_decodes_with_mcap_ros2(runs):
    """The recorded schema is the ros2msg text Foxglove reads: mcap_ros2's decoder builds
    the MarkerArray from it."""
    from mcap_ros2.decoder import DecoderFactory
    with open(runs[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        schemas = {s.name: s for s in reader.get_summary().schemas.values()}
        assert schemas["visualization_msgs/msg/MarkerArray"].encoding == "ros2msg"
        got = [(m.log_time, d) for _, ch, m, d in reader.iter_decoded_messages(
            topics=[MARKERS])]
    assert len(got) == 10
    t, last = got[-1]
    names = [(m.ns, m.id) for m in last.markers]
    assert ("links", 1) in names and ("tool", 0) in names
    strip = next(m for m in last.markers if m.ns == "links" and m.id == 1)
    assert len(strip.points) == 11 and strip.color.a == 1.0


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_realtime_markers_are_logged_at_their_tick(tmp_path):
    """Realtime: the marker thread builds the arrays after the tick they show; the
    recorder logs each at its stamp, and the tip is the ground truth's at that tick."""
    from flexarm_ros.run import run
    path = tmp_path / "rt.mcap"
    res = run(SCENE, 1.0, "realtime", record=path, namespace=NS, progress=False)
    assert res.ticks == 1000 and res.recorded[MARKERS] == 31       # 0, 34, ..., 1000 ms
    bag = _rosbags(path)
    tips = {t: (m.point.x, m.point.y) for t, m in bag[f"{NS}/{T.GT_TIP}"]}  # 100 Hz
    matched = 0
    for t, ma in bag[MARKERS]:
        stamp = ma.markers[0].header.stamp
        assert stamp.sec * 1_000_000_000 + stamp.nanosec == t
        if t in tips:
            tip = [m for m in ma.markers if m.ns == "links"][-1].points[-1]
            assert math.dist((tip.x, tip.y), tips[t]) < 1e-9
            matched += 1
    assert matched == 11                                          # every 100 ms


# ------------------------------------------------------------- the builder, no ROS
def test_marker_bytes_are_what_ros_reads():
    """The builder's bytes: rclpy deserializes them to the same values, and rosbags
    (an independent CDR implementation of the Jazzy type) writes the same bytes back."""
    from rclpy.serialization import deserialize_message
    from rosbags.typesys import Stores, get_typestore

    from flexarm_ros.nodes._msgconv import msg_class
    from flexarm_ros.nodes.markers import MARKER_ARRAY, ArmMarkers
    scene = load_scene(SCENE)
    am = ArmMarkers(scene, Chain(scene, backend="numpy"))
    q = np.random.default_rng(3).normal(size=am.geometry.chain.n) * 0.01
    d = am.message(1_234_000_000, q, True, 3.0, -1.5)
    data = am.cdr(1_234_000_000, q, True, 3.0, -1.5)
    assert data == encode_cdr(MARKER_ARRAY, d)               # validated encoder, same bytes
    ts = get_typestore(Stores.ROS2_JAZZY)
    assert ts.serialize_cdr(ts.deserialize_cdr(data, MARKER_ARRAY), MARKER_ARRAY) == data
    msg = deserialize_message(data, msg_class(MARKER_ARRAY))
    assert len(msg.markers) == len(d["markers"])
    for got, want in zip(msg.markers, d["markers"]):
        assert (got.ns, got.id, got.type, got.action) == (want["ns"], want["id"],
                                                          want["type"], want["action"])
        assert [(p.x, p.y, p.z) for p in got.points] == [
            (p["x"], p["y"], p["z"]) for p in want["points"]]
        assert got.header.stamp.sec == 1 and got.header.stamp.nanosec == 234_000_000


def test_contact_force_arrow_starts_at_the_tool_along_the_wall_force():
    from flexarm_ros.nodes.markers import ArmMarkers
    scene = load_scene(SCENE)
    chain = Chain(scene, backend="numpy")
    am = ArmMarkers(scene, chain, force_scale=0.01)
    q = np.zeros(chain.n)
    arrow = next(m for m in am.message(0, q, True, 3.0, -1.5)["markers"]
                 if m["ns"] == "contact_force")
    assert arrow["type"] == ARROW and arrow["action"] == 0
    start, end = ([p["x"], p["y"]] for p in arrow["points"])
    # straight arm along x (base angle 0): the tool is tool.position beyond the tip
    assert scene.base_angle == 0.0
    tool = chain.tip_position(q) + np.asarray(scene.tool.position)
    assert np.allclose(start, tool, atol=1e-12)
    # wall normal n = (1, 0), tangent t = E·n = (0, 1): F = 3 n - 1.5 t
    assert np.allclose(np.subtract(end, start), [0.03, -0.015], atol=1e-12)
    free = next(m for m in am.message(0, q)["markers"] if m["ns"] == "contact_force")
    assert free["action"] == DELETE


def test_wall_line_is_on_the_scene_wall():
    from flexarm_ros.nodes.markers import ArmMarkers
    scene = load_scene(SCENE)
    am = ArmMarkers(scene, Chain(scene, backend="numpy"))
    wall = next(m for m in am.message(0, np.zeros(am.geometry.chain.n))["markers"]
                if m["ns"] == "wall")
    xs = [p["x"] for p in wall["points"]]
    assert wall["type"] == LINE_LIST and xs == [-0.025, -0.025]


@pytest.mark.parametrize("rung", ["rigid", "modal", "fem", "rod"])
def test_vectorized_centerlines_are_the_point_kinematics(rung):
    """Chain.centerlines (all points of a link at once, the bases cached) gives the
    positions of point_kinematics, the model's material-point kinematics."""
    scene = load_scene(SCENE).with_fidelity(rung=rung)
    chain = Chain(scene, backend="numpy")
    q = np.random.default_rng(5).normal(size=chain.n) * 0.05
    qd = np.zeros(chain.n)
    lines = chain.centerlines(q, 9)
    for k, lm in enumerate(chain.links):
        ref = [chain.point_kinematics(q, qd, k, "beam", (x, 0.0))[0]
               for x in np.linspace(0.0, lm.beam.length, 9)]
        assert np.abs(lines[k] - np.array(ref)).max() < 1e-14
    assert np.abs(lines[-1][-1] - chain.tip_position(q)).max() < 1e-14
    assert chain.centerlines(q, 9)[0] is not lines[0]          # a new array every call
