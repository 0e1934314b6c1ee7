"""Integrator rkn4 (issue 14): RK4 with the positions stepped by the fourth-order
Runge–Kutta–Nyström formulas. Checked against a second method (DOP853 at rtol 1e-12 of the
same model), against RK4 at equal steps, between the compiled and numpy paths, and its
stability limit against the growth of the steps themselves on linear oscillators."""

from __future__ import annotations

import json

import numpy as np
import pytest

from flexarm_ros.cli import main
from flexarm_ros.errors import StepTooLarge
from flexarm_ros.model.chain import Chain
from flexarm_ros.scene import load_scene
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.sim.step import rk4_step, rkn4_limit, rkn4_map, stability


def _tip(res) -> np.ndarray:
    return np.c_[res.columns["tip_x"], res.columns["tip_y"]]


def _reference(scene, duration):
    return simulate(scene.with_fidelity(integrator="dop853", rtol=1e-12, atol=1e-14), duration)


MODAL3 = {"rung": "modal", "refine": 3}


def test_rkn4_is_fourth_order_and_beats_rk4_at_equal_steps():
    """two_link_free, modal 3, 1 s: per halving of the step (4, 2 ms) the rkn4 tip error
    falls by about 2⁴; at each step, and at 7.5 ms, above the stable step where the
    highest mode is outside the asymptotic range, it is below RK4's (measured: 6.6e-7
    against 9.4e-7 m at 7.5 ms) — the same four right-hand sides per step."""
    sc = load_scene("two_link_free").with_fidelity(**MODAL3)
    ref = _tip(_reference(sc, 1.0))
    err = {}
    for integrator in ("rk4", "rkn4"):
        for h in (7.5e-3, 4e-3, 2e-3):
            res = simulate(sc.with_fidelity(integrator=integrator, dt=h), 1.0)
            assert res.run.dt == h
            assert res.run.rhs_evaluations <= 4 * res.run.steps + 2
            err[integrator, h] = np.max(np.linalg.norm(_tip(res) - ref, axis=1))
    ratio = err["rkn4", 4e-3] / err["rkn4", 2e-3]
    assert 10 < ratio < 25, err
    for h in (7.5e-3, 4e-3, 2e-3):
        assert err["rkn4", h] < 0.8 * err["rk4", h], err


def test_rkn4_carries_an_actuator_state_at_fourth_order():
    """link_motor: the DC motor's current is a first-order state that RKN4 steps by RK4's
    stages while the positions take Nyström's (a partitioned method): still fourth order
    in every state, on the output grid (steps of 0.25 and 0.125 ms)."""
    sc = load_scene("link_motor")
    ref = _reference(sc, 0.3)
    err = {}
    for h in (2.5e-4, 1.25e-4):
        res = simulate(sc.with_fidelity(integrator="rkn4", dt=h), 0.3)
        err[h] = max(np.abs(res.run.q - ref.run.q).max() / np.abs(ref.run.q).max(),
                     np.abs(res.run.z - ref.run.z).max() / np.abs(ref.run.z).max())
    ratio = err[2.5e-4] / err[1.25e-4]
    assert 10 < ratio < 25, err


