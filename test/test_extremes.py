"""Extremes: every run either completes with finite output or stops with a typed error whose
message says what to change — never a silent NaN, never an untyped crash.

Accepted outcomes of a run here:
* it completes and every output column is finite;
* it raises SimulationDiverged / StepTooLarge (or SceneError for a scene the model cannot
  represent) with a "To fix:" part naming what to change (step ``dt``, ``integrator``,
  ``rung``, or — for the small-deflection guard — ``max_deflection_ratio``).
"""

import re

import numpy as np
import pytest


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.chain import Chain
from flexarm_ros.errors import SceneError, SimulationDiverged, StepTooLarge
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

BACKENDS = ["numpy"] + (["numba"] if kchain.HAVE_NUMBA else [])
FIX = re.compile(r"\b(dt|integrator|rung|max_deflection_ratio)\b")

# seed 001 link (EI 2000 N·m², ρA 1 kg/m, L 1 m, hub I_H 0.0174 kg·m²)
EI0, RHO_A, L = 2000.0, 1.0, 1.0
PULSE = [{"joint": 1, "torque": {"type": "pulse", "amplitude": 0.55, "start": 0.0,
                                 "width": 0.1}}]


def _link(EI=EI0, tip=None, rung="cubic", refine=0, integrator="rk4", dt=0.0,
          output_dt=1e-3, inputs=PULSE, hub_inertia=0.0174, gravity=(0.0, 0.0), angle=0.0,
          static=False):
    link = {"name": "link", "beam": {"length": L, "EI": EI, "mass_per_length": RHO_A},
            "joint": {"initial_angle": angle}, "hub": {"inertia": hub_inertia}}
    if tip is not None:
        link["tip"] = tip
    return load_scene_dict({
        "name": "extreme", "gravity": list(gravity), "links": [link], "inputs": inputs,
        "initial": {"static_equilibrium": static},
        "fidelity": {"rung": rung, "refine": refine, "integrator": integrator, "dt": dt,
                     "output_dt": output_dt}})


def _assert_finite(res):
    bad = [k for k, v in res.columns.items() if not np.all(np.isfinite(v))]
    assert not bad, f"non-finite output columns: {bad}"
    assert res.run.success


def _assert_says_what_to_change(exc):
    msg = str(exc)
    if isinstance(exc, SceneError):
        # scene-level refusal: "key: ..., expected <what would be valid>"
        assert "expected" in msg, msg
        return
    assert "To fix:" in msg, msg
    assert FIX.search(msg.split("To fix:", 1)[1]), msg


def _run(scene, duration, backend="auto"):
    """Run; return the result, or the typed error after checking its message."""
    try:
        res = simulate(scene, duration, chain=Chain(scene, backend=backend))
    except (SimulationDiverged, SceneError) as exc:
        _assert_says_what_to_change(exc)
        return exc
    _assert_finite(res)
    return res


# -------------------------------------------------------------------- stiff / flexible
@pytest.mark.parametrize("rung, refine", [("rigid", 0), ("cubic", 0), ("modal", 2)])
def test_very_stiff_beam(rung, refine):
    # EI × 1e6: 10..300 kHz modes; the automatic RK4 step (down to 0.8 µs) follows them
    res = _run(_link(EI=EI0 * 1e6, rung=rung, refine=refine, output_dt=2e-4), 1e-3)
    assert not isinstance(res, Exception), res
    w = res.columns["link_tip_deflection"]
    assert np.abs(w).max() < 1e-6            # stiff: microns at most
    assert res.columns["link_joint"][-1] > 0  # and the torque did turn it


@pytest.mark.parametrize("rung, refine", [("cubic", 0), ("modal", 4), ("fem", 4)])
def test_very_flexible_beam(rung, refine):
    # EI / 100: the same pulse bends it ~100x more; still small deflection here
    res = _run(_link(EI=EI0 / 100, rung=rung, refine=refine), 0.5)
    assert not isinstance(res, Exception), res
    assert np.abs(res.columns["link_tip_deflection"]).max() > 1e-3


