"""Live tuning of the position loop: ``control.changes`` in every batch run, the
controller node's ``kp`` / ``kd`` / ``joint_target`` parameters set while the twin runs
(rclpy's own service client, as ``ros2 param set`` sends), each accepted set applied at a
tick and recorded on ``controller/parameter_changes``, and the bag's scene with those
entries (``flexarm bag scene``) rerunning the live run."""

from __future__ import annotations

import time

import numpy as np
import pytest

import flexarm_ros as fx
from flexarm_ros.cli import main
from flexarm_ros.errors import SceneError


def _run(scene, duration=3.0):
    return fx.simulate(scene, duration=duration)


# ------------------------------------------------------------------ control.changes
def test_a_gain_change_at_the_start_is_the_scene_with_those_gains():
    """Independent path: kp, kd changed at t = 0 by control.changes against the same scene
    with those gains as its own (the same ticks, to round-off)."""
    new = {"kp": [12.0, 16.0], "kd": [6.0, 9.0]}
    changed = _run(fx.load_scene("two_link_position",
                                 set={"control.changes": [{"time": 0.0, **new}]}))
    own = _run(fx.load_scene("two_link_position",
                             set={"control.kp": new["kp"], "control.kd": new["kd"]}))
    for col in ("link1_joint", "link2_joint", "link2_tip_deflection"):
        assert np.max(np.abs(changed[col] - own[col])) < 1e-12, col


def test_a_target_change_at_the_start_is_the_scene_with_that_target():
    target = [0.3, 1.0]
    changed = _run(fx.load_scene("two_link_position", set={
        "control.changes": [{"time": 0.0, "joint_target": target}]}))
    own = _run(fx.load_scene("two_link_position", set={"control.tip_target": None,
                                                      "control.joint_target": target}))
    for col in ("link1_joint", "link2_joint", "link2_tip_deflection", "link1_joint_target"):
        assert np.max(np.abs(changed[col] - own[col])) < 1e-12, col


def test_a_change_leaves_the_run_before_it_alone_and_changes_it_after():
    base = _run("two_link_position")
    stiffer = _run(fx.load_scene("two_link_position", set={
        "control.changes": [{"time": 1.0, "kp": [12.0, 16.0]}]}))
    t = base.t
    before, after = t < 1.0, t > 1.2
    gap = np.abs(stiffer["link1_joint"] - base["link1_joint"])
    assert np.max(gap[before]) < 1e-12
    assert np.max(gap[after]) > 1e-3
    # stiffer PD: the joint closer to its target after the change
    err = lambda r: np.abs(r["link1_joint"] - r["link1_joint_target"])[after].mean()  # noqa: E731
    assert err(stiffer) < err(base)


def test_a_shaper_change_shapes_the_next_target_step_as_its_closed_form():
    """A two-impulse shaper set at 1 s, a target step at 3 s: the commanded target is
    q₀ + ½(q* − q₀) from 3 s to 3.5 s and q* after, where q₀ is the command at 3 s."""
    sc = fx.load_scene("two_link_position", set={"control.changes": [
        {"time": 1.0, "shaper": {"times": [0.0, 0.5], "amplitudes": [0.5, 0.5]}},
        {"time": 3.0, "joint_target": [0.3, 1.0]}]})
    r = _run(sc, 4.0)
    t = r.t
    q0 = r["link1_joint_target"][np.searchsorted(t, 2.99)]
    mid = (t >= 3.0) & (t < 3.5 - 1e-9)
    assert np.max(np.abs(r["link1_joint_target"][mid] - (q0 + 0.5 * (0.3 - q0)))) < 1e-12
    assert np.max(np.abs(r["link1_joint_target"][t >= 3.5] - 0.3)) < 1e-12


def test_a_voltage_limit_change_clips_the_commands_from_its_time_on():
    base = _run("two_link_position", 2.0)
    limited = _run(fx.load_scene("two_link_position", set={
        "control.changes": [{"time": 0.5, "voltage_limit": [1.0, 1.0]}]}), 2.0)
    t = base.t
    for col in ("link1_voltage", "link2_voltage"):
        assert np.max(np.abs(limited[col] - base[col])[t < 0.5]) < 1e-12
        assert np.max(np.abs(limited[col])[t >= 0.5]) <= 1.0 + 1e-12
    assert np.max(np.abs(base["link1_voltage"])[t >= 0.5]) > 1.0      # it did clip


def test_a_voltage_limit_above_the_drives_is_refused():
    sc = fx.load_scene("two_link_position", set={
        "control.changes": [{"time": 0.5, "voltage_limit": [100.0, 1.0]}]})
    with pytest.raises(SceneError, match=r"control.changes\[0\].voltage_limit: got "
                                         r"\[100.0, 1.0\] V, expected 0 < V <= 24 V on "
                                         r"joint 1"):
        _run(sc, 0.1)


def test_a_shaped_scene_shapes_a_target_change_from_the_current_command():
    """With a shaper the new target is a staircase from the command at the change: the
    commanded target reaches it only after the shaper's last impulse."""
    shaped = fx.design("two_link_position", shaper="zv")
    last = shaped.control.shaper.times[-1]
    sc = _with_changes(shaped, [{"time": 4.0, "joint_target": [0.3, 1.0]}])
    r = _run(sc, 4.0 + last + 0.5)
    t, q = r.t, r["link1_joint_target"]
    assert abs(q[np.searchsorted(t, 4.0 + 0.5 * last)] - 0.3) > 1e-3   # still on its way
    assert abs(q[-1] - 0.3) < 1e-12


def _with_changes(scene, changes):
    from flexarm_ros.scene.keys import set_keys
    return set_keys(scene, {"control.changes": changes})