@pytest.mark.heavy
def test_compiled_and_numpy_rkn4_agree():
    """The compiled loop (``loops._rk4_step`` with ``nystrom``) and the numpy step
    (``step.rk4_step`` with ``nq``) are the same method: dense path (a step above the output
    period) and grid path (a step dividing it)."""
    sc = load_scene("two_link_free").with_fidelity(integrator="rkn4", **MODAL3)
    for h in (7.5e-3, 5e-4):
        s = sc.with_fidelity(dt=h)
        a = simulate(s, 0.2)
        b = simulate(s, 0.2, chain=Chain(s, backend="numpy"))
        np.testing.assert_allclose(a.run.q, b.run.q, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(a.run.qd, b.run.qd, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("zeta", [0.0, 0.1, 0.5, 1.0, 3.0])
def test_the_rkn4_limit_is_where_its_steps_start_to_grow(zeta):
    """q̈ + 2ζωq̇ + ω²q = 0: stepped 3000 times by the numpy step at 0.98 of the limit the
    state stays bounded, at 1.03 of it it grows — the limit depends on ζ (h·ω = 2.59
    undamped, 1.33 at ζ = 1), unlike RK4's |λ|-only one."""
    w = 50.0
    J = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    rate = float(np.abs(np.linalg.eigvals(J)).max())
    lim = rkn4_limit(J, 1, rate)

    def run(h):
        x = np.array([1.0, 0.0])
        for _ in range(3000):
            x = rk4_step(lambda t, y: J @ y, 0.0, x, h, nq=1)
        return np.abs(x).max()
    assert run(0.98 * lim) < 10.0
    assert run(1.03 * lim) > 1e3
    if zeta == 0.0:
        assert lim * w == pytest.approx(2.587, abs=2e-3)
    # with nq = 0 the map is RK4's polynomial Σ (hJ)^k/k!
    h = 0.5 / w
    A = h * J
    R = np.eye(2) + A + A @ A / 2 + A @ A @ A / 6 + A @ A @ A @ A / 24
    np.testing.assert_allclose(rkn4_map(J, 0, h), R, rtol=1e-13, atol=1e-15)


def test_a_growing_mode_does_not_count_as_the_steps_instability():
    """A linearization about a moving state can hold a mode that grows (q̈ = a·q, a > 0:
    a turning arm's centrifugal terms). Its map grows as the flow does, at every step, so
    it must not set the limit: beside an undamped oscillator the limit stays the
    oscillator's h·ω = 2.587 (before the fix it fell to the first scanned step, 0.25/ω —
    two_link_free's state at 0.5 s gave 0.16 ms for RK4's 8.7 ms)."""
    w, a = 50.0, 4.0
    J = np.zeros((4, 4))
    J[0, 2] = J[1, 3] = 1.0
    J[2, 0] = -w * w
    J[3, 1] = a
    rate = float(np.abs(np.linalg.eigvals(J)).max())
    assert rkn4_limit(J, 2, rate) * w == pytest.approx(2.587, abs=2e-3)
    # a state of two_link_free on its way (t = 0.5 s), where the bug showed
    sc = load_scene("two_link_free").with_fidelity(integrator="rkn4", **MODAL3)
    res = simulate(sc, 0.5)
    ch = res.chain
    q = np.array([res.columns[n][-1] for n in ch.names])
    qd = np.array([res.columns[n + "_rate"][-1] for n in ch.names])
    _, lim4, _ = stability(ch, q, qd, np.zeros(0), "rk4")
    _, lim, _ = stability(ch, q, qd, np.zeros(0), "rkn4")
    assert 0.9 * lim4 < lim < 1.2 * lim4


def test_a_step_above_the_rkn4_limit_is_refused():
    sc = load_scene("two_link_free").with_fidelity(integrator="rkn4", dt=0.0095, **MODAL3)
    with pytest.raises(StepTooLarge) as exc:
        simulate(sc, 0.1)
    assert "RKN4 stability limit" in str(exc.value)


def test_rkn4_from_the_cli_with_a_tolerance(tmp_path, capsys):
    """``--integrator rkn4 --tolerance``: the pilots step with rkn4, the error meets the
    tolerance (against DOP853) and the summary names the integrator."""
    out = tmp_path / "x.npz"
    argv = ["simulate", "two_link_free", "--rung", "modal", "--refine", "3", "--integrator",
            "rkn4", "--tolerance", "1e-5", "--duration", "0.5", "--json", "--out", str(out),
            "--best-effort"]        # the step's temporal error is tested here, not modal 3's
    assert main(argv) == 0
    summ = json.loads(capsys.readouterr().out)
    assert summ["integrator"] == "rkn4"
    assert summ["tolerance_m"] == 1e-5
    sc = load_scene("two_link_free").with_fidelity(integrator="rkn4", dt=summ["step_s"],
                                                   **MODAL3)
    err = np.max(np.linalg.norm(_tip(simulate(sc, 0.5)) - _tip(_reference(sc, 0.5)),
                                axis=1))
    assert err <= 1e-5


def test_the_twin_plant_steps_rkn4_where_the_scene_names_it():
    """The ROS twin's plant (sim/plant.Plant) steps the scene's rkn4 (no wall): held at the
    scene's own torques it follows the batch run of the same model, integrator and step to
    round-off, and parts from the RK4 batch run by RK4's larger error; any other
    integrator of a scene is batch-only and the plant says rk4."""
    from flexarm_ros.sim.plant import Plant
    sc = load_scene("two_link_free").with_fidelity(dt=1e-3, **MODAL3)
    end = {}
    for integrator in ("rk4", "rkn4"):
        s = sc.with_fidelity(integrator=integrator)
        end[integrator] = simulate(s, 0.3).run.q[-1]
    plant = Plant(sc.with_fidelity(integrator="rkn4"))
    assert plant.integrator == "rkn4" and plant.h == 1e-3
    plant.set_inputs([2.8, 1.1])                  # the scene's constant joint torques
    for _ in range(300):
        plant.step(1e-3)
    q = plant.chain.full_state(plant.t, plant.x)[0]
    assert np.abs(q - end["rkn4"]).max() < 1e-12
    assert np.abs(q - end["rk4"]).max() > 1e3 * np.abs(q - end["rkn4"]).max()
    assert Plant(sc.with_fidelity(integrator="dop853")).integrator == "rk4"
    assert Plant(load_scene("two_link_case1").with_fidelity(integrator="rk4")).integrator \
        == "rk4"


@pytest.mark.heavy
@pytest.mark.ros
def test_flexarm_run_reports_the_plants_integrator(capfd):
    """``flexarm run --json`` names the integrator the plant stepped with; a batch-only one
    is said at WARN level (ROS logging writes to the process's stderr: capfd)."""
    argv = ["run", "two_link_free", "--rung", "modal", "--refine", "3", "--duration", "0.02",
            "--no-record", "--json", "--quiet"]
    assert main(argv + ["--integrator", "rkn4"]) == 0
    out = json.loads(capfd.readouterr().out)
    assert out["integrator"] == "rkn4" and out["ticks"] == 20
    assert main(argv + ["--integrator", "radau"]) == 0
    cap = capfd.readouterr()
    assert json.loads(cap.out)["integrator"] == "rk4"
    assert "fidelity.integrator 'radau' applies to batch runs" in cap.err + cap.out


@pytest.mark.parametrize("name,integrator,words", [
    ("two_link_case1", "rkn4", "flexarm simulate refuses it"),
    ("two_link_free", "dop853", "batch runs only; flexarm run's plant steps rk4"),
])
def test_explain_says_where_an_integrator_does_not_apply(capsys, name, integrator, words):
    assert main(["explain", name, "--integrator", integrator]) == 0
    assert words in capsys.readouterr().out


def test_rkn4_with_a_wall_is_refused_in_one_line(capsys):
    code = main(["simulate", "two_link_case1", "--integrator", "rkn4", "--duration", "0.1",
                 "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert all(w in err[0] for w in ("fidelity.integrator", "'rkn4'", "wall", "expected rk4"))


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.3, 1.0])
def test_a_fixed_step_is_admitted_exactly_where_it_is_below_the_limit(zeta):
    """``rkn4_admits`` (the scan up to the step, what a run at a fixed step computes)
    against the limit itself: on q̈ + 2ζωq̇ + ω²q = 0 beside a rigid mode, for steps on
    both sides of the limit (outside the limit's refinement, 1.6e-3/rate)."""
    from flexarm_ros.model.explicit import rkn4_admits
    w = 40.0
    J = np.zeros((4, 4))
    J[0, 2] = J[1, 3] = 1.0
    J[2, 0], J[2, 2] = -w * w, -2 * zeta * w
    rate = float(np.abs(np.linalg.eigvals(J)).max())
    lim = rkn4_limit(J, 2, rate)
    for share in (0.3, 0.8, 0.99, 1.01, 1.2, 2.0):
        h = share * lim
        assert rkn4_admits(J, 2, rate, h) == (share < 1), (zeta, share)


def test_the_runs_check_of_a_fixed_step_agrees_with_the_limit():
    """two_link_free (rkn4 at a fixed 7.5 ms): the steps admitted about its initial state
    are those below RKN4's limit there (8.67 ms)."""
    from flexarm_ros.model.explicit import admits
    sc = load_scene("two_link_free")
    res = simulate(sc, 0.01)
    ch = res.chain
    q = np.array([res.columns[n][0] for n in ch.names])
    qd = np.array([res.columns[n + "_rate"][0] for n in ch.names])
    _, lim2, _ = stability(ch, q, qd, np.zeros(0), "rkn4")
    for h in (0.0075, 0.99 * lim2, 1.01 * lim2, 0.0095):
        assert admits(ch, q, qd, np.zeros(0), "rkn4", h) == (h < lim2), h
