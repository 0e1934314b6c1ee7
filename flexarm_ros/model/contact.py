"""Contact of the tool with a wall: impulse–constraint (seed 000) and compliant rungs.

Gap and contact Jacobians (docs/physics.md §8.1): the tool point r (fixed in the last tip
frame) has gap g = n·(r − p_wall) ≥ 0, normal and tangential Jacobians J_n = nᵀJ, J_t = tᵀJ
(t = E n), velocities v_n = J_n q̇, v_t = J_t q̇, and r̈ = J q̈ + c.

**Impulse–constraint rung** (seed 000 Ch. 4, Hariharesan 1998): three smooth modes and
the events between them, located on the step by root finding:

* free: M q̈ = f. Event g → 0⁻ : impact.
* impact (instantaneous, positions fixed): generalized impulse–momentum
  M(q̇⁺ − q̇⁻) = J_nᵀP_n + J_tᵀP_t with the tool held on the wall, J_n q̇⁺ = 0 (no
  restitution coefficient: a flexible arm bounces because its beams rebound). The
  friction impulse follows Coulomb's law by maximum dissipation (Moreau): the impulse in
  the cone |P_t| ≤ μ P_n that minimizes the post-impact kinetic energy — sticking
  (J_t q̇⁺ = 0) when |P_t| ≤ μ_s P_n suffices, else sliding at the cone's edge against the
  slip. Energy never increases (P_t = 0 is feasible and already dissipative), which avoids
  Kane's frictional-impact paradox of a fixed-direction sliding impulse.
* sliding: M q̈ = f + (J_n − μ s J_t)ᵀ λ, J_n q̈ = −c_n; λ ≥ 0 the normal force,
  friction −μ λ s (s = sign v_t). Events: λ → 0⁻ (separation), v_t → 0 (stick or keep
  slipping), d = G_nn − μ s G_nt → 0⁻ (Painlevé: a tangential impact, below).
* tangential impact (Painlevé's case, Génot & Brogliato 1999): where sliding has no
  consistent normal force (d ≤ 0) the contact jams — an impulse at zero approach speed,
  the impact law above with v_n = 0, which stops the slip with P_n > 0 and |P_t| ≤ μ P_n
  (d ≤ 0 puts the sticking impulse inside the cone); then sticking or separation.
* sticking: M q̈ = f + J_nᵀλ + J_tᵀλ_t, J_n q̈ = −c_n, J_t q̈ = −c_t. Events: λ → 0⁻,
  |λ_t| → μ_s λ (slip starts against λ_t).

While in contact the state is projected back onto g = 0, v_n = 0 (and v_t = 0 when
sticking) after every step (M-orthogonal projection); a step that drifted more than
``fidelity.contact_tolerance`` is retaken with half the step (kept while in contact). A re-impact within ``MIN_FLIGHT`` of a separation keeps
the contact (a burst of impacts goes to sliding instead of stalling the integrator).

**Compliant rung**: no events; a penalty force F_n = max(0, k δ^e + c δ̇) for
penetration δ = −g > 0 with c = 2ζ√(k_eff m_eff) (m_eff = 1/G_nn, G_nn = J_n M⁻¹ J_nᵀ at
the start; ζ = 1 by default: no contact rebound, as the impulse rung) and regularized
Coulomb friction −μ F_n v_t/√(v_t² + v_s²) enter the equations of motion as
J_nᵀF_n + J_tᵀF_t. Cheap per step, stiff: the automatic step follows the contact's
eigenvalue ω(ζ + √(ζ² − 1)), ω = √(k_eff G_nn), known before the run (why not a
Hunt–Crossley damping c ∝ δ^e: docs/decisions/0003-compliant-contact-with-fixed-damping.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled.layout import Workspace
from flexarm_ros.model.differentiate import jacobian

FREE, SLIDING, STICKING = 0, 1, 2
PHASES = ("free", "sliding", "sticking", "impact")
PHASE_CODE = {name: k for k, name in enumerate(PHASES)}
MIN_FLIGHT = 1e-6          # s: a re-impact sooner than this after separation keeps contact
MIN_DEPTH = 1e-3           # m: depth at which a compliant wall's stiffness is taken, at least
_E = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass
class Terms:
    """Everything one model evaluation gives at (t, x): free-coordinate mass matrix and
    forces, actuator rates, and the tool's kinematics (J, c on the free coordinates)."""
    M: np.ndarray
    f: np.ndarray
    zd: np.ndarray
    r: np.ndarray
    J: np.ndarray
    c: np.ndarray
    v: np.ndarray


