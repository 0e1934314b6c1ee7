"""Contact of the tool with a wall: impulse–constraint (seed 000) and compliant rungs.

Gap and contact Jacobians (PHYSICS.md): the tool point r (fixed in the last tip frame) has
gap g = n·(r − p_wall) ≥ 0, normal and tangential Jacobians J_n = nᵀJ, J_t = tᵀJ
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
  slipping).
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
eigenvalue ω(ζ + √(ζ² − 1)), ω = √(k_eff G_nn). (A Hunt–Crossley damping c ∝ δ^e was
tried first: its rate grows with the peak force, unknown before the run, and RK4 went
unstable at k = 1e7 N/m — measured.)
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from . import kernel, kernel_contact
from .errors import SceneError, SimulationDiverged

FREE, SLIDING, STICKING = 0, 1, 2
PHASES = ("free", "sliding", "sticking", "impact")
PHASE_CODE = {name: k for k, name in enumerate(PHASES)}
MIN_FLIGHT = 1e-6          # s: a re-impact sooner than this after separation keeps contact
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
        self.model = chain.kernel_args
        self.ws = kernel.workspace(self.model)
        self.free = chain.free
        self.nf = len(chain.free)
        self.c_contact = 0.0       # compliant damping, set from the start (set_start)

    def set_start(self, x0) -> float:
        """Fix the compliant damping c = 2ζ√(k_eff m_eff) at the start state; returns the
        contact's largest rate |λ| (1/s) for the automatic step."""
        tm = self.terms(0.0, x0)
        jn = self.n @ tm.J
        Gnn = float(jn @ np.linalg.solve(tm.M, jn))
        w = self.wall
        k_eff = w.exponent * w.stiffness * 1e-3 ** (w.exponent - 1.0)
        omega = math.sqrt(k_eff * Gnn)
        zeta = w.damping_ratio
        self.c_contact = 2.0 * zeta * math.sqrt(k_eff / Gnn)
        return omega * (zeta + math.sqrt(zeta * zeta - 1.0) if zeta > 1.0 else 1.0)

    # --------------------------------------------------------------------- evaluation
    def terms(self, t, x) -> Terms:
        """One compiled force evaluation plus the tool kinematics from the last tip frame."""
        ch, ws, nf = self.chain, self.ws, self.nf
        q, qd = ch.full_state(t, x)
        kernel.forces(float(t), q, qd, x[2 * nf:], self.model, ws)
        fr = self.free
        M = ws[kernel.W_M][np.ix_(fr, fr)]
        f = ws[kernel.W_F][fr].copy()
        zd = ws[kernel.W_ZD][:ch.nz].copy()
        o = ws[kernel.W_TIP][0:2]
        co = ws[kernel.W_TIP][2:4]
        psi, psid = ws[kernel.W_TIP][4], ws[kernel.W_TIP][5]
        cs, sn = math.cos(psi), math.sin(psi)
        ap = np.array([cs * self.p[0] - sn * self.p[1], sn * self.p[0] + cs * self.p[1]])
        Jfull = ws[kernel.W_JO] + np.outer(_E @ ap, ws[kernel.W_JPSI])
        c = co - psid * psid * ap
        if len(ch.presc_idx):
            c = c + Jfull[:, ch.presc_idx] @ ws[kernel.W_PDD][:len(ch.presc_idx)]
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

    def free_accelerations(self, t, x, mode, s=0.0) -> np.ndarray:
        """q̈ of the free coordinates in a mode (compiled, :mod:`kernel_contact`, on the
        numba backend for the impulse rung; else :meth:`rhs`)."""
        nf = self.nf
        if self.method != "compliant" and self.chain.backend == "numba":
            if getattr(self, "_scratch", None) is None:
                self._scratch = (kernel_contact.scratch(self), np.empty(len(x)))
            sc, out = self._scratch
            if kernel_contact.evaluate(float(t), np.asarray(x, float), int(mode), float(s),
                                       out, self.model, self.ws,
                                       kernel_contact.parameters(self), sc[8], sc):
                return out[nf:2 * nf].copy()
        return self.rhs(t, x, mode, s)[0][nf:2 * nf]

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


@dataclass
class ContactRun:
    """Samples of a contact run: per output time the phase code, forces, gap, tool state."""
    phase: np.ndarray
    normal_force: np.ndarray
    friction_force: np.ndarray
    gap: np.ndarray
    tool: np.ndarray          # (N, 2)
    tool_velocity: np.ndarray  # (N, 2)
    impacts: list
    max_drift: float
    mode: np.ndarray          # smooth mode (free/sliding/sticking) after each sample
    slip_sign: np.ndarray
    normal_impulse: np.ndarray   # cumulative normal impulse from the wall (N·s)

    def accelerations(self, contact, k, t, x) -> np.ndarray:
        """q̈ of the free coordinates at sample k (the mode's constrained dynamics)."""
        return contact.free_accelerations(t, x, int(self.mode[k]), float(self.slip_sign[k]))