def test_very_flexible_beam_overloaded_stops_with_the_deflection_guard():
    scene = _link(EI=EI0 / 100, rung="fem", refine=4,
                  inputs=[{"joint": 1, "torque": {"type": "constant", "value": 20.0}}])
    with pytest.raises(SimulationDiverged) as info:
        simulate(scene, 1.0)
    err = info.value
    assert "tip deflection" in err.quantity
    assert abs(err.last_value) > 0.4 * L
    _assert_says_what_to_change(err)


@pytest.mark.parametrize("mu", [0.0, 0.5, 2.0, 5.0, 10.0])
def test_tip_mass_from_zero_to_ten_beam_masses(mu):
    tip = {"mass": mu * RHO_A * L, "inertia": mu * RHO_A * L * 0.05**2} if mu else None
    res = _run(_link(tip=tip, rung="modal", refine=3, output_dt=2e-3), 0.3)
    assert not isinstance(res, Exception), res
    # heavier tip, slower arm: the joint still turns, never backwards under +torque
    assert res.columns["link_joint"][-1] > 0


def test_long_horizon_rigid_rung_two_link():
    # 20 s of a conservative two-link arm on the rigid rung: finite, energy kept
    def link(name, rate):
        return {"name": name, "beam": {"length": 0.5, "EI": 2.0, "mass_per_length": 0.5},
                "hub": {"inertia": 2e-3}, "tip": {"mass": 0.2, "inertia": 1e-3},
                "joint": {"initial_rate": rate}}
    scene = load_scene_dict({"name": "long", "links": [link("l1", 2.0), link("l2", -3.0)],
                             "fidelity": {"rung": "rigid", "integrator": "rk4",
                                          "output_dt": 0.02}})
    res = _run(scene, 20.0)
    assert not isinstance(res, Exception), res
    E = res.columns["energy"]
    assert np.max(np.abs(E - E[0])) / E[0] < 1e-6     # measured 1.2e-7 over 20 s
    assert res.columns["t"][-1] == pytest.approx(20.0)


# ---------------------------------------------------------------- explicit step limits
def _suggested_dt(msg):
    m = re.search(r"--dt <= ([0-9.eE+-]+) s", msg)
    assert m, msg
    return float(m.group(1))


def test_fine_fem_mesh_with_too_large_explicit_step_is_refused_up_front():
    scene = _link(rung="fem", refine=32, dt=1e-4, output_dt=1e-4)
    with pytest.raises(StepTooLarge) as info:
        simulate(scene, 1.0)
    err = info.value
    assert err.time == 0.0                       # refused before any step
    _assert_says_what_to_change(err)
    assert "stability limit" in str(err)
    assert _suggested_dt(str(err)) < 1e-4


@pytest.mark.heavy
def test_fine_fem_mesh_runs_at_the_suggested_step():
    scene = _link(rung="fem", refine=32, dt=1e-4, output_dt=1e-4)
    with pytest.raises(StepTooLarge) as info:
        simulate(scene, 1e-4)
    dt = 0.95 * _suggested_dt(str(info.value))
    res = _run(scene.with_fidelity(dt=dt), 1e-4)
    assert not isinstance(res, Exception), res
    assert res.run.dt <= dt


@pytest.mark.parametrize("rung, refine", [("cubic", 0), ("modal", 4), ("fd", 10)])
def test_forced_rk4_step_above_stability_limit_raises_up_front(rung, refine):
    probe = _link(rung=rung, refine=refine, dt=1.0, output_dt=1.0)
    with pytest.raises(StepTooLarge) as info:
        simulate(probe, 1.0)
    err = info.value
    assert err.time == 0.0
    _assert_says_what_to_change(err)
    limit = _suggested_dt(str(err))
    # just above the limit: refused; just below: runs with finite output
    with pytest.raises(StepTooLarge):
        simulate(probe.with_fidelity(dt=1.2 * limit, output_dt=0.01), 0.01)
    res = _run(probe.with_fidelity(dt=0.9 * limit, output_dt=0.01), 0.05)
    assert not isinstance(res, Exception), res


