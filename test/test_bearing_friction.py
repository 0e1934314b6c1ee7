"""Air bearings rubbing the table (model/bearings.py, docs/physics.md §8.5) against
independent truths: Coulomb's closed form for a body swung on a rigid link, the energy
balance of a flexible two-link chain, the numpy reference against the compiled kernel on
every rung, the twin's plant against the same closed form, friction off leaving a run
bit-identical, bad keys refused, and Case 3's centre drifting only with friction."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from flexarm_ros.errors import SceneError
from flexarm_ros.model import Chain
from flexarm_ros.model.bearings import bearing_states
from flexarm_ros.scene import (STANDARD_GRAVITY, Bearing, HighSpot, load_scene,
                               load_scene_dict)
from flexarm_ros.sim.simulate import simulate

# a rigid-ish link swinging a 1 kg body on the table: the body's CG runs on a circle of
# radius R, its bearing under the CG; friction torque μ m g₀ R about the joint
M_BODY, CG, L, RHO_A, I_BODY, I_HUB = 1.0, 0.05, 0.5, 0.02, 1e-3, 1e-3
R = L + CG
MU, OMEGA0 = 0.1, 2.0
J_JOINT = RHO_A * L ** 3 / 3.0 + M_BODY * R ** 2 + I_BODY + I_HUB
ALPHA = MU * M_BODY * STANDARD_GRAVITY * R / J_JOINT        # rad/s², the deceleration


def swing_scene(mu=MU, rung="rigid", v_slip=1e-4, duration=2.0):
    bearing = [{"link": "arm", "friction": mu, "slip_velocity": v_slip}] if mu else []
    return load_scene_dict({
        "name": "bearing_swing", "duration": duration,
        "links": [{"name": "arm", "joint": {"initial_rate": OMEGA0},
                   "hub": {"inertia": I_HUB},
                   "beam": {"length": L, "EI": 2000.0, "mass_per_length": RHO_A,
                            "damping": {"stiffness_proportional": 1e-3}},
                   "tip": {"mass": M_BODY, "inertia": I_BODY, "cg": [CG, 0.0]}}],
        "bearings": bearing,
        "fidelity": {"rung": rung, "output_dt": 1e-3}})


def test_a_swung_body_decelerates_and_stops_as_coulomb_says():
    """ω̇ = −μ m g₀ R / J while it slides (|v| ≫ v_s), and it stops after
    Δθ = J ω₀² / (2 μ m g₀ R): closed forms of Coulomb friction on a rigid swing."""
    res = simulate(swing_scene())
    t, th, om = (res.columns[k] for k in ("t", "arm_joint", "arm_joint_rate"))
    sliding = (t > 0.1) & (t < 0.9 * OMEGA0 / ALPHA)
    slope = np.polyfit(t[sliding], om[sliding], 1)[0]
    assert slope == pytest.approx(-ALPHA, rel=2e-3)
    assert th[-1] - th[0] == pytest.approx(OMEGA0 ** 2 / (2.0 * ALPHA), rel=2e-3)
    assert abs(om[-1]) < 1e-3 * OMEGA0          # at rest: the stick holds it
    # friction off: it swings on at ω₀ (nothing else slows it)
    free = simulate(swing_scene(mu=0.0, duration=0.5))
    assert free.columns["arm_joint_rate"][-1] == pytest.approx(OMEGA0, rel=1e-3)


@pytest.mark.heavy
def test_the_twins_plant_carries_the_friction():
    """The plant the ROS twin steps (held torques, here zero) stops the swung body at the
    same closed-form angle: the friction acts on the wire as in batch."""
    from flexarm_ros.sim.plant import Plant
    plant = Plant(swing_scene())
    for _ in range(200):
        plant.set_inputs([0.0])
        plant.step(0.01)
    q, qd = plant.joint_state()[:2]
    q0 = plant.q_initial[plant.chain.names.index("arm_joint")]
    assert q[0] - q0 == pytest.approx(OMEGA0 ** 2 / (2.0 * ALPHA), rel=2e-3)
    assert abs(qd[0]) < 1e-3 * OMEGA0


def _free_two_link(rung="cubic"):
    """two_link_free coasting (no torques, no damping) with friction under RB2 and RB4 and
    a high spot on RB2's path."""
    sc = load_scene("two_link_free")
    links = []
    for lk in sc.links:
        jt = dataclasses.replace(lk.joint, drive_damping=0.0, initial_rate=0.8)
        bm = dataclasses.replace(lk.beam, damping=dataclasses.replace(
            lk.beam.damping, viscous_per_length=0.0))
        links.append(dataclasses.replace(lk, joint=jt, beam=bm))
    fid = dataclasses.replace(sc.fidelity, rung=rung, output_dt=5e-4, tolerance=0.0)
    return dataclasses.replace(
        sc, links=tuple(links), inputs=(), fidelity=fid, control=None,
        bearings=(Bearing(link="link1", friction=0.02,
                          high_spots=(HighSpot(point=(0.33, 0.66), radius=0.05,
                                               friction=0.05),)),
                  Bearing(link="link2", friction=0.03, slip_velocity=0.01)))


