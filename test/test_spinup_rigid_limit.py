"""High hub speed (Kane, Ryan & Banerjee 1987 spin-up) and the rigid-body limit.

Spin-up: a 10 m beam (EI = 14000 N·m², ρA = 1.2 kg/m) on a hub on the spin axis whose
angle follows θ = (Ω/T)[t²/2 + (T/2π)²(cos 2πt/T − 1)], Ω = 6 rad/s, T = 15 s. Truth here
is a quasi-static estimate computed in the test: the tip deflection under the inertial load
−ρA θ̈ x of the peak angular acceleration, stiffened by the centrifugal (geometric) stiffness
of the first clamped-free mode at the rate of that instant (Rayleigh quotient of the exact
mode shape). Measured with modal 4 / rk4: the tip lags (w < 0, −y of the rotating frame)
with a peak of −0.576 m at t = 6.77 s, and returns to |w| < 4 mm after the ramp; without
foreshortening the run diverges at t ≈ 8.75 s (|w|/L > 0.5).

Rigid limit: a two-link arm with EI × 1e6 under constant joint torques against the classic
rigid two-link equations M(q)q̈ + C(q, q̇)q̇ = τ written and integrated here.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.scene import load_scene_dict
from flexarm_ros.sim.simulate import simulate

# ----------------------------------------------------------------------------- spin-up
L_S, EI_S, RHO_A_S = 10.0, 14000.0, 1.2
OMEGA, RAMP = 6.0, 15.0


def _spin_scene(foreshortening=True, refine=4, rung="modal"):
    return load_scene_dict({
        "name": "spin_up",
        "links": [{"name": "beam", "beam": {"length": L_S, "EI": EI_S,
                                            "mass_per_length": RHO_A_S, "hub_radius": 0.0}}],
        "inputs": [{"joint": 1, "motion": {"type": "spin_up", "omega": OMEGA,
                                           "ramp_time": RAMP}}],
        "fidelity": {"rung": rung, "refine": refine, "modal_basis": "clamped_free",
                     "integrator": "rk4", "dt": 0.0, "output_dt": 0.01,
                     "foreshortening": foreshortening}})


def _quasi_static_tip(t):
    """Tip deflection (m) at time t < T, quasi-static, first mode with centrifugal
    stiffening and in-plane spin softening (Rayleigh–Ritz on the exact clamped-free mode),
    scaled to the exact static tip deflection of the triangular load."""
    a = 2 * np.pi / RAMP
    rate = OMEGA / RAMP * (t - np.sin(a * t) / a)
    accel = OMEGA / RAMP * (1 - np.cos(a * t))
    beta = 1.8751040687119611
    sigma = (np.cosh(beta) + np.cos(beta)) / (np.sinh(beta) + np.sin(beta))
    xg, wg = np.polynomial.legendre.leggauss(40)
    x = 0.5 * L_S * (xg + 1)
    w = 0.5 * L_S * wg
    b = beta / L_S
    phi = np.cosh(b * x) - np.cos(b * x) - sigma * (np.sinh(b * x) - np.sin(b * x))
    dphi = b * (np.sinh(b * x) + np.sin(b * x) - sigma * (np.cosh(b * x) - np.cos(b * x)))
    k_el = EI_S * b**4 * np.sum(w * RHO_A_S * phi**2) / RHO_A_S   # EI∫φ''² = β⁴EI/L⁴ ∫φ²
    centrifugal = np.sum(w * RHO_A_S * (L_S**2 - x**2) / 2 * dphi**2)
    softening = np.sum(w * RHO_A_S * phi**2)
    k = k_el + rate**2 * (centrifugal - softening)
    stiffening = k_el / k
    q0 = RHO_A_S * accel * L_S                                 # triangular load at the tip
    exact_unstiffened = 11 * q0 * L_S**4 / (120 * EI_S)
    return -exact_unstiffened * stiffening


def test_spin_up_with_foreshortening_stays_bounded_to_10s():
    res = simulate(_spin_scene(), 10.0)
    c = res.columns
    w = c["beam_tip_deflection"]
    assert all(np.all(np.isfinite(v)) for v in c.values())
    k = int(np.argmax(np.abs(w)))
    peak, t_peak = w[k], c["t"][k]
    # sign: the beam lags the spinning hub, −y in the rotating frame
    assert peak < 0.0
    assert w.max() < 0.01
    # magnitude: the quasi-static deflection at peak acceleration (t = T/2) with the
    # centrifugal stiffening of that instant; the dynamic lag is small (T ≫ 1/f1)
    i = int(np.argmin(np.abs(c["t"] - RAMP / 2)))
    est = _quasi_static_tip(RAMP / 2)
    assert w[i] == pytest.approx(est, rel=0.01), (w[i], est)   # measured 2e-5 apart
    # bounded: far inside the small-deflection range, below the unstiffened static bound
    unstiffened = 11 * RHO_A_S * (2 * OMEGA / RAMP) * L_S**5 / (120 * EI_S)
    assert abs(peak) < unstiffened
    assert abs(peak) < 0.07 * L_S
    assert 5.0 < t_peak < 9.0


def test_spin_up_without_foreshortening_diverges():
    """Why the stiffening term exists: a linear floating-frame model (no foreshortening)
    spin-softens — its tip deflection grows past the small-deflection limit during the
    ramp (measured t ≈ 8.75 s), and the run stops with a message that says so."""
    with pytest.raises(SimulationDiverged) as info:
        simulate(_spin_scene(foreshortening=False), 20.0)
    err = info.value
    assert err.time < RAMP
    assert "tip deflection" in err.quantity
    assert "foreshortening" in str(err)
    assert abs(err.last_value) > 0.4 * L_S


@pytest.mark.slow
def test_spin_up_full_20s_bounded_and_converged():
    res4 = simulate(_spin_scene(refine=4), 20.0)
    res6 = simulate(_spin_scene(refine=6), 20.0)
    w4 = res4.columns["beam_tip_deflection"]
    w6 = res6.columns["beam_tip_deflection"]
    t = res4.columns["t"]
    assert abs(w4).max() < 0.07 * L_S
    assert abs(w4[t >= RAMP]).max() < 0.01        # the rate is constant: back near zero
    assert np.abs(w4 - w6).max() < 1e-3           # 4 modes are converged (measured 1.4e-4)
    fem = simulate(_spin_scene(rung="fem", refine=8), 20.0).columns["beam_tip_deflection"]
    assert np.abs(w4 - fem).max() < 1e-3          # measured 1.6e-4


# ------------------------------------------------------------------------- rigid limit
L1, L2, RHO_A, EI = 0.5, 0.4, 0.5, 2.0
HUB = [{"mass": 0.3, "inertia": 2e-3}, {"mass": 0.15, "inertia": 1e-3}]
TIPB = [{"mass": 0.25, "inertia": 1e-3, "cg": [0.02, 0.0]},
        {"mass": 0.1, "inertia": 5e-4, "cg": [0.03, 0.01]}]
TAU = (0.8, 0.25)
Q0 = (0.2, 0.5)


def _stiff_two_link(rung, stiffness=1e6, integrator="radau", beta=1e-4, output_dt=0.005):
    """EI × stiffness; Rayleigh damping β·K only calms the (rigid-irrelevant) kHz modes so an
    implicit integrator can step over them: it does no work on the rigid motion."""
    def link(name, length, i):
        return {"name": name,
                "beam": {"length": length, "EI": EI * stiffness, "mass_per_length": RHO_A,
                         "damping": {"stiffness_proportional": beta}},
                "joint": {"initial_angle": Q0[i]}, "hub": HUB[i], "tip": TIPB[i]}
    return load_scene_dict({
        "name": "stiff_two_link",
        "links": [link("l1", L1, 0), link("l2", L2, 1)],
        "inputs": [{"joint": 1, "torque": {"type": "constant", "value": TAU[0]}},
                   {"joint": 2, "torque": {"type": "constant", "value": TAU[1]}}],
        "fidelity": {"rung": rung, "integrator": integrator, "rtol": 1e-8, "atol": 1e-10,
                     "output_dt": output_dt}})


def _rigid_two_link(t_eval):
    """Classic rigid two-link arm: uniform rods (ρA, length) + hub bodies on the joints +
    tip bodies (mass, inertia about CG, CG offset (cx, cy) in the link frame beyond the rod
    end); joint 2 at the end of rod 1. Composite link 2 about joint 2: mass m2, first
    moment (s2x, s2y), inertia I2; link 1 about joint 1: inertia I1.

        M = [[I1 + m2 L1² + I2 + 2a, I2 + a], [I2 + a, I2]],
        a = L1 (s2x cos q2 − s2y sin q2),  a' = da/dq2,
        C q̇ = [a' (2 q̇1 q̇2 + q̇2²), −a' q̇1²]   (Christoffel symbols of M).
    """
    def rod_and_bodies(length, i):
        m_rod = RHO_A * length
        hub, tip = HUB[i], TIPB[i]
        cx, cy = length + tip["cg"][0], tip["cg"][1]
        m = m_rod + hub["mass"] + tip["mass"]
        sx = m_rod * length / 2 + tip["mass"] * cx
        sy = tip["mass"] * cy
        inertia = (m_rod * length**2 / 3 + hub["inertia"] + tip["inertia"]
                   + tip["mass"] * (cx**2 + cy**2))
        return m, sx, sy, inertia

    _, _, _, I1 = rod_and_bodies(L1, 0)
    m2, s2x, s2y, I2 = rod_and_bodies(L2, 1)

    def f(_t, y):
        q1, q2, u1, u2 = y
        c, s = np.cos(q2), np.sin(q2)
        a = L1 * (s2x * c - s2y * s)
        da = -L1 * (s2x * s + s2y * c)
        M = np.array([[I1 + m2 * L1**2 + I2 + 2 * a, I2 + a], [I2 + a, I2]])
        cq = np.array([da * (2 * u1 * u2 + u2**2), -da * u1**2])
        acc = np.linalg.solve(M, np.array(TAU) - cq)
        return [u1, u2, acc[0], acc[1]]

    sol = solve_ivp(f, (0.0, t_eval[-1]), [Q0[0], Q0[1], 0.0, 0.0], method="DOP853",
                    rtol=1e-12, atol=1e-14, t_eval=t_eval)
    assert sol.success
    return sol.y[0], sol.y[1]


def _joint_error(res):
    c = res.columns
    q1, q2 = _rigid_two_link(c["t"])
    return max(np.abs(c["l1_joint"] - q1).max(), np.abs(c["l2_joint"] - q2).max()), q2


@pytest.mark.parametrize("rung", ["cubic", "rigid"])
def test_very_stiff_two_link_reproduces_the_rigid_arm(rung):
    res = simulate(_stiff_two_link(rung), 0.5)
    err, q2 = _joint_error(res)
    assert err < 1e-5, err                       # measured ~7e-8 rad
    assert abs(q2[-1] - Q0[1]) > 0.3             # the arm really moved (q2: +0.51 rad)
    assert all(np.all(np.isfinite(v)) for v in res.columns.values())


def test_rigid_limit_is_approached_as_stiffness_grows():
    # the elastic part of the joint angles scales like 1/EI (measured 1.5e-3, 7.5e-6 rad)
    # (EI × 100 is soft enough for the automatic RK4 step, undamped; × 1e4 needs radau)
    e2, _ = _joint_error(simulate(_stiff_two_link("cubic", stiffness=1e2, integrator="rk4",
                                                  beta=0.0), 0.5))
    e4, _ = _joint_error(simulate(_stiff_two_link("cubic", stiffness=1e4), 0.5))
    assert e4 < e2 / 20, (e2, e4)


@pytest.mark.slow
def test_very_stiff_two_link_undamped_rk4_reproduces_the_rigid_arm():
    # no damping at all, explicit RK4 at the automatic step (7.6 µs: 66 100 steps;
    # measured error 1.3e-7 rad)
    res = simulate(_stiff_two_link("cubic", integrator="rk4", beta=0.0), 0.5)
    err, _ = _joint_error(res)
    assert err < 1e-5, err