# ------------------------------------------------------------------------- fast spin
def test_fast_spin_up_either_runs_or_stops_clearly():
    scene = load_scene_dict({
        "name": "fast_spin",
        "links": [{"name": "link", "beam": {"length": L, "EI": EI0, "mass_per_length": RHO_A}}],
        "inputs": [{"joint": 1, "motion": {"type": "spin_up", "omega": 60.0,
                                           "ramp_time": 0.5}}],
        "fidelity": {"rung": "modal", "refine": 4, "modal_basis": "clamped_free",
                     "integrator": "rk4", "output_dt": 1e-3}})
    res = _run(scene, 1.0)
    if not isinstance(res, Exception):
        # centrifugal stiffening keeps the spinning beam's deflection small
        assert np.abs(res.columns["link_tip_deflection"]).max() < 0.5 * L


# ------------------------------------------------------------------ degenerate models
@pytest.mark.parametrize("backend", BACKENDS)
def test_rigid_rung_without_joint_inertia_fails_clearly(backend):
    """The rigid rung's spring angle and the joint angle move the link identically; with no
    hub or drive inertia on the joint coordinate the mass matrix is singular. That scene
    must be refused (or fail) with a typed error that says what to change — not a bare
    numpy LinAlgError or a NaN."""
    scene = _link(rung="rigid", hub_inertia=0.0)
    try:
        res = _run(scene, 0.1, backend=backend)
    except np.linalg.LinAlgError as exc:
        pytest.fail(f"untyped error from a singular mass matrix: {exc!r}")
    if isinstance(res, Exception):
        assert "inertia" in str(res) or "singular" in str(res), str(res)


def test_static_equilibrium_beyond_buckling_is_not_reported_as_a_valid_start():
    """A flexible arm pointing up whose weight far exceeds its buckling load (P_cr =
    π²EI/4L² ≈ 1.2 N here vs ~20 N axial) has no stable small-deflection equilibrium.
    The linear solve of the static equation still returns one (the tangent stiffness is
    indefinite), and the run then starts at rest from an unstable state. It should be
    reported instead (typed error naming what to change)."""
    scene = _link(EI=0.5, rung="cubic", tip={"mass": 2.0}, gravity=(0.0, -9.81),
                  angle=1.2, static=True, inputs=[{"joint": 1, "motion": {"type": "hold"}}])
    with pytest.raises((SceneError, SimulationDiverged)) as info:
        simulate(scene, 0.2)
    msg = str(info.value)
    assert "buckl" in msg or "unstable" in msg or "stiff" in msg, msg


def test_no_nan_in_any_column_of_a_completed_run_with_everything():
    # gravity, tip CG offset, joint flexibility, damping, a pulse — on the fd rung
    scene = load_scene_dict({
        "name": "all", "gravity": [0.0, -9.81],
        "links": [{"name": "link",
                   "beam": {"length": L, "EI": EI0, "mass_per_length": RHO_A,
                            "hub_radius": 0.075, "thickness": 0.02,
                            "damping": {"viscous_per_length": 0.1,
                                        "stiffness_proportional": 1e-5}},
                   "hub": {"inertia": 0.0174}, "tip": {"mass": 0.5, "inertia": 2e-3,
                                                       "cg": [0.01, 0.005]},
                   "joint": {"flexibility": {"stiffness": 500.0, "damping": 0.05,
                                             "motor_inertia": 0.01}}}],
        "inputs": PULSE, "initial": {"static_equilibrium": True},
        "fidelity": {"rung": "fd", "refine": 8, "integrator": "rk4", "output_dt": 2e-3}})
    res = _run(scene, 0.2)
    assert not isinstance(res, Exception), res
