"""The speed–accuracy study (flexarm study): rows, errors, frequencies, Pareto flags, plot."""

import json
import math

import numpy as np
import pytest

from flexarm_ros.studies import ladder as study
from flexarm_ros.testing.beam_theory import tip_loaded_frequencies_hz
from flexarm_ros.model.chain import Chain
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

# a short stiff-ish link clamped to its hub (hub_radius 0), a tip body at the tip and a
# torque pulse: first frequency 4.17 Hz, FEM 8 highest rate ~9e4 1/s
L, EI, RHO_A, TIP_M, TIP_J = 0.3, 2.0, 0.3, 0.3, 1e-4
DURATION = 0.2


def small_scene(inputs=True, initial_rate=0.0):
    data = {
        "name": "study_probe",
        "duration": 1.0,
        "links": [{"name": "arm",
                   "joint": {"initial_rate": initial_rate},
                   "beam": {"length": L, "EI": EI, "mass_per_length": RHO_A},
                   "hub": {"inertia": 0.005},
                   "tip": {"mass": TIP_M, "inertia": TIP_J}}],
    }
    if inputs:
        data["inputs"] = [{"joint": 1, "torque": {"type": "pulse", "amplitude": 0.2,
                                                   "start": 0.0, "width": 0.02}}]
    return load_scene_dict(data)


@pytest.fixture(scope="module")
def quick():
    lines = []
    rows = study.run_study(small_scene(), duration=DURATION, quick=True, progress=lines.append)
    return rows, lines


def _row(rows, rung, refine, integrator="rk4"):
    (r,) = [r for r in rows if (r["rung"], r["refinement"], r["integrator"])
            == (rung, refine, integrator)]
    return r


@pytest.mark.heavy
def test_rows_have_the_keys_and_are_json(quick):
    rows, lines = quick
    assert len(rows) == len(study.default_ladder(quick=True))
    required = {"rung", "refinement", "integrator", "n_coordinates", "wall_s_per_sim_s",
                "real_time_factor", "rhs_evaluations", "tip_rms_error_m", "tip_max_error_m",
                "first_frequency_hz", "first_frequency_error", "energy_drift", "status",
                "pareto"}
    for r in rows:
        assert required <= set(r)
        assert set(study.ROW_KEYS) <= set(r)
        assert r["status"] == "ok", r["status"]
        assert r["wall_s_per_sim_s"] > 0 and r["rhs_evaluations"] > 0
        assert math.isclose(r["real_time_factor"] * r["wall_s_per_sim_s"], 1.0)
        assert math.isclose(r["duration_s"], DURATION)
        assert r["energy_drift"] is None          # torque input: energy not conserved
        assert r["reference"].startswith("fem 8 rk4")
    json.loads(json.dumps(rows))                  # plain JSON
    assert len(lines) >= len(rows)                 # progress: one line per row at least
    assert rows.meta["reference"].startswith("fem 8")
    est = rows.meta["reference_error_estimate_m"]      # fem 4 error / 15
    assert est == pytest.approx(_row(rows, "fem", 4)["tip_rms_error_m"] / 15)


def test_reference_against_itself_has_zero_error():
    res = simulate(small_scene().with_fidelity(rung="fem", refine=4), 0.05)
    e = study._errors(res, res)
    assert e["tip_rms_error_m"] == 0.0 and e["tip_max_error_m"] == 0.0
    # a different output grid is compared on the reference's samples (interpolated)
    cols = dict(res.columns)
    sub = {k: np.asarray(v)[::2] for k, v in cols.items()}
    e2 = study._errors(sub, res)
    assert e2["tip_rms_error_m"] < 1e-3 * np.ptp(cols["tip_y"])


def test_errors_decrease_with_refinement(quick):
    rows, _ = quick
    fem2, fem4 = _row(rows, "fem", 2), _row(rows, "fem", 4)
    assert fem4["tip_rms_error_m"] < 0.5 * fem2["tip_rms_error_m"]
    assert fem4["tip_max_error_m"] < fem2["tip_max_error_m"]
    assert fem4["first_frequency_error"] < fem2["first_frequency_error"]
    # the crudest rung is the worst
    assert _row(rows, "rigid", 1)["tip_rms_error_m"] > fem4["tip_rms_error_m"]


def test_frequencies_against_closed_form(quick):
    rows, _ = quick
    exact = tip_loaded_frequencies_hz(EI, RHO_A, L, TIP_M, TIP_J, 1)[0]
    f_ref = rows.meta["reference_first_frequency_hz"]
    assert f_ref == pytest.approx(exact, rel=1e-7)           # the reference is converged
    cubic = _row(rows, "cubic", 1)
    assert cubic["first_frequency_hz"] > exact               # Rayleigh–Ritz: from above
    expected = abs(cubic["first_frequency_hz"] - exact) / exact
    # the study measures against the reference, whose own error is |f_ref − exact|/exact
    assert abs(cubic["first_frequency_error"] - expected) <= 1.01 * abs(f_ref - exact) / exact
    assert 1e-5 < cubic["first_frequency_error"] < 0.05


