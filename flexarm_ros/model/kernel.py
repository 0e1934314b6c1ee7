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
import os

import numpy as np

from .programs import eval_motion, eval_torque

try:  # pragma: no cover - exercised by whichever environment runs the tests
    if os.environ.get("FLEXARM_NO_NUMBA"):
        raise ImportError("disabled by FLEXARM_NO_NUMBA")
    import numba
    HAVE_NUMBA = True
    _jit = numba.njit(cache=True)
except ImportError:
    HAVE_NUMBA = False

    def _jit(f):
        return f

eval_torque_c = _jit(eval_torque)
eval_motion_c = _jit(eval_motion)

#: RK4's first and last stages are evaluated STAGE_EPS·h inside the step, so an input that
#: jumps exactly on a step boundary is seen with its value on that step (right limit at the
#: start, left limit at the end) instead of leaking an O(h) impulse into the neighbour.
STAGE_EPS = 1e-9

# status codes of the compiled loop
OK, NON_FINITE, DEFLECTION = 0, 1, 2


@_jit
def _add_body(M, h, Qg, m, inertia, cgx, cgy, ox, oy, Jo, cox, coy, psi, Jpsi, psid, g,
              nact):
    if m == 0.0 and inertia == 0.0:
        return
    c = math.cos(psi)
    s = math.sin(psi)
    ax = c * cgx - s * cgy
    ay = s * cgx + c * cgy
    cx = cox - psid * psid * ax
    cy = coy - psid * psid * ay
    Jx = np.empty(nact)
    Jy = np.empty(nact)
    for i in range(nact):
        Jx[i] = Jo[0, i] - ay * Jpsi[i]
        Jy[i] = Jo[1, i] + ax * Jpsi[i]
    for i in range(nact):
        h[i] += m * (Jx[i] * cx + Jy[i] * cy)
        Qg[i] += m * (Jx[i] * g[0] + Jy[i] * g[1])
        for j in range(i, nact):
            M[i, j] += m * (Jx[i] * Jx[j] + Jy[i] * Jy[j]) + inertia * Jpsi[i] * Jpsi[j]


@_jit
def chain_terms(q, qd, M, h, Qg, n, nl, ij, e0, ne, bodies, joff, rh, npt, X, MP, PHI, SS,
                SLOPE, g, fs, base_angle, Mdrive):
    """Fill M (n, n), h (n,), Qg (n,) at (q, q̇) — chain.Chain.kinematics in loops."""
    for i in range(n):
        h[i] = 0.0
        Qg[i] = 0.0
        for j in range(n):
            M[i, j] = Mdrive[i, j] if j >= i else 0.0
    ox = 0.0
    oy = 0.0
    cox = 0.0
    coy = 0.0
    Jo = np.zeros((2, n))
    Jpsi = np.zeros(n)
    psi = base_angle
    psid = 0.0
    nemax = PHI.shape[2]
    Seta = np.empty(nemax)
    Jx = np.empty(n)
    Jy = np.empty(n)
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
        _add_body(M, h, Qg, bodies[k, 0, 0], bodies[k, 0, 1], bodies[k, 0, 2],
                  bodies[k, 0, 3], ox, oy, Jo, cox, coy, psi, Jpsi, psid, g, nact)
        c = math.cos(psi)
        s = math.sin(psi)
        P = npt[k]
        tox = 0.0
        toy = 0.0
        tcx = 0.0
        tcy = 0.0
        Jtx = np.empty(n)
        Jty = np.empty(n)
        for p in range(P + 1):
            uf = 0.0
            ax_acc = 0.0
            ud = 0.0
            w = 0.0
            wd = 0.0
            for a in range(nk):
                w += PHI[k, p, a] * q[s0 + a]
                wd += PHI[k, p, a] * qd[s0 + a]
            if fs:
                for a in range(nk):
                    acc = 0.0
                    accd = 0.0
                    for b in range(nk):
                        acc += SS[k, p, a, b] * q[s0 + b]
                        accd += SS[k, p, a, b] * qd[s0 + b]
                    Seta[a] = acc
                    uf -= 0.5 * acc * q[s0 + a]
                    ud -= acc * qd[s0 + a]
                    ax_acc -= accd * qd[s0 + a]
            else:
                for a in range(nk):
                    Seta[a] = 0.0
            sx = rh[k] + X[k, p] + uf
            sy = w
            Asx = c * sx - s * sy
            Asy = s * sx + c * sy
            Adx = c * ud - s * wd
            Ady = s * ud + c * wd
            cx = cox - psid * psid * Asx - 2.0 * psid * Ady + ax_acc * c
            cy = coy - psid * psid * Asy + 2.0 * psid * Adx + ax_acc * s
            for i in range(nact):
                Jx[i] = Jo[0, i] - Asy * Jpsi[i]
                Jy[i] = Jo[1, i] + Asx * Jpsi[i]
            for a in range(nk):
                Jx[s0 + a] += -c * Seta[a] - s * PHI[k, p, a]
                Jy[s0 + a] += -s * Seta[a] + c * PHI[k, p, a]
            if p < P:
                m = MP[k, p]
                for i in range(nact):
                    h[i] += m * (Jx[i] * cx + Jy[i] * cy)
                    Qg[i] += m * (Jx[i] * g[0] + Jy[i] * g[1])
                    mjx = m * Jx[i]
                    mjy = m * Jy[i]
                    for j in range(i, nact):
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
        _add_body(M, h, Qg, bodies[k, 1, 0], bodies[k, 1, 1], bodies[k, 1, 2],
                  bodies[k, 1, 3], ox, oy, Jo, cox, coy, psi, Jpsi, psid, g, nact)
    for i in range(n):
        for j in range(i):
            M[i, j] = M[j, i]


