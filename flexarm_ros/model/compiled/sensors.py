"""Compiled accelerometer read-out: :func:`sensors.true_value` for accelerometers, from the
frames the kernel left in its workspace (``ws.frames`` / ``ws.frame_jac``) at the instant's
state, the beam point through the kernel's own :func:`chain.beam_point`.

The equations are those of :meth:`chain.Chain.point_kinematics` (the numpy reference):
on a beam at abscissa x, with the hub frame (o, J_o, c_o, ψ, J_ψ, ψ̇) and the basis
(φ(x), φ′(x), S(x)),

    s = [r_h + x − ½ ηᵀS η,  φᵀη],   A = R(ψ),   r = o + A s,
    J = J_o + (E A s) J_ψ + A [−Sη; φᵀ] (on η),
    c = c_o − ψ̇² A s + 2 ψ̇ E A ṡ − (η̇ᵀS η̇) A ê₁,

on a hub / tip body at offset p: r = o + A p, J = J_o + (E A p) J_ψ, c = c_o − ψ̇² A p.
The reading is the specific force f = J q̈ + c − g on the sensing axis turned with the
local frame angle (ψ + φ′ᵀη on a beam). Tests check it against the numpy path to
round-off (test_sensors.py).
"""

from __future__ import annotations

import math

import numpy as np


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import jit as _jit, jit_inline as _jit_inline, jit_raw as _jit_raw
from flexarm_ros.model.compiled.layout import Model, named

HUB, TIP, BEAM, ROD = 0, 1, 2, 3


def no_accelerometers() -> tuple:
    """:func:`pack`'s arrays (after the index) for no accelerometer."""
    return (np.zeros((0, 3), dtype=np.int64), np.zeros((0, 5)), np.zeros((0, 1, 1)),
            np.zeros((0, 1)), np.zeros((0, 1, 1, 1)))


def pack(chain, sensors) -> tuple:
    """The accelerometers of ``sensors`` (SensorModels) as arrays for :func:`readings`:
    (index into ``sensors``, ints (m, 3) = link, body, e0; floats (m, 5) = p_x, p_y, axis
    x, axis y, r_h; basis φ (m, 1, max(ne_max, P_max)), φ′ (m, ne_max) and S (m, 1,
    ne_max, ne_max): φ and S in the model's per-point layout, one point per
    accelerometer). On a rod (body ROD): φ[r, 0, :P] the integration row W(x), φ′ the
    row ∂θ/∂η and S[r, 0, 0] the row ∂ε/∂η at its abscissa (model/rod.py)."""
    acc = [j for j, sm in enumerate(sensors) if sm.spec.kind == "accelerometer"]
    nemax = max(lm.beam.n for lm in chain.links)
    pmax = max(len(lm.beam.x) for lm in chain.links)
    m = len(acc)
    ints = np.zeros((m, 3), dtype=np.int64)
    flt = np.zeros((m, 5))
    phi = np.zeros((m, 1, max(nemax, pmax)))
    slope = np.zeros((m, nemax))
    S = np.zeros((m, 1, nemax, nemax))
    for r, j in enumerate(acc):
        sm = sensors[j]
        lm = chain.links[sm.link]
        body = {"hub": HUB, "tip": TIP, "beam": BEAM}[sm.spec.body]
        if body == BEAM and lm.beam.rod is not None:
            body = ROD
        ints[r] = (sm.link, body, lm.eta.start)
        pos = np.asarray(sm.spec.position, float)
        flt[r] = (pos[0], pos[1] if len(pos) > 1 else 0.0, sm.axis[0], sm.axis[1],
                  lm.beam.hub_radius)
        if body == ROD:         # the integration row, ∂θ/∂η and ∂ε/∂η at its abscissa
            w, t_row, c_row = lm.beam.rod.point_rows(pos[0])
            ne = lm.beam.n
            phi[r, 0, :len(w)], slope[r, :ne], S[r, 0, 0, :ne] = w, t_row, c_row
        elif body == BEAM:
            ne = lm.beam.n
            ph, sl, SS = sm.basis
            phi[r, 0, :ne], slope[r, :ne], S[r, 0, :ne, :ne] = ph, sl, SS
    return np.array(acc, dtype=np.int64), ints, flt, phi, slope, S


