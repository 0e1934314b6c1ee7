"""The rerun view of a twin bag (flexarm_ros.viz), read back from the .rrd file with
rerun's own chunk reader, against truths taken from the bag and the scene YAML: entity
paths, the accelerometer batches expanded to one row per sample on a uniform 1/fs grid
ending at each message's log time, the arm centerline from the hub's rim to
ground_truth/tip, the tool at the tip frame's tool.position, the wall on its line, the
contact-force arrow (F_n·n + F_t·E·n at the tool), and the
`flexarm run --rerun` / `--rerun-spawn` / `flexarm replay --rerun` commands."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from flexarm_ros.bag import BagWriter, read_bag, to_dict
from flexarm_ros.scene import load_scene, resolve_scene_path
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cosim import cosimulate

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

NS = "/flexarm"
SCENE = "two_link_case1"
DURATION = 0.1
CONTACT_TICKS = range(40, 46)            # ticks given an invented contact force
FN, FT = 3.0, -1.5                        # N: normal and friction in the wall frame
SHARED_BAG = Path("/tmp/shared_bags/case1_2p5s.mcap")


def _write_bag(path, messages, scene_name, edit=None):
    """An MCAP as `flexarm run` records it: absolute topics, log time = simulation time,
    metadata flexarm_ros with the scene YAML; ``edit(topic, data, t_ns)`` may change
    a message."""
    info = {"scene": scene_name, "scene_yaml": resolve_scene_path(scene_name).read_text(),
            "namespace": NS, "time_mode": "lockstep"}
    with BagWriter(path, metadata=info) as w:
        for m in messages:
            data = edit(m.topic, m.data, m.t_ns) if edit else m.data
            w.write(T.resolve(NS, m.topic), m.msgtype, data, m.t_ns)


def _contact(topic, data, t_ns):
    tick = t_ns // 1_000_000
    if tick in CONTACT_TICKS and topic == T.TOOL_CONTACT:
        return {"data": True}
    if tick in CONTACT_TICKS and topic == T.TOOL_WRENCH:
        d = yaml.safe_load(yaml.safe_dump(data))
        d["wrench"]["force"].update(x=FN, y=FT)
        return d
    return data


def _permuted(topic, data, t_ns):
    """ground_truth/coordinates with its names (and values) in reverse order."""
    if topic != T.GT_COORDINATES:
        return data
    d = dict(data)
    for k in ("name", "position", "velocity", "effort"):
        d[k] = list(data[k])[::-1]
    return d


@pytest.fixture(scope="module")
def cosim():
    return cosimulate(load_scene(SCENE), DURATION).messages


@pytest.fixture(scope="module")
def bag_path(tmp_path_factory, cosim):
    path = tmp_path_factory.mktemp("view") / "case1.mcap"
    _write_bag(path, cosim, SCENE, _contact)
    return path


def read_rrd(path):
    """{entity path: [(t_ns or None for static, {component: value})]} sorted by time."""
    import pyarrow as pa
    recs = RrdReader(path).recordings()
    assert len(recs) == 1
    out = {}
    for ch in RrdReader(path).stream():
        rb = ch.to_record_batch()
        names = [n for n in rb.schema.names if ":" in n]
        t = (rb.column("sim_time").cast(pa.int64()).to_pylist() if "sim_time" in
             rb.schema.names else [None] * rb.num_rows)
        cols = {n: rb.column(n).to_pylist() for n in names}
        rows = out.setdefault(ch.entity_path.lstrip("/"), [])
        for i in range(rb.num_rows):
            rows.append((t[i], {n: cols[n][i] for n in names}))
    for rows in out.values():
        rows.sort(key=lambda r: -1 if r[0] is None else r[0])
    return out


@pytest.fixture(scope="module")
def rrd(tmp_path_factory, bag_path):
    from flexarm_ros.viz.rerun_view import ViewOptions, bag_to_rerun
    path = tmp_path_factory.mktemp("rrd") / "case1.rrd"
    summ = bag_to_rerun(bag_path, path, options=ViewOptions(shape_rate_hz=200.0,
                                                            force_scale=0.01))
    assert summ.rrd == path and path.stat().st_size > 0
    return read_rrd(path)


@pytest.mark.heavy
def test_entity_paths(rrd):
    want = {"world", "world/wall", "world/arm/link1", "world/arm/link2", "world/tool",
            "world/tip_path", "world/contact_force", "plots/contact/in_contact",
            "plots/contact/normal_force", "plots/contact/friction_force",
            "plots/joint_angles/measured/link1_joint", "plots/joint_angles/true/link2_joint",
            "plots/commands/link1"} | {f"plots/accelerometers/acc_{c}" for c in "ABCD"}
    assert want <= set(rrd), want - set(rrd)


def test_accelerometer_batches_expand_to_uniform_samples(rrd, bag_path):
    bag = read_bag(bag_path)
    msgs = bag[f"{NS}/{T.ACCEL_BATCH}"]
    accels = [s for s in load_scene(SCENE).sensors if s.kind == "accelerometer"]
    period_ns = round(1e9 / accels[0].rate_hz)
    assert period_ns == 250_000 and len(msgs) > 10
    for j, sensor in enumerate(accels):
        rows = rrd[f"plots/accelerometers/{sensor.name}"]
        times = np.array([t for t, _ in rows])
        values = np.array([v["Scalars:scalars"][0] for _, v in rows])
        n_rows = [m.layout.dim[0].size for _, m in msgs]
        assert len(rows) == sum(n_rows) == len(msgs) * n_rows[0]
        assert np.all(np.diff(times) == period_ns)          # uniform at 1/fs throughout
        ends = np.cumsum(n_rows) - 1
        assert list(times[ends]) == [t for t, _ in msgs]    # each batch ends at its time
        c = msgs[0][1].layout.dim[1].size
        want = np.concatenate([np.asarray(m.data).reshape(-1, c)[:, j] for _, m in msgs])
        assert np.array_equal(values, want)


def test_centerline_ends_at_the_recorded_tip(rrd, bag_path):
    bag = read_bag(bag_path)
    tips = {t: (m.point.x, m.point.y) for t, m in bag[f"{NS}/{T.GT_TIP}"]}
    rows = rrd["world/arm/link2"]
    assert [t for t, _ in rows] == list(range(0, 100_000_001, 5_000_000))   # ≤ 200 Hz
    for t, v in rows:
        strip = np.array(v["LineStrips3D:strips"][0])
        assert strip.shape == (21, 3) and np.all(strip[:, 2] == 0)
        assert np.abs(strip[-1, :2] - tips[t]).max() < 1e-6       # float32 in the file
    # beam 1 starts at the rim of the hub RB1, hub_radius from joint 1 along q1 = 55 deg
    # (at rest and undeformed at t = 0)
    r1 = load_scene(SCENE).links[0].beam.hub_radius
    base = np.array(rrd["world/arm/link1"][0][1]["LineStrips3D:strips"][0])[0]
    assert r1 > 0.03
    assert np.abs(base[:2] - r1 * np.array([np.cos(np.radians(55.0)),
                                            np.sin(np.radians(55.0))])).max() < 1e-7
    tool = {t: v["Points3D:positions"][0] for t, v in rrd["world/tool"]}
    assert all(np.abs(np.array(tool[t][:2]) - _tool_truth(bag, t)).max() < 1e-6
               for t, _ in rows)
    path = np.array(rrd["world/tip_path"][-1][1]["LineStrips3D:strips"][0])
    assert np.abs(path[-1, :2] - tips[max(tips)]).max() < 1e-6
    assert np.abs(path[0, :2] - tips[0]).max() < 1e-6


@pytest.mark.heavy
def test_centerlines_match_the_tip_in_double_precision(bag_path, tmp_path, cosim):
    """Before rerun's float32: to 1e-9, also when the coordinates come in another name
    order (mapped by name, not index)."""
    from flexarm_ros.viz import BagView
    tips = {t: np.array([m.point.x, m.point.y])
            for t, m in read_bag(bag_path)[f"{NS}/{T.GT_TIP}"]}
    frames = BagView(bag_path).shape_frames(rate_hz=0)
    assert len(frames) == len(tips)
    for f in frames:
        assert np.abs(f.centerlines[-1][-1] - tips[f.t_ns]).max() < 1e-9
    other = tmp_path / "permuted.mcap"
    _write_bag(other, cosim, SCENE, _permuted)
    perm = BagView(other).shape_frames(rate_hz=0)
    assert read_bag(other)[f"{NS}/{T.GT_COORDINATES}"][0][1].name[0] == "link2_tip_rot"
    for a, b in zip(frames, perm):
        assert np.array_equal(a.q, b.q)
        assert all(np.array_equal(x, y) for x, y in zip(a.centerlines, b.centerlines))


def _tool_truth(bag, t_ns):
    """The tool point at ``t_ns``: ground_truth/tip plus the scene's tool.position turned
    by the tip frame's angle, which on the cubic rung is the sum of the joint angles and
    the beams' tip-rotation coordinates (the cubic shapes have slope 1 at the tip for the
    rotation coordinate and 0 for the displacement)."""
    sc = load_scene(SCENE)
    assert sc.fidelity.rung == "cubic" and sc.tool.position[1] == 0.0
    (_, tip), = [(t, m) for t, m in bag[f"{NS}/{T.GT_TIP}"] if t == t_ns]
    (_, co), = [(t, m) for t, m in bag[f"{NS}/{T.GT_COORDINATES}"] if t == t_ns]
    c = dict(zip(co.name, co.position))
    psi = c["link1_joint"] + c["link1_tip_rot"] + c["link2_joint"] + c["link2_tip_rot"]
    return (np.array([tip.point.x, tip.point.y])
            + sc.tool.position[0] * np.array([np.cos(psi), np.sin(psi)]))


def test_wall_is_drawn_on_the_scene_wall(rrd):
    wall = yaml.safe_load(resolve_scene_path(SCENE).read_text())["walls"][0]
    (t, v), = rrd["world/wall"]
    strip = np.array(v["LineStrips3D:strips"][0])
    assert t is None and strip.shape == (2, 3)                       # static
    n, p = np.array(wall["normal"], float), np.array(wall["point"], float)
    assert np.abs((strip[:, :2] - p) @ n).max() < 1e-7               # both ends on the line
    assert abs(strip[1, 1] - strip[0, 1]) > 1.0                       # spans the workspace
    assert np.abs(strip[:, :2].mean(axis=0) - p).max() < 1e-6         # centred on the point


def test_contact_force_arrow_at_the_tool(rrd, bag_path):
    bag = read_bag(bag_path)
    rows = rrd["world/contact_force"]
    shown = [(t, v) for t, v in rows if v.get("Arrows3D:vectors")]
    assert [t // 1_000_000 for t, _ in shown] == list(CONTACT_TICKS)
    # the wall's inward normal is +x, so t = E·n = +y: F = FN·x + FT·y, 0.01 m/N
    for t, v in shown:
        assert np.allclose(v["Arrows3D:vectors"][0], [0.01 * FN, 0.01 * FT, 0.0], atol=1e-7)
        assert np.abs(np.array(v["Arrows3D:origins"][0][:2]) - _tool_truth(bag, t)).max() < 1e-6
    cleared = [t for t, v in rows if "Clear:is_recursive" in v]
    assert cleared == [(CONTACT_TICKS[-1] + 1) * 1_000_000]
    flag = rrd["plots/contact/in_contact"]
    assert [v["Scalars:scalars"][0] for _, v in flag] == \
        [1.0 if t // 1_000_000 in CONTACT_TICKS else 0.0 for t, _ in flag]
    normal = {t: v["Scalars:scalars"][0] for t, v in rrd["plots/contact/normal_force"]}
    assert normal[CONTACT_TICKS[0] * 1_000_000] == FN and normal[0] == 0.0


def test_joint_angles_are_the_recorded_values(rrd, bag_path):
    bag = read_bag(bag_path)
    gt = bag[f"{NS}/{T.GT_JOINT_STATES}"]
    rows = rrd["plots/joint_angles/true/link2_joint"]
    k = list(gt[0][1].name).index("link2_joint")
    assert [t for t, _ in rows] == [t for t, _ in gt]
    assert [v["Scalars:scalars"][0] for _, v in rows] == [m.position[k] for _, m in gt]


def test_missing_rerun_is_a_clear_error(monkeypatch):
    from flexarm_ros.viz import rerun_view
    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(rerun_view.RerunUnavailable, match=r"pip install -e \.\[viz\]"):
        rerun_view.require_rerun()


def _env(**extra):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(150 + (os.getpid() + 41) % 80), **extra)
    return env


@pytest.mark.subprocess
def test_replay_rerun_converts_without_ros(bag_path, tmp_path):
    out = tmp_path / "cli.rrd"
    p = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "replay", str(bag_path),
                        "--rerun", str(out), "--shape-rate", "50"], env=_env(),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "rclpy" not in p.stderr and str(out) in p.stdout
    rows = read_rrd(out)["world/arm/link1"]
    assert [t for t, _ in rows] == list(range(0, 100_000_001, 20_000_000))


@pytest.mark.subprocess
def test_run_rerun_spawn_without_display_fails_before_running(tmp_path):
    env = _env()
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    p = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "run", "link_motor",
                        "--duration", "0.05", "--no-record", "--rerun-spawn", "--quiet"],
                       env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert p.returncode == 2
    assert "no display" in p.stderr and "Traceback" not in p.stderr
    assert "real-time factor" not in p.stdout                       # did not run


@pytest.mark.heavy
@pytest.mark.subprocess
def test_run_rerun_converts_the_recorded_run(tmp_path):
    """`flexarm run --no-record --rerun` records to a temporary bag and converts it."""
    out = tmp_path / "run.rrd"
    p = subprocess.run([sys.executable, "-m", "flexarm_ros.cli", "run", "link_motor",
                        "--duration", "0.05", "--no-record", "--rerun", str(out), "--quiet"],
                       env=_env(), capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    rrd = read_rrd(out)
    assert [t for t, _ in rrd["world/arm/link1"]] == list(range(0, 50_000_001, 10_000_000))
    assert "plots/joint_angles/measured/link1_joint" in rrd
    assert list(tmp_path.glob("*.mcap")) == []                      # no bag left behind


@pytest.mark.slow
@pytest.mark.skipif(not SHARED_BAG.exists(), reason="needs the 2.5 s two_link_case1 bag")
def test_wall_strike_bag(tmp_path):
    """The real 2.5 s run with the wall strike: every arm drawing ends at the tip, and
    while in contact the arrow pushes the tool off the wall (+x) with friction along y."""
    from flexarm_ros.viz.rerun_view import bag_to_rerun
    out = tmp_path / "strike.rrd"
    summ = bag_to_rerun(SHARED_BAG, out)
    rrd = read_rrd(out)
    bag = read_bag(SHARED_BAG)
    tips = {t: (m.point.x, m.point.y) for t, m in bag[f"{NS}/{T.GT_TIP}"]}
    for t, v in rrd["world/arm/link2"]:
        assert np.abs(np.array(v["LineStrips3D:strips"][0][-1][:2]) - tips[t]).max() < 1e-6
    wrench = {t: to_dict(m)["wrench"]["force"] for t, m in bag[f"{NS}/{T.TOOL_WRENCH}"]}
    shown = [(t, v) for t, v in rrd["world/contact_force"] if v.get("Arrows3D:vectors")]
    assert len(shown) > 100
    for t, v in shown:
        f = wrench[t]
        assert np.allclose(v["Arrows3D:vectors"][0][:2],
                           [summ.force_scale * f["x"], summ.force_scale * f["y"]],
                           rtol=1e-6, atol=1e-9)
        assert f["x"] >= 0
    print(f"{SHARED_BAG}: {summ.text()}")
