"""Statics under gravity against beam theory, and the energy balance of free and damped runs.

Statics truth: Roark/Blevins cantilever formulas (:mod:`beam_theory`) for the horizontal
arm, and, for an inclined arm (gravity with an axial component), the linear beam-column
equation EI w'''' − (N w')' = ρA g_t solved here with ``scipy.integrate.solve_bvp``: that is
what the second-order (foreshortening) model must reproduce — gravity stiffening when the
arm hangs (tension), softening when it points up (compression).

Energy truth: with no damping and no input the total energy (column ``energy``: kinetic +
elastic + gravity, computed by the numpy chain independently of the integrator's rhs) is
an invariant; with damping it may only decrease, at the rate q̇ᵀ D q̇.

Seed 002 (Gannon 1986) arm: L = 0.9985 m, EI = 200e9·4.065e-10, ρA = 7861.05·6.17795e-4,
tip 2.115 kg at the beam tip, g = 9.8066, vertical plane, arm horizontal, joint held.
Measured here (fem 8): linear tip deflection 0.157444 m = beam theory to 1e-13 (Gannon's
program starts from 0.146 m: 7.3 % less than beam theory for these constants); the
static_equilibrium solution equals the linear one to ~1e-13 for the horizontal arm (see
test_horizontal_arm_static_equilibrium_is_the_linear_solution for why).
"""

import numpy as np
import pytest
from scipy.integrate import cumulative_simpson, solve_bvp

from flexarm_ros.testing import beam_theory as bt
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.linear import reduced_coordinates
from flexarm_ros.scene import config_dir, load_scene, load_scene_dict
from flexarm_ros.sim.simulate import simulate
from flexarm_ros.model.statics import initial_x, static_equilibrium
from flexarm_ros.sim.step import choose_step

# seed 002 arm
L = 0.9985
EI = 200e9 * 4.065e-10
RHO_A = 7861.05 * 6.17795e-4
TIP = 2.115
G = 9.8066


def _seed_scene(rung="fem", refine=8, angle=0.0, g=G, tip=None, output_dt=1e-3):
    tip = {"mass": TIP} if tip is None else tip
    return load_scene_dict({
        "name": "seed002", "gravity": [0.0, -g],
        "links": [{"name": "arm", "joint": {"initial_angle": angle},
                   "beam": {"length": L, "EI": EI, "mass_per_length": RHO_A},
                   "tip": tip}],
        "inputs": [{"joint": 1, "motion": {"type": "hold"}}],
        "initial": {"static_equilibrium": True},
        "fidelity": {"rung": rung, "refine": refine, "output_dt": output_dt}})


def _linear_static(chain):
    """K⁻¹ Q_grav at η = 0 on the non-drive coordinates (one Newton step from zero)."""
    q0 = chain.initial_q()[0]
    keep = reduced_coordinates(chain, "locked")
    kin = chain.kinematics(q0, np.zeros(chain.n))
    q = q0.copy()
    q[keep] = np.linalg.solve(chain.K[np.ix_(keep, keep)], kin.Qg[keep])
    return q


def _tip_slope(chain, q):
    lm = chain.links[0]
    return float(lm.beam.slope_tip @ q[lm.eta])


DELTA_BT = bt.cantilever_static_tip_deflection(EI, RHO_A, L, G, TIP)
SLOPE_BT = bt.cantilever_static_tip_slope(EI, RHO_A, L, G, TIP)


# -------------------------------------------------------------------------- statics
@pytest.mark.parametrize("rung, refine, tol, slope_tol", [("fem", 8, 1e-6, 1e-6),
                                                          ("cubic", 1, 1e-6, 1e-6),
                                                          ("modal", 4, 1e-5, 1e-3)])
def test_linear_static_deflection_matches_beam_theory(rung, refine, tol, slope_tol):
    chain = Chain(_seed_scene(rung, refine))
    q = _linear_static(chain)
    w = chain.tip_deflections(q)[0]
    assert w < 0.0                                     # down, with gravity
    assert abs(w) == pytest.approx(DELTA_BT, rel=tol)
    assert abs(_tip_slope(chain, q)) == pytest.approx(SLOPE_BT, rel=slope_tol)
    assert DELTA_BT == pytest.approx(0.157444, rel=1e-5)  # vs Gannon's 0.146 m: +7.8 %