@pytest.mark.parametrize("changes, says", [
    ([{"time": 1.0, "kp": [1.0]}], "control.changes[0].kp: got 1 values, expected 2"),
    ([{"time": 1.0, "kp": [-1.0, 2.0]}], "control.changes[0].kp"),
    ([{"time": 2.0, "kd": [1.0, 1.0]}, {"time": 1.0, "kd": [2.0, 2.0]}],
     "control.changes[1].time: got 1 s, expected after the previous change's 2 s"),
    ([{"time": 1.0}], "control.changes[0]: got no kp, kd, joint_target, voltage_limit or "
                      "shaper"),
    ([{"time": 1.0, "joint_target": [0.0, 1.0], "gain": 2}], "gain"),
])
def test_a_bad_change_is_refused_in_one_line(changes, says):
    with pytest.raises(SceneError) as err:
        fx.load_scene("two_link_position", set={"control.changes": changes})
    assert says in str(err.value) and "\n" not in str(err.value)


def test_changes_in_open_loop_are_refused():
    with pytest.raises(SceneError, match="control.changes\\[0\\]: got a change with "
                                         "control.mode 'open_loop'"):
        fx.load_scene("two_link_case1", set={"control.changes": [{"time": 0.5,
                                                                  "kp": [1.0, 1.0]}]})


# ------------------------------------------------------------------ the live twin
@pytest.mark.ros
@pytest.mark.subprocess
@pytest.mark.heavy
@pytest.mark.timeout(400)
@pytest.mark.parametrize("layout", ["one", "split", "processes"])
def test_a_gain_set_on_the_live_twin_is_applied_recorded_and_rerun(tmp_path, layout, ros_client,
                                                                 twin_process):
    """A lockstep `flexarm run two_link_position --record` in a child process; this
    process, a plain rclpy user, sets the controller's kp once the twin passes 0.5 s of
    scene time (and tries bad sets, refused with the reason, nothing changing), then a
    shaper and a target. The bag holds the kp entry alone at a tick ≥ 0.5 s and then the
    shaper's and the target's; the arm moves differently from an untouched run after the
    kp change; `flexarm bag scene` of the bag, run by flexarm simulate, equals the live
    run's ground truth at every tick."""
    pytest.importorskip("rclpy")
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from sensor_msgs.msg import JointState
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.recording import recorded_changes

    ns, bag, duration = f"/live_{layout}", tmp_path / "live.mcap", 12.0
    proc = twin_process("two_link_position", "--mode", "lockstep", "--duration",
                        str(duration), "--record", str(bag), "--quiet", "--namespace", ns,
                        layout=layout)

    def arr(values):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                              double_array_value=values)

    client = ros_client("tuner")
    stamps = []
    client.node.create_subscription(JointState, f"{ns}/joint_states", lambda m: stamps.append(
        m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec), 10)
    srv = f"{ns}/controller/set_parameters"

    def set_one(name, value):
        return client.call(SetParameters, srv, SetParameters.Request(
            parameters=[Parameter(name=name, value=arr(value))])).results[0]

    deadline = time.monotonic() + 120
    while not stamps or stamps[-1] < 0.5:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the twin did not reach 0.5 s"
        client.spin_once()
    bad = set_one("kp", [-1.0, 2.0])
    assert not bad.successful and "kp" in bad.reason and ">= 0" in bad.reason, bad.reason
    bad = set_one("joint_target", [0.1])
    assert not bad.successful and "expected 2" in bad.reason, bad.reason
    bad = set_one("voltage_limit", [100.0, 1.0])
    assert not bad.successful and "voltage_limit: got [100.0, 1.0] V" in bad.reason, \
        bad.reason
    bad = set_one("shaper_impulses", [0.0, 0.5, 0.5, 0.6])
    assert not bad.successful and "shaper.amplitudes: got a sum of 1.1" in bad.reason, \
        bad.reason
    ok = set_one("kp", [12.0, 16.0])
    assert ok.successful, ok.reason
    n, deadline = len(stamps), time.monotonic() + 60
    while len(stamps) < n + 50:               # the kp change applied, alone
        assert proc.poll() is None and time.monotonic() < deadline, "the twin stopped"
        client.spin_once()
    for name, value in (("shaper_impulses", [0.0, 0.5, 0.5, 0.5]),
                        ("joint_target", [0.3, 1.0])):
        ok = set_one(name, value)
        assert ok.successful, (name, ok.reason)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err

    b = read_bag(str(bag))
    changes = recorded_changes(b)
    assert changes[0]["kp"] == [12.0, 16.0] and set(changes[0]) == {"time", "kp"}, changes
    assert 0.5 <= changes[0]["time"] < duration
    later = {k for c in changes[1:] for k in c} - {"time"}
    assert later == {"shaper", "joint_target"}, changes

    out = tmp_path / "rerun.yaml"
    assert main(["bag", "scene", str(bag), "--out", str(out)]) == 0
    rerun = fx.simulate(fx.load_scene(str(out)), duration=duration)
    untouched = fx.simulate("two_link_position", duration=duration)
    msgs = b[f"{ns}/{T.GT_JOINT_STATES}"]
    ns_grid = np.round(rerun.t * 1e9).astype(np.int64)
    idx = np.searchsorted(ns_grid, np.array([ts for ts, _ in msgs], dtype=np.int64))
    q_live = np.array([m.position[0] for _, m in msgs])
    assert np.max(np.abs(rerun["link1_joint"][idx] - q_live)) < 1e-9
    t_live = rerun.t[idx]
    late = t_live > changes[0]["time"] + 0.3
    assert np.max(np.abs(untouched["link1_joint"][idx] - q_live)[late]) > 1e-3
