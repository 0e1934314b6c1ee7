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
from typing import NamedTuple

import numpy as np


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import loops as kloops
from flexarm_ros.model.compiled import sensors as ksensors
from flexarm_ros.model.compiled import jit as _jit, jit_inline as _jit_inline, jit_raw as _jit_raw
from flexarm_ros.model.compiled.layout import Model, named

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


class Scratch(NamedTuple):
    """Work arrays of :func:`evaluate` / :func:`span` (nf free coordinates, m states)."""
    jn: np.ndarray      # (nf,) ∂(n·r)/∂q_free of the tool point
    jt: np.ndarray      # (nf,) ∂(t·r)/∂q_free
    y1: np.ndarray      # (nf,) M⁻¹f
    y2: np.ndarray      # (nf,) M⁻¹w (sliding) or M⁻¹j_n
    y3: np.ndarray      # (nf,) M⁻¹j_t
    w: np.ndarray       # (nf,) j_n − μ s j_t
    ff: np.ndarray      # (nf,) f of the free coordinates
    acc: np.ndarray     # (nf,) constrained accelerations
    res: np.ndarray     # (12,) the evaluation's results, R_*
    k1: np.ndarray      # (m,) RK4 stages
    k2: np.ndarray
    k3: np.ndarray
    k4: np.ndarray
    tmp: np.ndarray     # (m,) stage state
    x1: np.ndarray      # (m,) end of step
    xdot: np.ndarray    # (m,) the end state's rate (event functions)
    x: np.ndarray       # (m,) current state


def scratch(contact) -> tuple:
    """Work arrays for :func:`evaluate` / :func:`span` (allocated once per stepper), as the
    plain tuple they take (see :mod:`layout`; ``Scratch._make(sc).res`` reads the results)."""
    nf = contact.nf
    m = 2 * nf + contact.chain.nz
    e = np.empty
    return tuple(Scratch(jn=e(nf), jt=e(nf), y1=e(nf), y2=e(nf), y3=e(nf), w=e(nf),
                         ff=e(nf), acc=e(nf), res=e(12), k1=e(m), k2=e(m), k3=e(m), k4=e(m),
                         tmp=e(m), x1=e(m), xdot=e(m), x=e(m)))


@_jit_raw
def _eval(t, x, mode, s, out, model, ws, cp, sc):
    """ẋ of mode (``s`` the slip direction when sliding) into ``out``; the contact forces,
    gap and tool state into ``sc.res`` (R_*). Returns False at a singular constraint."""
    res = sc.res
    free = model.free
    presc = model.presc
    n = model.n
    nz = model.nz
    nf = free.shape[0]
    q = ws.q
    qd = ws.qd
    jn, jt, y1, y2, y3, w, ff, acc = sc.jn, sc.jt, sc.y1, sc.y2, sc.y3, sc.w, sc.ff, sc.acc
    for i in range(nf):
        q[free[i]] = x[i]
        qd[free[i]] = x[nf + i]
    kchain.fill_forces(t, q, qd, x[2 * nf:], model, ws)
    M = ws.M
    f = ws.f
    Mff = ws.Mff
    L = ws.L
    yy = ws.y
    tip = ws.tip
    Jo = ws.Jo
    Jpsi = ws.Jpsi
    pdd = ws.pdd
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
    ok = kchain.cholesky_solve(Mff, ff, nf, L, yy, y1)
    ln = 0.0
    lt = 0.0
    if ok and mode == SLIDING:
        mu = cp[CP_MU]
        for a in range(nf):
            w[a] = jn[a] - mu * s * jt[a]
        kchain.cholesky_solve(Mff, w, nf, L, yy, y2)
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
        kchain.cholesky_solve(Mff, jn, nf, L, yy, y2)
        kchain.cholesky_solve(Mff, jt, nf, L, yy, y3)
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
    zd = ws.zd
    for a in range(nf):
        out[a] = x[nf + a]
        out[nf + a] = acc[a] if ok else np.nan
    for a in range(nz):
        out[2 * nf + a] = zd[a]
    return ok


@_jit
def evaluate(t, x, mode, s, out, model_args, ws_args, cp, sc_args):
    """:func:`_eval` for Python callers (the stepper's samples; model, workspace and
    scratch as plain tuples, see :mod:`layout`)."""
    model, ws = named(model_args, ws_args)
    return _eval(t, x, mode, s, out, model, ws, cp, Scratch(*sc_args))


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


#: columns of a sample row (:func:`span`'s ``R``): the evaluation's R_* and the
#: cumulative normal impulse
S_IMPULSE = 9
SAMPLE_COLUMNS = 10