@pytest.mark.heavy
def test_the_energy_lost_is_the_work_of_friction():
    """A flexible two-link chain coasting without drives or damping: the drop of its
    energy equals ∫ Σ_b (−F_b·v_b) dt, the friction power at the bearing points (read
    point by point, not through the generalized forces the kernel integrates)."""
    sc = _free_two_link()
    res = simulate(sc, 0.6)
    ch = res.chain
    c = res.columns
    q = np.column_stack([c[n] for n in ch.names])
    qd = np.column_stack([c[f"{n}_rate"] for n in ch.names])
    E = np.array([ch.energy(q[k], qd[k])["total"] for k in range(len(q))])
    P = np.array([sum(b["power"] for b in bearing_states(ch, q[k], qd[k], None, c["t"][k]))
                  for k in range(len(q))])
    W = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(c["t"]))])
    lost = E[0] - E
    assert lost[-1] > 0.1 * E[0]                  # friction took a good part of it
    assert np.max(np.abs(lost - W)) < 2e-4 * E[0]


@pytest.mark.heavy
@pytest.mark.parametrize("rung", ["rigid", "cubic", "modal", "fem", "fd", "rod"])
def test_the_compiled_kernel_equals_the_numpy_reference(rung):
    """Every rung: the compiled right-hand side with bearings (binding and a high spot on
    RB2) equals the numpy reference's to round-off, and differs from the run without."""
    sc = load_scene("two_link_case3_backlash")
    sc = dataclasses.replace(
        sc, fidelity=dataclasses.replace(sc.fidelity, rung=rung),
        bearings=(Bearing(link="link1", friction=0.05, binding=0.3,
                          high_spots=(HighSpot(point=(0.42, 0.60), radius=0.03,
                                               friction=0.3),)),
                  Bearing(link="link2", friction=0.05)))
    fast, ref = Chain(sc, backend="numba"), Chain(sc, backend="numpy")
    if fast.backend != "numba":
        pytest.skip("numba not in use")
    rng = np.random.default_rng(7)
    nf = len(fast.free)
    x = np.concatenate([fast.initial_q()[0][fast.free] + 0.01 * rng.standard_normal(nf),
                        0.3 * rng.standard_normal(nf), np.zeros(fast.nz)])
    a, b = fast.rhs(0.1, x), ref.rhs(0.1, x)
    assert np.max(np.abs(a - b)) <= 1e-8 * np.max(np.abs(a))
    floating = Chain(dataclasses.replace(sc, bearings=()), backend="numba").rhs(0.1, x)
    assert np.max(np.abs(a - floating)) > 1e-6 * np.max(np.abs(a))


