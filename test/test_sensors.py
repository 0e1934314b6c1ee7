"""Sensors against independent truths (docs/physics.md, "Sensors come from the model").

* accelerometer on a link spinning at constant Ω: centripetal specific force −Ω²·r along
  the link (r the distance from the joint axis), zero across it; at rest in a vertical
  plane it reads −g·ê (+g for an axis pointing up) — rigid-body kinematics by hand;
* encoder: counts are the integer ⌊n·Δθ·lines·4/2π⌋ of the drive angle, recomputed here;
* strain of a statically loaded cantilever (seed 002 arm under gravity with a tip mass):
  ε = (t/2)·M(x)/EI with M(x) = P(L − x) + q(L − x)²/2 (statics by hand);
* noise is reproducible from its seed and its statistics match the declared std; the ADC
  clips and quantizes to the declared range and resolution.
"""

import math

import numpy as np
import pytest

from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

G = 9.8066


def _spin_scene(omega=6.0, sensors=(), rung="rigid", EI=1e9, hub_radius=0.05):
    return load_scene_dict({
        "name": "spin", "links": [{
            "name": "arm", "beam": {"length": 1.0, "EI": EI, "mass_per_length": 1.0,
                                    "hub_radius": hub_radius},
            "hub": {"inertia": 0.01}, "tip": {"mass": 0.2, "inertia": 1e-4}}],
        "inputs": [{"joint": 1, "motion": {"type": "spin_up", "omega": omega,
                                            "ramp_time": 0.2}}],
        "sensors": list(sensors), "duration": 0.4,
        "fidelity": {"rung": rung, "output_dt": 1e-3}})


def test_accelerometer_reads_centripetal_acceleration_in_uniform_rotation():
    omega, x, rh = 6.0, 0.7, 0.05
    sensors = [{"name": "radial", "kind": "accelerometer", "link": "arm",
                "position": [x, 0.0], "axis": [1.0, 0.0], "rate_hz": 1000},
               {"name": "transverse", "kind": "accelerometer", "link": "arm",
                "position": [x, 0.0], "rate_hz": 1000},
               {"name": "tipbody", "kind": "accelerometer", "link": "arm", "body": "tip",
                "position": [0.02, 0.01], "axis": [1.0, 0.0], "rate_hz": 1000}]
    res = simulate(_spin_scene(omega, sensors), 0.4)
    tab = res.sensor_tables[1000.0]
    late = tab["t"] >= 0.3            # ramp over at 0.2 s: uniform rotation
    # a rigid link (EI = 1e9) spinning at Ω: r̈ = −Ω² r toward the axis
    np.testing.assert_allclose(tab["radial"][late], -omega**2 * (rh + x), rtol=1e-6)
    np.testing.assert_allclose(tab["transverse"][late], 0.0, atol=1e-6 * omega**2)
    # tip-body point (1.0 + 0.02, 0.01) in the tip frame; axis along the link
    np.testing.assert_allclose(tab["tipbody"][late], -omega**2 * (rh + 1.02), rtol=1e-6)
    # during the ramp the transverse axis feels the tangential acceleration α·r
    t = tab["t"][(tab["t"] > 0.02) & (tab["t"] < 0.18)]
    alpha = omega / 0.2 * (1 - np.cos(2 * math.pi * t / 0.2))
    ramp = (tab["t"] > 0.02) & (tab["t"] < 0.18)
    np.testing.assert_allclose(tab["transverse"][ramp], alpha * (rh + x), rtol=1e-5,
                               atol=1e-6)


def test_accelerometer_reads_gravity_at_rest_in_a_vertical_plane():
    sensors = [{"name": "up", "kind": "accelerometer", "link": "arm", "body": "hub",
                "position": [0.0, 0.0], "axis": [0.0, 1.0], "rate_hz": 100,
                "sensitivity": 0.1 / G},
               {"name": "along", "kind": "accelerometer", "link": "arm", "body": "hub",
                "position": [0.0, 0.0], "axis": [1.0, 0.0], "rate_hz": 100}]
    ang = 0.3
    sc = load_scene_dict({
        "name": "g", "gravity": [0.0, -G], "links": [{
            "name": "arm", "joint": {"initial_angle": ang},
            "beam": {"length": 0.5, "EI": 1e6, "mass_per_length": 1.0}}],
        "inputs": [{"joint": 1, "motion": {"type": "hold"}}],
        "sensors": sensors, "initial": {"static_equilibrium": True}, "duration": 0.05})
    tab = simulate(sc).sensor_tables[100.0]
    # hub frame at angle ang: local y axis = (−sin, cos); specific force −g = (0, +G)
    np.testing.assert_allclose(tab["up_true"], G * math.cos(ang), rtol=1e-9)
    np.testing.assert_allclose(tab["up"], 0.1 * math.cos(ang), rtol=1e-9)   # volts, 100 mV/g
    np.testing.assert_allclose(tab["along_true"], G * math.sin(ang), rtol=1e-9)


