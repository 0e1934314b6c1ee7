"""LQG designed on the twin (``flexarm design --lqg``): the regulator and the Kalman gain
against python-control and SciPy on the exported model, the law in the controller core
against the linear loop it was designed on and against the twin's response to a small
move, and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from flexarm_ros.cli import main
from flexarm_ros.control.lqg import LqgLaw, design_lqg
from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.scene import load_scene
from flexarm_ros.scene.keys import set_keys
from flexarm_ros.scene.loading import load_scene_dict
from flexarm_ros.twin.batch import run_scene
from flexarm_ros.twin.cores import ControllerCore

control = pytest.importorskip("control")

WEIGHTS = "angle=0.01,deflection=0.003,rate=10,voltage=1"


def _designed(tmp_path, scene="two_link_position", weights=WEIGHTS, extra=()):
    out = tmp_path / "lqg.yaml"
    argv = ["design", scene, "--lqg", "--out", str(out), *extra]
    if weights:
        argv += ["--weights", weights]
    assert main(argv) == 0
    return out


def _at_target(sc, q):
    return set_keys(sc, {f"links[{k}].joint.initial_angle": float(v)
                         for k, v in enumerate(q)})


def test_the_regulator_is_python_controls_dlqr_on_the_exported_model(tmp_path, capsys):
    """K of the written scene = control.dlqr on ``flexarm linearize``'s export at the
    target pose, sampled by scipy.signal.cont2discrete, with Q and R from the recorded
    Bryson weights."""
    import flexarm_ros as fx
    from scipy.signal import cont2discrete
    out = _designed(tmp_path)
    assert "LQG on 12 states" in capsys.readouterr().out
    sc = load_scene(out)
    lqg = sc.control.lqg
    assert "control.dlqr" in lqg.design and "flexarm design" in lqg.design
    exp = fx.linearize(_at_target(load_scene("two_link_position"), lqg.y_goal),
                       python_control=False)
    assert exp.states == list(lqg.states)
    Ad, Bd, *_ = cont2discrete((exp.A, exp.B, exp.C, exp.D), 1e-3, method="zoh")
    assert np.allclose(lqg.A, Ad, rtol=0, atol=1e-12)
    w = lqg.weights
    n = len(exp.states)
    Q = np.zeros((n, n))
    for name in ("link1", "link2"):
        i, r = exp.states.index(f"{name}_joint"), exp.states.index(f"{name}_joint_rate")
        Q[i, i] += 1 / w.angle ** 2
        Q[r, r] += 1 / w.rate ** 2
        c = exp.C[exp.outputs.index(f"{name}_tip_deflection")]
        Q += np.outer(c, c) / w.deflection ** 2
    K, _, _ = control.dlqr(Ad, Bd, Q, np.eye(2) / w.voltage ** 2)
    assert np.allclose(lqg.K, K, rtol=1e-6, atol=1e-9 * np.max(np.abs(K)))


def test_the_estimator_gain_solves_the_kalman_riccati_equation():
    """M = P Cᵀ (C P Cᵀ + V)⁻¹ with P the stabilizing solution of the filter's DARE
    (scipy.linalg.solve_discrete_are, not the design's own route through control.dlqe),
    and python-control's predictor gain is A M."""
    from scipy.linalg import solve_discrete_are
    sc = load_scene("two_link_position")
    ctl = ControllerCore(sc)
    d = design_lqg(sc, ctl.q_goal, ctl.q_start, {"voltage": 1.0})
    P = solve_discrete_are(d.A.T, d.C.T, d.W, d.V)
    M = P @ d.C.T @ np.linalg.inv(d.C @ P @ d.C.T + d.V)
    assert np.allclose(d.M, M, rtol=1e-6, atol=1e-9 * np.max(np.abs(M)))
    L, _, _ = control.dlqe(d.A, np.eye(len(d.A)), d.C, d.W, d.V)
    assert np.allclose(np.asarray(L), d.A @ d.M, rtol=1e-6, atol=1e-9 * np.max(np.abs(L)))
    # the encoders' quantization sets V: a 2000-count-per-rev motor encoder → Δ²/12
    assert np.all(np.diag(d.V) > 0) and np.all(np.sqrt(np.diag(d.V)) < 1e-3)


def test_the_controller_core_runs_the_written_law(tmp_path):
    """The core's commands for a sequence of encoder angles are the recursion of the
    section's matrices, written out here in numpy."""
    sc = load_scene(_designed(tmp_path))
    lqg = sc.control.lqg
    ctl = ControllerCore(sc)
    A, B, C, K, M = (np.array(getattr(lqg, k)) for k in "ABCKM")
    x, u = np.array(lqg.x_start), np.zeros(2)
    rng = np.random.default_rng(0)
    for k in range(50):
        y = np.array(ctl.q_start) + rng.normal(0, 1e-3, 2) * k / 50
        if k:
            x = A @ x + B @ u
        x = x + M @ (y - np.array(lqg.y_goal) - C @ x)
        u = np.clip(-K @ x, -ctl.limit, ctl.limit)
        assert np.allclose(ctl.update(k * 1e-3, 1e-3, y), u, rtol=0, atol=1e-12)


def test_the_twins_small_move_under_lqg_is_the_designed_linear_loop():
    """A 0.02 rad move of joint 2 at the target pose: the twin (encoders, 1 kHz, the
    nonlinear arm and quasi-static motors) under the designed LQG against the design's
    own sampled linear plant under the same law — the last link's tip deflection within
    6 % of its peak and joint 2 within 2 % of the move over 3 s."""
    sc = load_scene("two_link_position")
    q = ControllerCore(sc).q_goal
    small = set_keys(_at_target(sc, [q[0], q[1] - 0.02]),
                     {"control.tip_target": None,
                      "control.joint_target": [float(q[0]), float(q[1])]})
    ctl = ControllerCore(small)
    d = design_lqg(small, ctl.q_goal, ctl.q_start, {"voltage": 1.0})
    import dataclasses
    from flexarm_ros.scene.schema import from_mapping
    from flexarm_ros.scene.sections import Lqg
    from flexarm_ros.control.lqg import lqg_record
    rec, _ = lqg_record(small, ctl.q_goal, ctl.q_start, {"voltage": 1.0})
    run = dataclasses.replace(small, control=dataclasses.replace(
        small.control, lqg=from_mapping(Lqg, rec, "control.lqg")))
    res = run_scene(run, 3.0)
    w = np.asarray(res.columns["link2_tip_deflection"])
    q2 = np.asarray(res.columns["link2_joint"])
    row = d.continuous.outputs.index("link2_tip_deflection")
    law = LqgLaw(run.control.lqg, ctl.limit)
    x = d.x_start.copy()
    lin_w, lin_q = [], []
    for k in range(3000):
        lin_w.append(d.continuous.C[row] @ x)
        lin_q.append(q[1] + x[d.continuous.states.index("link2_joint")])
        u = law.update(ctl.q_goal + d.C @ x)
        x = d.A @ x + d.B @ u
    lin_w.append(d.continuous.C[row] @ x)
    lin_q.append(q[1] + x[d.continuous.states.index("link2_joint")])
    n = min(len(w), len(lin_w))
    assert np.max(np.abs(w)) > 1e-4
    assert np.max(np.abs(np.array(lin_w[:n]) - w[:n])) <= 0.06 * np.max(np.abs(w))
    assert np.max(np.abs(np.array(lin_q[:n]) - q2[:n])) <= 0.02 * 0.02


def test_a_designed_scene_runs_in_the_batch_commands(tmp_path):
    out = _designed(tmp_path)
    csv = tmp_path / "lqg.csv"
    assert main(["simulate", str(out), "--duration", "0.5", "--quiet", "--out",
                 str(csv)]) == 0
    head = csv.read_text().splitlines()[0]
    assert "link2_voltage" in head
    res = run_scene(load_scene(out), 0.5)
    assert res.loop["lane"] == "reference"
    v = np.asarray(res.columns["link1_voltage"])
    assert np.all(np.isfinite(v)) and np.max(np.abs(v)) > 0


# ------------------------------------------------------------------ refusals
@pytest.mark.parametrize("argv,says", [
    (["--lqg", "--weights", "speed=1"], "--weights: got key 'speed', expected one of angle"),
    (["--lqg", "--weights", "angle=-1"], "--weights: got angle='-1', expected a finite"),
    (["--lqg", "--weights", "angle"], "--weights: got 'angle', expected key=value"),
    (["--shaper", "zvd", "--weights", "angle=1"], "--weights: got 'angle=1' with --shaper"),
    (["--lqg", "--modes", "1"], "--modes: got 1 with --lqg"),
    (["--lqg", "--set", "gravity=[0.0,-9.81]"], "gravity: got [0.0, -9.81]"),
])
def test_lqg_refusals_are_one_line_exit_2(tmp_path, capsys, argv, says):
    rc = main(["design", "two_link_position", "--out", str(tmp_path / "x.yaml"), *argv])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and says in err and len(err.splitlines()) == 1, err


def _lqg_data(tmp_path):
    return yaml.safe_load(_designed(tmp_path).read_text())


def test_a_written_lqg_of_the_wrong_shape_is_refused_naming_the_matrix(tmp_path):
    data = _lqg_data(tmp_path)
    data["control"]["lqg"]["K"] = data["control"]["lqg"]["K"][:1]
    with pytest.raises(SceneError, match=r"control\.lqg\.K: got a 1×12 matrix, expected 2×12"):
        load_scene_dict(data)


def test_an_unstable_written_regulator_is_refused(tmp_path):
    data = _lqg_data(tmp_path)
    data["control"]["lqg"]["K"] = [[0.0] * 12, [0.0] * 12]
    data["control"]["lqg"]["A"][0][0] = 1.5
    with pytest.raises(SceneError, match=r"control\.lqg\.K: got a regulator with \|z\|"):
        load_scene_dict(data)


def test_an_lqg_outside_position_control_or_beside_a_shaper_is_refused(tmp_path):
    data = _lqg_data(tmp_path)
    data["control"]["shaper"] = {"times": [0.0], "amplitudes": [1.0]}
    with pytest.raises(SceneError, match="control.lqg: got an LQG with control.mode "
                                         "'position' and a shaper"):
        load_scene_dict(data)


def test_an_lqg_for_another_target_is_refused(tmp_path):
    data = _lqg_data(tmp_path)
    data["control"]["tip_target"] = [0.9, 1.0]
    with pytest.raises(SceneError, match=r"control\.lqg\.y_goal: got .* expected the "
                                         r"target's joint angles"):
        ControllerCore(load_scene_dict(data))


def test_the_python_api_designs_the_same_lqg(tmp_path):
    import flexarm_ros as fx
    cli = load_scene(_designed(tmp_path)).control.lqg
    api = fx.design("two_link_position", lqg=True, weights=WEIGHTS).control.lqg
    assert np.array_equal(np.array(api.K), np.array(cli.K))
    assert np.array_equal(np.array(api.M), np.array(cli.M))
    with pytest.raises(InputError, match="weights: got key 'bad'"):
        fx.design("two_link_position", lqg=True, weights={"bad": 1.0})


@pytest.mark.parametrize("seed", [1, 4, 13])
def test_an_lqg_is_designed_and_run_on_a_generated_arm(tmp_path, seed):
    """A zoo arm under the joint PD (1–4 links, strips or tubes, tip masses or none): the
    design writes a scene that loads and runs, with finite voltages within the supply."""
    import flexarm_ros as fx
    from flexarm_ros.testing.zoo import arm
    data = arm(seed, control="position")
    data["gravity"] = [0.0, 0.0]
    sc = fx.design(load_scene_dict(data), lqg=True)
    lqg = sc.control.lqg
    assert len(lqg.y_goal) == len(sc.links)
    assert np.max(np.abs(np.linalg.eigvals(np.array(lqg.A) - np.array(lqg.B) @
                                           np.array(lqg.K)))) < 1.0
    res = fx.simulate(sc, duration=0.3)
    ctl = ControllerCore(sc)
    for lk, lim in zip(sc.links, ctl.limit):
        v = res[f"{lk.name}_voltage"]
        assert np.all(np.isfinite(v)) and np.max(np.abs(v)) <= lim + 1e-12


@pytest.mark.heavy
@pytest.mark.ros
@pytest.mark.subprocess
def test_the_ros_lockstep_run_of_an_lqg_scene_equals_simulate(tmp_path, ros_against_batch):
    """A real lockstep ROS run of the LQG scene (the controller node runs the estimator
    and the regulator on the joint_states it receives): its ground_truth/joint_states
    equal the batch run's joints at every tick to 1e-9 rad."""
    n, gap, travel = ros_against_batch(_designed(tmp_path), tmp_path / "lqg.mcap", 0.6, "/lq")
    assert n >= 590 and gap <= 1e-9 and travel > 1e-4