@_jit_inline
def _sample(k, tk, xk, mode, s, X, R, QDD, impulse, model, ws, cp, sc, out, acc, ACC,
            qdd):
    """Sample k at (tk, xk) in ``mode``: the state into X[k], the evaluation's results and
    the cumulative normal impulse into R[k], q̈ of the free coordinates (the right-hand
    side at the sample) into QDD[k], and the accelerometers of ``acc``
    (:func:`ksensors.pack`'s arrays) into ACC[k] from this evaluation's frames."""
    nf = model.free.shape[0]
    _eval(tk, xk, mode, s, out, model, ws, cp, sc)
    for i in range(xk.shape[0]):
        X[k, i] = xk[i]
    for j in range(S_IMPULSE):
        R[k, j] = sc.res[j]
    R[k, S_IMPULSE] = impulse
    free = model.free
    for a in range(nf):
        QDD[k, a] = out[nf + a]
        qdd[free[a]] = out[nf + a]
    if acc[0].shape[0]:
        presc = model.presc
        for j in range(presc.shape[0]):
            qdd[presc[j]] = ws.pdd[j]
        ksensors.fill_readings(ws.q, ws.qd, qdd, model, ws, acc[0], acc[1], acc[2], acc[3],
                           acc[4], ACC[k])


def span(x0, t0, t_target, h, mode, s, max_ratio, tol, model_args, ws_args, cp, sc_args,
         ts, k, X, R, QDD, impulse0, max_steps, acc, ACC):
    """RK4 steps of at most ``h`` in one contact mode from (t0, x0) towards ``t_target``
    (the reference's step sequence: dt = min(h, t_target − t)), projecting after each
    step in contact. Stops at the start of the first step with an event, excess drift or a
    singular constraint, or after ``max_steps`` accepted steps.

    Samples: the instants ts[k], ts[k + 1], … that an accepted step reaches are written
    (:func:`_sample`: state, R_* and cumulative impulse, q̈, accelerometers ``acc`` into
    ACC) — a sample inside a step from
    the cubic Hermite interpolant of the step (ẋ by the right-hand side at both ends, as
    :func:`loops.rk4_dense`; the impulse interpolated linearly within the step), one on a
    step's end (within 1e-12 s) from the step's own state; ``impulse0`` is the cumulative
    impulse at t0. The step never depends on the samples.

    Returns (code, t, x, normal impulse ∫λ dt of the accepted steps, accepted steps,
    evaluations, largest drift, offending state, next sample index) with code kchain.OK
    (t_target or max_steps reached), EVENT, DRIFT, SINGULAR, kchain.NON_FINITE or
    kchain.DEFLECTION (t, x the last good state; the offending state last). Model,
    workspace and scratch come as plain tuples (see :mod:`layout`). Python around the
    compiled core.
    """
    loc = np.empty((4, x0.shape[0]))
    qdd = np.empty(Model._make(model_args).n)
    ind = np.empty((2, 2))
    code, t, impulse, steps, calls, drift_max, bad, k = _span(
        x0, t0, t_target, h, mode, s, max_ratio, tol, model_args, ws_args, cp, sc_args, ts, k,
        X, R, QDD, impulse0, max_steps, acc, ACC, loc, qdd, ind)
    sc = Scratch(*sc_args)
    return (code, t, sc.x.copy(), impulse, steps, calls, drift_max,
            (sc.x1 if bad else sc.x).copy(), k)


