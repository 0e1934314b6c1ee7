"""Moves to follow: the reference through a trajectory's points against closed forms, the
shaped reference against the shaper's staircase, a scene's move program in the batch run,
trajectories on controller/joint_trajectory validated on entry (a rejected one changes
nothing), and a real ROS run following one."""

from __future__ import annotations

import math

import numpy as np
import pytest

from flexarm_ros.control.trajectory import Reference, Trajectory, check_points
from flexarm_ros.errors import SceneError
from flexarm_ros.scene import load_scene
from flexarm_ros.scene.keys import set_keys
from flexarm_ros.twin.batch import run_scene
from flexarm_ros.twin.cores import ControllerCore

NAMES = ["a_joint", "b_joint"]


def test_positions_only_are_linear_between_points():
    tr = Trajectory(1.0, [0.0, 0.0], [0.0, 0.0], [0.5, 1.5], [[1.0, -1.0], [2.0, 0.0]])
    for t, want, rate in ((1.25, [0.5, -0.5], [2.0, -2.0]), (2.0, [1.5, -0.5], [1.0, 1.0])):
        q, qd = tr.at(t)
        assert np.allclose(q, want, rtol=0, atol=1e-15) and np.allclose(qd, rate, atol=1e-15)
    assert np.array_equal(tr.at(0.5)[0], [0.0, 0.0]) and np.array_equal(tr.at(9.0)[0], [2, 0])
    assert np.array_equal(tr.at(9.0)[1], [0.0, 0.0])


def test_points_with_velocities_reproduce_a_cubic_exactly():
    """Cubic Hermite segments reproduce any cubic polynomial: q(t) = 0.3 − t + 2t² − 0.7t³
    sampled with its derivative at the points is r(t) everywhere between them."""
    p = np.polynomial.Polynomial([0.3, -1.0, 2.0, -0.7])
    dp = p.deriv()
    knots = np.array([0.4, 0.9, 1.7, 2.0])
    tr = Trajectory(0.0, [p(0.0)], [dp(0.0)], knots, [[p(k)] for k in knots],
                    [[dp(k)] for k in knots])
    for t in np.linspace(0.01, 1.99, 57):
        q, qd = tr.at(t)
        assert q[0] == pytest.approx(p(t), abs=1e-13) and qd[0] == pytest.approx(dp(t),
                                                                                 abs=1e-12)


def test_a_shaped_step_reference_is_the_shapers_staircase():
    from flexarm_ros.scene.sections import Shaper
    sh = Shaper(times=(0.0, 0.4, 0.8), amplitudes=(0.25, 0.5, 0.25))
    ref = Reference([0.0], sh)
    ref.add(Trajectory(0.0, [0.0], [0.0], [1e-9], [[2.0]]))
    for t in (0.0, 0.1, 0.4, 0.6, 0.8, 3.0):
        assert ref.at(t)[0][0] == pytest.approx(2.0 * sh.share(t), abs=1e-12)


