"""Honest accuracy (issue 36): for the shipped scenes without a wall the tutorial ones name
(spin_up, link_tipmass, two_link_free) and T in {1e-3, 1e-4, 1e-5, 1e-6} m, rung auto
either meets T in both measures over the whole run against the physics — the
geometrically exact rod with 12 terms, more than the check after the run takes — with its
estimates within 3× of the measured errors, or says it cannot; never claims it.

The measures (sim/truth.py): the tip position in the world frame and the elastic tip
deflection of every link in its hub frame, each the largest over the run."""

import functools

import numpy as np
import pytest

from flexarm_ros.model.chain import Chain
from flexarm_ros.model.statics import initial_x
from flexarm_ros.scene import load_scene
from flexarm_ros.sim import truth
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.sim.step import choose_step

DURATIONS = {"spin_up": 20.0, "link_tipmass": 1.0, "two_link_free": 1.0}


@functools.lru_cache(maxsize=4)
def _physics(name):
    sc = load_scene(name).with_fidelity(rung="rod", refine=12, integrator="rk4", dt=0.0,
                                        tolerance=0.0)
    ch = Chain(sc)
    h = choose_step(ch, initial_x(ch), "rk4", 0.0, sc.fidelity.output_dt, dense=True)
    return simulate(sc.with_fidelity(dt=0.5 * h), DURATIONS[name]).columns


@pytest.mark.heavy
@pytest.mark.parametrize("tol", [1e-3, 1e-4, 1e-5, 1e-6])
@pytest.mark.parametrize("name", ["spin_up", "link_tipmass", "two_link_free"])
def test_a_tolerance_is_met_against_the_physics_or_said_not_to_be(name, tol):
    T = DURATIONS[name]
    res = simulate(load_scene(name).with_fidelity(rung="auto", tolerance=tol), T)
    s = res.summary()
    ref = _physics(name)
    links = [lm.name for lm in res.chain.links]
    got = truth.measures(res.columns, ref, links)
    if not s["tolerance_met"]:
        assert s["tolerance_met"] is False and "not met" in s["warning"], s
        return
    assert got.position_m <= tol and got.deflection_max_m <= tol, (s["rung"], got)
    own = s["check"]["reference_error"]
    floor_p = max(got.position_m, own["position_m"])
    floor_d = max(got.deflection_max_m, max(own["deflection_m"]))
    assert got.position_m <= s["estimated_tip_error_m"] <= 3 * floor_p, (got, s)
    assert got.deflection_max_m <= s["estimated_deflection_error_m"] <= 3 * floor_d, (got, s)


def test_the_measures_and_the_metric():
    """The deflection share and the tolerance's metric: a run that meets the position but
    not the deflection (link_tipmass's modal 3 at 1e-5 m: 3.5e-6 m and 4.6e-5 m) is met
    with metric position and not with deflection or both."""
    sc = load_scene("link_tipmass")
    res = simulate(sc.with_fidelity(estimate=True), 1.0)
    chk = res.truth
    assert chk.ok and chk.estimate.position_m < 1e-5 < chk.estimate.deflection_max_m
    assert chk.met(1e-5, "position") == {"position": True}
    assert chk.met(1e-5, "deflection") == {"deflection": False}
    assert chk.met(1e-5, "both") == {"position": True, "deflection": False}
    share = chk.estimate.deflection_share[0]
    assert share == pytest.approx(chk.estimate.deflection_m[0] /
                                  chk.estimate.deflection_peak_m[0])
    with pytest.raises(Exception, match="tolerance_metric"):
        sc.with_fidelity(tolerance_metric="angle")


def test_a_wall_is_not_checked_and_not_claimed():
    res = simulate(load_scene("two_link_case1").with_fidelity(tolerance=1e-3), 0.3)
    assert res.truth is not None and not res.truth.ok and "wall" in res.truth.status