class ContactStepper:
    """Fixed-step RK4 through the contact modes with located events (module doc), as an
    object: ``advance(t_target)`` moves the state to ``t_target`` (a batch run and the ROS
    simulator's plant both drive it); ``sample()`` reads the contact quantities."""

    def __init__(self, chain, contact: WallContact, x0, h, guard, t0=0.0):
        self.chain = chain
        self.contact = contact
        self.h = h
        self.guard = guard
        self.t = t0
        self.x = np.array(x0, float)
        self.mode, self.s = FREE, 0.0
        self.last_sep = -math.inf
        self.impacts: list[ImpactRecord] = []
        self.impact_pending = False
        self.calls = 0
        self.steps = 0
        self.max_drift = 0.0
        self.normal_impulse = 0.0       # cumulative ∫λ dt + impact impulses (N·s)
        self.h_contact = h              # step while in contact (halved on excess drift)
        self.compliant = contact.method == "compliant"
        # smooth stretches of the impulse rung in compiled code (numba backend); events,
        # impacts and retaken steps stay in the Python reference below
        self.compiled = not self.compliant and chain.backend == "numba"
        if self.compiled:
            self._sc = kernel_contact.scratch(contact)
            self._xdot = np.empty(len(self.x))
            self._cp = kernel_contact.parameters(contact)

    # ------------------------------------------------------------------ internals
    def _rk4(self, t0, x0, dt, md, sg, want_impulse=False):
        """One RK4 step; with ``want_impulse`` also the normal impulse ∫λ dt over it (the
        stages' forces with the RK4 weights)."""
        f = self.contact.rhs
        k1, l1, _, _ = f(t0 + kernel.STAGE_EPS * dt, x0, md, sg)
        k2, l2, _, _ = f(t0 + 0.5 * dt, x0 + 0.5 * dt * k1, md, sg)
        k3, l3, _, _ = f(t0 + 0.5 * dt, x0 + 0.5 * dt * k2, md, sg)
        k4, l4, _, _ = f(t0 + (1 - kernel.STAGE_EPS) * dt, x0 + dt * k3, md, sg)
        self.calls += 4
        x = self.chain.clamp_states(x0 + (dt / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4))
        if want_impulse:
            return x, (dt / 6.0) * (l1 + 2 * l2 + 2 * l3 + l4)
        return x

    def _indicators(self, tt, xx, md, sg):
        """Event functions of a mode (positive while the mode holds)."""
        if self.compliant:
            return ()
        _, ln, lt, tm = self.contact.rhs(tt, xx, md, sg)
        if md == FREE:
            return (self.contact.gap(tm),)
        if md == SLIDING:
            return (ln, sg * (self.contact.t @ tm.v))
        return (ln, self.contact.mus * ln - abs(lt))

    def _transition(self, tt, xx, which):
        """New (x, mode, s) after event ``which`` of the current mode at time tt."""
        c, nf = self.contact, self.contact.nf
        if self.mode == FREE:                              # impact
            tm = c.terms(tt, xx)
            v = xx[nf:2 * nf]
            vn = c.n @ tm.J @ v
            ke0 = c.kinetic(tm, v)
            v1, pn, pt, stick = c.impulse(tm, v)
            xx = xx.copy()
            xx[nf:2 * nf] = v1
            new_mode = STICKING if stick else SLIDING
            vt1 = c.t @ tm.J @ v1
            sg = 0.0 if stick else (math.copysign(1.0, vt1) if vt1 != 0 else
                                    -math.copysign(1.0, pt) if pt else 1.0)
            if new_mode == SLIDING and abs(vt1) < 1e-12:
                new_mode, sg = _stick_or_slip(c, tt, xx)
            _, ln, _, _ = c.rhs(tt, xx, new_mode, sg)
            outcome = "sticking" if new_mode == STICKING else "sliding"
            if ln < 0 and tt - self.last_sep > MIN_FLIGHT:
                new_mode, sg, outcome = FREE, 0.0, "bounce"
                self.last_sep = tt
            self.impacts.append(ImpactRecord(tt, pn, pt, -vn, ke0, c.kinetic(tm, v1),
                                             outcome))
            self.normal_impulse += pn
            self.impact_pending = True
            return xx, new_mode, sg
        if which == 0:                                     # normal force turned pulling
            self.last_sep = tt
            return xx, FREE, 0.0
        if self.mode == SLIDING:                           # slip speed reached zero
            md, sg = _stick_or_slip(c, tt, xx)
            return xx, md, sg
        _, _, lt, _ = c.rhs(tt, xx, STICKING)              # static friction exceeded
        return xx, SLIDING, -math.copysign(1.0, lt)

    def _compliant_step(self, t, x):
        """Largest stable RK4 step near or in a compliant contact: 1.5/|λ| of the contact's
        spring–damper with the tool's effective mass at the current configuration (it can
        be far lighter than at the start); the fixed step elsewhere."""
        c = self.contact
        tm = c.terms(t, x)
        g = c.gap(tm)
        vn = c.n @ tm.v
        if g > 0.0 and g + min(vn, 0.0) * self.h > 0.0:
            return self.h                       # cannot reach the wall within this step
        jn = c.n @ tm.J
        Gnn = float(jn @ np.linalg.solve(tm.M, jn))
        w = c.wall
        delta = max(-g, 1e-3)
        k_eff = w.exponent * w.stiffness * delta ** (w.exponent - 1.0)
        omega = math.sqrt(k_eff * Gnn)
        zeta = 0.5 * c.c_contact * math.sqrt(Gnn / k_eff)
        rate = omega * (zeta + math.sqrt(zeta * zeta - 1.0) if zeta > 1.0 else 1.0)
        return min(self.h, 1.5 / rate)

    # --------------------------------------------------------------------- public
    def advance(self, t_target):
        """Integrate to ``t_target`` (steps of at most h; events located and handled)."""
        chain, h = self.chain, self.h
        t, x, mode, s = self.t, self.x, self.mode, self.s
        events_here = 0
        cp = self._cp if self.compiled else None
        while t < t_target - 1e-15:
            if self.compiled:
                hh = h if mode == FREE else min(h, self.h_contact)
                code, t, x, dp, nst, calls, drift, x_bad = kernel_contact.span(
                    x, float(t), float(t_target), hh, int(mode), float(s),
                    chain.fidelity.max_deflection_ratio, chain.fidelity.contact_tolerance,
                    self.contact.model, self.contact.ws, cp, self._sc)
                self.normal_impulse += dp
                self.steps += nst
                self.calls += calls
                self.max_drift = max(self.max_drift, drift)
                if code == kernel.OK:
                    break
                if code in (kernel.NON_FINITE, kernel.DEFLECTION):
                    self.guard.last = x
                    self.guard.check(t + min(hh, t_target - t), x_bad)
                # an event, excess drift or a singular constraint in the next step: the
                # reference below takes that step
            dt = min(h, t_target - t)
            if self.compliant:
                dt = min(dt, self._compliant_step(t, x))
            elif mode != FREE:
                dt = min(dt, self.h_contact)
            x1, dp = self._rk4(t, x, dt, mode, s, want_impulse=True)
            self.steps += 1
            if not np.all(np.isfinite(x1)):
                self.guard.check(t + dt, x1)
            ind0 = self._indicators(t, x, mode, s)
            ind1 = self._indicators(t + dt, x1, mode, s)
            hit = [j for j, (a, b) in enumerate(zip(ind0, ind1)) if a >= 0.0 > b]
            if hit:
                best_tau, best_j = dt, hit[0]
                for j in hit:                  # earliest crossing among the mode's events
                    def fun(tau, j=j):
                        return self._indicators(t + tau, self._rk4(t, x, tau, mode, s),
                                                mode, s)[j]
                    tau = brentq(fun, 0.0, dt, xtol=1e-14, rtol=1e-12) if fun(0.0) > 0 else 0.0
                    if tau < best_tau:
                        best_tau, best_j = tau, j
                xe, dp = (self._rk4(t, x, best_tau, mode, s, want_impulse=True)
                          if best_tau > 0 else (x, 0.0))
                self.normal_impulse += dp
                t += best_tau
                self.mode, self.s = mode, s
                x, mode, s = self._transition(t, xe, best_j)
                events_here = events_here + 1 if best_tau <= 1e-12 else 0
                if events_here > 50:
                    raise SimulationDiverged(
                        "contact events", t, float(self.contact.gap(self.contact.terms(t, x))),
                        "use fidelity.contact: compliant, or a finer --dt",
                        detail="more than 50 contact events at one instant (Zeno)")
                continue
            if mode != FREE and not self.compliant:
                x1p, drift = self.contact.project(t + dt, x1, mode)
                tol = chain.fidelity.contact_tolerance
                if drift > tol:
                    # the step drifted the tool off the wall by more than the tolerance:
                    # retake it with smaller steps while in contact
                    self.h_contact = 0.5 * min(self.h_contact, dt)
                    if self.h_contact < 1e-6 * h:
                        raise SimulationDiverged(
                            "tool drift off the wall", t + dt, drift,
                            f"reduce the step (--dt, now {h:.3g} s) or raise "
                            f"fidelity.contact_tolerance", detail=f"drift {drift:.3g} m in "
                            f"one step exceeds fidelity.contact_tolerance = {tol:.3g} m even "
                            f"at a step of {self.h_contact:.3g} s")
                    continue
                self.max_drift = max(self.max_drift, drift)
                x1 = x1p
            x, t = x1, t + dt
            self.normal_impulse += dp
            self.guard.check(t, x)
        self.t, self.x, self.mode, self.s = t_target, x, mode, s

    def sample(self):
        """(phase code, λ_n, λ_t, gap, tool r, tool ṙ, q̈_free) at the current state; the
        phase is 'impact' once after an impact."""
        c = self.contact
        if self.compiled:
            res = self._sc[8]
            if kernel_contact.evaluate(float(self.t), self.x, int(self.mode), float(self.s),
                                       self._xdot, c.model, c.ws, self._cp, res, self._sc):
                ph = PHASE_CODE["impact"] if self.impact_pending else self.mode
                self.impact_pending = False
                R = kernel_contact
                return (ph, res[R.R_LN], res[R.R_LT], res[R.R_GAP],
                        np.array([res[R.R_RX], res[R.R_RY]]),
                        np.array([res[R.R_VX], res[R.R_VY]]), self._xdot[c.nf:2 * c.nf].copy())
        xd, ln, lt, tm = c.rhs(self.t, self.x, self.mode, self.s)
        ph = self.mode
        if self.compliant:
            ph = FREE if ln <= 0 else (STICKING if abs(c.t @ tm.v) < c.wall.slip_velocity
                                       else SLIDING)
        if self.impact_pending:
            ph = PHASE_CODE["impact"]
            self.impact_pending = False
        return ph, ln, lt, c.gap(tm), tm.r.copy(), tm.v.copy(), xd[c.nf:2 * c.nf]


