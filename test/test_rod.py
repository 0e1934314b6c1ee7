"""The geometrically exact rung (model/rod.py) against independent truths: the elastica's
closed form (Bisshopp & Drucker, checked here against a boundary-value solve), the
small-deflection frequencies of beam theory, energy conservation, the spin-up's
convergence (and the floor of the second-order rungs it removes), and the compiled kernel
against the numpy reference."""

import numpy as np
import pytest

from flexarm_ros.ensemble.keys import set_keys
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.statics import initial_state
from flexarm_ros.scene import load_scene, load_scene_dict
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.testing import beam_theory as bt


def _elastica_scene(alpha, terms, EA=None):
    """A 1 m cantilever (EI = 1 N·m², a negligible mass per length), its joint held, a tip
    mass whose weight is α EI / L² (P L²/EI = α), at static equilibrium."""
    beam = {"length": 1.0, "EI": 1.0, "mass_per_length": 1e-9}
    if EA is not None:
        beam["EA"] = EA
    return load_scene_dict({
        "name": "elastica", "gravity": [0.0, -9.81],
        "links": [{"name": "b", "joint": {}, "beam": beam, "tip": {"mass": alpha / 9.81}}],
        "inputs": [{"joint": 1, "motion": {"type": "hold"}}],
        "initial": {"static_equilibrium": True},
        "fidelity": {"rung": "rod", "refine": terms}})


def test_the_elastica_closed_form_agrees_with_a_boundary_value_solve():
    """The truth itself: Bisshopp & Drucker's elliptic integrals against scipy's
    solve_bvp on θ″ = −α cos θ, and their table (α = 1: v/L = 0.30172, u/L = 0.05643)."""
    from scipy.integrate import solve_bvp
    for alpha in (0.01, 1.0, 3.0):
        u, v, th = bt.elastica_tip(alpha)

        def f(s, y, a=alpha):
            return np.vstack([y[1], -a * np.cos(y[0]), np.cos(y[0]), np.sin(y[0])])
        s = np.linspace(0, 1, 200)
        y0 = np.zeros((4, s.size))
        y0[2] = s
        sol = solve_bvp(f, lambda ya, yb: np.array([ya[0], yb[1], ya[2], ya[3]]), s, y0,
                        tol=1e-10, max_nodes=100000)
        assert sol.success
        assert abs((1 - sol.y[2, -1]) - u) < 1e-10 and abs(sol.y[3, -1] - v) < 1e-10
        assert abs(sol.y[0, -1] - th) < 1e-10
    u, v, _ = bt.elastica_tip(1.0)
    assert (round(v, 5), round(u, 5)) == (0.30172, 0.05643)


@pytest.mark.parametrize("alpha", [1.0, 3.0])
def test_the_rod_meets_the_elastica_at_large_deflection(alpha):
    """P L²/EI = 1 and 3 (a 26° and 56° tip slope, 30 % and 60 % of L deflection): the
    static rod converges spectrally to the closed form — 3 terms within 1e-4, 8 within
    2e-9 of L (the negligible beam weight's share) — where a second-order rung cannot
    follow (its small-deflection bound is 50 % of L)."""
    u, v, _ = bt.elastica_tip(alpha)
    errs = []
    for terms in (3, 5, 8):
        ch = Chain(_elastica_scene(alpha, terms))
        tip = ch.tip_position(initial_state(ch)[0])
        errs.append(max(abs((1 - tip[0]) - u), abs(-tip[1] - v)))
    assert errs[0] < 1e-4 and errs[2] < 2e-9, errs
    assert errs[0] > errs[1] > errs[2]


def test_small_deflection_frequencies_are_beam_theorys():
    """link_tipmass on the rod rung, joint locked: the first four natural frequencies
    converge spectrally to the tip-loaded cantilever's closed form (mass 0.5 kg, inertia
    0.002 kg·m²): within 1e-6 relative with 12 terms, f4 off by ~3e-5 with 8 — the
    rod's linearization is the Euler-Bernoulli beam."""
    from flexarm_ros.model.linear import natural_modes
    lk = load_scene("link_tipmass").links[0]
    ref = bt.tip_loaded_frequencies_hz(lk.beam.EI, lk.beam.mass_per_length, lk.beam.length,
                                       lk.tip.mass, lk.tip.inertia, 4)
    err = {}
    for terms in (8, 12):
        ch = Chain(load_scene("link_tipmass").with_fidelity(rung="rod", refine=terms))
        f = np.asarray(natural_modes(ch, initial_state(ch)[0], "locked").frequencies_hz)
        err[terms] = np.abs(f[f > 1e-6][:4] / ref - 1)
    assert err[12].max() < 1e-6 and 1e-6 < err[8][3] < 1e-4, err