@dataclass
class ImpactRecord:
    """One impact: time, impulses (N·s), approach speed, kinetic energy before/after."""
    time: float
    normal_impulse: float
    friction_impulse: float
    approach_speed: float
    kinetic_before: float
    kinetic_after: float
    outcome: str            # sticking / sliding / bounce


class WallContact:
    """The tool–wall contact of a chain (one wall)."""

    def __init__(self, chain, wall, tool, method: str):
        self.chain = chain
        self.wall = wall
        self.method = method
        n = np.asarray(wall.normal, float)
        self.n = n / np.linalg.norm(n)
        self.t = _E @ self.n
        self.d = float(self.n @ np.asarray(wall.point, float))
        self.mu = wall.friction
        self.mus = wall.mu_static
        self.p = np.asarray(tool.position, float)
        self.kernel_args = chain.kernel_args
        self.ws = kchain.workspace(self.kernel_args)
        self.free = chain.free
        self.nf = len(chain.free)
        self.c_contact = 0.0       # compliant damping, set from the start (set_start)

    def set_start(self, x0) -> float:
        """Fix the compliant damping c = 2ζ√(k_eff m_eff) at the start state; returns the
        contact's largest rate |λ| (1/s) for the automatic step."""
        k_eff, Gnn = self.spring(self.terms(0.0, x0), 0.0)
        zeta = self.wall.damping_ratio
        self.c_contact = 2.0 * zeta * math.sqrt(k_eff / Gnn)
        return spring_damper_rate(math.sqrt(k_eff * Gnn), zeta)

    def spring(self, tm, depth):
        """(k_eff, G_nn) of the compliant wall with the tool ``depth`` (m) inside it, at
        least MIN_DEPTH (a Hertz-type law's stiffness vanishes at first touch): the tangent
        stiffness k_eff = p·k·δ^(p−1) and the tool's inverse effective mass along the
        normal, G_nn = j_nᵀM⁻¹j_n, at the configuration of ``tm``."""
        jn = self.n @ tm.J
        Gnn = float(jn @ np.linalg.solve(tm.M, jn))
        w = self.wall
        k_eff = w.exponent * w.stiffness * max(depth, MIN_DEPTH) ** (w.exponent - 1.0)
        return k_eff, Gnn

    # --------------------------------------------------------------------- evaluation
    def terms(self, t, x) -> Terms:
        """One compiled force evaluation plus the tool kinematics from the last tip frame."""
        ch, ws, nf = self.chain, self.ws, self.nf
        q, qd = ch.full_state(t, x)
        kchain.forces(float(t), q, qd, x[2 * nf:], self.kernel_args, ws)
        ws = Workspace._make(ws)
        fr = self.free
        M = ws.M[np.ix_(fr, fr)]
        f = ws.f[fr].copy()
        zd = ws.zd[:ch.nz].copy()
        o = ws.tip[0:2]
        co = ws.tip[2:4]
        psi, psid = ws.tip[4], ws.tip[5]
        cs, sn = math.cos(psi), math.sin(psi)
        ap = np.array([cs * self.p[0] - sn * self.p[1], sn * self.p[0] + cs * self.p[1]])
        Jfull = ws.Jo + np.outer(_E @ ap, ws.Jpsi)
        c = co - psid * psid * ap
        if len(ch.presc_idx):
            c = c + Jfull[:, ch.presc_idx] @ ws.pdd[:len(ch.presc_idx)]
        return Terms(M, f, zd, o + ap, Jfull[:, fr].copy(), c, Jfull @ qd)

    def gap(self, tm: Terms) -> float:
        return float(self.n @ tm.r - self.d)

    # ------------------------------------------------------------------- accelerations
    def accelerations(self, tm: Terms, mode: int, s: float = 0.0):
        """(q̈_free, λ_n, λ_t) in a mode: λ_n the normal force (N), λ_t the tangential
        force (N) — friction −μλs when sliding, the holding force when sticking."""
        M, f = tm.M, tm.f
        if mode == FREE:
            return np.linalg.solve(M, f), 0.0, 0.0
        jn = self.n @ tm.J
        cn = self.n @ tm.c
        nf = self.nf
        if mode == SLIDING:
            jt = self.t @ tm.J
            A = np.zeros((nf + 1, nf + 1))
            A[:nf, :nf] = M
            A[:nf, nf] = -(jn - self.mu * s * jt)
            A[nf, :nf] = jn
            sol = _solve_kkt(A, np.concatenate([f, [-cn]]))
            lam = sol[nf]
            return sol[:nf], lam, -self.mu * s * lam
        jt = self.t @ tm.J
        ct = self.t @ tm.c
        A = np.zeros((nf + 2, nf + 2))
        A[:nf, :nf] = M
        A[:nf, nf] = -jn
        A[:nf, nf + 1] = -jt
        A[nf, :nf] = jn
        A[nf + 1, :nf] = jt
        sol = _solve_kkt(A, np.concatenate([f, [-cn, -ct]]))
        return sol[:nf], sol[nf], sol[nf + 1]

    def compliant_force(self, tm: Terms):
        """(F_n, F_t) of the compliant rung at the tool."""
        g = self.gap(tm)
        if g >= 0.0:
            return 0.0, 0.0
        w = self.wall
        delta = -g
        ddelta = -(self.n @ tm.v)
        fn = max(w.stiffness * delta ** w.exponent + self.c_contact * ddelta, 0.0)
        vt = self.t @ tm.v
        ft = -self.mu * fn * vt / math.sqrt(vt * vt + w.slip_velocity ** 2)
        return fn, ft

    def rhs(self, t, x, mode, s=0.0):
        """ẋ in a mode, and the contact forces (λ_n, λ_t) at that instant."""
        tm = self.terms(t, x)
        nf = self.nf
        if self.method == "compliant":
            fn, ft = self.compliant_force(tm)
            if fn:
                tm.f = tm.f + (self.n @ tm.J) * fn + (self.t @ tm.J) * ft
            a, ln, lt = np.linalg.solve(tm.M, tm.f), fn, ft
        else:
            a, ln, lt = self.accelerations(tm, mode, s)
        return np.concatenate([x[nf:2 * nf], a, tm.zd]), ln, lt, tm

    # -------------------------------------------------------------------------- impact
    def impulse(self, tm: Terms, qd_free):
        """Post-impact free rates and (P_n, P_t, sticking) — maximum-dissipation Coulomb
        impulse with J_n q̇⁺ = 0 (see module doc)."""
        Minv = np.linalg.inv(tm.M)
        jn = self.n @ tm.J
        jt = self.t @ tm.J
        vn, vt = jn @ qd_free, jt @ qd_free
        Gnn, Gnt, Gtt = jn @ Minv @ jn, jn @ Minv @ jt, jt @ Minv @ jt
        det = Gnn * Gtt - Gnt * Gnt
        if det > 1e-14 * Gnn * Gtt:
            pn = (-vn * Gtt + vt * Gnt) / det
            pt = (-vt * Gnn + vn * Gnt) / det
            if pn >= 0.0 and abs(pt) <= self.mus * pn:
                return qd_free + Minv @ (jn * pn + jt * pt), pn, pt, True
        # Pn(Pt) = (−vn − Gnt Pt)/Gnn; optimum over Pt in |Pt| <= μ Pn(Pt)
        pt_star = (-vt * Gnn + vn * Gnt) / det if det > 0 else 0.0
        lo, hi = -math.inf, math.inf
        a0 = self.mu * (-vn) / Gnn
        for sign in (1.0, -1.0):          # sign·Pt <= μ Pn(Pt) = a0 − μ(Gnt/Gnn)·Pt
            coef = sign + self.mu * Gnt / Gnn
            if coef > 0:
                hi = min(hi, a0 / coef)
            elif coef < 0:
                lo = max(lo, a0 / coef)
        pt = min(max(pt_star, lo), hi) if self.mu > 0 else 0.0
        pn = (-vn - Gnt * pt) / Gnn
        return qd_free + Minv @ (jn * pn + jt * pt), pn, pt, False

    # --------------------------------------------------------------------- projection
    def project(self, t, x, mode):
        """Move (q, q̇) back onto g = 0, v_n = 0 (and v_t = 0 when sticking) by the
        M-orthogonal projection; returns the corrected state and the drift removed."""
        nf = self.nf
        tm = self.terms(t, x)
        g = self.gap(tm)
        Minv = np.linalg.inv(tm.M)
        jn = self.n @ tm.J
        x = x.copy()
        x[:nf] -= Minv @ jn * (g / (jn @ Minv @ jn))
        rows = [jn] if mode == SLIDING else [jn, self.t @ tm.J]
        Jc = np.array(rows)
        v = Jc @ x[nf:2 * nf]
        x[nf:2 * nf] -= Minv @ Jc.T @ np.linalg.solve(Jc @ Minv @ Jc.T, v)
        return x, abs(g)

    def kinetic(self, tm: Terms, qd_free) -> float:
        return 0.5 * qd_free @ tm.M @ qd_free

    def painleve(self, tm: Terms, s: float) -> float:
        """The sliding mode's consistency margin d = G_nn − μ s G_nt (1/kg), the factor of
        the normal force in J_n q̈ = −c_n: λ = (−c_n − J_n M⁻¹f)/d. Positive: one normal
        force for every state (sliding or separation). Zero or negative: Painlevé's case —
        sliding has no solution (free flight heads into the wall) or two (it separates as
        well); the stepper resolves it by a tangential impact (§8.2)."""
        Minv_jn = np.linalg.solve(tm.M, self.n @ tm.J)
        return float((self.n @ tm.J) @ Minv_jn - self.mu * s * ((self.t @ tm.J) @ Minv_jn))








