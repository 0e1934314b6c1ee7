"""Compiled smooth stepping of the impulse–constraint contact (:mod:`contact`).

:class:`contact.ContactStepper` is the readable reference: RK4 steps in one contact mode
(free flight, sliding, sticking), event functions checked at both ends of every step,
the M-orthogonal projection back onto the wall after each step in contact. This module
runs exactly that loop in compiled code for as long as nothing happens — no event
function changes sign, the projection's drift stays within the tolerance, the
constraint is regular — and returns to the reference at the start of the step where
something does, which then locates the event (root finding), applies the impact law or
retakes the step (event handling stays in one place, in Python).

The constrained accelerations are those of the reference's KKT system, solved through
the Schur complement with the Cholesky factor of the (symmetric positive-definite) mass
matrix of the free coordinates:

* free: M q̈ = f;
* sliding: M q̈ = f + w λ, j_n q̈ = −c_n with w = j_n − μ s j_t:
  λ = (−c_n − j_n M⁻¹f) / (j_n M⁻¹w), λ_t = −μ s λ;
* sticking: M q̈ = f + j_n λ_n + j_t λ_t, j_n q̈ = −c_n, j_t q̈ = −c_t:
  G λ = −c − J M⁻¹f with G = J M⁻¹Jᵀ (2 × 2).

A (near-)singular Schur complement (kinematic singularity) hands the step back to the
reference, whose least-squares solve handles it. Tests compare both paths to round-off
(test_contact.py).
"""

from __future__ import annotations

import math

import numpy as np


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import jit as _jit, jit_inline as _jit_inline

FREE, SLIDING, STICKING = 0, 1, 2
#: return codes of :func:`span` (kchain.OK / NON_FINITE / DEFLECTION shared)
EVENT, DRIFT, SINGULAR = 10, 11, 12
# contact parameters: wall normal, tangent, offset d (n·r = d on the wall), μ, μ_s, tool p
CP_NX, CP_NY, CP_TX, CP_TY, CP_D, CP_MU, CP_MUS, CP_PX, CP_PY = range(9)
# evaluation results
R_LN, R_LT, R_GAP, R_VN, R_VT, R_RX, R_RY, R_VX, R_VY = range(9)


def parameters(contact) -> np.ndarray:
    """The contact's parameters as the array the compiled functions read."""
    return np.array([contact.n[0], contact.n[1], contact.t[0], contact.t[1], contact.d,
                     contact.mu, contact.mus, contact.p[0], contact.p[1]])


def scratch(contact) -> tuple:
    """Work arrays for :func:`evaluate` / :func:`span` (allocated once per stepper)."""
    nf = contact.nf
    m = 2 * nf + contact.chain.nz
    return (np.empty(nf), np.empty(nf), np.empty(nf), np.empty(nf), np.empty(nf),
            np.empty(nf), np.empty(nf), np.empty(nf), np.empty(12), np.empty(m),
            np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m),
            np.empty(m))


