"""The arm's URDF and TF against the model: the URDF parsed by the standard library's XML
parser and its joints composed (a reader of our own here, not the generator's code)
reproduce the deformed centerline of ``Chain.centerlines`` within 1 mm over whole runs of
shipped and generated arms; in a recorded bag, /tf_static and /tf resolve every frame a
stamped message names and place the beams on the ground truth's centerline; a
transient-local subscriber started after the twin receives ``robot_description``."""

from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import flexarm_ros as fx
from flexarm_ros.model.chain import Chain
from flexarm_ros.twin.robot_description import Description

TOL_M = 1e-9          # m: the frames sit on the sample points, to round-off


def _urdf_joints(text: str) -> dict:
    """child link -> (parent, x, y, yaw0, joint name, movable, prismatic) from the URDF's
    XML (a prismatic joint slides along its parent's x, the others turn about z)."""
    root = ET.fromstring(text)
    out = {}
    for j in root.findall("joint"):
        o = j.find("origin")
        x, y, _ = (float(v) for v in o.get("xyz").split())
        yaw = float(o.get("rpy").split()[2])
        out[j.find("child").get("link")] = (j.find("parent").get("link"), x, y, yaw,
                                            j.get("name"), j.get("type") != "fixed",
                                            j.get("type") == "prismatic")
    assert {ln.get("name") for ln in root.findall("link")} >= set(out) | {"world"}
    return out


def _frame(joints: dict, values: dict, frame: str) -> tuple:
    """(x, y) of ``frame`` in world: the URDF's joints composed root to leaf."""
    path = []
    while frame != "world":
        parent, x, y, yaw, name, movable, _ = joints[frame]
        v = values[name] if movable else 0.0
        path.append((x + v, y, yaw) if joints[frame][6] else (x, y, yaw + v))
        frame = parent
    X = Y = A = 0.0
    for x, y, a in reversed(path):
        X, Y = X + math.cos(A) * x - math.sin(A) * y, Y + math.sin(A) * x + math.cos(A) * y
        A += a
    return X, Y


def _worst_gap(scene, duration, every=25):
    chain = Chain(scene)
    d = Description(chain)
    joints = _urdf_joints(d.urdf())
    run = fx.simulate(scene, duration=duration)
    worst = 0.0
    for i in range(0, len(run.t), every):
        q = np.array([run[n][i] for n in chain.names])
        values = dict(zip(d.movable, d.positions(q)))
        lines = chain.centerlines(q, d.n + 1)
        for k, lm in enumerate(chain.links):
            for s in range(d.n):
                x, y = _frame(joints, values, f"{lm.name}_seg{s}")
                worst = max(worst, math.hypot(x - lines[k][s][0], y - lines[k][s][1]))
            x, y = _frame(joints, values, f"{lm.name}_tip")
            worst = max(worst, math.hypot(x - lines[k][-1][0], y - lines[k][-1][1]))
    return worst, run


@pytest.mark.parametrize("name, duration", [("two_link_case1", 2.5), ("spin_up", 2.0),
                                            ("hydraulic_2kg", 1.0), ("link_tipmass", 0.3)])
def test_the_urdf_composed_is_the_models_deformed_centerline(name, duration):
    """two_link_case1 through its strike, the spin-up's 0.1 m deflection, the hydraulic
    arm's 0.22 m under gravity (the segments' frames on the sample points to round-off)."""
    worst, _ = _worst_gap(fx.load_scene(name), duration)
    assert worst < TOL_M, worst


@pytest.mark.parametrize("seed", [3, 8])
def test_a_generated_arm_is_described_too(seed):
    """Arms of the zoo (datasheet-term scenes the suite has never shipped)."""
    from flexarm_ros.scene import load_scene_dict
    from flexarm_ros.testing.zoo import arm
    scene = load_scene_dict(arm(seed, links=3))
    worst, _ = _worst_gap(scene, min(scene.duration, 1.0), every=50)
    assert worst < TOL_M, worst


