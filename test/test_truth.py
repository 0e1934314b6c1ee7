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
    # the clamped modes by RK4, link_tipmass's default before session 21
    sc = load_scene("link_tipmass").with_fidelity(modal_basis="chain_loaded",
                                                  integrator="rk4")
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


def _distance(a, b, links):
    """The test's own measures (largest over the common samples): tip position, and the
    tip deflection of every link."""
    k = min(len(a["t"]), len(b["t"]))
    pos = np.max(np.hypot(np.asarray(a["tip_x"][:k]) - b["tip_x"][:k],
                          np.asarray(a["tip_y"][:k]) - b["tip_y"][:k]))
    defl = max(np.max(np.abs(np.asarray(a[f"{n}_tip_deflection"][:k]) -
                             b[f"{n}_tip_deflection"][:k])) for n in links)
    return float(pos), float(defl)


def test_a_closed_loop_is_checked_with_its_controller_in_the_loop():
    """--estimate of a scene whose controller moves the arm (two_link_position, 1 s): the
    reference runs the same controller and driver (an open-loop reference would be the
    arm at rest, metres off); the estimate bounds the distance to the rod with 12 terms
    at half its automatic step, closed loop too, within 3×."""
    from flexarm_ros.twin.batch import run_scene
    sc = load_scene("two_link_position")
    T = 1.0
    res = run_scene(sc.with_fidelity(estimate=True), T)
    chk = res.truth
    assert chk is not None and chk.ok, chk
    s = res.summary()
    assert s["loop"] == "closed" and s["estimated_tip_error_m"] == chk.estimate.position_m
    ref_sc = sc.with_fidelity(rung="rod", refine=12, integrator="rk4", dt=0.0)
    ref = run_scene(ref_sc, T).columns
    links = [lm.name for lm in res.chain.links]
    pos, defl = _distance(res.columns, ref, links)
    own = chk.reference_error
    assert pos <= chk.estimate.position_m <= 3 * max(pos, own.position_m), (pos, chk)
    assert defl <= chk.estimate.deflection_max_m <= 3 * max(defl, own.deflection_max_m)
    # the open loop (no controller: the arm holds still) is not what was checked
    import dataclasses
    still = run_scene(dataclasses.replace(ref_sc, control=None), T, open_loop=True).columns
    assert _distance(res.columns, still, links)[0] > 100 * chk.estimate.position_m
    # --tolerance of a closed loop (refused until session 22): certified by this check
    # alone — met where it shows it (and the distance to rod 12 agrees), else said not met
    # with what to change, never claimed
    met = []
    for tol in (1e-3, 1e-5):
        r = run_scene(sc.with_fidelity(tolerance=tol), T)
        s = r.summary()
        met.append(s["tolerance_met"])
        assert s["tolerance_m"] == tol and "checked after the run" in s["tolerance_source"]
        p, d = _distance(r.columns, ref, links)
        if s["tolerance_met"]:
            assert max(p, d) <= tol and "warning" not in s, (tol, p, d, s)
        else:
            assert s["tolerance_met"] is False and max(p, d) > tol, (tol, p, d, s)
            assert "not met" in s["warning"] and "--rung rod" in s["warning"]
            assert "--rung auto" not in s["warning"]       # auto refuses this closed loop
    assert met == [True, False]          # both verdicts seen: the test can fail either way


def test_explain_shows_the_model_form_error(capsys):
    """flexarm explain ends with the chosen model's error against the rod over the
    scene's run, the same figures as simulate --estimate; a wall says why there is none;
    --no-check leaves the line out."""
    from flexarm_ros.cli import main
    assert main(["explain", "link_tipmass", "--set", "duration=1.0", "--rung", "modal",
                 "--refine", "3"]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if "model-form" in ln][0]
    assert line.startswith("model-form error over the scene's 1 s (whole run), modal "
                           "(refine 3)")
    res = simulate(load_scene("link_tipmass").with_fidelity(estimate=True, rung="modal",
                                                            refine=3), 1.0)
    est = res.truth.estimate
    assert f"tip position {est.position_m:.2g} m" in line
    assert f"link1 {est.deflection_m[0]:.2g} m ({100 * est.deflection_share[0]:.2g} %" in line
    assert main(["explain", "two_link_case1", "--no-check"]) == 0
    assert "model-form error" not in capsys.readouterr().out
    assert main(["explain", "two_link_case1"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "not measured against the physics" in last and "wall" in last
