"""State-space model of a scene about its initial state (``flexarm linearize``).

x = [q_free, q̇_free, z] (z: actuator states, e.g. armature current i — seed 001's
actuator-augmented form x = [Z, Ż, i]), u = the actuator inputs (torque N·m, voltage V or
valve current A, one per driven joint, in joint order), y = hub (joint) angles, beam tip
deflections and every declared sensor (encoders as continuous counts, accelerometers in
m/s², strain, potentiometer angle, tip position x/y). ``state_units``, ``input_units`` and
``output_units`` give the SI unit of each, aligned with the names.

The matrices are assembled from the model's parts, not by differencing the whole
right-hand side (a test does that, as the independent check):

    M δq̈ = −K_t δq − D_t δq̇ + B_z δz + B_u δu,      δż = Z_q̇ δq̇ + Z_z δz + Z_u δu,
    A = [[0, I, 0], [−M⁻¹K_t, −M⁻¹D_t, M⁻¹B_z], [0, Z_q̇, Z_z]],  B = [[0], [M⁻¹B_u], [Z_u]],

with K_t the tangent stiffness (elastic + gravity's geometric stiffness, plus the engaged
backlash springs, plus ∂(M q̈₀)/∂q when the start is not an equilibrium), D_t the damping
plus the drives' back-EMF damping n²K_tK_b/R (quasi-static current), and the drive
derivatives from :mod:`drives` (seed 000 Eq. 5.11; seed 001 Sec. 4; seed 002 Appendix B).
Inputs are linearized about u₀ = 0 (the hydraulic null bias is part of the model); the
state must be at rest (q̇ = 0), where the velocity-product terms have zero derivative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.model import drives
from flexarm_ros.errors import SceneError
from flexarm_ros.model.differentiate import jacobian
from flexarm_ros.model.linear import tangent_stiffness
from flexarm_ros.model.sensors import build_sensors
from flexarm_ros.model.statics import initial_state


@dataclass
class StateSpace:
    """ẋ = A x + B u, y = C x + D u (deviations from the operating point x0, u0 = 0)."""
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: list
    inputs: list
    outputs: list
    x0: np.ndarray
    state_units: list = field(default_factory=list)
    input_units: list = field(default_factory=list)
    output_units: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                "D": self.D.tolist(), "states": self.states, "inputs": self.inputs,
                "outputs": self.outputs, "x0": self.x0.tolist(),
                "state_units": self.state_units, "input_units": self.input_units,
                "output_units": self.output_units}


def zoh(A, B, dt: float):
    """(Φ, Γ): ẋ = A x + B u sampled exactly with u held over ``dt`` s — Φ = e^{A dt},
    Γ = ∫₀^dt e^{A s} ds B, the blocks of one matrix exponential of [[A, B], [0, 0]]·dt."""
    from scipy.linalg import expm
    n, m = B.shape
    E = np.zeros((n + m, n + m))
    E[:n, :n] = A * dt
    E[:n, n:] = B * dt
    F = expm(E)
    return F[:n, :n], F[:n, n:]


#: unit of an actuator input, by its kind
INPUT_UNITS = {"torque": "N·m", "voltage": "V", "current": "A"}
#: unit of a sensor output, by its kind (encoders as continuous counts)
SENSOR_UNITS = {"encoder": "counts", "potentiometer": "rad", "strain": "m/m",
                "tip_position": "m", "accelerometer": "m/s²"}


def _drive_derivatives(a, w, z):
    """(∂τ/∂w, ∂τ/∂z, ∂τ/∂u, ∂ż/∂w, ∂ż/∂z, ∂ż/∂u) of one actuator at u = 0."""
    p = a.par
    if a.kind == drives.IDEAL:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
    if a.kind in (drives.DC_QUASI_STATIC, drives.DC_CURRENT):
        n, kt = p[drives.DC_GEAR_RATIO], p[drives.DC_TORQUE_CONSTANT]
        kb, R = p[drives.DC_BACK_EMF_CONSTANT], p[drives.DC_RESISTANCE]
    if a.kind == drives.DC_QUASI_STATIC:
        i = (0.0 - kb * n * w) / R
        if abs(i) >= p[drives.DC_CURRENT_LIMIT]:    # at the current limit: no sensitivity
            return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        return -n * n * kt * kb / R, 0.0, n * kt / R, 0.0, 0.0, 0.0
    if a.kind == drives.DC_CURRENT:
        L = p[drives.DC_INDUCTANCE]
        return 0.0, n * kt, 0.0, -kb * n / L, -R / L, 1.0 / L
    D_m, eta = p[drives.HYD_DISPLACEMENT], p[drives.HYD_TORQUE_EFFICIENCY]
    ctm, kv = p[drives.HYD_LEAKAGE], p[drives.HYD_VALVE_GAIN]
    ps, vt, beta = p[drives.HYD_SUPPLY_PRESSURE], p[drives.HYD_TOTAL_VOLUME], \
        p[drives.HYD_BULK_MODULUS]
    i = 0.0 + p[drives.HYD_VALVE_BIAS]
    dp = ps - z if i >= 0.0 else ps + z
    gain = 4.0 * beta / vt
    root = math.sqrt(max(dp, 0.0))
    dq_di = kv * root
    dq_dp = -kv * abs(i) / (2.0 * root) if root > 0 else 0.0
    return 0.0, eta * D_m, 0.0, -gain * D_m, gain * (dq_dp - ctm), gain * dq_di


def linearize(chain, outputs: bool = True) -> StateSpace:
    """The linear model of ``chain`` about the scene's initial state (see module doc).
    ``outputs=False`` leaves C, D and the output names empty (A and B only: the automatic
    fidelity's analysis, :mod:`flexarm_ros.model.autofidelity`)."""
    q0, qd0, z0 = initial_state(chain)
    if np.any(qd0 != 0.0):
        moving = [chain.names[i] for i in np.nonzero(qd0)[0]]
        raise SceneError(f"linearize: got initial rates on {', '.join(moving)}, expected a "
                         f"state at rest (set the joints' initial_rate to 0)")
    free = chain.free
    nf, nz, na = len(free), chain.nz, len(chain.actuators)
    n = chain.n
    zero = np.zeros(n)
    kin = chain.kinematics(q0, zero)
    M = kin.M[np.ix_(free, free)]
    x0 = np.concatenate([q0[free], qd0[free], z0])
    qdd0 = chain.full_qdd(0.0, x0) if na == 0 else _qdd_zero_input(chain, q0, z0)
    # −∂(Q_g − h − K q)/∂q, all coords: at rest h = 0 to first order, so without gravity
    # K_t is the elastic K itself (as natural_modes takes it)
    Kt = tangent_stiffness(chain, q0) if chain.has_gravity else chain.K.copy()
    Dt = chain.D.copy()
    for im, ij, b, k, c in chain.backlash:                # engaged mesh springs
        if abs(q0[im] - q0[ij]) > b:
            blk = np.array([[1.0, -1.0], [-1.0, 1.0]])
            Kt[np.ix_([im, ij], [im, ij])] += k * blk
            Dt[np.ix_([im, ij], [im, ij])] += c * blk
    if np.max(np.abs(qdd0)) > 0.0:                        # not an equilibrium: ∂(M q̈₀)/∂q
        Kt += jacobian(lambda q: chain.kinematics(q, zero).M @ qdd0, q0)
    Bz = np.zeros((n, nz))
    Bu = np.zeros((n, na))
    Zw = np.zeros((nz, n))
    Zz = np.zeros((nz, nz))
    Zu = np.zeros((nz, na))
    for j, a in enumerate(chain.actuators):
        zj = z0[a.state] if a.state >= 0 else 0.0
        t_w, t_z, t_u, z_w, z_z, z_u = _drive_derivatives(a, qd0[a.coord], zj)
        Dt[a.coord, a.coord] -= t_w
        Bu[a.coord, j] += t_u
        if a.state >= 0:
            Bz[a.coord, a.state] += t_z
            Zw[a.state, a.coord] += z_w
            Zz[a.state, a.state] += z_z
            Zu[a.state, j] += z_u
    Minv = np.linalg.inv(M)
    ns = 2 * nf + nz
    A = np.zeros((ns, ns))
    B = np.zeros((ns, na))
    A[:nf, nf:2 * nf] = np.eye(nf)
    A[nf:2 * nf, :nf] = -Minv @ Kt[np.ix_(free, free)]
    A[nf:2 * nf, nf:2 * nf] = -Minv @ Dt[np.ix_(free, free)]
    A[nf:2 * nf, 2 * nf:] = Minv @ Bz[free]
    A[2 * nf:, nf:2 * nf] = Zw[:, free]
    A[2 * nf:, 2 * nf:] = Zz
    B[nf:2 * nf] = Minv @ Bu[free]
    B[2 * nf:] = Zu
    if outputs:
        C, D, names, out_units = _outputs(chain, q0, kin, A, B, nf, qdd0)
    else:
        C, D, names, out_units = np.zeros((0, ns)), np.zeros((0, na)), [], []
    inputs = [f"{chain.links[a.link].name}_{a.input_kind}" for a in chain.actuators]
    return StateSpace(A, B, C, D, chain.state_labels(), inputs, names, x0,
                      chain.state_units(), [INPUT_UNITS[a.input_kind] for a in chain.actuators],
                      out_units)


def _qdd_zero_input(chain, q0, z0):
    """q̈ at the initial state with every actuator input at zero."""
    saved = [(a.enc, a.program) for a in chain.actuators]
    from flexarm_ros.model.programs import encode
    from flexarm_ros.scene import Program
    for a in chain.actuators:
        a.enc = encode(Program(type="constant", value=0.0))
    try:
        qdd, _ = chain.dynamics(0.0, q0, np.zeros(chain.n), z0)
    finally:
        for a, (enc, prog) in zip(chain.actuators, saved):
            a.enc, a.program = enc, prog
    return qdd


def _outputs(chain, q0, kin, A, B, nf, qdd0):
    """Rows of C and D, names and units: hub angles, tip deflections, then every declared
    sensor."""
    free = chain.free
    n = chain.n
    ns, na = A.shape[0], B.shape[1]
    rows_c, rows_d, names, units = [], [], [], []

    def from_q(row_q):                       # output = row_q · q (positions only)
        c = np.zeros(ns)
        c[:nf] = row_q[free]
        rows_c.append(c)
        rows_d.append(np.zeros(na))

    for lm in chain.links:
        r = np.zeros(n)
        r[lm.i_joint] = 1.0
        from_q(r)
        names.append(f"{lm.name}_joint")
        units.append("rad")
    for lm in chain.links:
        r = np.zeros(n)
        r[lm.eta] = lm.beam.phi_tip
        from_q(r)
        names.append(f"{lm.name}_tip_deflection")
        units.append("m")
    g = chain.gravity
    for sm in build_sensors(chain):
        kind = sm.spec.kind
        units += [SENSOR_UNITS[kind]] * (2 if kind == "tip_position" else 1)
        if kind in ("encoder", "potentiometer"):
            r = np.zeros(n)
            r[sm.coord] = sm.gain if kind == "encoder" else 1.0
            from_q(r)
            names.append(sm.name)
        elif kind == "strain":
            r = np.zeros(n)
            r[chain.links[sm.link].eta] = sm.curvature
            from_q(r)
            names.append(sm.name)
        elif kind == "tip_position":
            J = kin.tip_frames[-1].Jo
            for k, ax in enumerate("xy"):
                from_q(J[k])
                names.append(f"{sm.name}_{ax}")
        else:   # accelerometer: e·(J q̈ − g), e turning with the frame angle ψ(q)
            _, J, _, psi = chain.point_kinematics(q0, np.zeros(n), sm.link, sm.spec.body,
                                                  sm.spec.position, basis=sm.basis)
            cs, sn = math.cos(psi), math.sin(psi)
            e = np.array([cs * sm.axis[0] - sn * sm.axis[1], sn * sm.axis[0] + cs * sm.axis[1]])
            Epe = np.array([-e[1], e[0]])               # ∂e/∂ψ
            dpsi = _point_angle_jacobian(chain, q0, sm)
            eJ = (e @ J)[free]
            c = eJ @ A[nf:2 * nf]
            c[:nf] += (-(g @ Epe)) * dpsi[free]
            if np.max(np.abs(qdd0)) > 0.0:    # not an equilibrium: ∂(e·J)/∂q · q̈₀
                c[:nf] += _moving_frame_term(chain, q0, sm, qdd0)[free]
            rows_c.append(c)
            rows_d.append(eJ @ B[nf:2 * nf])
            names.append(sm.name)
    C = np.array(rows_c).reshape(len(names), ns)
    D = np.array(rows_d).reshape(len(names), na)
    return C, D, names, units


def _moving_frame_term(chain, q0, sm, qdd0):
    """∂/∂q [e(ψ(q))ᵀ J(q)] q̈₀ at rest (central differences of the point kinematics): the
    accelerometer's sensitivity to configuration when the start is not an equilibrium."""
    zero = np.zeros(chain.n)

    def proj(q):
        _, J, _, psi = chain.point_kinematics(q, zero, sm.link, sm.spec.body,
                                              sm.spec.position, basis=sm.basis)
        cs, sn = math.cos(psi), math.sin(psi)
        e = np.array([cs * sm.axis[0] - sn * sm.axis[1], sn * sm.axis[0] + cs * sm.axis[1]])
        return e @ (J @ qdd0)

    return jacobian(proj, q0)


def _point_angle_jacobian(chain, q0, sm):
    """∂ψ/∂q of the sensor frame angle (linear in q: joint angles and slopes)."""
    n = chain.n
    zero = np.zeros(n)

    def psi(q):
        return chain.point_kinematics(q, zero, sm.link, sm.spec.body, sm.spec.position,
                                      basis=sm.basis)[3]

    # ψ is linear in q (sum of joint angles and φ′ᵀη): a unit difference is exact
    psi0 = psi(q0)
    return np.array([psi(q0 + e) - psi0 for e in np.eye(n)])