def test_small_load_static_equilibrium_scaled_up_matches_beam_theory():
    # Newton from zero under g·1e-6: the nonlinear part is 1e-6 smaller, so ×1e6 is linear
    scale = 1e-6
    chain = Chain(_seed_scene(g=G * scale))
    q = static_equilibrium(chain, chain.initial_q()[0])
    w = chain.tip_deflections(q)[0] / scale
    assert abs(w) == pytest.approx(DELTA_BT, rel=1e-6)


def test_horizontal_arm_static_equilibrium_is_the_linear_solution():
    """For the horizontal arm gravity is transverse; in this second-order model the
    transverse position is exactly w = φᵀη and foreshortening only moves points along the
    arm, so the gravity potential is linear in η and the static solution IS the linear one
    (measured difference ~1e-13). The elastica's shortening of the moment arm is a
    third-order effect the model does not have; it must not invent one either way."""
    chain = Chain(_seed_scene())
    w_lin = chain.tip_deflections(_linear_static(chain))[0]
    w_nl = chain.tip_deflections(static_equilibrium(chain, chain.initial_q()[0]))[0]
    assert abs(w_nl / w_lin - 1.0) < 0.03               # the bound
    assert abs(w_nl) <= abs(w_lin) * (1 + 1e-9)          # not larger than linear
    assert abs(w_nl / w_lin - 1.0) < 1e-9               # measured: equal to round-off


def test_static_foreshortening_matches_the_beam_theory_shape():
    # the tip moves inward by ½∫w′² dx; w′ of the loaded cantilever in closed form
    chain = Chain(_seed_scene("fem", 16))
    q = static_equilibrium(chain, chain.initial_q()[0])
    q_dist, P = RHO_A * G, TIP * G
    x, wgt = np.polynomial.legendre.leggauss(8)
    x = 0.5 * L * (x + 1)
    wgt = 0.5 * L * wgt
    r = L - x
    slope = (q_dist * (L**3 - r**3) / 6 + P * (L**2 - r**2) / 2) / EI
    shortening = 0.5 * np.sum(wgt * slope**2)
    tip_x = chain.tip_position(q)[0]
    assert L - tip_x == pytest.approx(shortening, rel=1e-6)
    assert shortening > 0.01                        # 16 mm: the test can see it


def _beam_column_tip_deflection(psi):
    """Tip w(L) of the inclined cantilever (arm at angle ψ, gravity −y) by solve_bvp of
    EI w'''' − (N w')' = ρA g_t,  N(x) = g_a (ρA (L − x) + M)  (tension > 0),
    w(0) = w'(0) = 0, w''(L) = 0, EI w'''(L) − N(L) w'(L) + M g_t = 0."""
    e = np.array([np.cos(psi), np.sin(psi)])
    n = np.array([-np.sin(psi), np.cos(psi)])
    g = np.array([0.0, -G])
    ga, gt = g @ e, g @ n

    def N(x):
        return ga * (RHO_A * (L - x) + TIP)

    def f(x, y):
        return np.vstack([y[1], y[2], y[3],
                          (RHO_A * gt - ga * RHO_A * y[1] + N(x) * y[2]) / EI])

    def bc(ya, yb):
        return np.array([ya[0], ya[1], yb[2], EI * yb[3] - N(L) * yb[1] + TIP * gt])

    xs = np.linspace(0.0, L, 201)
    sol = solve_bvp(f, bc, xs, np.zeros((4, xs.size)), tol=1e-10, max_nodes=100000)
    assert sol.status == 0, sol.message
    return float(sol.sol(L)[0])