@_jit
def _eval(t, x, mode, s, out, model, ws, cp, res, sc):
    """ẋ of mode (``s`` the slip direction when sliding) into ``out``; the contact forces,
    gap and tool state into ``res`` (R_*). Returns False at a singular constraint."""
    free = model[kchain.M_FREE]
    presc = model[kchain.M_PRESC]
    n = model[kchain.M_N]
    nz = model[kchain.M_NZ]
    nf = free.shape[0]
    q = ws[kchain.W_Q]
    qd = ws[kchain.W_QD]
    jn, jt, y1, y2, y3, w, ff, acc, g2 = sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6], \
        sc[7], sc[8]
    for i in range(nf):
        q[free[i]] = x[i]
        qd[free[i]] = x[nf + i]
    kchain.forces(t, q, qd, x[2 * nf:], model, ws)
    M = ws[kchain.W_M]
    f = ws[kchain.W_F]
    Mff = ws[kchain.W_MFF]
    L = ws[kchain.W_L]
    yy = ws[kchain.W_Y]
    tip = ws[kchain.W_TIP]
    Jo = ws[kchain.W_JO]
    Jpsi = ws[kchain.W_JPSI]
    pdd = ws[kchain.W_PDD]
    nx, ny, tx, ty = cp[CP_NX], cp[CP_NY], cp[CP_TX], cp[CP_TY]
    c = math.cos(tip[4])
    s_ = math.sin(tip[4])
    apx = c * cp[CP_PX] - s_ * cp[CP_PY]
    apy = s_ * cp[CP_PX] + c * cp[CP_PY]
    psid = tip[5]
    ccx = tip[2] - psid * psid * apx
    ccy = tip[3] - psid * psid * apy
    vx = 0.0
    vy = 0.0
    for i in range(n):
        jx = Jo[0, i] - apy * Jpsi[i]
        jy = Jo[1, i] + apx * Jpsi[i]
        vx += jx * qd[i]
        vy += jy * qd[i]
    for j in range(presc.shape[0]):
        i = presc[j]
        ccx += (Jo[0, i] - apy * Jpsi[i]) * pdd[j]
        ccy += (Jo[1, i] + apx * Jpsi[i]) * pdd[j]
    for a in range(nf):
        i = free[a]
        jx = Jo[0, i] - apy * Jpsi[i]
        jy = Jo[1, i] + apx * Jpsi[i]
        jn[a] = nx * jx + ny * jy
        jt[a] = tx * jx + ty * jy
        ff[a] = f[i]
        for b in range(nf):
            Mff[a, b] = M[i, free[b]]
    rx = tip[0] + apx
    ry = tip[1] + apy
    res[R_GAP] = nx * rx + ny * ry - cp[CP_D]
    res[R_VN] = nx * vx + ny * vy
    res[R_VT] = tx * vx + ty * vy
    res[R_RX] = rx
    res[R_RY] = ry
    res[R_VX] = vx
    res[R_VY] = vy
    cn = nx * ccx + ny * ccy
    ct = tx * ccx + ty * ccy
    ok = kchain._cholesky_solve(Mff, ff, nf, L, yy, y1)
    ln = 0.0
    lt = 0.0
    if ok and mode == SLIDING:
        mu = cp[CP_MU]
        for a in range(nf):
            w[a] = jn[a] - mu * s * jt[a]
        kchain._cholesky_solve(Mff, w, nf, L, yy, y2)
        den = 0.0
        num = -cn
        nj = 0.0
        ny2 = 0.0
        for a in range(nf):
            den += jn[a] * y2[a]
            num -= jn[a] * y1[a]
            nj += jn[a] * jn[a]
            ny2 += y2[a] * y2[a]
        if abs(den) <= 1e-12 * math.sqrt(nj * ny2):
            ok = False
        else:
            ln = num / den
            lt = -mu * s * ln
            for a in range(nf):
                acc[a] = y1[a] + ln * y2[a]
    elif ok and mode == STICKING:
        kchain._cholesky_solve(Mff, jn, nf, L, yy, y2)
        kchain._cholesky_solve(Mff, jt, nf, L, yy, y3)
        gnn = 0.0
        gnt = 0.0
        gtt = 0.0
        bn = -cn
        bt = -ct
        for a in range(nf):
            gnn += jn[a] * y2[a]
            gnt += jn[a] * y3[a]
            gtt += jt[a] * y3[a]
            bn -= jn[a] * y1[a]
            bt -= jt[a] * y1[a]
        det = gnn * gtt - gnt * gnt
        if det <= 1e-12 * gnn * gtt:
            ok = False
        else:
            ln = (gtt * bn - gnt * bt) / det
            lt = (gnn * bt - gnt * bn) / det
            for a in range(nf):
                acc[a] = y1[a] + ln * y2[a] + lt * y3[a]
    elif ok:
        for a in range(nf):
            acc[a] = y1[a]
    res[R_LN] = ln
    res[R_LT] = lt
    zd = ws[kchain.W_ZD]
    for a in range(nf):
        out[a] = x[nf + a]
        out[nf + a] = acc[a] if ok else np.nan
    for a in range(nz):
        out[2 * nf + a] = zd[a]
    return ok


#: :func:`_eval` for Python callers (the stepper's samples)
evaluate = _eval


@_jit_inline
def _indicators(mode, s, mus, res, ind):
    """The reference's event functions of a mode (positive while it holds); their count."""
    if mode == FREE:
        ind[0] = res[R_GAP]
        return 1
    ind[0] = res[R_LN]
    if mode == SLIDING:
        ind[1] = s * res[R_VT]
    else:
        ind[1] = mus * res[R_LN] - abs(res[R_LT])
    return 2


