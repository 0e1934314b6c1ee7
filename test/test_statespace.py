"""``linearize`` against independent truths.

The state-space matrices are assembled from the model's parts (statespace.py); here they
are compared with central finite differences of the full nonlinear model — the compiled
right-hand side for A and B, the sensor read-outs of :mod:`sensors` for C and D — and the
eigenvalues of an undamped, undriven scene with the natural frequencies of ``flexarm
modes`` (a generalized symmetric eigenproblem, a different computation).
"""

import copy
import json

import numpy as np
import pytest

from flexarm_ros.cli import main
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.linear import natural_modes
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.model.sensors import build_sensors, measure, true_value
from flexarm_ros.model.statics import initial_state
from flexarm_ros.model.statespace import linearize

G = 9.8066
MOTOR = {"type": "dc_motor", "gear_ratio": 12, "torque_constant": 0.05,
         "back_emf_constant": 0.05, "resistance": 1.2, "inductance": 0.05}
HYD = {"type": "hydraulic", "displacement": 6.2271e-5, "torque_efficiency": 0.9,
       "leakage": 3.70648e-13, "valve_gain": 2.402963e-6, "supply_pressure": 1.37889e7,
       "total_volume": 3.05127e-4, "bulk_modulus": 6.9e8, "rated_current": 0.010}
SENSORS = [
    {"name": "enc", "kind": "encoder", "joint": 1, "rate_hz": 1000},
    {"name": "acc_mid", "kind": "accelerometer", "link": "arm", "position": [0.5, 0.0],
     "rate_hz": 1000},
    {"name": "acc_tip", "kind": "accelerometer", "link": "arm", "body": "tip",
     "position": [0.01, 0.0], "axis": [1.0, 0.0], "rate_hz": 1000},
    {"name": "gauge", "kind": "strain", "link": "arm", "position": [0.3, 0.0],
     "rate_hz": 1000},
    {"name": "pot", "kind": "potentiometer", "joint": 1, "rate_hz": 1000},
    {"name": "tip", "kind": "tip_position", "rate_hz": 1000}]


def _scene(drive=None, input_kind="torque", gravity=(0.0, 0.0), rung="fd", refine=6,
           angle=0.2, u=0.0, static=False, sensors=True, damping=0.0):
    joint = {"initial_angle": angle, "drive_inertia": 0.1352}
    if drive is not None:
        joint["drive"] = drive
    motor = drive is not None and drive["type"] == "dc_motor"
    enc = [dict(s, on_motor_shaft=motor) if s["kind"] == "encoder" else s for s in SENSORS]
    return load_scene_dict({
        "name": "lin", "gravity": list(gravity),
        "links": [{"name": "arm", "joint": joint,
                   "beam": {"length": 1.0, "EI": 2000.0, "mass_per_length": 1.0,
                            "thickness": 0.01,
                            "damping": {"stiffness_proportional": damping}},
                   "hub": {"inertia": 0.0174}, "tip": {"mass": 0.5, "inertia": 0.002}}],
        "inputs": [{"joint": 1, input_kind: {"type": "constant", "value": u}}],
        "initial": {"static_equilibrium": static},
        "sensors": enc if sensors else [],
        "fidelity": {"rung": rung, "refine": refine}})


CASES = {
    "torque": dict(),
    "dc_motor_with_current_state": dict(drive=MOTOR, input_kind="voltage"),
    "dc_motor_quasi_static": dict(drive={**MOTOR, "inductance": 0.0}, input_kind="voltage"),
    "hydraulic_under_gravity": dict(drive=HYD, input_kind="current",
                                    gravity=(0.0, -G), static=True, rung="modal", refine=3),
    "torque_under_gravity_not_at_rest_equilibrium": dict(gravity=(0.0, -G), rung="cubic"),
}


def _outputs(chain, sensors, x, u_scene):
    """Nonlinear outputs at state x: hub angle, tip deflection, then the sensors' true
    values (encoder without the floor: a continuous count)."""
    q, qd = chain.full_state(0.0, x)
    qdd = chain.full_qdd(0.0, x)
    q_init = initial_state(chain)[0]
    y = [q[lm.i_joint] for lm in chain.links]
    y += list(chain.tip_deflections(q))
    for sm in sensors:
        if sm.spec.kind == "encoder":
            y.append(sm.gain * (q[sm.coord] - q_init[sm.coord]))
        elif sm.spec.kind == "tip_position":
            y += list(true_value(sm, chain, q, qd, qdd, q_init))
        else:
            y.append(true_value(sm, chain, q, qd, qdd, q_init))
    return np.array(y)


