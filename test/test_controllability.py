"""``flexarm linearize``: the unit of every state, input and output, and the PBH
controllability test on models whose answer is known."""

import json

import numpy as np
import pytest

from flexarm_ros.cli import main
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.controllability import TOL, pbh_test
from flexarm_ros.model.statespace import linearize
from flexarm_ros.scene import load_scene, load_scene_dict

HYD = {"type": "hydraulic", "displacement": 6.2271e-5, "torque_efficiency": 0.9,
       "leakage": 3.70648e-13, "valve_gain": 2.402963e-6, "supply_pressure": 1.37889e7,
       "total_volume": 3.05127e-4, "bulk_modulus": 6.9e8, "rated_current": 0.010}
MOTOR = {"type": "dc_motor", "gear_ratio": 12, "torque_constant": 0.05,
         "back_emf_constant": 0.05, "resistance": 1.2, "inductance": 0.05}
SENSORS = [
    {"name": "enc", "kind": "encoder", "joint": 1, "on_motor_shaft": False, "rate_hz": 1000},
    {"name": "acc", "kind": "accelerometer", "link": "arm", "position": [0.5, 0.0],
     "rate_hz": 1000},
    {"name": "gauge", "kind": "strain", "link": "arm", "position": [0.3, 0.0],
     "rate_hz": 1000},
    {"name": "pot", "kind": "potentiometer", "joint": 1, "rate_hz": 1000},
    {"name": "tip", "kind": "tip_position", "rate_hz": 1000}]


def _scene(drive, input_kind, rung, refine=2, flexible_joint=False):
    joint = {"drive_inertia": 0.1352, "drive": drive}
    if flexible_joint:
        joint["flexibility"] = {"stiffness": 500.0, "motor_inertia": 0.01}
    return load_scene_dict({
        "name": "units",
        "links": [{"name": "arm", "joint": joint,
                   "beam": {"length": 1.0, "EI": 2000.0, "mass_per_length": 1.0,
                            "thickness": 0.01},
                   "hub": {"inertia": 0.0174}, "tip": {"mass": 0.5, "inertia": 0.002}}],
        "inputs": [{"joint": 1, input_kind: {"type": "constant", "value": 0.0}}],
        "sensors": SENSORS, "fidelity": {"rung": rung, "refine": refine}})


@pytest.mark.parametrize("drive, kind, rung, flex, coords, z_unit, u_unit", [
    (MOTOR, "voltage", "fem", False, [("arm_joint", "rad"), ("arm_w1", "m"), ("arm_th1", "rad"),
                                      ("arm_w2", "m"), ("arm_th2", "rad")], "A", "V"),
    (HYD, "current", "modal", False, [("arm_joint", "rad"), ("arm_mode1", "m"),
                                      ("arm_mode2", "m")], "Pa", "A"),
    (MOTOR, "voltage", "rigid", True, [("arm_motor", "rad"), ("arm_joint", "rad"),
                                       ("arm_spring", "rad")], "A", "V"),
    (MOTOR, "voltage", "cubic", False, [("arm_joint", "rad"), ("arm_tip_disp", "m"),
                                        ("arm_tip_rot", "rad")], "A", "V"),
    (MOTOR, "voltage", "fd", False, [("arm_joint", "rad")] + [(f"arm_y{i}", "m")
                                                              for i in range(1, 5)], "A", "V"),
])
def test_units_are_aligned_with_states_inputs_and_outputs(drive, kind, rung, flex, coords,
                                                         z_unit, u_unit):
    sc = _scene(drive, kind, rung, refine=4 if rung == "fd" else 2, flexible_joint=flex)
    ss = linearize(Chain(sc))
    names, units = zip(*coords)
    z = "arm_pressure" if z_unit == "Pa" else "arm_current"
    assert ss.states == list(names) + [f"{n}_rate" for n in names] + [z]
    assert ss.state_units == list(units) + [f"{u}/s" for u in units] + [z_unit]
    assert ss.inputs == [f"arm_{kind}"] and ss.input_units == [u_unit]
    assert list(zip(ss.outputs, ss.output_units)) == [
        ("arm_joint", "rad"), ("arm_tip_deflection", "m"), ("enc", "counts"),
        ("acc", "m/s²"), ("gauge", "m/m"), ("pot", "rad"), ("tip_x", "m"), ("tip_y", "m")]


def test_linearize_json_and_npz_carry_the_units(tmp_path, capsys):
    assert main(["linearize", "link_motor", "--json", "--rung", "cubic"]) == 0
    out = json.loads(capsys.readouterr().out)
    for names in ("states", "inputs", "outputs"):
        units = out[names[:-1] + "_units"]
        assert len(units) == len(out[names]) and all(units), names
    assert dict(zip(out["states"], out["state_units"]))["link1_joint_rate"] == "rad/s"
    assert out["input_units"] == ["V"]
    assert out["controllable"] is True
    assert out["controllability"]["tol"] == TOL
    npz = tmp_path / "ss.npz"
    assert main(["linearize", "link_motor", "--out", str(npz), "--rung", "cubic"]) == 0
    z = np.load(npz)
    assert list(z["state_units"]) == out["state_units"]
    assert list(z["output_units"]) == out["output_units"]


# ------------------------------------------------------------------------------ the PBH test
def test_pbh_double_integrator_is_controllable():
    """A rigid body driven by a torque (θ̈ = τ/J): a Jordan block at 0, controllable."""
    r = pbh_test([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1 / 0.3]])
    assert r.controllable and r.uncontrollable == []


def test_pbh_finds_a_mode_the_input_does_not_reach():
    """A decoupled mode (a zero row of B, diagonal A) is uncontrollable, the others not."""
    r = pbh_test(np.diag([-1.0, -2.0, -3.0]), [[1.0], [0.0], [1.0]])
    assert not r.controllable
    assert r.uncontrollable == [pytest.approx(-2.0)]


def test_pbh_two_equal_oscillators_need_two_inputs():
    """Two identical undamped oscillators pushed by the same force: the difference of their
    motions never changes (symmetry), so one input cannot control them; two inputs can."""
    w2 = 400.0
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 0] = A[3, 1] = -w2
    assert not pbh_test(A, [[0.0], [0.0], [1.0], [1.0]]).controllable
    assert pbh_test(A, [[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]).controllable


def test_pbh_without_inputs_nothing_is_controllable():
    r = pbh_test(np.diag([-1.0, -5.0]), np.zeros((2, 0)))
    assert not r.controllable and len(r.uncontrollable) == 2


@pytest.mark.parametrize("rung", ["rigid", "cubic", "modal", "fem", "fd"])
def test_a_torque_at_the_hub_controls_a_flexible_link(rung):
    """One flexible link driven at the hub: every mode moves the hub, so the torque
    controls them all, whatever the rung (the controllability matrix's rank, numerically,
    says otherwise)."""
    ss = linearize(Chain(load_scene("link").with_fidelity(rung=rung, refine=10)))
    r = pbh_test(ss.A, ss.B)
    assert r.controllable, (r.uncontrollable, r.margins.min())


def test_open_backlash_leaves_the_links_uncontrollable():
    """two_link_case3_backlash starts at rest inside the gear backlash: at that operating
    point the links are not connected to their motors, so the voltages cannot move them."""
    ss = linearize(Chain(load_scene("two_link_case3_backlash")))
    r = pbh_test(ss.A, ss.B)
    assert not r.controllable
    assert r.margins.min() < TOL * 1e-3
