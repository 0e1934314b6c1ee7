"""Seed 002's hydraulic arm in the twin: the servovalve current crosses the wire, the
actuator's load pressure is integrated by the plant with the arm (sim/plant.py).

Until session 13 the driver computed the torque with the joint rate held over the 6 ms
control period and the plant held it: across the oil column's stiffness that coupling
diverged at t = 0.133 s. The truth here is the batch simulation of the same scene (one
model, drives and arm together) with the valve step where the twin's controller first
sends it: the first tick at or after 0.1 s, 0.102 s."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from flexarm_ros.model import drives
from flexarm_ros.scene import load_scene
from flexarm_ros.scene.sections import Program
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.cores import DriverCore
from flexarm_ros.twin.cosim import cosimulate
from flexarm_ros.twin.validation import Validator

PERIOD = 0.006


def _step_at_the_tick(scene):
    first = np.ceil(scene.inputs[0].program.start / PERIOD - 1e-9) * PERIOD
    inp = dataclasses.replace(scene.inputs[0],
                              current=Program(type="step", amplitude=0.004, start=first))
    return dataclasses.replace(scene, inputs=(inp,))


@pytest.mark.parametrize("name", ["hydraulic_2kg", "hydraulic_0kg"])
def test_the_twin_moves_the_hydraulic_arm_as_the_batch_model_does(name):
    """Co-simulation (simulator, driver, controller cores, lockstep) at a 0.1 ms plant step
    against ``flexarm simulate``'s model at the same step: the tip on every tick within
    1e-8 m over a swing of decimetres, and the driver's reported load pressure within
    1e-3 Pa of the batch state (the pressure oscillates by ~1 MPa)."""
    sc = load_scene(name).with_fidelity(dt=1e-4)
    T_end = 0.5
    res = cosimulate(sc, T_end)
    tip = np.array([[m.data["point"]["x"], m.data["point"]["y"]]
                    for m in res.topic(T.GT_TIP)])
    ref = simulate(_step_at_the_tick(sc).with_fidelity(output_dt=PERIOD), T_end)
    n = len(tip)
    assert n == round(T_end / PERIOD) + 1 and len(ref.columns["t"]) >= n
    btip = np.c_[ref.columns["tip_x"], ref.columns["tip_y"]][:n]
    assert np.linalg.norm(tip[-1] - tip[0]) > 0.1                   # it swings
    assert np.max(np.linalg.norm(tip - btip, axis=1)) < 1e-8
    p = np.array([m.data["effort"][0] for m in res.topic(T.MOTOR_STATES)])
    p_ref = ref.columns["arm_pressure"][:len(p)]
    assert np.ptp(p_ref) > 5e5
    assert np.max(np.abs(p - p_ref)) < 1e-3


def test_a_hydraulic_effort_is_the_valve_current_and_is_validated_in_amperes():
    """The driver passes the held command (A above the null bias) to the simulator, and a
    closed valve (watchdog) as minus the null bias; the simulator's validator takes the
    valve's rating, not a torque limit, and names amperes."""
    sc = load_scene("hydraulic_2kg")
    res = cosimulate(sc, 0.2)
    cmds = [m.data["data"] for m in res.topic(T.COMMANDS)]
    effs = [m.data["data"] for m in res.topic(T.EFFORTS)]
    assert effs == cmds and max(e[0] for e in effs) == pytest.approx(0.004)
    v = Validator(sc, "effort")
    rated = sc.links[0].joint.drive.rated_current
    assert v.reason([0.5 * rated]) is None
    assert v.reason([1.5 * rated]) is not None and "A" in v.expectation()
    drv = DriverCore(sc)
    drv.accept(0.0, [0.004])
    assert drv.update(0.0, PERIOD, [0.0])[0] == 0.004
    late = drv.update(1.0, PERIOD, [0.0])[0]                 # past the watchdog
    assert drv.tripped and late == -drv.par[0][drives.HYD_VALVE_BIAS] and abs(late) < rated


def test_explain_says_what_a_hydraulic_joint_takes_on_the_wire(capsys):
    """The control period, the watchdog and the null bias the wire value is taken from."""
    from flexarm_ros.cli import main
    from flexarm_ros.model.chain import Chain
    assert main(["explain", "hydraulic_2kg", "--no-check"]) == 0
    text = capsys.readouterr().out
    from flexarm_ros.model.statics import initial_state
    chain = Chain(load_scene("hydraulic_2kg"))
    initial_state(chain)                               # the null bias that holds the start
    bias = chain.actuators[0].par[drives.HYD_VALVE_BIAS]
    assert bias > 0
    assert "control every 6 ms (166.667 Hz)" in text and "older than 0.05 s" in text
    assert f"minus the null bias I0 = {bias * 1e3:.4g} mA" in text
    assert "effort: the valve current within the same ±0.01 A" in text