def test_friction_off_leaves_a_run_bit_identical():
    """Bearings with μ = 0 and no high spot (the bodies float free) change nothing."""
    sc = swing_scene(mu=0.0, duration=0.3)
    off = dataclasses.replace(sc, bearings=(Bearing(link="arm", friction=0.0),))
    a, b = simulate(sc).columns, simulate(off).columns
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k


@pytest.mark.parametrize("bearing, message", [
    ({"link": "arm", "friction": -0.1},
     "bearings[0].friction: got -0.1, expected a finite number >= 0.0 and <= 1.0"),
    ({"link": "arm", "friction": 0.1, "slip_velocity": 0.0},
     "bearings[0].slip_velocity: got 0.0, expected a finite number > 0.0 (m/s)"),
    ({"link": "nope", "friction": 0.1},
     "bearings[0].link: got 'nope', expected one of arm"),
    ({"link": "arm", "body": "hub", "friction": 0.1},
     "bearings[0].body: got 'hub' on link 'arm', whose mass is 0"),
    ({"link": "arm", "body": "base"},
     "bearings[0].body: got 'base', expected one of hub, tip"),
    ({"link": "arm", "friction": 0.1, "binding": 2.0},
     "bearings[0].binding: got 2.0 on link 'arm' tip, which houses no drive"),
    ({"link": "arm", "high_spots": [{"point": [0, 0], "radius": 0.0, "friction": 0.1}]},
     "bearings[0].high_spots[0].radius: got 0.0, expected a finite number > 0.0 (m)"),
    ({"link": "arm", "mu": 0.1}, "bearings[0].mu: unknown key; expected one of binding"),
])
def test_bad_bearings_are_refused_naming_key_value_and_expectation(bearing, message):
    data = {"name": "bad", "links": [{"name": "arm", "beam": {
        "length": 0.5, "EI": 10.0, "mass_per_length": 0.1},
        "tip": {"mass": 1.0}}], "bearings": [bearing]}
    with pytest.raises(SceneError) as err:
        load_scene_dict(data)
    assert message in str(err.value)


def test_two_bearings_under_one_body_are_refused():
    data = {"name": "bad", "links": [{"name": "arm", "beam": {
        "length": 0.5, "EI": 10.0, "mass_per_length": 0.1}, "tip": {"mass": 1.0}}],
        "bearings": [{"link": "arm", "friction": 0.1}, {"link": "arm", "friction": 0.2}]}
    with pytest.raises(SceneError, match=r"bearings\[1\].link: got 'arm' tip again"):
        load_scene_dict(data)


@pytest.mark.heavy
def test_case3_centre_drifts_with_a_high_spot_and_not_without_friction():
    """Case 3 (backlash, ±0.5 V square waves): the angles swing at the drive's 0.667 Hz
    with or without friction; the oscillation centre (per-cycle means) drifts — a slope
    beyond three standard errors — with friction that depends on where the bearing is
    (a high spot on RB2's path), and not without friction. Ten periods."""
    from flexarm_ros.studies import bearings_seed000 as st
    base = load_scene("two_link_case3_backlash")
    T = 10 / st.DRIVE_HZ
    off = st.case3_run(base, T)
    on = st.case3_run(st.with_bearings(base, 0.0045, spots=st.spot_centres(base)), T)
    for r in (off, on):
        for q in ("q1", "q2"):
            assert r[q]["frequency"] == pytest.approx(st.DRIVE_HZ, rel=0.03)
            assert 0.5 < r[q]["amplitude"] < 3.0          # degrees: a few, as the source
    assert all(abs(off[q]["drift"]) < 2.0 * off[q]["drift_se"] for q in ("q1", "q2"))
    assert all(abs(on[q]["drift"]) > 3.0 * on[q]["drift_se"] for q in ("q1", "q2"))