@pytest.mark.parametrize("deg", [30.0, -30.0, 60.0])
def test_inclined_arm_static_deflection_matches_beam_column_theory(deg):
    psi = np.radians(deg)
    truth = _beam_column_tip_deflection(psi)
    chain = Chain(_seed_scene("fem", 16, angle=float(psi)))
    q = static_equilibrium(chain, chain.initial_q()[0])
    w = chain.tip_deflections(q)[0]
    assert w == pytest.approx(truth, rel=1e-6)
    w_lin = chain.tip_deflections(_linear_static(chain))[0]
    # pointing up: compression softens (more deflection); hanging: tension stiffens
    if deg > 0:
        assert abs(w) > abs(w_lin) * 1.05
    else:
        assert abs(w) < abs(w_lin) * 0.95


def test_rigid_rung_static_deflection_is_its_own_closed_form():
    # rigid link on K = 3EI/L: Lβ = L·(ρA g L²/2 + M g L)/(3EI/L)
    chain = Chain(_seed_scene("rigid", 1))
    q = static_equilibrium(chain, chain.initial_q()[0])
    exact = RHO_A * G * L**4 / (6 * EI) + TIP * G * L**3 / (3 * EI)
    assert abs(chain.tip_deflections(q)[0]) == pytest.approx(exact, rel=1e-12)


def test_fd_static_deflection_converges_at_second_order():
    errs = []
    for n in (10, 20, 40):
        chain = Chain(_seed_scene("fd", n))
        w = chain.tip_deflections(static_equilibrium(chain, chain.initial_q()[0]))[0]
        errs.append(abs(abs(w) - DELTA_BT) / DELTA_BT)
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 3.5) & (ratios < 4.5)), (errs, ratios)


def test_shipped_hydraulic_scene_static_deflection():
    """The shipped seed-002 scene has the load's CG e = 7.9 mm beyond the tip: its weight
    adds the tip moment P·e, i.e. P·e·L²/(2EI) of deflection (Roark case 3a) — exactly, in
    the linear part. The static_equilibrium turns the tip body by the full tip angle θ, so
    the moment arm of that offset is e·cos θ: the nonlinear deflection is slightly smaller
    (measured 1.6e-4 relative)."""
    if "hydraulic_2kg" not in [p.stem for p in config_dir().glob("*.yaml")]:
        pytest.fail("config/hydraulic_2kg.yaml (seed 002 scene) is not shipped")
    scene = load_scene("hydraulic_2kg").with_fidelity(rung="fem", refine=8)
    lk = scene.links[0]
    chain = Chain(scene)
    q0 = chain.initial_q()[0]
    q = static_equilibrium(chain, q0)
    w_lin = chain.tip_deflections(_linear_static(chain))[0]
    w_nl = chain.tip_deflections(q)[0]
    g = abs(scene.gravity[1])
    b, tip = lk.beam, lk.tip
    exact = (bt.cantilever_static_tip_deflection(b.EI, b.mass_per_length, b.length, g,
                                                 tip.mass)
             + tip.mass * g * tip.cg[0] * b.length**2 / (2 * b.EI))
    assert scene.gravity[0] == 0.0 and q0[chain.links[0].i_joint] == 0.0
    assert abs(w_lin) == pytest.approx(exact, rel=1e-6)
    assert 0.0 < 1.0 - w_nl / w_lin < 1e-3
    # Gannon's program starts from 0.146 m: 7.8 % below this (see the scene's assumptions)
    assert abs(w_nl) == pytest.approx(0.1584, abs=2e-4)


def test_arm_started_at_static_equilibrium_stays_put():
    res = simulate(_seed_scene("fem", 8, output_dt=0.01), 0.2)
    c = res.columns
    assert res.run.success
    assert c["arm_tip_deflection"][0] == pytest.approx(-DELTA_BT, rel=1e-6)
    drift = np.hypot(c["tip_x"] - c["tip_x"][0], c["tip_y"] - c["tip_y"][0]).max()
    assert drift < 1e-9, drift


