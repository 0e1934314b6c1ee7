"""Integration through the contact modes: :class:`ContactStepper` steps RK4 within a smooth
mode (the compiled fast lane between events) and locates and resolves the events of
:mod:`flexarm_ros.model.contact` (impact, separation, stick and slip) on the step."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from flexarm_ros.sim.budget import Pace
from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import contact as kcontact
from flexarm_ros.model.compiled import sensors as ksensors
from flexarm_ros.model.contact import (FREE, MIN_FLIGHT, PHASE_CODE, SLIDING, STICKING,
                                       ImpactRecord, WallContact, stick_or_slip,
                                       spring_damper_rate)
from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.sim.integrate import hermite
from flexarm_ros.sim.step import RK4_AUTO, rk4_step

#: index of Painlevé's margin among the sliding mode's event functions
PAINLEVE = 2


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
    qdd: np.ndarray | None = None   # (N, n_free) q̈ at each sample, as the stepper read it
    acc: np.ndarray | None = None   # (N, n_acc) accelerometer specific forces at each sample


class SampleBuffer:
    """Samples the stepper writes as its steps reach their instants ``ts`` (s, rising):
    state X (N, m), the contact quantities R (N, 10: λ_n, λ_t, gap, v_n, v_t, tool r, tool
    ṙ, cumulative normal impulse — :mod:`kcontact`'s R_* and S_IMPULSE), q̈ of the free
    coordinates QDD (N, nf), phase code, smooth mode and slip sign; ``k`` the next row.
    With ``acc`` (:func:`ksensors.pack`'s arrays after the index; numba backend) also the
    accelerometers' specific forces ACC (N, n_acc), read from the sample's own evaluation
    in compiled stretches; rows the Python reference wrote are marked in ``ref_rows`` and
    read by :meth:`complete`."""

    def __init__(self, ts, m: int, nf: int, acc=None):
        N = len(ts)
        self.ts = np.ascontiguousarray(ts, float)
        self.X = np.zeros((N, m))
        self.R = np.zeros((N, kcontact.SAMPLE_COLUMNS))
        self.QDD = np.zeros((N, nf))
        self.phase = np.zeros(N, dtype=np.int64)
        self.mode = np.zeros(N, dtype=np.int64)
        self.sign = np.zeros(N)
        self.acc = acc if acc is not None else ksensors.no_accelerometers()
        self.ACC = np.zeros((N, len(self.acc[0])))
        self.ref_rows = np.zeros(N, dtype=bool)
        self.k = 0

    def put(self, k, x, ln, lt, gap, n, t, r, v, impulse, qdd) -> None:
        """Row k written by the Python side: state, contact quantities (v_n = n·ṙ, v_t =
        t·ṙ with the wall's normal and tangent), cumulative impulse, q̈; its
        accelerometers are left to :meth:`complete`."""
        self.X[k] = x
        self.R[k] = (ln, lt, gap, n @ v, t @ v, r[0], r[1], v[0], v[1], impulse)
        self.QDD[k] = qdd
        self.ref_rows[k] = True

    def reset(self, ts) -> None:
        """Reuse the rows for new instants (as many or fewer)."""
        self.ts = np.ascontiguousarray(ts, float)
        self.k = 0
        self.ref_rows[:] = False

    def complete(self, chain, ws) -> None:
        """ACC of the rows the Python reference wrote (one compiled call for them all)."""
        if not self.ACC.shape[1]:
            return
        rows = np.nonzero(self.ref_rows[:self.k])[0]
        if len(rows):
            out = np.empty((len(rows), self.ACC.shape[1]))
            ksensors.table(self.ts[rows], self.X[rows], self.QDD[rows], True,
                           chain.kernel_args, ws, *self.acc, out)
            self.ACC[rows] = out
            self.ref_rows[rows] = False


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
        self._no_samples = SampleBuffer(np.empty(0), len(self.x), contact.nf)
        if self.compliant:
            contact.set_start(self.x)   # the compliant damping is fixed at the start state
        # smooth stretches of the impulse rung in compiled code (numba backend); events,
        # impacts and retaken steps stay in the Python reference below
        self.compiled = not self.compliant and chain.backend == "numba"
        if self.compiled:
            self._sc = kcontact.scratch(contact)
            self._res = kcontact.Scratch._make(self._sc).res      # what evaluate() leaves
            self._xdot = np.empty(len(self.x))
            self._cp = kcontact.parameters(contact)

    # ------------------------------------------------------------------ internals
    def _rhs(self, t, x, md, sg):
        """(ẋ, λ_n, λ_t, gap, tool speed along the wall) in mode ``md``: the event steps'
        evaluations. Compiled (:func:`kcontact.evaluate`, the same equations as
        ``contact.rhs``; test_contact holds them equal to round-off) when the stepper is,
        so an event costs tens of µs per evaluation rather than ~100; the reference
        otherwise, and where the compiled one finds the constraint singular."""
        c = self.contact
        if self.compiled:
            out = np.empty(len(x))
            if kcontact.evaluate(float(t), x, int(md), float(sg), out, c.kernel_args, c.ws,
                                 self._cp, self._sc):
                r = self._res
                return (out, float(r[kcontact.R_LN]), float(r[kcontact.R_LT]),
                        float(r[kcontact.R_GAP]), float(r[kcontact.R_VT]))
        xd, ln, lt, tm = c.rhs(t, x, md, sg)
        return xd, ln, lt, c.gap(tm), float(c.t @ tm.v)

    def _rk4(self, t0, x0, dt, md, sg, want_impulse=False):
        """One RK4 step in mode ``md`` (:func:`~flexarm_ros.sim.step.rk4_step`); with
        ``want_impulse`` also the normal impulse ∫λ dt over it (the stages' normal forces
        with the RK4 weights)."""
        rhs = self.contact.rhs if self.compliant else self._rhs
        self.calls += 4
        if want_impulse:
            x, impulse = rk4_step(lambda t, x: rhs(t, x, md, sg)[:2], t0, x0, dt,
                                  quadrature=True)
            return self.chain.clamp_states(x), impulse
        return self.chain.clamp_states(rk4_step(lambda t, x: rhs(t, x, md, sg)[0], t0, x0, dt))

    def _indicators(self, tt, xx, md, sg):
        """Event functions of a mode (positive while the mode holds)."""
        if self.compliant:
            return ()
        _, ln, lt, gap, vt = self._rhs(tt, xx, md, sg)
        if md == FREE:
            return (gap,)
        if md == SLIDING:                # λ, slip, Painlevé's margin (PAINLEVE)
            return (ln, sg * vt, self.contact.painleve(self.contact.terms(tt, xx), sg))
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
                new_mode, sg = stick_or_slip(c, tt, xx)
            if new_mode == SLIDING and c.painleve(c.terms(tt, xx), sg) <= 0.0:
                # sliding away from the impact would be Painlevé's case: the impact's
                # impulse and the tangential one at once
                self.impacts.append(ImpactRecord(tt, pn, pt, -vn, ke0, c.kinetic(tm, v1),
                                                 "sliding"))
                self.normal_impulse += pn
                return self._tangential_impact(tt, xx)
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
        if self.mode == SLIDING and (which == PAINLEVE or (
                which == 0 and c.painleve(c.terms(tt, xx), self.s) <= 0.0)):
            # Painlevé's inconsistent case: d = G_nn − μ s G_nt reached zero while sliding
            # (λ through its pole), or λ = N/d reached zero with d < 0 — beyond, sliding
            # would pull (N > 0, d < 0) while free flight heads into the wall: the contact
            # jams by a tangential impact
            return self._tangential_impact(tt, xx)
        if which == 0:                                     # normal force turned pulling
            self.last_sep = tt
            return xx, FREE, 0.0
        if self.mode == SLIDING:                           # slip speed reached zero
            md, sg = stick_or_slip(c, tt, xx)
            return xx, md, sg
        _, _, lt, _ = c.rhs(tt, xx, STICKING)              # static friction exceeded
        # (a slip into d < 0 is Painlevé's indeterminate case — sliding with λ = N/d > 0
        # and lift-off both solve it; the sliding solution carries the sticking force on
        # continuously and is taken)
        return xx, SLIDING, -math.copysign(1.0, lt)

    def _tangential_impact(self, tt, xx):
        """Painlevé's case resolved as the literature does (Génot & Brogliato 1999; the
        impulse a Moreau–Jean time-stepping scheme finds): an impact without collision — the
        impact law at the current state (v_n = 0) gives the impulse that stops the slip, with
        P_n > 0 and |P_t| ≤ μ P_n inside the cone since d = G_nn − μ s G_nt ≤ 0. Then
        sticking, or free flight if the stuck contact would pull. Recorded as an impact with
        the outcome 'jam'."""
        c, nf = self.contact, self.contact.nf
        tm = c.terms(tt, xx)
        v = xx[nf:2 * nf]
        ke0 = c.kinetic(tm, v)
        v1, pn, pt, stick = c.impulse(tm, v)
        xx = xx.copy()
        xx[nf:2 * nf] = v1
        self.impacts.append(ImpactRecord(tt, pn, pt, -float(c.n @ tm.J @ v), ke0,
                                         c.kinetic(tm, v1), "jam"))
        self.normal_impulse += pn
        self.impact_pending = True
        if stick:
            mode, sg = STICKING, 0.0
        else:                                  # not reached with μ_s ≥ μ (docstring)
            vt1 = float(c.t @ tm.J @ v1)
            mode, sg = SLIDING, (math.copysign(1.0, vt1) if vt1 else -math.copysign(1.0, pt))
        _, ln, _, _ = c.rhs(tt, xx, mode, sg)
        if ln < 0.0:
            self.last_sep = tt
            return xx, FREE, 0.0
        return xx, mode, sg

    def _compliant_step(self, t, x):
        """Largest stable RK4 step near or in a compliant contact: RK4_AUTO/|λ| of the
        contact's spring–damper with the tool's effective mass at the current configuration
        (it can be far lighter than at the start); the fixed step elsewhere."""
        c = self.contact
        tm = c.terms(t, x)
        g = c.gap(tm)
        vn = c.n @ tm.v
        if g > 0.0 and g + min(vn, 0.0) * self.h > 0.0:
            return self.h                       # cannot reach the wall within this step
        k_eff, Gnn = c.spring(tm, -g)
        zeta = 0.5 * c.c_contact * math.sqrt(Gnn / k_eff)
        return min(self.h, RK4_AUTO / spring_damper_rate(math.sqrt(k_eff * Gnn), zeta))

    # ------------------------------------------------------------------ samples
    def _fill(self, buf, t, x, dt, x1, mode, s, imp0, dimp, t_target):
        """Samples of ``buf`` that the step (t, x) → (t + dt, x1) in ``mode`` reaches: the
        reference of the compiled :func:`kcontact.span`'s sampling (Hermite inside the
        step with ẋ just inside both ends, the step's own state on its end)."""
        if buf.k >= len(buf.ts):
            return
        ts, k0 = buf.ts, buf.k
        t1 = t + dt
        seps = 1e-12 * max(1.0, t_target)
        k = k0
        if ts[k] < t1 - seps:
            rhs = self.contact.rhs if self.compliant else self._rhs
            f0 = rhs(t + STAGE_EPS * dt, x, mode, s)[0]
            f1 = rhs(t + (1.0 - STAGE_EPS) * dt, x1, mode, s)[0]
            self.calls += 2
            while k < len(ts) and ts[k] < t1 - seps:
                th = (ts[k] - t) / dt
                self._sample_at(buf, k, ts[k], hermite(th, dt, x, f0, x1, f1), mode, s,
                                imp0 + th * dimp)
                k += 1
        if k < len(ts) and ts[k] <= t1 + seps:
            self._sample_at(buf, k, ts[k], x1, mode, s, imp0 + dimp)
            k += 1
        buf.k = k
        self._stamp(buf, k0, k, mode, s)

    def _sample_at(self, buf, k, tk, xk, mode, s, impulse):
        """Row k of ``buf`` at (tk, xk) (the reference of :func:`kcontact._sample`)."""
        c = self.contact
        self.calls += 1
        if self.compiled:           # as _rhs: the compiled evaluation where there is one
            out = np.empty(len(xk))
            if kcontact.evaluate(float(tk), xk, int(mode), float(s), out, c.kernel_args,
                                 c.ws, self._cp, self._sc):
                r, R = self._res, kcontact
                buf.put(k, xk, r[R.R_LN], r[R.R_LT], r[R.R_GAP], c.n, c.t,
                        (r[R.R_RX], r[R.R_RY]), np.array([r[R.R_VX], r[R.R_VY]]), impulse,
                        out[c.nf:2 * c.nf])
                return
        xd, ln, lt, tm = c.rhs(tk, xk, mode, s)
        buf.put(k, xk, ln, lt, c.gap(tm), c.n, c.t, tm.r, tm.v, impulse, xd[c.nf:2 * c.nf])

    def _compliant_phase(self, ln, vt):
        """The compliant rung's phase from the contact force and the slip speed (scalars
        or arrays): free without force, sticking below the wall's slip velocity."""
        return np.where(ln <= 0, FREE, np.where(np.abs(vt) < self.contact.wall.slip_velocity,
                                                STICKING, SLIDING))

    def _stamp(self, buf, k0, k1, mode, s):
        """Phase, mode and slip sign of the samples k0..k1-1 (taken in ``mode``); the first
        of them is 'impact' after an impact."""
        if k1 <= k0:
            return
        sl = slice(k0, k1)
        buf.mode[sl], buf.sign[sl] = mode, s
        if self.compliant:
            buf.phase[sl] = self._compliant_phase(buf.R[sl, kcontact.R_LN],
                                                  buf.R[sl, kcontact.R_VT])
        else:
            buf.phase[sl] = mode
        if self.impact_pending:
            buf.phase[k0] = PHASE_CODE["impact"]
            self.impact_pending = False

    # --------------------------------------------------------------------- public
    def advance(self, t_target, buf=None, max_steps=None):
        """Integrate to ``t_target`` (steps of at most h; events located and handled);
        with ``max_steps`` stop after about that many steps (at a step's end). The samples
        of ``buf`` (:class:`SampleBuffer`) that the steps reach are written on the way —
        they never change the steps."""
        chain, h = self.chain, self.h
        t, x, mode, s = self.t, self.x, self.mode, self.s
        events_here = 0
        cp = self._cp if self.compiled else None
        steps0 = self.steps
        limit = max_steps if max_steps is not None else 2 ** 62
        if buf is None:
            buf = self._no_samples
        while t < t_target - 1e-15 and self.steps - steps0 < limit:
            if self.compiled:
                hh = h if mode == FREE else min(h, self.h_contact)
                k0 = buf.k
                code, t, x, dp, nst, calls, drift, x_bad, buf.k = kcontact.span(
                    x, float(t), float(t_target), hh, int(mode), float(s),
                    chain.fidelity.max_deflection_ratio, chain.fidelity.contact_tolerance,
                    self.contact.kernel_args, self.contact.ws, cp, self._sc,
                    buf.ts, buf.k, buf.X, buf.R, buf.QDD, self.normal_impulse,
                    limit - (self.steps - steps0), buf.acc, buf.ACC)
                self._stamp(buf, k0, buf.k, mode, s)
                self.normal_impulse += dp
                self.steps += nst
                self.calls += calls
                self.max_drift = max(self.max_drift, drift)
                if code == kchain.OK:
                    if t >= t_target - 1e-15:
                        break
                    continue        # max_steps reached
                if code in (kchain.NON_FINITE, kchain.DEFLECTION):
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
            # an indicator turning negative; in free flight any step ending inside the wall,
            # also one starting a hair inside it (the gap after a bounce or a lift-off is 0
            # to round-off: with "starts ≥ 0" alone a re-contact within the next step was
            # missed and the tool passed through the wall — two_link_case2 at a 4.75 ms
            # step, 3.8 cm deep)
            hit = [j for j, (a, b) in enumerate(zip(ind0, ind1))
                   if b < 0.0 and (a >= 0.0 or mode == FREE)]
            if hit:
                best_tau, best_j = dt, hit[0]
                for j in hit:                  # earliest crossing among the mode's events
                    def fun(tau, j=j):
                        return self._indicators(t + tau, self._rk4(t, x, tau, mode, s),
                                                mode, s)[j]
                    tau = _first_crossing(fun, dt)
                    # Painlevé's margin and λ change sign together (λ through its pole):
                    # the margin's event wins the tie
                    if tau < best_tau or (mode == SLIDING and j == PAINLEVE
                                          and tau <= best_tau + 1e-12 * max(1.0, t)):
                        best_tau, best_j = tau, j
                xe, dp = (self._rk4(t, x, best_tau, mode, s, want_impulse=True)
                          if best_tau > 0 else (x, 0.0))
                if mode != FREE and best_tau > 0:
                    # the event's state back on the wall, as every step's end in contact
                    # (near Painlevé's case λ is large and a partial step drifts)
                    xe, drift = self.contact.project(t + best_tau, xe, mode)
                    self.max_drift = max(self.max_drift, drift)
                if best_tau > 0:
                    self._fill(buf, t, x, best_tau, xe, mode, s, self.normal_impulse, dp,
                               t_target)
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
            self._fill(buf, t, x, dt, x1, mode, s, self.normal_impulse, dp, t_target)
            x, t = x1, t + dt
            self.normal_impulse += dp
            self.guard.check(t, x)
        self.t = t_target if t >= t_target - 1e-15 else t
        self.x, self.mode, self.s = x, mode, s

    def sample(self):
        """(phase code, λ_n, λ_t, gap, tool r, tool ṙ, q̈_free) at the current state; the
        phase is 'impact' once after an impact."""
        c = self.contact
        if self.compiled:
            res = self._res
            if kcontact.evaluate(float(self.t), self.x, int(self.mode), float(self.s),
                                 self._xdot, c.kernel_args, c.ws, self._cp, self._sc):
                ph = PHASE_CODE["impact"] if self.impact_pending else self.mode
                self.impact_pending = False
                R = kcontact
                return (ph, res[R.R_LN], res[R.R_LT], res[R.R_GAP],
                        np.array([res[R.R_RX], res[R.R_RY]]),
                        np.array([res[R.R_VX], res[R.R_VY]]), self._xdot[c.nf:2 * c.nf].copy())
        xd, ln, lt, tm = c.rhs(self.t, self.x, self.mode, self.s)
        ph = self.mode
        if self.compliant:
            ph = int(self._compliant_phase(ln, c.t @ tm.v))
        if self.impact_pending:
            ph = PHASE_CODE["impact"]
            self.impact_pending = False
        return ph, ln, lt, c.gap(tm), tm.r.copy(), tm.v.copy(), xd[c.nf:2 * c.nf]


def _first_crossing(fun, dt) -> float:
    """The first τ in [0, dt] where ``fun`` (an event function along the step, fun(dt) < 0)
    goes from positive to negative. From fun(0) > 0: Brent's root. From fun(0) ≤ 0 (the
    tool a hair inside the wall after a bounce): the first root after ``fun`` was positive,
    found on samples at dt·2⁻ᵏ (k = 1…30) and dt·k/16; none positive: 0 (the tool is not
    leaving: the event is now)."""
    from scipy.optimize import brentq        # on an event only: start-up time
    if fun(0.0) > 0:
        return brentq(fun, 0.0, dt, xtol=1e-14, rtol=1e-12)
    grid = sorted(set(dt * 2.0 ** -np.arange(1, 31)) | set(dt * np.arange(1, 16) / 16) | {dt})
    left = None
    for tau in grid:
        v = fun(tau)
        if v > 0:
            left = tau
        elif left is not None and v < 0:
            return brentq(fun, left, tau, xtol=1e-14, rtol=1e-12)
    return 0.0


def integrate_contact(chain, contact: WallContact, x0, t_end, h, output_dt, guard,
                      progress=None, breakpoints=(), accelerometers=None):
    """Run a :class:`ContactStepper` over [0, t_end] with samples every ``output_dt``
    (written by the stepper as its steps reach them: the step ``h`` may exceed the output
    period). A step ends on every input breakpoint in ``breakpoints`` (a program's jump).
    ``accelerometers``: :func:`ksensors.pack`'s arrays after the index — their readings
    at every sample come back as ContactRun.acc.

    Returns (xs (N, m), ContactRun, steps, rhs_evaluations)."""
    n_out = int(np.floor(t_end / output_dt + 1e-9))
    N = n_out + 1
    st = ContactStepper(chain, contact, x0, h, guard)
    buf = SampleBuffer(np.arange(N) * output_dt, len(x0), contact.nf, accelerometers)
    _sample_now(st, buf)                                  # the start
    pace = Pace(chain, t_end, "contact rk4", explain=lambda t, x: _why_contact_step(st, h))
    stops = sorted({float(b) for b in breakpoints if 0.0 < b < t_end} | {float(t_end)})
    chunk = max(1, int(np.ceil(t_end / 100 / h)))         # steps per progress report
    last_report = time.perf_counter()
    for t_stop in stops:
        while st.t < t_stop - 1e-12 * max(1.0, t_end):
            st.advance(t_stop, buf, max_steps=chunk)
            pace.check(st.steps, st.t, st.x)
            now = time.perf_counter()
            if progress is not None and now - last_report > 1.0:
                progress(st.t / t_end)
                last_report = now
    while buf.k < N:               # t_end on the grid but below rounding: the end state
        _sample_now(st, buf)
    buf.complete(chain, kchain.workspace(chain.kernel_args))
    R = buf.R
    return buf.X, ContactRun(buf.phase, R[:, kcontact.R_LN], R[:, kcontact.R_LT],
                             R[:, kcontact.R_GAP], R[:, kcontact.R_RX:kcontact.R_RY + 1],
                             R[:, kcontact.R_VX:kcontact.R_VY + 1], st.impacts, st.max_drift,
                             buf.mode, buf.sign, R[:, kcontact.S_IMPULSE], buf.QDD,
                             buf.ACC if accelerometers is not None else None), \
        st.steps, st.calls


def warm_up(chain, contact: WallContact, x0, accelerometers=None) -> None:
    """Compile (or load from numba's cache) the compiled contact functions with the
    argument types of a run, outside its timing: the first call of each costs 0.1–40 s
    (cache load / compilation), which a run's real-time factor must not count."""
    if chain.backend != "numba" or contact.method == "compliant":
        return
    x0 = np.array(x0, float)
    sc, cp = kcontact.scratch(contact), kcontact.parameters(contact)
    buf = SampleBuffer(np.zeros(1), len(x0), contact.nf, accelerometers)
    kcontact.span(x0, 0.0, 0.0, 1.0, FREE, 0.0, 1.0, 1.0, contact.kernel_args, contact.ws,
                  cp, sc, buf.ts, 0, buf.X, buf.R, buf.QDD, 0.0, 1, buf.acc, buf.ACC)
    kcontact.evaluate(0.0, x0, FREE, 0.0, np.empty(len(x0)), contact.kernel_args,
                      contact.ws, cp, sc)
    if buf.ACC.shape[1]:
        ksensors.table(buf.ts[:0], buf.X[:0], buf.QDD[:0], True, chain.kernel_args,
                       kchain.workspace(chain.kernel_args), *buf.acc, buf.ACC[:0])


def _sample_now(st, buf) -> None:
    """Row buf.k at the stepper's current state (:meth:`ContactStepper.sample`)."""
    k = buf.k
    ph, ln, lt, gap, r, v, qdd = st.sample()
    buf.put(k, st.x, ln, lt, gap, st.contact.n, st.contact.t, r, v, st.normal_impulse, qdd)
    buf.phase[k], buf.mode[k], buf.sign[k] = ph, st.mode, st.s
    buf.k = k + 1


def _why_contact_step(st, h) -> str:
    """What shortened the contact stepper's steps below the free step ``h``."""
    w = st.contact.wall
    if st.contact.method == "compliant":
        return (f"In contact the compliant step follows the wall's own rate: walls[0]."
                f"stiffness = {w.stiffness:g} N/m^e, walls[0].exponent = {w.exponent:g}, "
                f"walls[0].damping_ratio = {w.damping_ratio:g}. To fix: a softer "
                f"walls[0].stiffness, or fidelity.contact: impulse")
    return (f"The contact events (impacts, stick–slip) cut the step {h:.3g} s: walls[0]."
            f"friction = {w.friction:g}, fidelity.contact_tolerance = "
            f"{st.chain.fidelity.contact_tolerance:g} m. To fix: fidelity.contact: compliant, "
            f"or a larger fidelity.contact_tolerance")