def spring_damper_rate(omega, zeta) -> float:
    """Largest |λ| (1/s) of a spring–damper of natural frequency ω and damping ratio ζ:
    ω(ζ + √(ζ² − 1)) when overdamped (ζ > 1), else ω."""
    return omega * (zeta + math.sqrt(zeta * zeta - 1.0) if zeta > 1.0 else 1.0)


def _solve_kkt(A, b):
    """Solve the constrained-dynamics (KKT) system; at a kinematic singularity (the two
    contact constraints dependent, e.g. a straight arm) take the least-squares solution
    (accelerations unique, multipliers of minimum norm)."""
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def stick_or_slip(contact, t, x):
    """At zero slip speed: stick if static friction holds, else slip against λ_t."""
    _, ln, lt, _ = contact.rhs(t, x, STICKING)
    if abs(lt) <= contact.mus * ln:
        return STICKING, 0.0
    return SLIDING, -math.copysign(1.0, lt)


def constrained_rate(contact: WallContact, x0) -> float:
    """Largest |λ| of the Jacobian of the sliding and sticking dynamics at x0 (the tool held
    on a wall through its current position): holding the tool raises the arm's highest
    frequency, and the RK4 step must be stable in every mode."""
    nf = contact.nf
    x0 = np.array(x0, float)
    x0[nf:2 * nf] = 0.0      # on the constraint manifold: at rest (a moving state is off it
    #                          and its Jacobian has spurious drift rates)
    d0 = contact.d
    contact.d = float(contact.n @ contact.terms(0.0, x0).r)    # wall through the tool
    try:
        worst = 0.0
        for mode in (SLIDING, STICKING):
            J = jacobian(lambda x: contact.rhs(0.0, x, mode, 1.0)[0], x0)
            worst = max(worst, float(np.abs(np.linalg.eigvals(J)).max()))
    finally:
        contact.d = d0
    return worst


def build_contact(chain):
    """The scene's wall contact, or None (no wall: no contact machinery)."""
    sc = chain.scene
    if not sc.walls:
        return None
    return WallContact(chain, sc.walls[0], sc.tool, chain.fidelity.contact)


def check_integrator(chain):
    if chain.scene.walls and chain.fidelity.integrator != "rk4":
        raise SceneError(f"fidelity.integrator: got {chain.fidelity.integrator!r} with a "
                         f"wall, expected rk4 (the contact integrator locates events on "
                         f"fixed RK4 steps)")