@pytest.mark.heavy
@pytest.mark.subprocess
def test_the_study_runs_its_batches_on_the_runner_alike_here_and_on_dask():
    """The seed-000 study runs a batch of simulations as one call of the ensemble runner,
    not a loop of its own: Case 3's amplitudes for μ = 0 and 0.0045 (two and a half drive
    periods: two whole ones) are one batch of one task per μ; in this process and on a
    Dask local cluster of two workers they are the same numbers (the printed table to the
    digit, the values to round-off — bit-identical when measured, but the workers run
    numpy's BLAS single-threaded); and each is the amplitude a direct ``simulate`` of the
    same scene gives, read here from its joint angles (half the range over the second
    period)."""
    pytest.importorskip("distributed")
    from flexarm_ros.ensemble.runner import SerialExecutor, open_executor
    from flexarm_ros.studies import bearings_seed000 as st

    class Counting(SerialExecutor):
        def __init__(self):
            self.batches = []

        def map(self, fn, items, *args, **kwargs):
            self.batches.append((fn, len(items)))
            return super().map(fn, items, *args, **kwargs)

    mus, per = (0.0, 0.0045), 1.0 / st.DRIVE_HZ
    serial_ex = Counting()
    serial = st.case3_amplitudes(mus, serial_ex, 2.5 * per)
    assert serial_ex.batches == [(st.case3_variant, len(mus))]
    with open_executor(2) as ex:
        dask = st.case3_amplitudes(mus, ex, 2.5 * per)
    assert st.case3_amplitudes_table(dask) == st.case3_amplitudes_table(serial)
    base = load_scene("two_link_case3_backlash")
    for mu in mus:
        assert dask[mu] == pytest.approx(serial[mu], rel=1e-12, abs=0.0)
        c = simulate(st.with_bearings(base, mu) if mu else base, 2.5 * per).columns
        second = (c["t"] >= per) & (c["t"] < 2 * per)
        truth = [0.5 * np.ptp(np.degrees(c[f"{lk.name}_joint"][second])) for lk in base.links]
        assert serial[mu] == pytest.approx(truth, rel=1e-12, abs=0.0)
    assert serial[0.0045][0] < 0.99 * serial[0.0][0]     # the friction is there


def test_the_friction_law_is_bounded_and_opposes_the_motion():
    """|F| < μN, F·v < 0, F → −(μN/v_s) v near rest and → −μN v/|v| fast."""
    from flexarm_ros.model.bearings import friction_force
    for vx, vy in [(1e-6, 0.0), (0.3, -0.4), (-5.0, 2.0)]:
        fx, fy = friction_force(vx, vy, 2.0, 1e-3)
        assert math.hypot(fx, fy) < 2.0 and fx * vx + fy * vy < 0.0
    assert friction_force(1e-6, 0.0, 2.0, 1e-3)[0] == pytest.approx(-2.0e-3, rel=1e-6)
    assert friction_force(0.0, -10.0, 2.0, 1e-3)[1] == pytest.approx(2.0, rel=1e-8)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("tau0", [3.0, -3.0])