def test_a_shaped_ramp_is_the_sum_of_the_delayed_ramps():
    from flexarm_ros.scene.sections import Shaper
    sh = Shaper(times=(0.0, 0.5), amplitudes=(0.6, 0.4))
    ref = Reference([0.0], sh)
    ref.add(Trajectory(0.0, [0.0], [0.0], [1.0], [[1.0]]))
    ramp = lambda t: min(max(t, 0.0), 1.0)  # noqa: E731
    for t in np.linspace(0, 2, 41):
        want = 0.6 * ramp(t + 1e-9) + 0.4 * ramp(t - 0.5 + 1e-9)
        assert ref.at(t)[0][0] == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("names,times,pos,vel,says", [
    (["a_joint", "c_joint"], [1.0], [[0, 0]], None, "joint_names: got 'c_joint', expected"),
    (["a_joint", "a_joint"], [1.0], [[0, 0]], None, "expected each of a_joint, b_joint once"),
    (NAMES, [1.0, 1.0], [[0, 0], [1, 1]], None, "strictly increasing"),
    (NAMES, [0.0], [[0, 0]], None, "expected finite times > 0 s"),
    (NAMES, [1.0], [[0, math.nan]], None, "points[0].positions: got a non-finite value"),
    (NAMES, [1.0], [[0]], None, "points[0].positions: got 1 values, expected 2"),
    (NAMES, [1.0], [[0, 2.0]], None, "got 2 rad for b_joint, expected within its position "
                                     "limits [-1, 1] rad"),
    (NAMES, [1.0, 2.0], [[0, 0], [0, 0]], [[0, 0], [0]], "points[1].velocities: got 1"),
    (NAMES, [], [], None, "points: got none"),
])
def test_a_bad_trajectory_is_refused_with_its_reason(names, times, pos, vel, says):
    with pytest.raises(ValueError, match=None) as exc:
        check_points(NAMES, names, times, pos, vel, [None, (-1.0, 1.0)])
    assert says in str(exc.value), str(exc.value)


def test_names_in_any_order_are_put_in_the_scenes_order():
    order, P, V = check_points(NAMES, ["b_joint", "a_joint"], [1.0], [[2.0, 1.0]],
                               [[0.2, 0.1]], [None, None])
    assert order == [1, 0] and P.tolist() == [[1.0, 2.0]] and V.tolist() == [[0.1, 0.2]]


# ------------------------------------------------------------------ the move program
def _moves_scene(**extra):
    sc = load_scene("examples/three_link_position.yaml")
    moves = [{"time": 1.0, "joint_target": [0.15, -0.15, 0.15]},
             {"time": 2.5, "joint_target": [0.3, -0.3, 0.3]}]
    return set_keys(sc, {"control.joint_target": [], "control.moves": moves, **extra})


def test_a_move_program_is_followed_in_the_batch_run():
    """The controller's targets at every tick are the program's linear reference, and the
    arm ends within 2 % of the last move."""
    sc = _moves_scene()
    res = run_scene(sc, 4.0)
    t = np.asarray(res.columns["t"])
    tr = Trajectory(0.0, [0.0] * 3, [0.0] * 3, [1.0, 2.5],
                    [[0.15, -0.15, 0.15], [0.3, -0.3, 0.3]])
    for k in range(0, len(t), 97):
        want = tr.at(float(t[k]))[0]
        got = [res.columns[f"{lk.name}_joint_target"][k] for lk in sc.links]
        assert np.allclose(got, want, rtol=0, atol=1e-4), t[k]   # the last tick's target
    for lk, goal in zip(sc.links, (0.3, -0.3, 0.3)):
        assert abs(res.columns[f"{lk.name}_joint"][-1] - goal) <= 0.02 * 0.3
    assert res.loop["lane"] == "reference"


def test_move_program_refusals_name_the_move():
    with pytest.raises(SceneError, match=r"control\.moves\[0\]\.joint_target: got 0\.15 "
                                         r"rad for shoulder.*position limits"):
        _moves_scene(**{"links[0].joint.position_limits": [-0.1, 0.1]})
    with pytest.raises(SceneError, match="exactly one of tip_target / joint_target / moves"):
        _moves_scene(**{"control.joint_target": [0.3, -0.3, 0.3]})
    with pytest.raises(SceneError, match="control.moves.time: got"):
        set_keys(load_scene("examples/three_link_position.yaml"),
                 {"control.joint_target": [], "control.moves": [
                     {"time": 2.0, "joint_target": [0, 0, 0]},
                     {"time": 1.0, "joint_target": [0, 0, 0]}]})