@pytest.mark.parametrize("case", sorted(CASES))
def test_matrices_match_finite_differences_of_the_nonlinear_model(case):
    kw = CASES[case]
    chain = Chain(_scene(**kw))
    ss = linearize(chain)
    x0 = ss.x0
    ns = len(x0)
    Afd = np.zeros((ns, ns))
    Cfd = np.zeros((len(ss.outputs), ns))
    sensors = build_sensors(chain)
    for j in range(ns):
        d = 1e-6 * max(1.0, abs(x0[j]))
        xp, xm = x0.copy(), x0.copy()
        xp[j] += d
        xm[j] -= d
        Afd[:, j] = (chain.rhs(0.0, xp) - chain.rhs(0.0, xm)) / (2 * d)
        Cfd[:, j] = (_outputs(chain, sensors, xp, 0) - _outputs(chain, sensors, xm, 0)) / (2 * d)
    scale = np.abs(Afd).max(axis=1, keepdims=True) + 1e-300
    assert np.max(np.abs(ss.A - Afd) / scale) < 1e-6
    # rows that vanish to first order (axial acceleration at rest) compare absolutely
    tol = 1e-6 * np.abs(Cfd).max(axis=1, keepdims=True) + 1e-9
    assert np.all(np.abs(ss.C - Cfd) <= tol)
    # B and D: the same scene with the input program at ±du
    du = {"torque": 1e-3, "voltage": 1e-3, "current": 1e-6}[kw.get("input_kind", "torque")]
    ch_p = Chain(_scene(**kw, u=du))
    ch_m = Chain(_scene(**kw, u=-du))
    for ch in (ch_p, ch_m):           # same operating point (the hydraulic null bias)
        initial_state(ch)
    Bfd = (ch_p.rhs(0.0, x0) - ch_m.rhs(0.0, x0)) / (2 * du)
    np.testing.assert_allclose(ss.B[:, 0], Bfd, rtol=1e-6, atol=1e-9 * np.abs(Bfd).max())
    Dfd = (_outputs(ch_p, build_sensors(ch_p), x0, du)
           - _outputs(ch_m, build_sensors(ch_m), x0, -du)) / (2 * du)
    np.testing.assert_allclose(ss.D[:, 0], Dfd, rtol=1e-6, atol=1e-9 * (np.abs(Dfd).max() + 1))


@pytest.mark.parametrize("rung,refine", [("fd", 8), ("modal", 4), ("cubic", 1)])
def test_eigenvalues_match_natural_modes(rung, refine):
    chain = Chain(_scene(rung=rung, refine=refine, sensors=False))
    ss = linearize(chain)
    eig = np.linalg.eigvals(ss.A)
    osc = np.sort(eig[eig.imag > 1e-6].imag) / (2 * np.pi)
    assert np.max(np.abs(eig.real)) < 1e-6 * np.abs(eig).max()     # undamped
    modes = natural_modes(chain, joints="free").frequencies_hz
    modes = modes[modes > 0]
    np.testing.assert_allclose(osc, modes, rtol=1e-8)


def test_seed001_actuator_augmented_form_states_and_cli(tmp_path, capsys):
    import yaml
    sc = _scene(drive=MOTOR, input_kind="voltage", rung="fd", refine=4)
    path = tmp_path / "s.yaml"
    data = {"name": "lin", "links": [
        {"name": "arm", "joint": {"drive_inertia": 0.1352, "drive": MOTOR},
         "beam": {"length": 1.0, "EI": 2000.0, "mass_per_length": 1.0},
         "hub": {"inertia": 0.0174}, "tip": {"mass": 0.5, "inertia": 0.002}}],
        "inputs": [{"joint": 1, "voltage": {"type": "constant", "value": 3.0}}],
        "fidelity": {"rung": "fd", "refine": 4}}
    path.write_text(yaml.safe_dump(data))
    assert main(["linearize", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {"A", "B", "C", "D", "states", "inputs", "outputs"}
    # x = [Z, Ż, i]: hub angle + 4 nodal deflections, their rates, the armature current
    assert out["states"] == (["arm_joint"] + [f"arm_y{i}" for i in range(1, 5)]
                             + ["arm_joint_rate"] + [f"arm_y{i}_rate" for i in range(1, 5)]
                             + ["arm_current"])
    assert out["inputs"] == ["arm_voltage"]
    assert out["outputs"][:2] == ["arm_joint", "arm_tip_deflection"]
    A = np.array(out["A"])
    # the current row: L di/dt = V − R i − K_b n θ̇  → A[i, i] = −R/L, B[i] = 1/L
    assert A[-1, -1] == pytest.approx(-1.2 / 0.05)
    assert A[-1, 5] == pytest.approx(-0.05 * 12 / 0.05)
    assert np.array(out["B"])[-1, 0] == pytest.approx(1 / 0.05)
    npz = tmp_path / "ss.npz"
    assert main(["linearize", str(path), "--out", str(npz), "--rung", "fd",
                 "--refine", "6"]) == 0
    z = np.load(npz)
    assert z["A"].shape == (15, 15) and list(z["states"])[-1] == "arm_current"
    assert main(["linearize", str(path), "--out", str(tmp_path / "ss.txt")]) == 2
    assert "expected a .npz file" in capsys.readouterr().err
