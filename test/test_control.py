"""Control laws (flexarm_ros.control) against independent truths.

* Joint PD (seed 000 Eq. 5.16) and the static motor map (Eq. 5.17) against the DC-motor
  steady-state relation T = n K_t (V − K_b n q̇)/R written out here.
* Newton–Raphson inverse kinematics against forward kinematics and the closed-form
  two-link solution; unreachable and singular cases.
* Closed loop on an independent rigid two-link arm written in this file (Lagrange
  equations, integrated by scipy's solve_ivp) with quasi-static DC motors, the controller
  sampled with a zero-order hold, joint angles read through quantized motor-shaft
  encoders: seed 000's position demo (tip (1.15, 1.2) m → (1.0, 1.0) m) and a sanding pass
  on a penalty wall with Coulomb friction.
* The sanding state machine on a synthetic kinematic tool.

Geometry. Link lengths come from config/two_link_case1_geometry.yaml: l1 = hub radius + beam 1 +
joint-2 offset = 0.731452 m, l2 = hub radius + beam 2 + tool offset = 0.968548 m (reach
1.700 m, the middle of the window the source's own demo points and Fig. 5.24 allow; the
scene's assumptions). From a base at the world origin, as in the seed, the demo points are
reachable (|(1.15, 1.2)| = 1.662 m, |(1.0, 1.0)| = 1.414 m, sanding tip y up to 1.35 m on
x = −25 mm: 1.350 m; checked).

Gains of the closed-loop tests (not given in the source; chosen for a critically damped
~1 Hz joint response, well below the ~10 Hz beam modes): kp = (100, 50) N·m/rad,
kd = (26, 10) N·m·s/rad; control rate 200 Hz; encoder velocity low-pass 20 Hz; supply 24 V.
(They were (60, 25) and (20, 7) with every rigid-body offset at zero: reach 1.3075 m, the
tool at the beam-2 tip, l2 = 0.6575 m. The reach grew by 1.30 and the tool's lever about
joint 2 by 1.47, so kp by about their squares and kd by the ratios, which keeps the
stiffness and damping the tool feels.)
"""

import inspect
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from flexarm_ros.control import (EncoderVelocity, JointPD, JointPositionController, MotorVoltageMap, PlanarTwoLink, SandingTask)

#: the source's geometry (the gains below were tuned on it): the geometry-only arm, which
#: two_link_case1 was before it shipped the Case 1 calibration (issue 40: tool 0.3186 m,
#: reach 1.735 m)
CONFIG = Path(__file__).resolve().parents[1] / "config" / "two_link_case1_geometry.yaml"
KP = np.array([100.0, 50.0])        # N·m/rad ("spring_i" of Eq. 5.16)
KD = np.array([26.0, 10.0])         # N·m·s/rad ("damp_i")
CONTROL_DT = 0.005                  # s, 200 Hz
BASE = (0.0, 0.0)                   # m, the seed's Newtonian origin at joint 1
SUPPLY = 24.0                       # V


# ---------------------------------------------------------------------------- rig data
def _scene():
    return yaml.safe_load(CONFIG.read_text())


def _link_lengths(sc):
    """l1 = hub_radius + beam length + joint-2 offset along the link; l2 = hub_radius + beam
    length + the tool's offset along the link in RB4's frame (the tool point)."""
    a, b = sc["links"]
    l1 = (a["beam"].get("hub_radius", 0.0) + a["beam"]["length"]
          + a["tip"].get("joint_offset", [0.0, 0.0])[0])
    l2 = (b["beam"].get("hub_radius", 0.0) + b["beam"]["length"]
          + sc.get("tool", {}).get("position", [0.0, 0.0])[0])
    return l1, l2