def test_a_rejected_trajectory_changes_nothing_and_an_accepted_one_starts_now():
    sc = load_scene("examples/three_link_position.yaml")
    ctl = ControllerCore(sc)
    names = [f"{lk.name}_joint" for lk in sc.links]
    ctl.update(0.5, 1e-3, ctl.q_start)
    before = (ctl.q_cmd.copy(), ctl.q_goal.copy())
    why = ctl.accept_trajectory(0.5, None, names, [1.0], [[0.1, math.inf, 0.1]])
    assert "non-finite" in why
    ctl.update(0.6, 1e-3, ctl.q_start)
    assert np.array_equal(ctl.q_cmd, before[0]) and np.array_equal(ctl.q_goal, before[1])
    assert ctl.accept_trajectory(0.6, None, names, [1.0], [[0.1, -0.1, 0.1]]) is None
    ctl.update(1.1, 1e-3, ctl.q_start)          # halfway from the step's target to the new
    assert np.allclose(ctl.q_cmd, 0.5 * (np.array(before[1]) + [0.1, -0.1, 0.1]))
    assert np.allclose(ctl.qd_cmd, np.array([0.1, -0.1, 0.1]) - before[1])
    assert np.allclose(ctl.q_goal, [0.1, -0.1, 0.1])


def test_a_trajectory_is_refused_outside_position_control_and_under_lqg():
    import flexarm_ros as fx
    sc = load_scene("two_link_case1")
    ctl = ControllerCore(sc)
    assert "expected 'position'" in ctl.accept_trajectory(0.0, None, ["a"], [1.0], [[0]])
    lqg = ControllerCore(fx.design("two_link_position", lqg=True, weights={"voltage": 1.0}))
    why = lqg.accept_trajectory(0.0, None, ["link1_joint", "link2_joint"], [1.0], [[0, 0]])
    assert "the LQG regulates to the target it was designed at" in why


@pytest.mark.ros
@pytest.mark.subprocess
def test_the_controller_node_follows_a_trajectory_and_refuses_a_bad_one(tmp_path):
    """A real lockstep run of three_link_position with a user's node publishing, at
    0.2 s, a trajectory naming a joint the arm does not have and then a valid one: the
    first is counted as rejected, the second moves the recorded targets to its point."""
    pytest.importorskip("trajectory_msgs")
    from rclpy.node import Node
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    from flexarm_ros.bag.reader import read_bag
    from flexarm_ros.nodes.common import QOS
    from flexarm_ros.run import InProcessGraph
    from flexarm_ros.twin import topics as T
    path = tmp_path / "jt.mcap"
    g = InProcessGraph(namespace="/jt", scene="examples/three_link_position.yaml",
                       mode="lockstep", duration=1.2, record=path)
    try:
        node = Node("user", namespace="/jt", context=g.context)
        g.executor.add_node(node)
        g.nodes["user"] = node
        pub = node.create_publisher(JointTrajectory, T.JOINT_TRAJECTORY, QOS)
        sim = g["simulator"]
        assert g.spin_until(lambda: sim.core.t >= 0.2, 120)

        def traj(names):
            m = JointTrajectory()
            m.joint_names = names
            p = JointTrajectoryPoint()
            p.positions = [0.05, -0.05, 0.05]
            p.time_from_start.nanosec = 400_000_000
            m.points = [p]
            return m
        pub.publish(traj(["shoulder_joint", "elbow_joint", "hand_joint"]))
        pub.publish(traj(["shoulder_joint", "elbow_joint", "wrist_joint"]))
        ctl = g["controller"]
        assert g.spin_until(lambda: ctl.trajectories == 1 and
                            ctl.rejections.total(T.JOINT_TRAJECTORY) == 1, 60)
        assert g.spin_until(lambda: sim.finished, 300)
        sim.halt()
        assert g.spin_until(g.recorded_all, 60)
    finally:
        g.close()
    targets = read_bag(path)[f"/jt/{T.JOINT_TARGETS}"]
    assert np.allclose(targets[-1][1].position, [0.05, -0.05, 0.05], atol=1e-12)
    assert np.allclose(targets[0][1].position, [0.3, -0.3, 0.3], atol=1e-12)
