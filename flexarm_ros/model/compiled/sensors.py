"""Compiled accelerometer read-out: :func:`sensors.true_value` for accelerometers, from the
frames the kernel left in its workspace (``kchain.W_FR``/``W_FJ``) at the instant's state.

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
from flexarm_ros.model.compiled import jit as _jit

HUB, TIP, BEAM = 0, 1, 2


def pack(chain, sensors) -> tuple:
    """The accelerometers of ``sensors`` (SensorModels) as arrays for :func:`readings`:
    (index into ``sensors``, ints (m, 3) = link, body, e0; floats (m, 5) = p_x, p_y, axis
    x, axis y, r_h; basis φ, φ′ (m, ne_max) and S (m, ne_max, ne_max))."""
    acc = [j for j, sm in enumerate(sensors) if sm.spec.kind == "accelerometer"]
    nemax = max(lm.beam.n for lm in chain.links)
    m = len(acc)
    ints = np.zeros((m, 3), dtype=np.int64)
    flt = np.zeros((m, 5))
    phi = np.zeros((m, nemax))
    slope = np.zeros((m, nemax))
    S = np.zeros((m, nemax, nemax))
    for r, j in enumerate(acc):
        sm = sensors[j]
        lm = chain.links[sm.link]
        body = {"hub": HUB, "tip": TIP, "beam": BEAM}[sm.spec.body]
        ints[r] = (sm.link, body, lm.eta.start)
        pos = np.asarray(sm.spec.position, float)
        flt[r] = (pos[0], pos[1] if len(pos) > 1 else 0.0, sm.axis[0], sm.axis[1],
                  lm.beam.hub_radius)
        if body == BEAM:
            ne = lm.beam.n
            ph, sl, SS = sm.basis
            phi[r, :ne], slope[r, :ne], S[r, :ne, :ne] = ph, sl, SS
    return np.array(acc, dtype=np.int64), ints, flt, phi, slope, S


@_jit
def readings(q, qd, qdd, model, ws, ints, flt, phi, slope, S, out):
    """out[r] = specific force (m/s²) of accelerometer r on its axis, from the frames in
    ``ws`` (filled by a kernel evaluation at this (q, q̇)) and q̈ of every coordinate."""
    n = model[kchain.M_N]
    ne_all = model[kchain.M_NE]
    fs = model[15]
    g = model[14]
    FR = ws[kchain.W_FR]
    FJ = ws[kchain.W_FJ]
    for r in range(ints.shape[0]):
        k = ints[r, 0]
        body = ints[r, 1]
        e0 = ints[r, 2]
        fj = 0 if body == BEAM else body
        ox = FR[k, fj, 0]
        oy = FR[k, fj, 1]
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
        if body == BEAM:
            ne = ne_all[k]
            x = flt[r, 0]
            seta_eta = 0.0
            w = 0.0
            wd = 0.0
            wdd = 0.0
            ud = 0.0
            udd_q = 0.0     # −(Sη)·η̈
            acc_ax = 0.0
            for a in range(ne):
                w += phi[r, a] * q[e0 + a]
                wd += phi[r, a] * qd[e0 + a]
                wdd += phi[r, a] * qdd[e0 + a]
                angle += slope[r, a] * q[e0 + a]
                if fs:
                    se = 0.0
                    sed = 0.0
                    for b in range(ne):
                        se += S[r, a, b] * q[e0 + b]
                        sed += S[r, a, b] * qd[e0 + b]
                    seta_eta += se * q[e0 + a]
                    ud -= se * qd[e0 + a]
                    udd_q -= se * qdd[e0 + a]
                    acc_ax -= sed * qd[e0 + a]
            sx = flt[r, 4] + x - 0.5 * seta_eta
            sy = w
            Asx = c * sx - s * sy
            Asy = s * sx + c * sy
            # A ṡ
            Adx = c * ud - s * wd
            Ady = s * ud + c * wd
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