@_jit_raw
def _span(x0, t0, t_target, h, mode, s, max_ratio, tol, model_args, ws_args, cp, sc_args,
          ts, k, X, R, QDD, impulse0, max_steps, acc, ACC, loc, qdd, ind):
    """:func:`span`'s loop without reference counting: returns (code, t, impulse, steps,
    evaluations, largest drift, offending state is sc.x1 (else sc.x), next sample); ``loc``
    (4, m), ``qdd`` (n,) and ``ind`` (2, 2) its scratch."""
    model, ws = named(model_args, ws_args)
    sc = Scratch(*sc_args)
    n_s = ts.shape[0]
    f0 = loc[0]
    f1 = loc[1]
    row = loc[2]
    sout = loc[3]
    m = x0.shape[0]
    nf = model.free.shape[0]
    nz = model.nz
    zlo = model.z_lo
    zhi = model.z_hi
    res = sc.res
    k1, k2, k3, k4, tmp, x1, xdot, x = sc.k1, sc.k2, sc.k3, sc.k4, sc.tmp, sc.x1, sc.xdot, \
        sc.x
    ind0 = ind[0]
    ind1 = ind[1]
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
        ok = _eval(t + eps * dt, x, mode, s, k1, model, ws, cp, sc)
        l1 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + 0.5 * dt * k1[i]
        ok = _eval(t + 0.5 * dt, tmp, mode, s, k2, model, ws, cp, sc) and ok
        l2 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + 0.5 * dt * k2[i]
        ok = _eval(t + 0.5 * dt, tmp, mode, s, k3, model, ws, cp, sc) and ok
        l3 = res[R_LN]
        for i in range(m):
            tmp[i] = x[i] + dt * k3[i]
        ok = _eval(t + (1.0 - eps) * dt, tmp, mode, s, k4, model, ws, cp, sc) and ok
        l4 = res[R_LN]
        calls += 4
        if not ok:
            return SINGULAR, t, impulse, steps, calls, drift_max, False, k
        finite = True
        for i in range(m):
            x1[i] = x[i] + (dt / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            if not math.isfinite(x1[i]):
                finite = False
        for a in range(nz):
            i = m - nz + a
            x1[i] = min(max(x1[i], zlo[a]), zhi[a])
        if not finite:
            return kchain.NON_FINITE, t, impulse, steps, calls, drift_max, True, k
        if not have_ind0:
            _eval(t, x, mode, s, xdot, model, ws, cp, sc)
            calls += 1
            ni = _indicators(mode, s, mus, res, ind0)
        ok = _eval(t + dt, x1, mode, s, xdot, model, ws, cp, sc)
        calls += 1
        ni = _indicators(mode, s, mus, res, ind1)
        if not ok:
            return SINGULAR, t, impulse, steps, calls, drift_max, False, k
        for j in range(ni):
            # free flight: any step ending inside the wall holds an event, also one that
            # starts a hair inside it after a bounce or lift-off (the reference's rule)
            if ind1[j] < 0.0 and (ind0[j] >= 0.0 or mode == FREE):
                return EVENT, t, impulse, steps, calls, drift_max, False, k
        if mode != FREE:
            # M-orthogonal projection onto g = 0, v_n = 0 (and v_t = 0 when sticking) with
            # M, j_n, j_t of the unprojected end state (the reference's `project`)
            gap = res[R_GAP]
            jn, jt, y2, y3 = sc.jn, sc.jt, sc.y2, sc.y3
            Mff = ws.Mff
            L = ws.L
            yy = ws.y
            kchain.cholesky_solve(Mff, jn, nf, L, yy, y2)      # M⁻¹ j_n
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
                kchain.cholesky_solve(Mff, jt, nf, L, yy, y3)  # M⁻¹ j_t
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
                return DRIFT, t, impulse, steps, calls, drift_max, False, k
            drift_max = max(drift_max, drift)
            have_ind0 = False
        else:
            ind0[0] = ind1[0]           # free flight: the end state is the next start
            have_ind0 = True
        if kchain.deflection_ratio(x1, model) > max_ratio:
            return kchain.DEFLECTION, t, impulse, steps, calls, drift_max, True, k
        t1 = t + dt
        dimp = (dt / 6.0) * (l1 + 2.0 * l2 + 2.0 * l3 + l4)
        seps = 1e-12 * max(1.0, t_target)
        if k < n_s and ts[k] < t1 - seps:         # samples inside the step
            for i in range(m):
                f0[i] = k1[i]
            _eval(t + (1.0 - eps) * dt, x1, mode, s, f1, model, ws, cp, sc)
            calls += 1
            while k < n_s and ts[k] < t1 - seps:
                th = (ts[k] - t) / dt
                kloops.hermite(th, dt, x, f0, x1, f1, row)
                _sample(k, ts[k], row, mode, s, X, R, QDD, impulse0 + impulse + th * dimp,
                        model, ws, cp, sc, sout, acc, ACC, qdd)
                calls += 1
                k += 1
        if k < n_s and ts[k] <= t1 + seps:         # a sample on the step's end
            _sample(k, ts[k], x1, mode, s, X, R, QDD, impulse0 + impulse + dimp, model, ws,
                    cp, sc, sout, acc, ACC, qdd)
            calls += 1
            k += 1
        for i in range(m):
            x[i] = x1[i]
        t = t1
        impulse += dimp
        steps += 1
        if steps >= max_steps:
            return kchain.OK, t, impulse, steps, calls, drift_max, False, k
    return kchain.OK, t_target, impulse, steps, calls, drift_max, False, k