def test_encoder_counts_are_exact_integers_of_the_shaft_angle():
    ratio, lines = 12.0, 500
    sc = load_scene_dict({
        "name": "enc", "links": [{
            "name": "arm", "beam": {"length": 1.0, "EI": 2000.0, "mass_per_length": 1.0},
            "hub": {"inertia": 0.0174},
            "joint": {"initial_angle": 0.2, "drive_inertia": 0.1352, "drive": {
                "type": "dc_motor", "gear_ratio": ratio, "torque_constant": 0.05,
                "back_emf_constant": 0.05, "resistance": 1.2, "inductance": 0.05}}}],
        "inputs": [{"joint": 1, "voltage": {"type": "piecewise_constant",
                                            "times": [0.0, 0.5], "values": [3.0, -3.0]}}],
        "sensors": [{"name": "enc", "kind": "encoder", "joint": 1, "rate_hz": 1000,
                     "lines_per_rev": lines},
                    {"name": "pot", "kind": "potentiometer", "joint": 1, "rate_hz": 1000}],
        "fidelity": {"rung": "cubic"}, "duration": 1.0})
    res = simulate(sc)
    tab = res.sensor_tables[1000.0]
    theta = res.columns["arm_joint"]
    np.testing.assert_array_equal(tab["t"], res.columns["t"])
    counts = tab["enc"]
    assert np.all(counts == np.round(counts))
    expect = np.floor(ratio * (theta - 0.2) * lines * 4 / (2 * math.pi) + 1e-9)
    np.testing.assert_array_equal(counts, expect)
    assert counts.max() > 1000 and np.any(np.diff(counts) < 0)     # it moved both ways
    np.testing.assert_array_equal(tab["pot"], theta)


@pytest.mark.heavy
@pytest.mark.parametrize("x_gauge", [0.25, 0.4993, 0.8])
def test_strain_of_statically_loaded_cantilever_matches_beam_theory(x_gauge):
    L, EI, rho_a, tip, t = 0.9985, 200e9 * 4.065e-10, 7861.05 * 6.17795e-4, 2.115, 3.175e-3
    sc = load_scene_dict({
        "name": "strain", "gravity": [0.0, -G], "links": [{
            "name": "arm", "beam": {"length": L, "EI": EI, "mass_per_length": rho_a,
                                    "thickness": t},
            "tip": {"mass": tip}}],
        "inputs": [{"joint": 1, "motion": {"type": "hold"}}],
        "initial": {"static_equilibrium": True},
        "sensors": [{"name": "gauge", "kind": "strain", "link": "arm",
                     "position": [x_gauge, 0.0], "rate_hz": 1000}],
        "fidelity": {"rung": "fem", "refine": 32, "foreshortening": False},
        "duration": 0.002})
    eps = simulate(sc).sensor_tables[1000.0]["gauge_true"][0]
    a = L - x_gauge
    moment = tip * G * a + rho_a * G * a**2 / 2        # hogging: curvature w'' < 0
    expect = -0.5 * t * moment / EI
    # Hermite cubics: curvature linear per element against a quadratic moment: O(h²)
    assert eps == pytest.approx(expect, rel=2e-3)


def test_noise_is_seeded_and_adc_quantizes():
    base = {"name": "a", "kind": "accelerometer", "link": "arm", "position": [0.5, 0.0],
            "axis": [1.0, 0.0], "rate_hz": 1000}
    noisy = dict(base, name="noisy", noise_std=0.05, seed=7)
    noisy2 = dict(base, name="noisy2", noise_std=0.05, seed=7)
    adc = dict(base, name="adc", sensitivity=0.01, adc_range=[-0.1, 0.1], adc_bits=8)
    res = simulate(_spin_scene(6.0, [base, noisy, noisy2, adc]), 0.4)
    tab = res.sensor_tables[1000.0]
    dev = tab["noisy"] - tab["a"]
    np.testing.assert_array_equal(tab["noisy"], tab["noisy2"])          # same seed
    assert np.std(dev) == pytest.approx(0.05, rel=0.1)
    assert abs(np.mean(dev)) < 4 * 0.05 / math.sqrt(len(dev))
    lsb = 0.2 / 255
    codes = (tab["adc"] + 0.1) / lsb
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-6)
    v = np.clip(0.01 * tab["a_true"], -0.1, 0.1)
    assert np.max(np.abs(tab["adc"] - v)) <= 0.5 * lsb + 1e-12
    # −Ω²r = −36·0.55 = −19.8 m/s² → −0.198 V: clipped at the range
    assert np.isclose(tab["adc"][-1], -0.1)