class RigidArm:
    """Independent rigid two-link arm on a horizontal table (no gravity), relative joint
    angle q2, Lagrange's equations:

        M(q) q̈ + c(q, q̇) + C q̇ = τ + Jᵀ f,
        M11 = I_A + I_B + m_B l1² + 2 s_B l1 cos q2 + J1,  M12 = I_B + s_B l1 cos q2,
        M22 = I_B + J2,  h = s_B l1 sin q2,  c = [−h (2 q̇1 q̇2 + q̇2²), h q̇1²],

    link 1 about the base: I_A = I_hub1 + m_b1 (L1²/12 + (r1 + L1/2)²) + m_RB2 c2² + I_RB2;
    link 2 about joint 2: mass m_B = m_hub3 + m_b2 + m_RB4, first moment s_B =
    m_b2 (r3 + L2/2) + m_RB4 c4, I_B = I_hub3 + m_b2 (L2²/12 + (r3 + L2/2)²) + m_RB4 c4²
    + I_RB4 (beams as uniform rods from the hub rims r1, r3; the hubs centred on the joints;
    RB2's and RB4's CGs at c2 = r1 + L1 + cg2, c4 = r3 + L2 + cg4 along the links; the
    tool at l2); J_i, C_i the gearbox J_eq, C_eq. DC motors with quasi-static current: τ = n K_t (V − K_b n q̇)/R,
    V clipped to ±supply. Optional wall x = wall_x (free side x > wall_x): penalty normal
    force f_n = max(0, k δ + c δ̇), δ = wall_x − x_tip, and Coulomb friction
    −μ f_n tanh(ẏ/v_s) along y.
    """

    def __init__(self, sc, base=BASE, supply=SUPPLY):
        a, b = sc["links"]
        self.l1, self.l2 = _link_lengths(sc)
        self.base = np.asarray(base, dtype=float)
        mb1 = a["beam"]["mass_per_length"] * a["beam"]["length"]
        mb2 = b["beam"]["mass_per_length"] * b["beam"]["length"]
        L1, L2 = a["beam"]["length"], b["beam"]["length"]
        r1, r3 = a["beam"].get("hub_radius", 0.0), b["beam"].get("hub_radius", 0.0)
        assert a["hub"].get("cg", [0.0, 0.0]) == b["hub"].get("cg", [0.0, 0.0]) == [0.0, 0.0]
        c2 = r1 + L1 + a["tip"].get("cg", [0.0, 0.0])[0]
        c4 = r3 + L2 + b["tip"].get("cg", [0.0, 0.0])[0]
        self.IA = (a["hub"]["inertia"] + mb1 * (L1 ** 2 / 12 + (r1 + L1 / 2) ** 2)
                   + a["tip"]["mass"] * c2 ** 2 + a["tip"]["inertia"])
        self.mB = b["hub"]["mass"] + mb2 + b["tip"]["mass"]
        self.sB = mb2 * (r3 + L2 / 2) + b["tip"]["mass"] * c4
        self.IB = (b["hub"]["inertia"] + mb2 * (L2 ** 2 / 12 + (r3 + L2 / 2) ** 2)
                   + b["tip"]["mass"] * c4 ** 2 + b["tip"]["inertia"])
        self.J = [a["joint"]["drive_inertia"], b["joint"]["drive_inertia"]]
        self.C = [a["joint"]["drive_damping"], b["joint"]["drive_damping"]]
        d = [a["joint"]["drive"], b["joint"]["drive"]]
        self.n = [x["gear_ratio"] for x in d]
        self.Kt = [x["torque_constant"] for x in d]
        self.Kb = [x["back_emf_constant"] for x in d]
        self.R = [x["resistance"] for x in d]
        self.supply = supply
        self.wall = None            # (wall_x, k, c, mu, v_s)

    def motor_torque(self, V, qd):
        V = [min(max(v, -self.supply), self.supply) for v in V]
        return [self.n[i] * self.Kt[i] * (V[i] - self.Kb[i] * self.n[i] * qd[i]) / self.R[i]
                for i in range(2)]

    def tip(self, q):
        a, b = q[0], q[0] + q[1]
        return np.array([self.base[0] + self.l1 * math.cos(a) + self.l2 * math.cos(b),
                         self.base[1] + self.l1 * math.sin(a) + self.l2 * math.sin(b)])

    def contact(self, x):
        """(in_contact, normal force N, friction force N along y) at state x."""
        if self.wall is None:
            return False, 0.0, 0.0
        wall_x, k, c, mu, v_s = self.wall
        q1, q2, w1, w2 = x
        s1, c1, s12, c12 = math.sin(q1), math.cos(q1), math.sin(q1 + q2), math.cos(q1 + q2)
        xt = self.base[0] + self.l1 * c1 + self.l2 * c12
        delta = wall_x - xt
        if delta <= 0.0:
            return False, 0.0, 0.0
        xd = -self.l1 * s1 * w1 - self.l2 * s12 * (w1 + w2)
        yd = self.l1 * c1 * w1 + self.l2 * c12 * (w1 + w2)
        fn = max(0.0, k * delta - c * xd)
        return True, fn, -mu * fn * math.tanh(yd / v_s)

    def rhs(self, t, x, V):
        q1, q2, w1, w2 = x
        c2, s2 = math.cos(q2), math.sin(q2)
        m11 = self.IA + self.IB + self.mB * self.l1 ** 2 + 2 * self.sB * self.l1 * c2 + self.J[0]
        m12 = self.IB + self.sB * self.l1 * c2
        m22 = self.IB + self.J[1]
        h = self.sB * self.l1 * s2
        tau = self.motor_torque(V, (w1, w2))
        f1 = tau[0] + h * (2 * w1 * w2 + w2 * w2) - self.C[0] * w1
        f2 = tau[1] - h * w1 * w1 - self.C[1] * w2
        if self.wall is not None:
            on, fn, ft = self.contact(x)
            if on:   # generalized forces Jᵀ f of the tip force (fn along +x, ft along y)
                s1, c1, s12, c12 = math.sin(q1), math.cos(q1), math.sin(q1 + q2), math.cos(q1 + q2)
                f1 += (-self.l1 * s1 - self.l2 * s12) * fn + (self.l1 * c1 + self.l2 * c12) * ft
                f2 += -self.l2 * s12 * fn + self.l2 * c12 * ft
        det = m11 * m22 - m12 * m12
        return [w1, w2, (m22 * f1 - m12 * f2) / det, (m11 * f2 - m12 * f1) / det]