@_jit
def _cholesky_solve(A, b, nf):
    """Solve A x = b for symmetric positive-definite A (nf × nf), in place on copies."""
    L = np.zeros((nf, nf))
    for j in range(nf):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if d <= 0.0:
            return np.full(nf, np.nan)
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, nf):
            v = A[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    y = np.empty(nf)
    for i in range(nf):
        v = b[i]
        for k in range(i):
            v -= L[i, k] * y[k]
        y[i] = v / L[i, i]
    x = np.empty(nf)
    for i in range(nf - 1, -1, -1):
        v = y[i]
        for k in range(i + 1, nf):
            v -= L[k, i] * x[k]
        x[i] = v / L[i, i]
    return x


@_jit
def rhs(t, x, n, nl, ij, e0, ne, bodies, joff, rh, npt, X, MP, PHI, SS, SLOPE, g, fs,
        base_angle, Mdrive, K, D, free, presc, mcode, mpar, tidx, tcode, tpar, ttimes,
        tvalues, tlen):
    """ẋ for x = [q_free, q̇_free] (chain.Chain.rhs, compiled)."""
    nf = free.shape[0]
    q = np.empty(n)
    qd = np.empty(n)
    for i in range(nf):
        q[free[i]] = x[i]
        qd[free[i]] = x[nf + i]
    npr = presc.shape[0]
    pdd = np.empty(npr)
    for j in range(npr):
        th, thd, thdd = eval_motion_c(mcode[j], mpar[j], t)
        q[presc[j]] = th
        qd[presc[j]] = thd
        pdd[j] = thdd
    M = np.empty((n, n))
    h = np.empty(n)
    Qg = np.empty(n)
    chain_terms(q, qd, M, h, Qg, n, nl, ij, e0, ne, bodies, joff, rh, npt, X, MP, PHI, SS,
                SLOPE, g, fs, base_angle, Mdrive)
    f = Qg - h
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += K[i, j] * q[j] + D[i, j] * qd[j]
        f[i] -= acc
    for j in range(tidx.shape[0]):
        L = tlen[j]
        f[tidx[j]] += eval_torque_c(tcode[j], tpar[j], ttimes[j, :L], tvalues[j, :L], t)
    for j in range(npr):
        for i in range(n):
            f[i] -= M[i, presc[j]] * pdd[j]
    Mff = np.empty((nf, nf))
    ff = np.empty(nf)
    for a in range(nf):
        ff[a] = f[free[a]]
        for b in range(nf):
            Mff[a, b] = M[free[a], free[b]]
    acc = _cholesky_solve(Mff, ff, nf)
    out = np.empty(2 * nf)
    for a in range(nf):
        out[a] = x[nf + a]
        out[nf + a] = acc[a]
    return out


@_jit
def _deflection_ratio(x, free, n, nl, e0, ne, PHI, npt, lengths, presc, mcode, mpar, t):
    """max over beams of |w(L)|/L (elastic coordinates are never prescribed)."""
    nf = free.shape[0]
    q = np.zeros(n)
    for i in range(nf):
        q[free[i]] = x[i]
    worst = 0.0
    which = 0
    for k in range(nl):
        w = 0.0
        for a in range(ne[k]):
            w += PHI[k, npt[k], a] * q[e0[k] + a]
        r = abs(w) / lengths[k]
        if r > worst:
            worst = r
            which = k
    return worst, which


@_jit
def rk4_loop(x0, h, per, n_out, out_dt, max_ratio, xs, n, nl, ij, e0, ne, bodies, joff, rh,
             npt, X, MP, PHI, SS, SLOPE, g, fs, base_angle, Mdrive, K, D, free, presc, mcode,
             mpar, tidx, tcode, tpar, ttimes, tvalues, tlen, lengths):
    """Fixed-step RK4 from t = 0, storing every ``per`` steps into xs[1..n_out].

    Returns (status, time, steps, last good state, offending state): status OK, NON_FINITE or DEFLECTION.
    """
    x = x0.copy()
    steps = 0
    for k in range(n_out):
        t0 = k * out_dt
        for j in range(per):
            t = t0 + j * h
            k1 = rhs(t + STAGE_EPS * h, x, n, nl, ij, e0, ne, bodies, joff, rh, npt, X, MP, PHI, SS, SLOPE,
                     g, fs, base_angle, Mdrive, K, D, free, presc, mcode, mpar, tidx, tcode,
                     tpar, ttimes, tvalues, tlen)
            k2 = rhs(t + 0.5 * h, x + 0.5 * h * k1, n, nl, ij, e0, ne, bodies, joff, rh, npt,
                     X, MP, PHI, SS, SLOPE, g, fs, base_angle, Mdrive, K, D, free, presc,
                     mcode, mpar, tidx, tcode, tpar, ttimes, tvalues, tlen)
            k3 = rhs(t + 0.5 * h, x + 0.5 * h * k2, n, nl, ij, e0, ne, bodies, joff, rh, npt,
                     X, MP, PHI, SS, SLOPE, g, fs, base_angle, Mdrive, K, D, free, presc,
                     mcode, mpar, tidx, tcode, tpar, ttimes, tvalues, tlen)
            k4 = rhs(t + (1.0 - STAGE_EPS) * h, x + h * k3, n, nl, ij, e0, ne, bodies, joff, rh, npt, X, MP, PHI,
                     SS, SLOPE, g, fs, base_angle, Mdrive, K, D, free, presc, mcode, mpar,
                     tidx, tcode, tpar, ttimes, tvalues, tlen)
            xn = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            steps += 1
            for i in range(xn.shape[0]):
                if not math.isfinite(xn[i]):
                    return NON_FINITE, t + h, steps, x, xn
            r, _ = _deflection_ratio(xn, free, n, nl, e0, ne, PHI, npt, lengths, presc,
                                     mcode, mpar, t + h)
            if r > max_ratio:
                return DEFLECTION, t + h, steps, x, xn
            x = xn
        xs[k + 1] = x
    return OK, n_out * out_dt, steps, x, x