def _two_rods():
    return load_scene_dict({
        "name": "two rods", "gravity": [0.0, 0.0],
        "links": [{"name": "l1", "joint": {"initial_rate": 2.0},
                   "beam": {"length": 0.8, "EI": 6.0, "mass_per_length": 0.9, "EA": 4e4,
                            "hub_radius": 0.05},
                   "hub": {"mass": 1.0, "inertia": 0.01},
                   "tip": {"mass": 0.3, "inertia": 0.002, "cg": [0.02, 0.01],
                           "joint_offset": [0.03, 0.0]}},
                  {"name": "l2", "joint": {"initial_angle": 0.4, "initial_rate": -3.0},
                   "beam": {"length": 0.6, "EI": 3.0, "mass_per_length": 0.6},
                   "tip": {"mass": 0.2, "inertia": 0.001}}],
        "fidelity": {"rung": "rod", "refine": 4}})


@pytest.mark.heavy
def test_energy_is_conserved_without_input():
    """Two rod links (one extensible, tip bodies with CG offsets), released spinning: the
    total energy over 1 s with DOP853 at rtol 1e-11 stays within 1e-9 of its start — the
    rod's kinematics, Jacobians and velocity-product terms are one consistent system."""
    sc = _two_rods().with_fidelity(integrator="dop853", rtol=1e-11, atol=1e-13)
    res = simulate(sc, 1.0)
    E = res.columns["energy"]
    assert abs(E).max() > 1.0
    assert np.max(np.abs(E - E[0])) / abs(E[0]) < 1e-9


def test_the_compiled_kernel_equals_the_numpy_reference():
    """Right-hand sides at random states (two rods; the spin-up's extensible rod with its
    prescribed hub) and the accelerometers on a rod (two_link_case1 on the rod rung):
    equal to round-off."""
    from flexarm_ros.model.compiled import chain as kchain
    from flexarm_ros.model.compiled import sensors as ksensors
    from flexarm_ros.model.compiled import HAVE_NUMBA
    from flexarm_ros.model.sensors import build_sensors, true_value
    if not HAVE_NUMBA:
        pytest.skip("numba disabled")
    rng = np.random.default_rng(7)
    spin = set_keys(load_scene("spin_up"), {"fidelity.rung": "rod"})
    for sc in (_two_rods(), spin):
        a, b = Chain(sc, backend="numpy"), Chain(sc)
        for _ in range(3):
            x = rng.normal(0, 0.05, 2 * len(a.free) + a.nz)
            ra, rb = a.rhs(1.3, x), b.rhs(1.3, x)
            assert np.max(np.abs(ra - rb)) <= 1e-11 * max(1.0, np.max(np.abs(ra)))
    sc = load_scene("two_link_case1").with_fidelity(rung="rod", refine=4)
    ch, chn = Chain(sc), Chain(sc, backend="numpy")
    sens = build_sensors(ch, sc)
    q, qd, qdd = (rng.normal(0, s, ch.n) for s in (0.05, 0.3, 2.0))
    idx, *arrs = ksensors.pack(ch, sens)
    ws = kchain.workspace(ch.kernel_args)
    kchain.forces(0.0, q, qd, np.zeros(ch.nz), ch.kernel_args, ws)
    out = np.empty(len(idx))
    ksensors.readings(q, qd, qdd, ch.kernel_args, ws, *arrs, out)
    ref = [true_value(sens[j], chn, q, qd, qdd, np.zeros(ch.n)) for j in idx]
    assert {sens[j].spec.body for j in idx} == {"beam", "tip"}
    assert np.max(np.abs(out - ref)) < 1e-12