def test_first_frequency_skips_rigid_modes_and_keeps_low_ones():
    free = Chain(small_scene(inputs=False).with_fidelity(rung="cubic"))
    f = study.first_frequency(free)          # joints free: a 0-Hz rigid mode comes first
    assert f is not None and f > 1.0
    # fine mesh: the first mode must survive beside a highest mode ~1e5 times above it
    fine = Chain(small_scene().with_fidelity(rung="fem", refine=32))
    exact = tip_loaded_frequencies_hz(EI, RHO_A, L, TIP_M, TIP_J, 1)[0]
    assert study.first_frequency(fine) == pytest.approx(exact, rel=1e-7)


def test_pareto_flags_are_the_non_dominated_rows(quick):
    rows, _ = quick
    pts = [(r["wall_s_per_sim_s"], r["tip_rms_error_m"]) for r in rows]
    tie = rows.meta["reference_error_estimate_m"]
    for i, (r, (c, e)) in enumerate(zip(rows, pts)):
        dominated = False
        for j, (c2, e2) in enumerate(pts):
            slack = tie + 0.01 * max(e, e2)      # errors this close are ties
            if j != i and c2 <= c and e2 <= e + slack and (c2 < c or e2 < e - slack):
                dominated = True
        assert r["pareto"] == (not dominated)
    assert any(r["pareto"] for r in rows)
    # the cheapest row is always on the front, the most accurate too
    assert rows[int(np.argmin([c for c, _ in pts]))]["pareto"]
    assert rows[int(np.argmin([e for _, e in pts]))]["pareto"]
    assert study.pareto_front([(1, 1), (2, 0.5), (2, 2), (0.5, 3), None, (1, 1)]) == \
        [True, True, False, True, False, True]
    # ties: a costlier point whose error is only 0.5 % lower is dominated
    assert study.pareto_front([(1, 1.0), (2, 0.995)], rel_tie=0.01) == [True, False]
    assert study.pareto_front([(1, 1.0), (2, 0.995)]) == [True, True]


@pytest.mark.heavy
def test_plot_and_table(quick, tmp_path):
    rows, _ = quick
    png = tmp_path / "pareto.png"
    study.plot_pareto(rows, png, title="study_probe")
    data = png.read_bytes()
    assert len(data) > 5000 and data[:8] == b"\x89PNG\r\n\x1a\n"
    table = study.format_table(rows)
    lines = table.splitlines()
    assert len(lines) >= len(rows) + 2
    assert len({len(line) for line in lines[2:2 + len(rows)] if "*" not in line}) <= 1
    assert "fem" in table and "reference: fem 8" in table


def test_a_failing_row_is_data_not_a_crash(tmp_path):
    ladder = [study.spec("cubic", 1, "rk4"),
              study.spec("fem", 4, "rk4", dt=0.05),      # far above the RK4 stability limit
              study.spec("fd", 2, "rk4")]                # fd needs >= 4 segments
    rows = study.run_study(small_scene(), duration=0.02, ladder=ladder,
                           reference=study.spec("fem", 4, "rk4"))
    ok, unstable, bad = rows
    assert ok["status"] == "ok"
    assert unstable["status"].startswith("StepTooLarge") and "stability limit" in \
        unstable["status"]
    assert unstable["tip_rms_error_m"] is None and unstable["pareto"] is False
    assert bad["status"].startswith("SceneError") and "fidelity.refine" in bad["status"]
    assert ok["pareto"] is True
    study.plot_pareto(rows, tmp_path / "p.png")                # failed rows listed, no crash
    assert (tmp_path / "p.png").stat().st_size > 0
    assert "StepTooLarge" in study.format_table(rows)


def test_energy_drift_of_a_conservative_scene():
    scene = small_scene(inputs=False, initial_rate=2.0)       # free flight, no damping
    rows = study.run_study(scene, duration=0.05, ladder=[study.spec("cubic", 1, "rk4"),
                                                         study.spec("cubic", 1, "dop853",
                                                                    1e-6, 1e-9)],
                           reference=study.spec("fem", 2, "rk4"))
    for r in rows:
        assert r["status"] == "ok"
        assert r["energy_drift"] is not None and 0.0 <= r["energy_drift"] < 1e-3
    assert rows.meta["joints"] == "free"


def test_rk4_reference_agrees_with_a_tight_dop853_one():
    """The reference integrates by RK4 at the automatic step: check that its time error is
    far below the spatial errors the study measures (DOP853 at rtol 1e-10 as the judge)."""
    scene = small_scene()
    T = 0.05
    rk4 = simulate(scene.with_fidelity(rung="fem", refine=4, integrator="rk4", dt=0.0), T)
    tight = simulate(scene.with_fidelity(rung="fem", refine=4, integrator="dop853",
                                         rtol=1e-10, atol=1e-12, dt=0.0), T)
    coarse = simulate(scene.with_fidelity(rung="fem", refine=2, integrator="rk4", dt=0.0), T)
    time_err = study._errors(rk4, tight)["tip_rms_error_m"]
    space_err = study._errors(coarse, tight)["tip_rms_error_m"]
    assert time_err < 1e-2 * space_err        # measured: 2e-11 m vs 1.8e-8 m