def integrate_contact(chain, contact: WallContact, x0, t_end, h, output_dt, guard,
                      progress=None):
    """Run a :class:`ContactStepper` over [0, t_end], sampling every ``output_dt``.

    Returns (xs (N, m), ContactRun, steps, rhs_evaluations)."""
    n_out = int(np.floor(t_end / output_dt + 1e-9))
    N = n_out + 1
    xs = np.empty((N, len(x0)))
    phase = np.zeros(N, dtype=np.int64)
    fn_out, ft_out, gap = np.zeros(N), np.zeros(N), np.zeros(N)
    tool, tvel = np.zeros((N, 2)), np.zeros((N, 2))
    modes, signs = np.zeros(N, dtype=np.int64), np.zeros(N)
    impulse = np.zeros(N)
    st = ContactStepper(chain, contact, x0, h, guard)
    last_report = time.perf_counter()
    for k in range(N):
        if k:
            st.advance(k * output_dt)
        xs[k] = st.x
        phase[k], fn_out[k], ft_out[k], gap[k], tool[k], tvel[k], _ = st.sample()
        modes[k], signs[k] = st.mode, st.s
        impulse[k] = st.normal_impulse
        now = time.perf_counter()
        if progress is not None and now - last_report > 1.0:
            progress(k * output_dt / t_end)
            last_report = now
    return xs, ContactRun(phase, fn_out, ft_out, gap, tool, tvel, st.impacts, st.max_drift,
                          modes, signs, impulse), st.steps, st.calls


