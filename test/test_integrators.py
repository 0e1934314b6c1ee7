"""Integrators against each other and against their known order and invariants."""

import numpy as np
import pytest

from flexarm_ros.errors import SimulationDiverged, StepTooLarge
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

LINK = {"name": "link", "duration": 0.5,
        "links": [{"name": "l1", "beam": {"length": 1.0, "EI": 2000.0, "mass_per_length": 1.0,
                                          "hub_radius": 0.075},
                   "hub": {"inertia": 0.0174}, "tip": {"mass": 0.5, "inertia": 0.002}}],
        "inputs": [{"joint": 1, "torque": {"type": "piecewise_constant",
                                           "times": [0.0, 0.2, 0.4],
                                           "values": [0.55, -0.55, 0.0]}}]}


def _scene(**fid):
    d = dict(LINK)
    d["fidelity"] = {"rung": "modal", "refine": 3, "output_dt": 0.01, **fid}
    return load_scene_dict(d)


def _tip(res):
    return np.column_stack([res.columns["tip_x"], res.columns["tip_y"]])


@pytest.fixture(scope="module")
def reference():
    return simulate(_scene(integrator="dop853", rtol=1e-12, atol=1e-14))


@pytest.mark.heavy
def test_rk4_converges_at_fourth_order(reference):
    errs = [np.abs(_tip(simulate(_scene(integrator="rk4", dt=dt))) - _tip(reference)).max()
            for dt in (2e-4, 1e-4)]
    assert 12 < errs[0] / errs[1] < 20          # 2⁴ = 16
    assert errs[1] < 1e-8


def test_trapezoid_converges_at_second_order(reference):
    errs = [np.abs(_tip(simulate(_scene(integrator="trapezoid", dt=dt))) -
                   _tip(reference)).max() for dt in (2e-4, 1e-4, 5e-5)]
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(3.0 < r < 5.0 for r in ratios), ratios    # 2² = 4


@pytest.mark.heavy
@pytest.mark.parametrize("integ", ["rk45", "radau", "bdf", "lsoda"])
def test_scipy_methods_agree_with_reference(integ, reference):
    res = simulate(_scene(integrator=integ, rtol=1e-9, atol=1e-12), duration=0.2)
    n = len(res.columns["t"])
    assert np.abs(_tip(res) - _tip(reference)[:n]).max() < 1e-6
    assert res.summary()["steps"] > 0 and res.summary()["rhs_evaluations"] > 0


def test_trapezoid_conserves_energy_without_input():
    d = dict(LINK, inputs=[])
    d["links"] = [dict(LINK["links"][0], joint={"initial_rate": 3.0})]
    d["fidelity"] = {"rung": "modal", "refine": 3, "integrator": "trapezoid", "dt": 1e-3,
                     "output_dt": 0.01}
    e = simulate(load_scene_dict(d), duration=2.0).columns["energy"]
    # not exactly conserved for the nonlinear chain, but no drift beyond O(h²)
    assert np.abs(e - e[0]).max() / e[0] < 1e-5


def test_trapezoid_is_stable_far_beyond_the_explicit_limit():
    """A fine FEM mesh at a step 50× the RK4 limit: rk4 refuses, trapezoid runs."""
    with pytest.raises(StepTooLarge, match="--dt"):
        simulate(_scene(rung="fem", refine=16, integrator="rk4", dt=1e-3), duration=0.05)
    res = simulate(_scene(rung="fem", refine=16, integrator="trapezoid", dt=1e-3),
                   duration=0.5)
    assert all(np.all(np.isfinite(c)) for c in res.columns.values())
    assert np.abs(res.columns["l1_tip_deflection"]).max() < 0.01


def test_divergence_is_reported_with_what_when_and_fix():
    """Linear floating frame (no foreshortening) in a fast spin: the beam diverges."""
    d = {"name": "spin", "links": [{"name": "b", "beam": {"length": 10.0, "EI": 14000.0,
                                                          "mass_per_length": 1.2}}],
         "inputs": [{"joint": 1, "motion": {"type": "spin_up", "omega": 6.0,
                                            "ramp_time": 15.0}}],
         "fidelity": {"rung": "modal", "refine": 2, "foreshortening": False,
                      "output_dt": 0.01}}
    with pytest.raises(SimulationDiverged) as info:
        simulate(load_scene_dict(d), duration=20.0)
    err = info.value
    assert "tip deflection of b" in str(err) and err.time < 15.0
    assert "foreshortening" in err.suggestion