@_jit
def span(x0, t0, t_target, h, mode, s, max_ratio, tol, model, ws, cp, sc):
    """RK4 steps of at most ``h`` in one contact mode from (t0, x0) towards ``t_target``
    (the reference's step sequence: dt = min(h, t_target − t)), projecting after each
    step in contact. Stops at the start of the first step with an event, excess drift or a
    singular constraint.

    Returns (code, t, x, normal impulse ∫λ dt of the accepted steps, accepted steps,
    evaluations, largest drift, offending state) with code kchain.OK (t_target reached),
    EVENT, DRIFT, SINGULAR, kchain.NON_FINITE or kchain.DEFLECTION (t, x the last good
    state; the offending state last).
    """
    m = x0.shape[0]
    nf = model[kchain.M_FREE].shape[0]
    nz = model[kchain.M_NZ]
    zlo = model[kchain.M_ZLO]
    zhi = model[kchain.M_ZHI]
    res = sc[8]
    k1, k2, k3, k4, tmp, x1, xdot, x = sc[9], sc[10], sc[11], sc[12], sc[13], sc[14], \
        sc[15], sc[16]
    ind0 = np.empty(2)
    ind1 = np.empty(2)
    for i in range(m):
        x[i] = x0[i]
    t = t0
    impulse = 0.0
    steps = 0
    calls = 0
    drift_max = 0.0
    have_ind0 = False
    mus = cp[CP_MUS]
    eps = kchain.STAGE_EPS
    while t < t_target - 1e-15:
        dt = min(h, t_target - t)
        ok = _eval(t + eps * dt, x, mode, s, k1, model, ws, cp, res, sc)
        l1 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + 0.5 * dt * k1[i]
        ok = _eval(t + 0.5 * dt, tmp, mode, s, k2, model, ws, cp, res, sc) and ok
        l2 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + 0.5 * dt * k2[i]
        ok = _eval(t + 0.5 * dt, tmp, mode, s, k3, model, ws, cp, res, sc) and ok
        l3 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + dt * k3[i]
        ok = _eval(t + (1.0 - eps) * dt, tmp, mode, s, k4, model, ws, cp, res, sc) and ok
        l4 = res[R_LN]
        calls += 4
        if not ok:
            return SINGULAR, t, x.copy(), impulse, steps, calls, drift_max, x.copy()
        finite = True
        for i in range(m):
            x1[i] = x[i] + (dt / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            if not math.isfinite(x1[i]):
                finite = False
        for a in range(nz):
            i = m - nz + a
            x1[i] = min(max(x1[i], zlo[a]), zhi[a])
        if not finite:
            return kchain.NON_FINITE, t, x.copy(), impulse, steps, calls, drift_max, x1.copy()
        if not have_ind0:
            _eval(t, x, mode, s, xdot, model, ws, cp, res, sc)
            calls += 1
            ni = _indicators(mode, s, mus, res, ind0)
        ok = _eval(t + dt, x1, mode, s, xdot, model, ws, cp, res, sc)
        calls += 1
        ni = _indicators(mode, s, mus, res, ind1)
        if not ok:
            return SINGULAR, t, x.copy(), impulse, steps, calls, drift_max, x.copy()
        for j in range(ni):
            if ind0[j] >= 0.0 and ind1[j] < 0.0:
                return EVENT, t, x.copy(), impulse, steps, calls, drift_max, x.copy()
        if mode != FREE:
            # M-orthogonal projection onto g = 0, v_n = 0 (and v_t = 0 when sticking) with
            # M, j_n, j_t of the unprojected end state (the reference's `project`)
            gap = res[R_GAP]
            jn, jt, y2, y3 = sc[0], sc[1], sc[3], sc[4]
            Mff = ws[kchain.W_MFF]
            L = ws[kchain.W_L]
            yy = ws[kchain.W_Y]
            kchain._cholesky_solve(Mff, jn, nf, L, yy, y2)      # M⁻¹ j_n
            gnn = 0.0
            vn = 0.0
            for a in range(nf):
                gnn += jn[a] * y2[a]
            for a in range(nf):
                x1[a] -= y2[a] * (gap / gnn)
            for a in range(nf):
                vn += jn[a] * x1[nf + a]
            if mode == SLIDING:
                for a in range(nf):
                    x1[nf + a] -= y2[a] * (vn / gnn)
            else:
                kchain._cholesky_solve(Mff, jt, nf, L, yy, y3)  # M⁻¹ j_t
                gnt = 0.0
                gtt = 0.0
                vt = 0.0
                for a in range(nf):
                    gnt += jn[a] * y3[a]
                    gtt += jt[a] * y3[a]
                    vt += jt[a] * x1[nf + a]
                det = gnn * gtt - gnt * gnt
                an = (gtt * vn - gnt * vt) / det
                at = (gnn * vt - gnt * vn) / det
                for a in range(nf):
                    x1[nf + a] -= y2[a] * an + y3[a] * at
            drift = abs(gap)
            if drift > tol:
                return DRIFT, t, x.copy(), impulse, steps, calls, drift_max, x.copy()
            drift_max = max(drift_max, drift)
            have_ind0 = False
        else:
            ind0[0] = ind1[0]           # free flight: the end state is the next start
            have_ind0 = True
        if kchain._deflection_ratio(x1, model) > max_ratio:
            return kchain.DEFLECTION, t, x.copy(), impulse, steps, calls, drift_max, \
                x1.copy()
        for i in range(m):
            x[i] = x1[i]
        t = t + dt
        impulse += (dt / 6.0) * (l1 + 2.0 * l2 + 2.0 * l3 + l4)
        steps += 1
    return kchain.OK, t_target, x.copy(), impulse, steps, calls, drift_max, x.copy()