def _solve_kkt(A, b):
    """Solve the constrained-dynamics (KKT) system; at a kinematic singularity (the two
    contact constraints dependent, e.g. a straight arm) take the least-squares solution
    (accelerations unique, multipliers of minimum norm)."""
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _stick_or_slip(contact, t, x):
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
    #                          and its Jacobian has spurious drift rates, measured 1e8 1/s)
    d0 = contact.d
    contact.d = float(contact.n @ contact.terms(0.0, x0).r)    # wall through the tool
    try:
        worst = 0.0
        for mode in (SLIDING, STICKING):
            m = len(x0)
            J = np.zeros((m, m))
            for j in range(m):
                dx = 1e-6 * max(1.0, abs(x0[j]))
                xp, xm = x0.copy(), x0.copy()
                xp[j] += dx
                xm[j] -= dx
                J[:, j] = (contact.rhs(0.0, xp, mode, 1.0)[0]
                           - contact.rhs(0.0, xm, mode, 1.0)[0]) / (2 * dx)
            worst = max(worst, float(np.abs(np.linalg.eigvals(J)).max()))
    finally:
        contact.d = d0
    return worst


def contact_rate(contact: WallContact, x0) -> float:
    """Compliant rung: the contact's largest rate (1/s) at x0 (sets its damping too)."""
    return contact.set_start(x0)


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