def _encoder_angles(q, n, counts_per_motor_rev=2000):
    """Joint angles as read by motor-shaft encoders (HEDS 5540/5500: 500 lines × 4)."""
    res = 2.0 * math.pi / (counts_per_motor_rev * np.asarray(n, dtype=float))
    return np.round(np.asarray(q) / res) * res


def _controller(arm, supply=SUPPLY, cutoff_hz=20.0):
    motor = MotorVoltageMap(arm.n, arm.Kt, arm.Kb, arm.R, supply)
    return JointPositionController(JointPD(KP, KD), motor, EncoderVelocity(cutoff_hz))


def _step(arm, x, t, dt, V):
    sol = solve_ivp(arm.rhs, (t, t + dt), x, args=(V,), rtol=1e-8, atol=1e-10)
    assert sol.success, sol.message
    return sol.y[:, -1]


# ---------------------------------------------------------------------------- package
@pytest.mark.subprocess
def test_control_imports_without_rclpy_and_documents_its_api():
    code = ("import sys; sys.modules['rclpy'] = None; import flexarm_ros.control; "
            "assert not any(m.startswith('rclpy') and sys.modules[m] is not None "
            "for m in sys.modules); print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr
    import flexarm_ros.control as ctl
    for name in ctl.__all__:
        obj = getattr(ctl, name)
        assert inspect.getdoc(obj), name
        for meth, fn in inspect.getmembers(obj, inspect.isfunction):
            if not meth.startswith("_"):
                assert inspect.getdoc(fn), f"{name}.{meth}"
    assert "Eq. 5.16" in ctl.JointPD.__doc__ and "Eq. 5.17" in ctl.MotorVoltageMap.voltage.__doc__


# ---------------------------------------------------------------------------- PD + motor
def test_pd_torque_formula_and_sign():
    pd = JointPD([60.0, 25.0], [20.0, 7.0])
    q, qd, qc = np.array([0.3, -0.2]), np.array([0.5, -1.0]), np.array([0.1, 0.1])
    np.testing.assert_allclose(pd.torque(q, qd, qc), [-20 * 0.5 - 60 * 0.2, 7.0 - 25 * (-0.3)],
                               rtol=0, atol=1e-14)
    # restoring: above the command → negative torque; moving → opposing torque
    assert np.all(pd.torque([1.0, 1.0], [0, 0], [0, 0]) < 0)
    assert np.all(pd.torque([0.0, 0.0], [1.0, 1.0], [0, 0]) < 0)
    # commanded rate: tracking error in rate only
    np.testing.assert_allclose(pd.torque(qc, [0.4, 0.4], qc, qd_cmd=[0.4, 0.4]), 0.0, atol=0)
    assert pd.torque(qc, qd, qc).tolist() == (-pd.kd * qd).tolist()
    with pytest.raises(ValueError, match="kp"):
        JointPD([-1.0, 1.0], [1.0, 1.0])


def test_voltage_map_inverts_the_static_motor_equation():
    sc = _scene()
    d = [ln["joint"]["drive"] for ln in sc["links"]]
    n, Kt, Kb, R = (np.array([x[k] for x in d]) for k in
                    ("gear_ratio", "torque_constant", "back_emf_constant", "resistance"))
    m = MotorVoltageMap(n, Kt, Kb, R)
    rng = np.random.default_rng(0)
    for _ in range(20):
        T, w = rng.uniform(-20, 20, 2), rng.uniform(-2, 2, 2)
        V = m.voltage(T, w)
        np.testing.assert_allclose(V, R / (Kt * n) * T + Kb * n * w, rtol=1e-14)   # Eq. 5.17
        T_back = n * Kt * (V - Kb * n * w) / R          # steady-state DC motor, independent
        np.testing.assert_allclose(T_back, T, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(m.torque(V, w), T, rtol=1e-12, atol=1e-12)
        assert not m.saturated.any()
    np.testing.assert_allclose(m.back_emf_damping, Kt * Kb * n ** 2 / R)


def test_voltage_clipping_flags():
    m = MotorVoltageMap([156.0, 236.0], [0.0302, 0.0258], [0.0302, 0.0258], [1.085, 4.44],
                        supply_voltage=[12.0, 6.0])
    V = m.voltage([100.0, -0.1], [0.0, 0.0])
    assert V.tolist() == [12.0, pytest.approx(-0.1 * 4.44 / (0.0258 * 236))]
    assert m.saturated.tolist() == [True, False]
    assert m.unclipped[0] > 12.0
    V = m.voltage([-100.0, 100.0], [0.0, 0.0])
    assert V.tolist() == [-12.0, 6.0] and m.saturated.tolist() == [True, True]
    # the controller reports the same flags
    ctrl = JointPositionController(JointPD([60.0, 25.0], [20.0, 7.0], motor=m))
    ctrl.update(0.0, 0.005, [0.0, 0.0], [0.0, 0.0], [1.0, -0.001])
    assert ctrl.saturated.tolist() == [True, False]
    with pytest.raises(ValueError, match="qd_meas"):
        ctrl.update(0.0, 0.005, [0.0, 0.0], None, [0.0, 0.0])


def test_encoder_velocity_filter():
    """Quantized ramp q = w t: the filtered rate converges to w (first-order lag, exact
    discretization), the error of a constant-rate ramp decays as exp(−2π f_c t)."""
    res, w, dt, fc = 2 * math.pi / (2000 * 156), 0.5, 0.001, 20.0
    ev = EncoderVelocity(fc)
    assert ev.update(0.0, dt, [0.0]).tolist() == [0.0]
    qd = None
    for k in range(1, 501):
        t = k * dt
        qd = ev.update(t, dt, np.round(np.array([w * t]) / res) * res)
    assert abs(qd[0] - w) < 2 * math.pi * fc * res + 1e-6 * w
    # unfiltered backward difference on exact data, and the lag of the filter
    plain = EncoderVelocity(None)
    plain.update(0.0, dt, [0.0])
    assert plain.update(dt, dt, [w * dt])[0] == pytest.approx(w)
    ev = EncoderVelocity(fc)
    ev.update(0.0, dt, [0.0])
    out = [ev.update(k * dt, dt, [w * k * dt])[0] for k in range(1, 11)]
    assert out[-1] == pytest.approx(w * (1 - math.exp(-2 * math.pi * fc * 10 * dt)), rel=1e-12)
    with pytest.raises(ValueError, match="dt"):
        ev.update(1.0, 0.0, [0.0])


# ---------------------------------------------------------------------------- kinematics
@pytest.fixture(scope="module")
def kin():
    return PlanarTwoLink(*_link_lengths(_scene()), base=BASE)


def test_forward_and_jacobian(kin):
    rng = np.random.default_rng(1)
    for q in rng.uniform(-3, 3, (20, 2)):
        J = kin.jacobian(q)
        h = 1e-6
        Jfd = np.column_stack([(kin.forward(q + h * e) - kin.forward(q - h * e)) / (2 * h)
                               for e in np.eye(2)])
        np.testing.assert_allclose(J, Jfd, atol=1e-8)
        assert np.linalg.det(J) == pytest.approx(kin.l1 * kin.l2 * math.sin(q[1]), abs=1e-12)
    np.testing.assert_allclose(kin.forward([0.0, 0.0]), [BASE[0] + kin.r_max, BASE[1]])


@pytest.mark.parametrize("elbow", ["up", "down"])
def test_inverse_round_trip_and_closed_form(kin, elbow):
    n_ok = 0
    for r in np.linspace(kin.r_min + 0.02, kin.r_max - 0.02, 9):
        for phi in np.linspace(-math.pi, math.pi, 13)[:-1]:
            p = kin.base + r * np.array([math.cos(phi), math.sin(phi)])
            ref = kin.analytic_inverse(p, elbow)
            assert ref.success
            # start away from the solution, on the wanted side
            guess = ref.q + np.array([0.3, -0.3 if elbow == "down" else 0.3])
            res = kin.inverse(p, guess, elbow=elbow)
            assert res.success, res.message
            assert res.iterations <= 50
            np.testing.assert_allclose(kin.forward(res.q), p, rtol=0, atol=1e-10)
            dq = (res.q - ref.q + math.pi) % (2 * math.pi) - math.pi
            np.testing.assert_allclose(dq, 0.0, atol=1e-8)
            assert (res.q[1] <= 0) if elbow == "up" else (res.q[1] >= 0)
            n_ok += 1
    assert n_ok == 9 * 12


def test_closed_form_is_independent_law_of_cosines(kin):
    p = np.array([1.0, 1.0])
    d = p - kin.base
    r2 = d @ d
    q2 = math.acos((r2 - kin.l1 ** 2 - kin.l2 ** 2) / (2 * kin.l1 * kin.l2))
    beta = math.acos((r2 + kin.l1 ** 2 - kin.l2 ** 2) / (2 * kin.l1 * math.sqrt(r2)))
    phi = math.atan2(d[1], d[0])
    np.testing.assert_allclose(kin.analytic_inverse(p, "down").q, [phi - beta, q2], atol=1e-12)
    np.testing.assert_allclose(kin.analytic_inverse(p, "up").q, [phi + beta, -q2], atol=1e-12)


def test_unreachable_targets_fail_with_a_message(kin):
    for p in [(1.15, 1.2), (1.0, 1.0), (-0.025, 1.35)]:        # the seed's points: reachable
        assert kin.reachable(p, margin=0.01)
    origin = PlanarTwoLink(kin.l1, kin.l2)
    for p in [(1.4, 1.0), (-0.025, 1.75), (0.0, -1.71)]:        # beyond the 1.700 m reach
        res = origin.inverse(p, (0.5, 0.5))
        assert not res.success and np.all(np.isfinite(res.q))
        assert "unreachable" in res.message and "annulus" in res.message
        assert f"({p[0]:.6g}, {p[1]:.6g})" in res.message
        assert f"{math.hypot(*p):.6g} m" in res.message
    inner = kin.base + np.array([0.001, 0.0])                   # inside |l1 − l2| = 237 mm
    res = kin.inverse(inner, (0.0, 2.0))
    assert not res.success and "unreachable" in res.message and "inner" in res.message
    assert np.all(np.isfinite(res.q)) and math.isfinite(res.residual)
    res = kin.inverse((math.nan, 1.0), (0.0, 0.0))
    assert not res.success and np.all(np.isfinite(res.q)) and "finite" in res.message
    assert not kin.analytic_inverse((5.0, 5.0), "up").success


def test_singular_starts_converge(kin):
    # straight arm, target closer in on the same ray: Jᵀe = 0, the plain Newton step fails
    for q0, r in [((0.4, 0.0), 1.0), ((0.4, 0.0), 0.3), ((1.0, math.pi), 0.9)]:
        p = kin.base + r * np.array([math.cos(q0[0]), math.sin(q0[0])])
        for elbow in (None, "up", "down"):
            res = kin.inverse(p, q0, elbow=elbow)
            assert res.success, (q0, r, elbow, res.message)
            np.testing.assert_allclose(kin.forward(res.q), p, atol=1e-10)
            if elbow is not None:
                assert (res.q[1] < 0) == (elbow == "up")
    # straight arm, target elsewhere (damped least squares near the singularity)
    res = kin.inverse((1.15, 1.2), (0.0, 0.0))
    assert res.success and res.residual <= 1e-10
    # a target on the outer edge of the workspace (singular solution)
    p = kin.base + kin.r_max * np.array([math.cos(0.7), math.sin(0.7)])
    res = kin.inverse(p, (0.2, 0.5))
    assert res.success, res.message
    np.testing.assert_allclose(res.q, [0.7, 0.0], atol=1e-4)


# ---------------------------------------------------------------------------- closed loop
def test_position_demo_settles():
    """Seed 000 Sec. 5.6.3 position demo on the independent rigid arm: tool point from
    (1.15, 1.2) m to (1.0, 1.0) m through Newton–Raphson IK and Eq. 5.16/5.17 at 200 Hz
    with encoder-derived rates. Settles within 1 mm by 2.5 s and stays there; no overshoot
    of the joint angles beyond 1 % of the step; the motors stay below the 24 V supply."""
    sc = _scene()
    arm = RigidArm(sc)
    kin = PlanarTwoLink(arm.l1, arm.l2, base=BASE)
    start, goal = np.array([1.15, 1.2]), np.array([1.0, 1.0])
    assert kin.reachable(start, margin=0.01) and kin.reachable(goal, margin=0.01)
    q0 = kin.inverse(start, (0.5, 0.5)).q
    ik = kin.inverse(goal, q0)
    assert ik.success
    ctrl = _controller(arm)
    x, t, dt = np.array([*q0, 0.0, 0.0]), 0.0, CONTROL_DT
    ts, err, qs, vmax = [], [], [], 0.0
    while t < 3.5 - 1e-9:
        V = ctrl.update(t, dt, _encoder_angles(x[:2], arm.n), None, ik.q)
        assert not ctrl.saturated.any()
        vmax = max(vmax, float(np.abs(V).max()))
        x = _step(arm, x, t, dt, V)
        t += dt
        ts.append(t)
        err.append(float(np.hypot(*(arm.tip(x[:2]) - goal))))
        qs.append(x[:2].copy())
    ts, err, qs = np.array(ts), np.array(err), np.array(qs)
    assert err[0] > 0.2                                     # it did move from the start
    late = ts >= 2.5
    assert err[late].max() < 1e-3, err[late].max()          # settled: 1 mm from 2.5 s on
    assert err[-1] < 1e-4
    # no sustained oscillation: error non-increasing over the last second (within encoder
    # quantization), joint rates small
    tail = err[ts >= 2.5]
    assert np.all(np.diff(tail) < 2e-5)
    assert np.abs(x[2:]).max() < 1e-3
    step = ik.q - q0
    overshoot = ((qs - ik.q) * np.sign(step)).max(axis=0)     # past the command, rad
    assert np.all(overshoot <= 0.01 * np.abs(step) + 1e-5), overshoot
    assert vmax < SUPPLY


def test_position_demo_with_a_low_supply_saturates_and_still_settles():
    """With a 6 V supply the middle motor saturates early on (flagged), the arm still
    reaches the goal (slower) — the clipping keeps the law bounded."""
    arm = RigidArm(_scene(), supply=6.0)
    kin = PlanarTwoLink(arm.l1, arm.l2, base=BASE)
    q0 = kin.inverse((1.15, 1.2), (0.5, 0.5)).q
    qc = kin.inverse((1.0, 1.0), q0).q
    ctrl = _controller(arm, supply=6.0)
    x, t, dt, sat = np.array([*q0, 0.0, 0.0]), 0.0, 0.01, np.zeros(2, dtype=bool)
    while t < 4.0 - 1e-9:
        V = ctrl.update(t, dt, _encoder_angles(x[:2], arm.n), None, qc)
        sat |= ctrl.saturated
        assert np.all(np.abs(V) <= 6.0)
        x = _step(arm, x, t, dt, V)
        t += dt
    assert sat.any()
    assert np.hypot(*(arm.tip(x[:2]) - np.array([1.0, 1.0]))) < 1e-3


# ---------------------------------------------------------------------------- sanding
def _sanding_task(**kw):
    args = dict(wall_x=-0.025, y_start=1.05, y_end=1.30, speed=0.1, normal_force=10.0,
                approach_from=(0.2, 0.95), approach_time=1.0, kp_force=1e-3, strokes=2,
                offset_max=0.01, press_time=0.1, reverse_time=0.1, lift_distance=0.05,
                lift_time=0.5)
    args.update(kw)
    return SandingTask(**args)


def _run_kinematic_tool(task, k_wall=2.0e4, slope=0.0, t_end=10.0, dt=1e-3):
    """Tool follows the target exactly; wall x_w(y) = wall_x + slope (y − 1.05) (the task
    knows only wall_x); contact when x <= x_w, force k·penetration."""
    tip, log = np.asarray(task.approach_from, float).copy(), []
    t = 0.0
    while t <= t_end:
        xw = task.wall_x + slope * (tip[1] - 1.05)
        pen = xw - tip[0]
        F = k_wall * pen if pen >= 0 else 0.0
        target, phase = task.update(t, dt, tip, pen >= 0, F)
        log.append((t, phase, target[0], target[1], F))
        tip = target
        if phase == "done":
            break
        t += dt
    return log


@pytest.mark.parametrize("slope", [0.0, 0.004])
def test_sanding_phases_on_a_kinematic_tool(slope):
    task = _sanding_task()
    log = _run_kinematic_tool(task, slope=slope)
    phases = [p for _, p in task.transitions]
    assert phases == ["approach", "press", "slide_forward", "reverse", "slide_back",
                      "lift_off", "done"], phases
    assert task.message == "" and task.strokes_done == 2
    ph = np.array([r[1] for r in log])
    y = np.array([r[3] for r in log])
    x = np.array([r[2] for r in log])
    F = np.array([r[4] for r in log])
    fwd, back = ph == "slide_forward", ph == "slide_back"
    # reverses at the ends: forward reaches y_end, back returns to y_start, monotonic
    assert y[fwd].max() == pytest.approx(1.30) and np.all(np.diff(y[fwd]) >= 0)
    assert np.all(np.diff(y[back]) <= 0) and y[back].min() < 1.06
    assert y[np.argmax(ph == "lift_off")] == pytest.approx(1.05)   # the back stroke's end
    assert np.all(y[ph == "reverse"] == pytest.approx(1.30))
    # force within ±20 % of the set point throughout both slides (and ±5 % when flat)
    slides = fwd | back
    band = 0.05 if slope == 0.0 else 0.2
    assert np.all(np.abs(F[slides] - 10.0) <= band * 10.0), (F[slides].min(), F[slides].max())
    # the command stays behind the wall by the force-law offset, within its clip
    assert np.all(np.abs(x[slides] + 0.025) <= 0.01)
    if slope == 0.0:
        assert np.all(x[slides] <= -0.025)
    # lift-off retreats to wall_x + lift_distance and ends out of contact
    assert x[-1] == pytest.approx(-0.025 + 0.05) and F[-1] == 0.0


def test_sanding_strokes_and_failures():
    task = _sanding_task(strokes=3, reverse_time=0.0)
    _run_kinematic_tool(task, t_end=20.0)
    assert [p for _, p in task.transitions] == [
        "approach", "press", "slide_forward", "reverse", "slide_back", "reverse",
        "slide_forward", "lift_off", "done"]
    # no wall at all: the search times out and the task lifts off with a message
    task = _sanding_task(search_timeout=0.5)
    t, dt = 0.0, 1e-3
    while task.phase != "done" and t < 5.0:
        task.update(t, dt, (0.0, 0.0), False, 0.0)
        t += dt
    assert task.phase == "done" and "no contact" in task.message
    with pytest.raises(ValueError, match="speed"):
        _sanding_task(speed=0.0)


@pytest.mark.heavy
def test_sanding_closed_loop_on_the_rigid_arm():
    """Whole chain on the rigid arm: SandingTask → Newton–Raphson IK → Eq. 5.16/5.17 at
    200 Hz → quasi-static motors → arm against a penalty wall x = −25 mm (k = 2e4 N/m,
    c = 50 N·s/m) with Coulomb friction μ = 0.5 (seed 000 Appendix C; tanh regularised at
    20 mm/s). Commanded stroke y = 1.0 → 1.3 m and back at 0.15 m/s, 5 N set point,
    kp_force = 0.05 m/(N·s). Checked: the phases in order, contact kept through both
    strokes, the tool reverses along the wall, and the normal force within ±20 % of 5 N
    once each stroke is under way (the first 0.8 s after a turn-around, where friction
    reverses and the arm's lag in y is taken up, is excluded)."""
    arm = RigidArm(_scene())
    arm.wall = (-0.025, 2.0e4, 50.0, 0.5, 0.02)
    kin = PlanarTwoLink(arm.l1, arm.l2, base=BASE)
    start = np.array([0.2, 0.95])
    for p in [(-0.3, 1.0), (-0.3, 1.3), start]:
        assert kin.reachable(p, margin=0.01)
    q0 = kin.inverse(start, (0.5, 1.5), elbow="down").q
    task = SandingTask(wall_x=-0.025, y_start=1.0, y_end=1.3, speed=0.15, normal_force=5.0,
                       approach_from=start, approach_time=1.0, kp_force=0.05, strokes=2,
                       offset_max=0.2, search_speed=0.05, press_time=0.2, reverse_time=0.2,
                       lift_time=0.5, force_tolerance=0.1)
    ctrl = _controller(arm)
    x, t, dt, q_cmd = np.array([*q0, 0.0, 0.0]), 0.0, CONTROL_DT, q0.copy()
    log = []
    while t < 12.0 and task.phase != "done":
        on, fn, _ = arm.contact(x)
        tip = arm.tip(x[:2])
        target, phase = task.update(t, dt, tip, on, fn)
        ik = kin.inverse(target, q_cmd)
        assert ik.success, ik.message
        q_cmd = ik.q
        V = ctrl.update(t, dt, _encoder_angles(x[:2], arm.n), None, q_cmd)
        log.append((t, phase, tip[0], tip[1], fn, on))
        x = _step(arm, x, t, dt, V)
        t += dt
    assert task.phase == "done"
    tr = dict((p, tt) for tt, p in task.transitions)
    assert [p for _, p in task.transitions] == ["approach", "press", "slide_forward",
                                                "reverse", "slide_back", "lift_off", "done"]
    ts, ph = np.array([r[0] for r in log]), np.array([r[1] for r in log])
    tip_y, F, on = (np.array([r[k] for r in log]) for k in (3, 4, 5))
    slides = (ph == "slide_forward") | (ph == "slide_back")
    assert on[slides].all()                                   # slid, never left the wall
    steady = (((ph == "slide_forward") & (ts > tr["slide_forward"] + 0.8))
              | ((ph == "slide_back") & (ts > tr["slide_back"] + 0.8)))
    assert steady.sum() > 300
    assert np.all(np.abs(F[steady] - 5.0) <= 1.0), (F[steady].min(), F[steady].max())
    # the tool went up the wall and came back down (lagging the command through friction)
    i_top = int(np.argmax(tip_y))
    assert tip_y[i_top] > 1.25 and tip_y[i_top:][ph[i_top:] == "lift_off"][0] < 1.2


def test_sanding_limits_from_the_scene_reach_the_task_and_bad_ones_are_named():
    """The sanding task's limits are scene keys (control.sanding.*): given values reach
    the controller's task; an invalid one is refused naming the key and the bound."""
    from flexarm_ros.errors import SceneError
    from flexarm_ros.scene import load_scene_dict, resolve_scene_path
    from flexarm_ros.twin.cores import ControllerCore
    data = yaml.safe_load(resolve_scene_path("two_link_sanding").read_text())
    data["control"]["sanding"].update({"offset_max": 0.03, "press_timeout": 4.0,
                                       "lift_distance": 0.08, "force_tolerance": 0.2})
    task = ControllerCore(load_scene_dict(data)).task
    assert (task.offset_max, task.press_timeout, task.lift_distance,
            task.force_tolerance) == (0.03, 4.0, 0.08, 0.2)
    assert task.offset_min == -0.03
    data["control"]["sanding"]["press_timeout"] = -1.0
    with pytest.raises(SceneError, match=r"press_timeout.*-1.*> 0"):
        load_scene_dict(data)