@_jit
def readings(q, qd, qdd, model_args, ws_args, ints, flt, phi, slope, S, out):
    """out[r] = specific force (m/s²) of accelerometer r on its axis, from the frames in
    the workspace (filled by a kernel evaluation at this (q, q̇)) and q̈ of every
    coordinate (model and workspace as plain tuples, see :mod:`layout`)."""
    model, ws = named(model_args, ws_args)
    fill_readings(q, qd, qdd, model, ws, ints, flt, phi, slope, S, out)


def table(ts, X, QDD, given, model_args, ws_args, ints, flt, phi, slope, S, out):
    """:func:`readings` of the states X[k] = [q_free, q̇_free, z] at the instants ts[k]
    into out[k] (one kernel evaluation per row for the frames): q̈ of the free coordinates
    from QDD[k] when ``given`` (e.g. the contact stepper's constrained accelerations), else
    from the chain's right-hand side there; the prescribed ones from their programs.
    Python around the compiled core."""
    _table(ts, X, QDD, given, model_args, ws_args, ints, flt, phi, slope, S, out,
           np.empty(X.shape[1]), np.empty(Model._make(model_args).n))


@_jit_raw
def _table(ts, X, QDD, given, model_args, ws_args, ints, flt, phi, slope, S, out, xdot, qdd):
    """:func:`table` without reference counting (``xdot``, ``qdd`` its scratch)."""
    model, ws = named(model_args, ws_args)
    free = model.free
    presc = model.presc
    nf = free.shape[0]
    for k in range(ts.shape[0]):
        kchain.rhs_into(ts[k], X[k], xdot, model, ws)
        for a in range(nf):
            qdd[free[a]] = QDD[k, a] if given else xdot[nf + a]
        for j in range(presc.shape[0]):
            qdd[presc[j]] = ws.pdd[j]
        fill_readings(ws.q, ws.qd, qdd, model, ws, ints, flt, phi, slope, S, out[k])


@_jit_inline
def _rod_point(q, qd, qdd, e0, ne, k, model, phi, slope, S, r, rh, c, s):
    """A point on rod link k at the abscissa of accelerometer r (the rows :func:`pack`
    stored): A s, A ṡ, A s̈ (with the coordinates' q̈) and θ(x) − ψ, from the rod's
    integrands at its Gauss points (:func:`flexarm_ros.model.compiled.chain.rod_local`'s
    equations at one row of W)."""
    T = model.rod_T
    C = model.rod_C
    P = model.npt[k]
    sx = rh
    sy = 0.0
    vx = 0.0
    vy = 0.0
    ax = 0.0
    ay = 0.0
    for i in range(P):
        th = 0.0
        thd = 0.0
        thdd = 0.0
        ep = 0.0
        epd = 0.0
        epdd = 0.0
        for a in range(ne):
            th += T[k, i, a] * q[e0 + a]
            thd += T[k, i, a] * qd[e0 + a]
            thdd += T[k, i, a] * qdd[e0 + a]
            ep += C[k, i, a] * q[e0 + a]
            epd += C[k, i, a] * qd[e0 + a]
            epdd += C[k, i, a] * qdd[e0 + a]
        ct = math.cos(th)
        st = math.sin(th)
        fac = 1.0 + ep
        w = phi[r, 0, i]
        sx += w * fac * ct
        sy += w * fac * st
        vx += w * (epd * ct - fac * thd * st)
        vy += w * (epd * st + fac * thd * ct)
        # f̈ = ε̈ t + (1 + ε) θ̈ n + 2 ε̇ θ̇ n − (1 + ε) θ̇² t
        ax += w * (epdd * ct - fac * thdd * st - 2.0 * epd * thd * st - fac * thd * thd * ct)
        ay += w * (epdd * st + fac * thdd * ct + 2.0 * epd * thd * ct - fac * thd * thd * st)
    th_x = 0.0
    for a in range(ne):
        th_x += slope[r, a] * q[e0 + a]
    return (c * sx - s * sy, s * sx + c * sy, c * vx - s * vy, s * vx + c * vy,
            c * ax - s * ay, s * ax + c * ay, th_x)