def test_the_binding_load_grows_with_the_housed_drives_torque(backend, tau0):
    """RB2-like body on link 1's tip, the next joint's ideal torque τ₀ housed on it: with
    only joint 1 turning at ω (straight arm, undeformed), the bearing point slides at
    v = ω r and the generalized friction forces are Q_joint1 = −μ(m g₀ + b|τ₀|) r s and
    Q_β = −μ(m g₀ + b|τ₀|)(L + c) s, s = v/√(v² + v_s²) (rigid rung: the spring angle β
    moves the tip by L and turns the body by 1); joint 2 feels none."""
    from flexarm_ros.model.compiled import chain as kchain
    from flexarm_ros.model.compiled.layout import Workspace
    m, hub_r, length, c, mu, b, vs, omega = 2.0, 0.04, 0.6, 0.05, 0.1, 2.0, 1e-3, 0.3
    link = {"beam": {"length": length, "EI": 50.0, "mass_per_length": 0.3,
                     "hub_radius": hub_r}, "hub": {"inertia": 1e-3}}
    data = {"name": "binding", "links": [
        dict(link, name="l1", tip={"mass": m, "cg": [c, 0.0], "joint_offset": [c, 0.0]}),
        dict(link, name="l2", tip={"mass": 1.0})],
        "inputs": [{"joint": 2, "torque": {"type": "constant", "value": tau0}}],
        "bearings": [{"link": "l1", "friction": mu, "binding": b, "slip_velocity": vs}],
        "fidelity": {"rung": "rigid"}}
    on = Chain(load_scene_dict(data), backend=backend)
    off = Chain(load_scene_dict(dict(data, bearings=[])), backend=backend)
    if on.backend != backend:
        pytest.skip("numba not in use")
    q, qd = on.initial_q()
    qd[on.names.index("l1_joint")] = omega
    z = np.zeros(on.nz)

    def forces(ch):
        if backend == "numpy":
            kin = ch.kinematics(q, qd)
            Qin, _ = ch.input_forces(0.0, qd, z)
            return Qin + kin.Qg - kin.h - ch.K @ q - ch.D @ qd + ch.bearing_forces(
                0.0, qd, z, kin)
        ws = kchain.workspace(ch.kernel_args)
        kchain.forces(0.0, q.copy(), qd.copy(), z, ch.kernel_args, ws)
        return Workspace._make(ws).f[:ch.n].copy()

    dQ = forces(on) - forces(off)
    r = hub_r + length + c
    v = omega * r
    load = mu * (m * STANDARD_GRAVITY + b * abs(tau0)) * v / math.hypot(v, vs)
    assert dQ[on.names.index("l1_joint")] == pytest.approx(-load * r, rel=1e-12)
    beta = next(i for i, nm in enumerate(on.names) if nm.startswith("l1_") and
                nm != "l1_joint")
    assert dQ[beta] == pytest.approx(-load * (length + c), rel=1e-12)
    assert abs(dQ[on.names.index("l2_joint")]) < 1e-12 * load


@pytest.mark.heavy
def test_the_lockstep_twin_and_the_batch_run_carry_the_same_friction():
    """two_link_position (the joint PD in the loop) with bearings under RB2 (binding on the
    middle drive's torque, a high spot at its start) and RB4: every coordinate of the
    twin's ground truth (the simulator, motor-driver and controller cores in lockstep)
    equals the batch closed-loop run on both lanes within 1e-9, and the friction moves
    the arm away from the run without it."""
    from flexarm_ros.twin import topics as T
    from flexarm_ros.twin.batch import simulate_closed_loop
    from flexarm_ros.twin.cosim import cosimulate
    base = load_scene("two_link_position")
    ch = Chain(base)
    q0, _ = ch.initial_q()
    rb2 = ch.point_kinematics(q0, 0 * q0, 0, "tip", base.links[0].tip.cg)[0]
    scene = dataclasses.replace(base, bearings=(
        Bearing(link="link1", friction=0.05, binding=0.5,
                high_spots=(HighSpot(point=tuple(rb2), radius=0.02, friction=0.1),)),
        Bearing(link="link2", friction=0.05)))
    duration = 0.3
    gt = cosimulate(scene, duration).topic(T.GT_COORDINATES)
    t_ns = np.array([m.t_ns for m in gt], dtype=np.int64)
    names = gt[0].data["name"]
    q = np.array([m.data["position"] for m in gt])
    moved = 0.0
    free = simulate_closed_loop(base, duration, lane="reference")
    for lane in ("reference", "compiled"):
        res = simulate_closed_loop(scene, duration, lane=lane)
        ns = np.round(np.asarray(res.columns["t"]) * 1e9).astype(np.int64)
        idx = np.searchsorted(ns, t_ns)
        assert np.array_equal(ns[idx], t_ns)
        for j, n in enumerate(names):
            assert np.max(np.abs(np.asarray(res.columns[n])[idx] - q[:, j])) <= 1e-9, (lane, n)
            moved = max(moved, np.max(np.abs(np.asarray(res.columns[n])[idx]
                                             - np.asarray(free.columns[n])[idx])))
    assert moved > 1e-4