@pytest.mark.ros
@pytest.mark.subprocess
@pytest.mark.heavy
@pytest.mark.timeout(400)
@pytest.mark.parametrize("layout", ["one", "split", "processes"])
def test_the_bags_tf_places_the_arm_and_a_late_viewer_gets_the_description(tmp_path, layout,
                                                                          ros_client,
                                                                          twin_process):
    pytest.importorskip("rclpy")
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.twin.recording import embedded_scene

    ns, bag = f"/urdf_{layout}", tmp_path / "r.mcap"
    proc = twin_process("two_link_case1", "--mode", "lockstep", "--duration", "8", "--record",
                        str(bag), "--quiet", "--namespace", ns, layout=layout)
    client = ros_client("late_viewer")
    states, urdf = [], []
    client.node.create_subscription(JointState, f"{ns}/joint_states",
                                    lambda m: states.append(1), 10)
    deadline = time.monotonic() + 120
    while not states:                                  # the twin is running
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        client.spin_once()
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client.node.create_subscription(String, f"{ns}/robot_description",
                                    lambda m: urdf.append(m.data), qos)
    deadline = time.monotonic() + 30
    while not urdf:
        assert time.monotonic() < deadline, "no robot_description for a late subscriber"
        client.spin_once()
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert urdf[0].startswith("<?xml") and "two_link_case1" in urdf[0]

    b = read_bag(str(bag))
    text = b[f"{ns}/robot_description"][0][1].data
    assert text == urdf[0]
    joints = _urdf_joints(text)
    tree = {}                                              # child -> (parent, x, y, yaw)
    for _, m in b["/tf_static"]:
        for tr in m.transforms:
            tree[tr.child_frame_id] = tr
    tf = b["/tf"]
    assert len(tf) == len(b[f"{ns}/robot_state/joint_states"]) > 50
    # every frame a stamped message names resolves to world through the bag's TF
    frames = {m.header.frame_id for topic, msgs in b.messages.items() for _, m in msgs[:3]
              if hasattr(m, "header") and m.header.frame_id}
    frames |= {mk.header.frame_id for _, m in b[f"{ns}/arm_markers"][:3] for mk in m.markers}
    known = set(tree) | {tr.child_frame_id for tr in tf[0][1].transforms} | {"world"}
    assert frames and frames <= known, frames - known
    # /tf at a time against the model's centerline from ground_truth/coordinates then
    scene = embedded_scene(b)
    chain = Chain(scene)
    coords = {ts: m for ts, m in b[f"{ns}/ground_truth/coordinates"]}
    checked = worst = 0
    for ts, m in tf[::5]:
        if ts not in coords:
            continue
        for tr in m.transforms:
            tree[tr.child_frame_id] = tr
        q = np.array([coords[ts].position[coords[ts].name.index(n)] for n in chain.names])
        lines = chain.centerlines(q, Description(chain).n + 1)
        for k, lm in enumerate(chain.links):
            x, y = _compose_tf(tree, f"{lm.name}_tip")
            worst = max(worst, math.hypot(x - lines[k][-1][0], y - lines[k][-1][1]))
            x, y = _compose_tf(tree, f"{lm.name}_seg3")
            worst = max(worst, math.hypot(x - lines[k][3][0], y - lines[k][3][1]))
        checked += 1
    assert checked > 10 and worst < TOL_M, (checked, worst)
    assert set(joints) >= {f"{lm.name}_tip" for lm in chain.links}


def _compose_tf(tree, frame):
    path = []
    while frame != "world":
        tr = tree[frame]
        t, r = tr.transform.translation, tr.transform.rotation
        path.append((t.x, t.y, 2 * math.atan2(r.z, r.w)))
        frame = tr.header.frame_id
    X = Y = A = 0.0
    for x, y, a in reversed(path):
        X, Y = X + math.cos(A) * x - math.sin(A) * y, Y + math.sin(A) * x + math.cos(A) * y
        A += a
    return X, Y


def test_flexarm_urdf_and_fx_urdf_write_the_description(tmp_path, capsys):
    from flexarm_ros.cli import main
    out = tmp_path / "arm.urdf"
    assert main(["urdf", "two_link_case1", "--out", str(out)]) == 0
    text = out.read_text()
    assert text == fx.urdf("two_link_case1")
    joints = _urdf_joints(text)
    assert {"tool", "wall", "link2_tip", "link1_seg9_end"} <= set(joints)
    assert joints["wall"][0] == "world" and joints["link2_hub"][0] == "link1_tip"
    assert main(["urdf", "link", "--segments", "1"]) == 2
    assert "--segments: got 1, expected 2 to 200" in capsys.readouterr().err