# --------------------------------------------------------------------------- energy
def _two_link(rung, refine=0, integrator="dop853", gravity=(0.0, 0.0), damping=None,
              output_dt=0.01, rtol=1e-10, atol=1e-12, **fid):
    """Two-link arm (tip bodies with CG offsets, hub bodies), initial joint rates, no input."""
    def link(name, length, rate, angle, tip_mass):
        d = {"name": name,
             "beam": {"length": length, "EI": 2.0, "mass_per_length": 0.5},
             "joint": {"initial_rate": rate, "initial_angle": angle},
             "hub": {"mass": 0.1, "inertia": 2e-3},
             "tip": {"mass": tip_mass, "inertia": 1e-3, "cg": [0.02, 0.01]}}
        if damping:
            d["beam"]["damping"] = damping["beam"]
            d["joint"]["drive_damping"] = damping["drive"]
        return d
    return load_scene_dict({
        "name": "two_link", "gravity": list(gravity),
        "links": [link("l1", 0.5, 2.0, 0.3, 0.2), link("l2", 0.4, -3.0, 0.6, 0.1)],
        "fidelity": {"rung": rung, "refine": refine, "integrator": integrator,
                     "rtol": rtol, "atol": atol, "output_dt": output_dt, **fid}})


def _drift(res):
    E = res.columns["energy"]
    return float(np.max(np.abs(E - E[0])) / abs(E[0]))


@pytest.mark.parametrize("gravity", [(0.0, 0.0), (0.0, -9.81)], ids=["plane", "gravity"])
@pytest.mark.parametrize("rung, refine", [("rigid", 0), ("cubic", 0)])
def test_energy_conserved_dop853(rung, refine, gravity):
    # measured: 3e-14..2e-12 relative over 2 s
    res = simulate(_two_link(rung, refine, gravity=gravity), 2.0)
    assert res.run.success
    assert _drift(res) < 1e-9


@pytest.mark.parametrize("rung, refine, duration", [("modal", 3, 0.5), ("fem", 2, 0.2),
                                                    ("fd", 4, 0.5)])
def test_energy_conserved_dop853_finer_rungs_short(rung, refine, duration):
    # short versions of the slow test below (numpy rhs: the modes up to kHz set the cost)
    res = simulate(_two_link(rung, refine, gravity=(0.0, -9.81)), duration)
    assert _drift(res) < 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("gravity", [(0.0, 0.0), (0.0, -9.81)], ids=["plane", "gravity"])
@pytest.mark.parametrize("rung, refine", [("modal", 3), ("fem", 4), ("fd", 8)])
def test_energy_conserved_dop853_finer_rungs(rung, refine, gravity):
    # measured 2e-14..9e-14 over 2 s (fem 4: ~25 s wall with numba)
    res = simulate(_two_link(rung, refine, gravity=gravity), 2.0)
    assert _drift(res) < 1e-9


# rk4 with the automatic step (1.5/|λ|max, no longer capped by the output period) over
# 2 s: measured relative drift rigid 7.3e-6 (h = 16.6 ms), cubic 2.0e-6, modal 3 1.9e-6,
# fem 2 2.6e-7, fd 4 9.8e-7 (slow: fem 4 4.9e-9, fd 8 4.4e-8); bounds ~10x above.
RK4_BOUND = {("rigid", 0): 5e-5, ("cubic", 0): 2e-5, ("modal", 3): 3e-5,
             ("fem", 2): 3e-6, ("fd", 4): 8e-6, ("fem", 4): 6e-8, ("fd", 8): 5e-7}