@_jit_inline
def fill_readings(q, qd, qdd, model, ws, ints, flt, phi, slope, S, out):
    """:func:`readings` on the named model and workspace."""
    n = model.n
    ne_all = model.ne
    fs = model.foreshortening
    g = model.gravity
    FR = ws.frames
    FJ = ws.frame_jac
    Seta = ws.Seta
    if not fs:                  # kchain.beam_point leaves Sη alone then
        for a in range(Seta.shape[0]):
            Seta[a] = 0.0
    for r in range(ints.shape[0]):
        k = ints[r, 0]
        body = ints[r, 1]
        e0 = ints[r, 2]
        fj = 0 if body == BEAM or body == ROD else body     # a beam point: its hub frame
        cox = FR[k, fj, 2]
        coy = FR[k, fj, 3]
        psi = FR[k, fj, 4]
        psid = FR[k, fj, 5]
        c = math.cos(psi)
        s = math.sin(psi)
        # J_o q̈ and J_ψ q̈ of the frame
        aox = cox
        aoy = coy
        apsi = 0.0
        for i in range(n):
            aox += FJ[k, fj, 0, i] * qdd[i]
            aoy += FJ[k, fj, 1, i] * qdd[i]
            apsi += FJ[k, fj, 2, i] * qdd[i]
        angle = psi
        if body == ROD:
            Asx, Asy, Adx, Ady, Addx, Addy, th_x = _rod_point(q, qd, qdd, e0, ne_all[k],
                                                             k, model, phi, slope, S, r,
                                                             flt[r, 4], c, s)
            angle += th_x
            ax = aox - Asy * apsi + Addx - psid * psid * Asx - 2.0 * psid * Ady
            ay = aoy + Asx * apsi + Addy - psid * psid * Asy + 2.0 * psid * Adx
        elif body == BEAM:
            ne = ne_all[k]
            Asx, Asy, Adx, Ady, acc_ax = kchain.beam_point(q, qd, e0, ne, phi, S, r, 0, fs,
                                                           flt[r, 4] + flt[r, 0], c, s, Seta)
            wdd = 0.0
            udd_q = 0.0     # −(Sη)·η̈
            for a in range(ne):
                wdd += phi[r, 0, a] * qdd[e0 + a]
                udd_q -= Seta[a] * qdd[e0 + a]
                angle += slope[r, a] * q[e0 + a]
            # A (∂s/∂η) η̈
            Addx = c * udd_q - s * wdd
            Addy = s * udd_q + c * wdd
            ax = (aox - Asy * apsi + Addx - psid * psid * Asx - 2.0 * psid * Ady
                  + acc_ax * c)
            ay = (aoy + Asx * apsi + Addy - psid * psid * Asy + 2.0 * psid * Adx
                  + acc_ax * s)
        else:
            px = flt[r, 0]
            py = flt[r, 1]
            Apx = c * px - s * py
            Apy = s * px + c * py
            ax = aox - Apy * apsi - psid * psid * Apx
            ay = aoy + Apx * apsi - psid * psid * Apy
        fx = ax - g[0]
        fy = ay - g[1]
        ca = math.cos(angle)
        sa = math.sin(angle)
        ex = ca * flt[r, 2] - sa * flt[r, 3]
        ey = sa * flt[r, 2] + ca * flt[r, 3]
        out[r] = fx * ex + fy * ey