@pytest.mark.heavy
def test_the_spin_up_converges_below_the_second_order_floor():
    """Kane et al.'s spin-up (20 s): the rod with 5 terms and its stretch lies within
    2e-6 m of 8 terms over the whole run, and within 2e-6 m of it in the tip deflection;
    the converged second-order rung (modal 4, the default until now) stays ~2e-3 m away — the floor the
    quadratic foreshortening leaves (docs/physics.md §5.4: 0.2–0.4 % of the 0.574 m peak)."""
    sc = load_scene("spin_up").with_fidelity(output_dt=0.01)
    runs = {}
    for key, over in (("rod5", dict(rung="rod", refine=5)), ("rod8", dict(rung="rod",
                                                                         refine=8)),
                      ("modal4", dict(rung="modal", refine=4))):
        runs[key] = simulate(sc.with_fidelity(**over), 20.0).columns

    def pos(a, b):
        return np.hypot(a["tip_x"] - b["tip_x"], a["tip_y"] - b["tip_y"]).max()
    assert pos(runs["rod5"], runs["rod8"]) < 2e-6
    assert np.abs(runs["rod5"]["beam_tip_deflection"]
                  - runs["rod8"]["beam_tip_deflection"]).max() < 2e-6
    assert 1.5e-3 < pos(runs["modal4"], runs["rod8"]) < 3e-3
    assert runs["rod8"]["beam_tip_deflection"].min() == pytest.approx(-0.5738, abs=2e-4)


def test_two_link_free_on_its_four_gauss_points_tracks_the_default_six():
    """The shipped two_link_free carries each rod's mass on 4 Gauss points (fidelity
    .rod_points) instead of 6: over 0.5 s its tip position stays within 1e-7 m and its
    tip deflections within 1e-6 m (7.0e-7 measured) of the same rod on the default
    quadrature; against rod 12 over the 2 s both are 5.9e-7 m tip and 5.4-5.5e-6 m
    deflection (session 25; test_truth holds the shipped scene against the top rung)."""
    sc = load_scene("two_link_free")
    assert sc.fidelity.rod_points == 4
    six = sc.with_fidelity(rod_points=0, dt=sc.fidelity.dt)
    a = simulate(sc, duration=0.5).columns
    b = simulate(six, duration=0.5).columns
    tip = np.hypot(np.asarray(a["tip_x"]) - b["tip_x"], np.asarray(a["tip_y"]) - b["tip_y"])
    assert tip.max() < 1e-7
    for name in ("link1", "link2"):
        key = f"{name}_tip_deflection"
        assert np.abs(np.asarray(a[key]) - b[key]).max() < 1e-6
        assert np.abs(np.asarray(b[key])).max() > 1e-3       # the beams do bend


@pytest.mark.parametrize("value, says", [
    (2, "fidelity.rod_points: got 2 Gauss points for 3 curvature terms, expected 0 "
        "(the default, 6) or at least 4"),
    (-1, "fidelity.rod_points"),
    (65, "fidelity.rod_points")])
def test_a_rod_quadrature_too_coarse_or_out_of_range_is_refused_by_name(value, says):
    from flexarm_ros.errors import InputError
    with pytest.raises(InputError) as exc:
        sc = set_keys(load_scene("two_link_free"), {"fidelity.rod_points": value})
        Chain(sc)
    assert says in str(exc.value)


def test_another_rung_or_refinement_leaves_the_scenes_rod_quadrature():
    """The 4 points were measured for two_link_free's rod 3: rod 5, or another rung, goes
    back to the default quadrature unless told otherwise."""
    sc = load_scene("two_link_free")
    assert sc.with_fidelity(refine=5).fidelity.rod_points == 0
    assert sc.with_fidelity(rung="modal").fidelity.rod_points == 0
    assert sc.with_fidelity(refine=5, rod_points=7).fidelity.rod_points == 7
    assert sc.with_fidelity(dt=0.005).fidelity.rod_points == 4


def test_the_lowest_modes_of_a_longer_rod_carry_beam_theorys_frequencies():
    """fidelity.rod_modes: link_tipmass, joint locked, on the lowest 3 bending modes of the
    12-term rod has the tip-loaded cantilever's first three frequencies within 1e-6
    relative (the closed form of test_small_deflection_frequencies_are_beam_theorys), where
    the rod of 3 Legendre terms — as many coordinates — is off by more than 1 % in its
    third; the lowest modes are the accurate ones of a Galerkin basis."""
    from flexarm_ros.model.linear import natural_modes
    lk = load_scene("link_tipmass").links[0]
    ref = bt.tip_loaded_frequencies_hz(lk.beam.EI, lk.beam.mass_per_length, lk.beam.length,
                                       lk.tip.mass, lk.tip.inertia, 3)
    err = {}
    for terms, modes in ((12, 3), (3, 0)):
        ch = Chain(load_scene("link_tipmass").with_fidelity(rung="rod", refine=terms,
                                                           rod_modes=modes))
        assert ch.links[0].beam.n == 3
        f = np.asarray(natural_modes(ch, initial_state(ch)[0], "locked").frequencies_hz)
        err[terms] = np.abs(f[f > 1e-6][:3] / ref - 1)
    assert err[12].max() < 1e-6 and err[3][2] > 1e-2, err