def _rk4_energy(rung, refine):
    # the automatic step is no longer capped by the output period (dense output between
    # steps); RK4's damping is a property of its steps, so the output period is set to a
    # whole number of automatic steps and every sample is a step end
    scene = _two_link(rung, refine, integrator="rk4")
    chain = Chain(scene)
    h = choose_step(chain, initial_x(chain), "rk4", 0.0, 0.01, dense=True)
    scene = _two_link(rung, refine, integrator="rk4", output_dt=h * max(1, round(0.01 / h)))
    res = simulate(scene, 2.0)
    assert res.run.success and res.run.dt == pytest.approx(h, rel=1e-12)
    assert _drift(res) < RK4_BOUND[(rung, refine)]
    E = res.columns["energy"]
    assert E[-1] <= E[0] * (1 + 1e-12)                  # RK4 loses energy over the run
    if rung != "rigid":
        # ... and at every step where its damping of the elastic modes dominates; the
        # rigid rung's automatic step (16.6 ms, h·|λ|max = 1.5 on the nonlinear rigid-body
        # motion) gains up to 2.9e-9·E₀ on 22 of its 120 steps (measured; 0 at 10 ms)
        assert np.all(np.diff(E) <= 1e-12 * abs(E[0]))


@pytest.mark.parametrize("rung, refine", [("rigid", 0), ("cubic", 0), ("modal", 3),
                                          ("fem", 2), ("fd", 4)])
def test_energy_rk4_auto_step(rung, refine):
    _rk4_energy(rung, refine)


@pytest.mark.slow
@pytest.mark.parametrize("rung, refine", [("fem", 4), ("fd", 8)])
def test_energy_rk4_auto_step_finer(rung, refine):
    _rk4_energy(rung, refine)


@pytest.mark.heavy
def test_energy_rk4_numpy_backend():
    scene = _two_link("cubic", integrator="rk4")
    res = simulate(scene, 2.0, chain=Chain(scene, backend="numpy"))
    assert _drift(res) < RK4_BOUND[("cubic", 0)]


DAMPING = {"beam": {"viscous_per_length": 0.05, "stiffness_proportional": 1e-4},
           "drive": 0.01}


@pytest.mark.parametrize("rung, refine", [("rigid", 0), ("cubic", 0), ("modal", 3),
                                          ("fem", 2), ("fd", 4)])
def test_damped_energy_never_increases(rung, refine):
    res = simulate(_two_link(rung, refine, gravity=(0.0, -9.81), damping=DAMPING), 0.5)
    E = res.columns["energy"]
    assert np.all(np.isfinite(E))
    assert np.all(np.diff(E) <= 1e-11 * abs(E[0])), np.diff(E).max()
    assert E[-1] < E[0] * (1 - 1e-3)                    # and it does dissipate


@pytest.mark.parametrize("which", ["beam_viscous", "beam_stiffness", "drive"])
def test_energy_loss_equals_damping_work(which):
    # E(t) − E(0) = −∫ q̇ᵀ D q̇ dt, D assembled independently of the rhs here from the scene
    damping = {"beam": {"viscous_per_length": 0.0, "stiffness_proportional": 0.0},
               "drive": 0.0}
    if which == "beam_viscous":
        damping["beam"]["viscous_per_length"] = 2.0
    elif which == "beam_stiffness":
        damping["beam"]["stiffness_proportional"] = 5e-3
    else:
        damping["drive"] = 0.02
    scene = _two_link("cubic", damping=damping, output_dt=5e-4)
    res = simulate(scene, 0.5)
    chain = res.chain
    qd = res.run.qd
    D = np.zeros((chain.n, chain.n))
    for lm in chain.links:
        b = lm.beam
        # viscous: ∫ c ẇ² dx = η̇ᵀ (c/ρA · M_e) η̇ ; Rayleigh: β η̇ᵀ K_e η̇
        D[lm.eta, lm.eta] += (damping["beam"]["viscous_per_length"] / 0.5 * b.M_e
                              + damping["beam"]["stiffness_proportional"] * b.K)
        D[lm.i_joint, lm.i_joint] += damping["drive"]
    power = np.einsum("ti,ij,tj->t", qd, D, qd)
    t = res.columns["t"]
    lost = cumulative_simpson(power, x=t, initial=0.0)
    E = res.columns["energy"]
    # measured mismatch / loss: 8e-6 (viscous), 3e-5 (Rayleigh), 6e-7 (drive)
    assert lost[-1] > 1e-6 * E[0]                       # a visible amount
    np.testing.assert_allclose(E[0] - E, lost, rtol=0, atol=2e-4 * lost[-1])
