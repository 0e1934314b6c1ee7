"""Compiled chain kernel: the same equations as :mod:`chain`, written as scalar loops for numba.

:class:`chain.Chain` is the readable, vectorized numpy reference. This module evaluates
exactly the same M(q), h(q, q̇) and Q_grav (same points, same S(x), same propagation) in
loops that numba compiles, and runs a whole fixed-step RK4 integration inside compiled
code. Tests check both give the same numbers to round-off; without numba (or with
``FLEXARM_NO_NUMBA=1``) the chain falls back to the numpy path.

Measured on this machine (bench/bench_ladder.py): one right-hand side of the two-link
cubic arm takes ~250 µs in numpy and a few µs compiled.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.programs import eval_motion, eval_torque

from flexarm_ros.model.compiled import HAVE_NUMBA, jit as _jit, jit_inline as _jit_inline  # noqa: F401
from flexarm_ros.model.drives import actuator_rate, actuator_torque, backlash_torque

eval_torque_c = _jit(eval_torque)
eval_motion_c = _jit(eval_motion)
actuator_torque_c = actuator_torque      # compiled in drives (they call each other)
actuator_rate_c = actuator_rate
backlash_torque_c = backlash_torque

#: RK4's first and last stages are evaluated STAGE_EPS·h inside the step, so an input that
#: jumps exactly on a step boundary is seen with its value on that step (right limit at the
#: start, left limit at the end) instead of leaking an O(h) impulse into the neighbour.
STAGE_EPS = 1e-9

# Positions in the model tuple (Chain._pack) used by index, and workspace slots
# (workspace()); numba folds these module constants at compile time.
M_N, M_NL, M_E0, M_NE, M_NPT, M_X, M_PHI, M_FREE, M_PRESC = 0, 1, 3, 4, 8, 9, 11, 20, 21
M_K, M_D, M_MCODE, M_MPAR = 18, 19, 22, 23
M_TIDX, M_TCODE, M_TPAR, M_TTIMES, M_TVALUES, M_TLEN = 24, 25, 26, 27, 28, 29
M_AKIND, M_APAR, M_AZI, M_BIDX, M_BPAR, M_NZ, M_ZLO, M_ZHI = 31, 32, 33, 34, 35, 36, 37, 38
(W_Q, W_QD, W_M, W_H, W_QG, W_JO, W_JPSI, W_SETA, W_JX, W_JY, W_JTX, W_JTY, W_MFF, W_FF,
 W_L, W_Y, W_ACC, W_PDD, W_F, W_XDOT, W_ZD, W_TIP, W_FR, W_FJ) = range(24)

# status codes of the compiled loop
OK, NON_FINITE, DEFLECTION, NEWTON = 0, 1, 2, 3


@_jit
def _add_body(M, h, Qg, m, inertia, cgx, cgy, ox, oy, Jo, cox, coy, psi, Jpsi, psid, g,
              nact, Jx, Jy):
    if m == 0.0 and inertia == 0.0:
        return
    c = math.cos(psi)
    s = math.sin(psi)
    ax = c * cgx - s * cgy
    ay = s * cgx + c * cgy
    cx = cox - psid * psid * ax
    cy = coy - psid * psid * ay
    for i in range(nact):
        Jx[i] = Jo[0, i] - ay * Jpsi[i]
        Jy[i] = Jo[1, i] + ax * Jpsi[i]
    for i in range(nact):
        h[i] += m * (Jx[i] * cx + Jy[i] * cy)
        Qg[i] += m * (Jx[i] * g[0] + Jy[i] * g[1])
        for j in range(i, nact):
            M[i, j] += m * (Jx[i] * Jx[j] + Jy[i] * Jy[j]) + inertia * Jpsi[i] * Jpsi[j]


def workspace(model):
    """Scratch arrays for :func:`chain_terms` / :func:`rhs_into` (allocated once per run)."""
    n = model[M_N]
    nemax = model[M_PHI].shape[2]
    nf = model[M_FREE].shape[0]
    npr = model[M_PRESC].shape[0]
    return (np.empty(n), np.empty(n), np.empty((n, n)), np.empty(n), np.empty(n),
            np.empty((2, n)), np.empty(n), np.empty(nemax), np.empty(n), np.empty(n),
            np.empty(n), np.empty(n), np.empty((nf, nf)), np.empty(nf), np.empty((nf, nf)),
            np.empty(nf), np.empty(nf), np.empty(max(npr, 1)), np.empty(n),
            np.empty(2 * nf + model[M_NZ]), np.empty(max(model[M_NZ], 1)), np.empty(6),
            np.empty((model[M_NL], 2, 6)), np.empty((model[M_NL], 2, 3, n)))


@_jit_inline
def _store_frame(ws, k, j, ox, oy, cox, coy, psi, psid, Jo, Jpsi, n):
    """Keep link k's hub (j = 0) or tip (j = 1) frame: ws[W_FR][k, j] = (o, c_o, ψ, ψ̇),
    ws[W_FJ][k, j] = (∂o_x/∂q, ∂o_y/∂q, ∂ψ/∂q) — what the sensors read."""
    fr = ws[W_FR]
    fj = ws[W_FJ]
    fr[k, j, 0] = ox
    fr[k, j, 1] = oy
    fr[k, j, 2] = cox
    fr[k, j, 3] = coy
    fr[k, j, 4] = psi
    fr[k, j, 5] = psid
    for i in range(n):
        fj[k, j, 0, i] = Jo[0, i]
        fj[k, j, 1, i] = Jo[1, i]
        fj[k, j, 2, i] = Jpsi[i]


@_jit_inline
def chain_terms(q, qd, model, ws):
    """Fill ws' M (n, n), h (n,), Qg (n,) at (q, q̇): chain.Chain.kinematics in loops; the
    last tip frame's (o, c_o, ψ, ψ̇) go to ws[W_TIP], its Jacobians stay in ws[W_JO]/[W_JPSI].

    Per mass point only the leading ``EXT[k, p]`` elastic coordinates can be non-zero in
    φ(x_p) and S(x_p) (finite elements and differences grow from the root), so the loops
    stop there.
    """
    n = model[M_N]
    nl = model[M_NL]
    ij = model[2]
    e0 = model[M_E0]
    ne = model[M_NE]
    bodies = model[5]
    joff = model[6]
    rh = model[7]
    npt = model[M_NPT]
    X = model[M_X]
    MP = model[10]
    PHI = model[M_PHI]
    SS = model[12]
    SLOPE = model[13]
    g = model[14]
    fs = model[15]
    base_angle = model[16]
    Mdrive = model[17]
    EXT = model[30]
    M = ws[W_M]
    h = ws[W_H]
    Qg = ws[W_QG]
    Jo = ws[W_JO]
    Jpsi = ws[W_JPSI]
    Seta = ws[W_SETA]
    Jx = ws[W_JX]
    Jy = ws[W_JY]
    Jtx = ws[W_JTX]
    Jty = ws[W_JTY]
    for i in range(n):
        h[i] = 0.0
        Qg[i] = 0.0
        Jpsi[i] = 0.0
        Jo[0, i] = 0.0
        Jo[1, i] = 0.0
        for j in range(n):
            M[i, j] = Mdrive[i, j] if j >= i else 0.0
    ox = 0.0
    oy = 0.0
    cox = 0.0
    coy = 0.0
    psi = base_angle
    psid = 0.0
    has_g = g[0] != 0.0 or g[1] != 0.0
    for k in range(nl):
        nk = ne[k]
        s0 = e0[k]
        nact = s0 + nk
        if k > 0:   # joint on the previous tip frame at joint_offset
            px = joff[k - 1, 0]
            py = joff[k - 1, 1]
            if px != 0.0 or py != 0.0:
                c = math.cos(psi)
                s = math.sin(psi)
                ax = c * px - s * py
                ay = s * px + c * py
                ox += ax
                oy += ay
                for i in range(n):
                    Jo[0, i] -= ay * Jpsi[i]
                    Jo[1, i] += ax * Jpsi[i]
                cox -= psid * psid * ax
                coy -= psid * psid * ay
        jj = ij[k]
        psi += q[jj]
        Jpsi[jj] += 1.0
        psid += qd[jj]
        _store_frame(ws, k, 0, ox, oy, cox, coy, psi, psid, Jo, Jpsi, n)
        _add_body(M, h, Qg, bodies[k, 0, 0], bodies[k, 0, 1], bodies[k, 0, 2],
                  bodies[k, 0, 3], ox, oy, Jo, cox, coy, psi, Jpsi, psid, g, nact, Jx, Jy)
        c = math.cos(psi)
        s = math.sin(psi)
        P = npt[k]
        tox = 0.0
        toy = 0.0
        tcx = 0.0
        tcy = 0.0
        psid2 = psid * psid
        for p in range(P + 1):
            ext = EXT[k, p]
            uf = 0.0
            ax_acc = 0.0
            ud = 0.0
            w = 0.0
            wd = 0.0
            for a in range(ext):
                w += PHI[k, p, a] * q[s0 + a]
                wd += PHI[k, p, a] * qd[s0 + a]
            if fs:
                for a in range(ext):
                    acc = 0.0
                    for b in range(ext):
                        acc += SS[k, p, a, b] * q[s0 + b]
                    Seta[a] = acc
                    uf -= 0.5 * acc * q[s0 + a]
                    ud -= acc * qd[s0 + a]
                    # −η̇ᵀSη̇ over the upper triangle (S is symmetric)
                    va = qd[s0 + a]
                    accd = 0.5 * SS[k, p, a, a] * va
                    for b in range(a + 1, ext):
                        accd += SS[k, p, a, b] * qd[s0 + b]
                    ax_acc -= 2.0 * accd * va
            else:
                for a in range(ext):
                    Seta[a] = 0.0
            sx = rh[k] + X[k, p] + uf
            sy = w
            Asx = c * sx - s * sy
            Asy = s * sx + c * sy
            Adx = c * ud - s * wd
            Ady = s * ud + c * wd
            cx = cox - psid2 * Asx - 2.0 * psid * Ady + ax_acc * c
            cy = coy - psid2 * Asy + 2.0 * psid * Adx + ax_acc * s
            na = s0 + ext if p < P else nact
            for i in range(s0):
                Jx[i] = Jo[0, i] - Asy * Jpsi[i]
                Jy[i] = Jo[1, i] + Asx * Jpsi[i]
            for i in range(s0, nact):
                Jx[i] = 0.0
                Jy[i] = 0.0
            for a in range(ext):
                Jx[s0 + a] = -c * Seta[a] - s * PHI[k, p, a]
                Jy[s0 + a] = -s * Seta[a] + c * PHI[k, p, a]
            if p < P:
                m = MP[k, p]
                if has_g:
                    for i in range(na):
                        Qg[i] += m * (Jx[i] * g[0] + Jy[i] * g[1])
                for i in range(na):
                    h[i] += m * (Jx[i] * cx + Jy[i] * cy)
                    mjx = m * Jx[i]
                    mjy = m * Jy[i]
                    for j in range(i, na):
                        M[i, j] += mjx * Jx[j] + mjy * Jy[j]
            else:
                tox = ox + Asx
                toy = oy + Asy
                tcx = cx
                tcy = cy
                for i in range(nact):
                    Jtx[i] = Jx[i]
                    Jty[i] = Jy[i]
        # tip frame
        ox = tox
        oy = toy
        cox = tcx
        coy = tcy
        for i in range(nact):
            Jo[0, i] = Jtx[i]
            Jo[1, i] = Jty[i]
        for a in range(nk):
            psi += SLOPE[k, a] * q[s0 + a]
            Jpsi[s0 + a] += SLOPE[k, a]
        psid = 0.0
        for i in range(n):
            psid += Jpsi[i] * qd[i]
        _store_frame(ws, k, 1, ox, oy, cox, coy, psi, psid, Jo, Jpsi, n)
        _add_body(M, h, Qg, bodies[k, 1, 0], bodies[k, 1, 1], bodies[k, 1, 2],
                  bodies[k, 1, 3], ox, oy, Jo, cox, coy, psi, Jpsi, psid, g, nact, Jx, Jy)
    for i in range(n):
        for j in range(i):
            M[i, j] = M[j, i]
    # the last tip frame (its Jacobians stay in ws[W_JO], ws[W_JPSI]): the tool's frame
    tip = ws[W_TIP]
    tip[0] = ox
    tip[1] = oy
    tip[2] = cox
    tip[3] = coy
    tip[4] = psi
    tip[5] = psid


@_jit
def _cholesky_solve(A, b, nf, L, y, x):
    """Solve A x = b for symmetric positive-definite A (nf × nf); False if A is not SPD."""
    for j in range(nf):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if d <= 0.0:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, nf):
            v = A[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    for i in range(nf):
        v = b[i]
        for k in range(i):
            v -= L[i, k] * y[k]
        y[i] = v / L[i, i]
    for i in range(nf - 1, -1, -1):
        v = y[i]
        for k in range(i + 1, nf):
            v -= L[k, i] * x[k]
        x[i] = v / L[i, i]
    return True


@_jit_inline
def forces(t, q, qd, z, model, ws):
    """Fill ws' M and f = Q_input + Q_coupling + Q_grav − h − K q − D q̇ − M[:, p] q̈_p at
    (t, q, q̇, z), with the prescribed coordinates of q, q̇ set from their programs at time t,
    and the actuator state rates ż into ws[W_ZD]."""
    n = model[M_N]
    K = model[M_K]
    D = model[M_D]
    presc = model[M_PRESC]
    mcode = model[M_MCODE]
    mpar = model[M_MPAR]
    tidx = model[M_TIDX]
    tcode = model[M_TCODE]
    tpar = model[M_TPAR]
    ttimes = model[M_TTIMES]
    tvalues = model[M_TVALUES]
    tlen = model[M_TLEN]
    akind = model[M_AKIND]
    apar = model[M_APAR]
    azi = model[M_AZI]
    bidx = model[M_BIDX]
    bpar = model[M_BPAR]
    M = ws[W_M]
    h = ws[W_H]
    Qg = ws[W_QG]
    pdd = ws[W_PDD]
    f = ws[W_F]
    zd = ws[W_ZD]
    npr = presc.shape[0]
    for j in range(npr):
        th, thd, thdd = eval_motion_c(mcode[j], mpar[j], t)
        q[presc[j]] = th
        qd[presc[j]] = thd
        pdd[j] = thdd
    chain_terms(q, qd, model, ws)
    for i in range(n):
        v = Qg[i] - h[i]
        for j in range(n):
            v -= K[i, j] * q[j] + D[i, j] * qd[j]
        f[i] = v
    for j in range(tidx.shape[0]):
        Lj = tlen[j]
        u = eval_torque_c(tcode[j], tpar[j], ttimes[j, :Lj], tvalues[j, :Lj], t)
        w = qd[tidx[j]]
        zj = z[azi[j]] if azi[j] >= 0 else 0.0
        f[tidx[j]] += actuator_torque_c(akind[j], apar[j], u, w, zj)
        if azi[j] >= 0:
            zd[azi[j]] = actuator_rate_c(akind[j], apar[j], u, w, zj)
    for j in range(bidx.shape[0]):
        im = bidx[j, 0]
        jl = bidx[j, 1]
        tau = backlash_torque_c(bpar[j, 0], bpar[j, 1], bpar[j, 2], q[im] - q[jl],
                                qd[im] - qd[jl])
        f[im] -= tau
        f[jl] += tau
    for j in range(npr):
        for i in range(n):
            f[i] -= M[i, presc[j]] * pdd[j]


@_jit
def rhs_into(t, x, out, model, ws):
    """out = ẋ for x = [q_free, q̇_free, z] (chain.Chain.rhs, compiled, no allocation)."""
    free = model[M_FREE]
    q = ws[W_Q]
    qd = ws[W_QD]
    M = ws[W_M]
    Mff = ws[W_MFF]
    ff = ws[W_FF]
    L = ws[W_L]
    y = ws[W_Y]
    acc = ws[W_ACC]
    f = ws[W_F]
    nf = free.shape[0]
    nz = model[M_NZ]
    for i in range(nf):
        q[free[i]] = x[i]
        qd[free[i]] = x[nf + i]
    forces(t, q, qd, x[2 * nf:], model, ws)
    for a in range(nf):
        ff[a] = f[free[a]]
        for b in range(nf):
            Mff[a, b] = M[free[a], free[b]]
    if not _cholesky_solve(Mff, ff, nf, L, y, acc):
        for a in range(nf):
            acc[a] = np.nan
    for a in range(nf):
        out[a] = x[nf + a]
        out[nf + a] = acc[a]
    zd = ws[W_ZD]
    for a in range(nz):
        out[2 * nf + a] = zd[a]


@_jit
def rhs(t, x, model, ws):
    """ẋ for x = [q_free, q̇_free, z] as a new array."""
    out = np.empty(x.shape[0])
    rhs_into(t, x, out, model, ws)
    return out


@_jit
def _deflection_ratio(x, model):
    """max over beams of |w(L)|/L (elastic coordinates are never prescribed)."""
    n = model[M_N]
    nl = model[M_NL]
    e0 = model[M_E0]
    ne = model[M_NE]
    npt = model[M_NPT]
    PHI = model[M_PHI]
    free = model[M_FREE]
    nf = free.shape[0]
    worst = 0.0
    for k in range(nl):
        w = 0.0
        for i in range(nf):
            j = free[i] - e0[k]
            if j >= 0 and j < ne[k]:
                w += PHI[k, npt[k], j] * x[i]
        r = abs(w) / model[M_X][k, npt[k]]   # X at the tip row = beam length
        if r > worst:
            worst = r
    return worst