def test_all_the_modes_of_a_rod_are_the_rod_itself():
    """rod_modes equal to the terms keeps every mode: the same model as 0 (all)."""
    from flexarm_ros.model import rod
    lk = load_scene("link_tipmass").links[0]
    a = rod.build(lk.beam, lk.tip, 5)
    b = rod.build(lk.beam, lk.tip, 5, modes=5)
    np.testing.assert_array_equal(a[0].T, b[0].T)
    np.testing.assert_array_equal(a[3], b[3])
    np.testing.assert_array_equal(a[5], b[5])


def test_the_stretch_stays_among_the_modes_kept():
    """spin_up's beam declares EA: its rod on the lowest 3 bending modes of 8 terms keeps
    the stretch coordinate too (3 + 1), which carries the 5e-4 m centrifugal stretch."""
    ch = Chain(load_scene("spin_up").with_fidelity(refine=8, rod_modes=3))
    basis = ch.links[0].beam.rod
    assert basis.T.shape[1] == 4
    assert np.count_nonzero(np.abs(basis.C).max(axis=0) > 0) == 1


def test_four_modes_of_rod_8_meet_1e_6_m_in_both_measures_on_two_link_free():
    """two_link_free on the lowest 4 bending modes of the 8-term rod, 5 Gauss points,
    RKN4 at 3.5 ms (0.88 of its 3.97 ms stability limit): within 1e-6 m of rod 12 (the top
    rung at its automatic RK4 step) over the 2 s in the tip position and in both links' tip
    deflections (measured 5.8e-8 m and 8.6e-7 m); rod 5, the Legendre rod that meets it,
    needs 1.7 ms (stability limit 1.96 ms), and rod 4 stops at 1.8e-6 m
    (docs/decisions/0033-rod-modes.md)."""
    from flexarm_ros.sim.truth import measures, reference_scene
    sc = load_scene("two_link_free")
    ref = simulate(reference_scene(sc, 12), 2.0).columns
    run = simulate(sc.with_fidelity(refine=8, rod_modes=4, rod_points=5, dt=0.0035), 2.0)
    assert run.chain.n == 2 + 2 * 4
    m = measures(run.columns, ref, [lm.name for lm in run.chain.links])
    assert m.position_m < 1e-6 and m.deflection_max_m < 1e-6, m
    assert min(m.deflection_peak_m) > 1e-2                   # the beams do bend


@pytest.mark.parametrize("over, says", [
    ({"fidelity.refine": 8, "fidelity.rod_modes": 9},
     "fidelity.rod_modes: got 9 for 8 curvature terms, expected 0 (all 8) or 1..8"),
    ({"fidelity.refine": 8, "fidelity.rod_modes": 4, "fidelity.rod_points": 4},
     "fidelity.rod_points: got 4 Gauss points for 4 rod modes of 8 curvature terms, "
     "expected 0 (the default, 11) or at least 5"),
    ({"fidelity.rod_modes": -1}, "fidelity.rod_modes"),
    ({"fidelity.rod_modes": 17}, "fidelity.rod_modes")])
def test_rod_modes_beyond_the_terms_or_out_of_range_are_refused_by_name(over, says):
    from flexarm_ros.errors import InputError
    with pytest.raises(InputError) as exc:
        Chain(set_keys(load_scene("two_link_free"), over))
    assert says in str(exc.value)


def test_another_rung_or_refinement_leaves_the_scenes_rod_modes():
    """rod_modes was chosen for one rod: another refinement or rung goes back to all."""
    sc = load_scene("two_link_free").with_fidelity(refine=8, rod_modes=4, rod_points=5)
    assert sc.with_fidelity(refine=10).fidelity.rod_modes == 0
    assert sc.with_fidelity(rung="modal").fidelity.rod_modes == 0
    assert sc.with_fidelity(dt=0.003).fidelity.rod_modes == 4