@pytest.mark.parametrize("rung,refine,fs", [("cubic", None, True), ("fem", 3, True),
                                            ("fd", 4, True), ("modal", 2, False),
                                            ("rigid", None, True)])
def test_compiled_accelerometers_equal_the_numpy_point_kinematics(rung, refine, fs):
    """The plant's compiled read-out (model.compiled.sensors) against Chain.point_kinematics at
    random states and accelerations, for sensors on beams, hub and tip bodies with offsets
    and oblique axes, in gravity."""
    import yaml
    from flexarm_ros.model.compiled import sensors as ksensors
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.scene import load_scene_dict, resolve_scene_path
    from flexarm_ros.model.sensors import build_sensors, true_value
    if not kchain.HAVE_NUMBA:
        pytest.skip("the compiled read-out needs numba (the numpy path is the reference)")
    data = yaml.safe_load(resolve_scene_path("two_link_case1").read_text())
    data["gravity"] = [0.3, -9.81]
    data["sensors"] = [
        {"name": "a_beam", "kind": "accelerometer", "link": "link1", "body": "beam",
         "position": [0.21, 0.0], "axis": [0.6, 0.8], "rate_hz": 1000},
        {"name": "a_hub", "kind": "accelerometer", "link": "link2", "body": "hub",
         "position": [0.03, -0.02], "axis": [1.0, 0.0], "rate_hz": 1000},
        {"name": "a_tip", "kind": "accelerometer", "link": "link2", "body": "tip",
         "position": [0.01, 0.02], "axis": [0.0, 1.0], "rate_hz": 1000},
        {"name": "a_beam2", "kind": "accelerometer", "link": "link2", "body": "beam",
         "position": [0.6, 0.0], "axis": [0.0, 1.0], "rate_hz": 1000}]
    scene = load_scene_dict(data).with_fidelity(rung=rung, refine=refine,
                                                foreshortening=fs)
    ch = Chain(scene)
    sens = build_sensors(ch, scene)
    idx, *arrs = ksensors.pack(ch, sens)
    ws = kchain.workspace(ch.kernel_args)
    out = np.empty(len(idx))
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(20):
        q = rng.normal(0.0, 0.05, ch.n) + ch.initial_q()[0]
        qd = rng.normal(0.0, 2.0, ch.n)
        qdd = rng.normal(0.0, 50.0, ch.n)
        kchain.forces(0.0, q.copy(), qd.copy(), np.zeros(max(ch.nz, 0)), ch.kernel_args, ws)
        ksensors.readings(q, qd, qdd, ch.kernel_args, ws, *arrs, out)
        kin = ch.kinematics(q, qd, frames_only=True)
        for r, j in enumerate(idx):
            ref = true_value(sens[j], ch, q, qd, qdd, None, kin)
            worst = max(worst, abs(out[r] - ref) / (1.0 + abs(ref)))
    assert worst < 1e-12, worst


def test_tip_position_and_encoder_tables_equal_the_per_sample_model():
    """The tables' whole-run read-outs (one compiled pass for the tip, one vector floor
    for the counts) against the model read one sample at a time (true_value)."""
    from flexarm_ros.model.sensors import build_sensors, true_value
    from flexarm_ros.scene import load_scene
    sc = load_scene("link_motor")
    res = simulate(sc, 0.3)
    tab = res.sensor_tables[1000.0]
    chain = res.chain
    q0 = res.run.q[0]
    models = {sm.name: sm for sm in build_sensors(chain, sc)}
    for k in (0, 57, len(tab["t"]) - 1):
        tip = true_value(models["tip"], chain, res.run.q[k], res.run.qd[k], None, q0)
        np.testing.assert_allclose([tab["tip_x"][k], tab["tip_y"][k]], tip, rtol=0,
                                   atol=1e-12)
        assert tab["enc"][k] == true_value(models["enc"], chain, res.run.q[k],
                                           res.run.qd[k], None, q0)
    assert abs(tab["enc"][-1]) > 100          # the motor shaft turned: counts moved
