"""Compiled chain kernel: the same equations as :mod:`chain`, written as scalar loops for numba.

:class:`chain.Chain` is the readable, vectorized numpy reference. This module evaluates
exactly the same M(q), h(q, q̇) and Q_grav (same points, same S(x), same propagation) in
loops that numba compiles, and runs a whole fixed-step RK4 integration inside compiled
code. Tests check both give the same numbers to round-off; without numba (or with
``FLEXARM_NO_NUMBA=1``) the chain falls back to the numpy path. The cost of one
right-hand side on either path is measured by ``bench/bench_ladder.py`` (docs/performance.md,
*Batch integration*).
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.programs import eval_motion, eval_torque

from flexarm_ros.model.compiled import (  # noqa: F401
    HAVE_NUMBA, jit as _jit, jit_inline as _jit_inline, jit_raw as _jit_raw)
from flexarm_ros.model.compiled.layout import Model, named, workspace  # noqa: F401  (kchain.workspace)
from flexarm_ros.model.drives import actuator_rate, actuator_torque, backlash_torque
from flexarm_ros.model.bearings import friction_coefficient, friction_force

eval_torque_c = _jit(eval_torque)
eval_motion_c = _jit(eval_motion)


@_jit
def motion_series(code, p, ts, out):
    """out[k] = (θ, θ̇, θ̈) of a prescribed motion at ts[k] (:func:`eval_motion` per
    sample in one compiled loop: a Python call per sample was 40 % of a 20 s spin_up's
    whole run)."""
    for k in range(ts.shape[0]):
        th, thd, thdd = eval_motion_c(code, p, ts[k])
        out[k, 0] = th
        out[k, 1] = thd
        out[k, 2] = thdd


@_jit
def torque_series(code, p, times, values, ts, out):
    """out[k] = the program's value at ts[k] (:func:`eval_torque` per sample in one
    compiled loop)."""
    for k in range(ts.shape[0]):
        out[k] = eval_torque_c(code, p, times, values, ts[k])


actuator_torque_c = actuator_torque      # compiled in drives (they call each other)
actuator_rate_c = actuator_rate
backlash_torque_c = backlash_torque

#: RK4's first and last stages are evaluated STAGE_EPS·h inside the step, so an input that
#: jumps exactly on a step boundary is seen with its value on that step (right limit at the
#: start, left limit at the end) instead of leaking an O(h) impulse into the neighbour.
STAGE_EPS = 1e-9

# status codes of the compiled loop
OK, NON_FINITE, DEFLECTION, NEWTON = 0, 1, 2, 3


@_jit_raw
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


@_jit_inline
def _store_frame(ws, k, j, ox, oy, cox, coy, psi, psid, Jo, Jpsi, n):
    """Keep link k's hub (j = 0) or tip (j = 1) frame: ws.frames[k, j] = (o, c_o, ψ, ψ̇),
    ws.frame_jac[k, j] = (∂o_x/∂q, ∂o_y/∂q, ∂ψ/∂q) — what the sensors read."""
    fr = ws.frames
    fj = ws.frame_jac
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
def beam_point(q, qd, s0, ext, phi, S, k, p, fs, x0, c, s, Seta):
    """A beam point's local kinematics turned into the world by its hub frame A = R(ψ)
    (c = cos ψ, s = sin ψ), from the leading ``ext`` elastic coordinates η = q[s0:],
    φ = ``phi[k, p]`` and S = ``S[k, p]`` at its abscissa (the model's per-point layout,
    indexed in place), x0 = r_h + x:

        s = (x0 − ½ηᵀSη, φᵀη),   ṡ = (−(Sη)ᵀη̇, φᵀη̇),   s̈ = (∂s/∂η) η̈ − (η̇ᵀSη̇) ê₁.

    Returns (A s, A ṡ, −η̇ᵀSη̇) as (Asx, Asy, Adx, Ady, acc_ax) and leaves Sη in
    ``Seta[:ext]`` (its ∂s_x/∂η = −Sη). Without foreshortening (``fs`` False) Seta is not
    touched: the caller zeroes it once per evaluation (an array written on both branches
    here would cost a reference-count update per point once inlined).
    """
    uf = 0.0
    acc_ax = 0.0
    ud = 0.0
    w = 0.0
    wd = 0.0
    for a in range(ext):
        w += phi[k, p, a] * q[s0 + a]
        wd += phi[k, p, a] * qd[s0 + a]
    if fs:
        for a in range(ext):
            acc = 0.0
            for b in range(ext):
                acc += S[k, p, a, b] * q[s0 + b]
            Seta[a] = acc
            uf -= 0.5 * acc * q[s0 + a]
            ud -= acc * qd[s0 + a]
            # −η̇ᵀSη̇ over the upper triangle (S is symmetric)
            va = qd[s0 + a]
            accd = 0.5 * S[k, p, a, a] * va
            for b in range(a + 1, ext):
                accd += S[k, p, a, b] * qd[s0 + b]
            acc_ax -= 2.0 * accd * va
    sx = x0 + uf
    return c * sx - s * w, s * sx + c * w, c * ud - s * wd, s * ud + c * wd, acc_ax


@_jit_inline
def _rigid_block(s0, Jo, Jpsi, m, inertia, acx, acy, cmx, cmy, rot_h, rot_g, g, has_g,
                 M, h, Qg):
    """A beam's share of the rigid coordinates' block (i, j < s0) from its sums — mass m,
    A c = (acx, acy), inertia I about the hub, m c_o + A Σm w = (cmx, cmy), the rotational
    terms rot_h and rot_g (:func:`beam_invariants`, :func:`rod_sums` give them):

        M_ij += m Jo_i·Jo_j + (Jψ_j Jo_i + Jψ_i Jo_j)·(A c)^⊥ + Jψ_i Jψ_j I,
        h_i += Jo_i·(cmx, cmy) + Jψ_i rot_h,    Qg_i += m Jo_i·g + Jψ_i rot_g."""
    for i in range(s0):
        oxi = Jo[0, i]
        oyi = Jo[1, i]
        pi = Jpsi[i]
        h[i] += oxi * cmx + oyi * cmy + pi * rot_h
        if has_g:
            Qg[i] += m * (oxi * g[0] + oyi * g[1]) + pi * rot_g
        ai = -oxi * acy + oyi * acx
        for j in range(i, s0):
            aj = -Jo[0, j] * acy + Jo[1, j] * acx
            M[i, j] += (m * (oxi * Jo[0, j] + oyi * Jo[1, j]) + Jpsi[j] * ai + pi * aj
                        + pi * Jpsi[j] * inertia)


@_jit_raw
def beam_invariants(q, qd, s0, nk, k, fs, m0, m1, m2, G, H, Jo, Jpsi, M, h, Qg, V, E, c, s,
                    cox, coy, psid, g, has_g):
    """Add link k's beam mass points to ws' M, h, Qg through its inertia invariants
    (``model.inv_*``, :func:`chain._invariants`) instead of point by point: the same sums
    as :func:`chain_terms`' loop, gathered by the powers of η they carry.

    With the hub frame (o, A = R(ψ), ψ̇, c_o = ö at q̈ = 0) and Jacobians Jo, Jψ of the
    coordinates i < s0, and a point's s = (x₀ − ½ηᵀSη, φᵀη), d_a = ∂s/∂η_a = (−(Sη)_a, φ_a),
    its acceleration at q̈ = 0 is c_o + A w, w = −ψ̇²s + 2ψ̇ṡ^⊥ − (η̇ᵀSη̇) ê₁ (v^⊥ = (−v_y, v_x)),
    and Σ_p m_p over the points of

        M_ij  = m Jo_i·Jo_j + (Jψ_j Jo_i + Jψ_i Jo_j)·(Ac)^⊥ + Jψ_i Jψ_j I      (i, j < s0)
        M_ia  = Jo_i·A e_a + Jψ_i f_a,     M_ab = Σ m d_a·d_b
        h_i   = Jo_i·(m c_o + A Σm w) + Jψ_i ((Ac)^⊥·c_o + 2ψ̇ Σm s·ṡ + Σm φᵀη η̇ᵀSη̇)
        h_a   = A e_a·c_o − ψ̇² Σm d_a·s + 2ψ̇ Σm d_a·ṡ^⊥ + Σm (Sη)_a η̇ᵀSη̇
        Qg_i  = m Jo_i·g + Jψ_i (Ac)^⊥·g,  Qg_a = A e_a·g

    with c = Σm s, I = Σm|s|², e_a = Σm d_a, f_a = Σm s^⊥·d_a, all polynomials in η with
    the invariants as coefficients (G_abc = Σm φ_a S_bc, H_abcd = Σm S_ab S_cd):
    Σm d_a·d_b = Σm φ_aφ_b + H_acbd η_cη_d, Σm d_a·s = −(Σm x₀S η)_a + ½H_abcd η_bη_cη_d
    + (Σm φφᵀη)_a (= ½∂I/∂η_a), f_a = Σm x₀φ_a − ½G_abc η_bη_c + G_bac η_bη_c,
    Σm d_a·ṡ^⊥ = (G_bac − G_abc) η_c η̇_b. Cost O(ne⁴) with foreshortening, O(ne²) without,
    against O(P·n²) for the P points; ``test_kernel`` holds both to the numpy reference.

    Arguments: the model's inv_* arrays (m0 … H) and foreshortening flag, the workspace's
    Jo, Jψ, M, h, Q_g and its scratch V = ws.inv_vec (rows: ΣmSη, Σm x₀Sη, Σm φφᵀη,
    ½∂I/∂η, f, h_a), E = ws.inv_E. Not inlined: each of the kernel's entry points inlines
    :func:`chain_terms`, and a copy of this function in each took ~50 s more to compile on
    a fresh machine; called with these arrays alone the call costs ~0.1 µs.
    """
    m = m0[k, 0]
    # quadratic and lower terms
    phe = 0.0               # Σm φᵀη
    phed = 0.0              # Σm φᵀη̇
    ese = 0.0               # ηᵀ(ΣmS)η
    esed = 0.0              # ηᵀ(ΣmS)η̇
    edsed = 0.0             # η̇ᵀ(ΣmS)η̇
    exse = 0.0              # ηᵀ(Σm x₀S)η
    epe = 0.0               # ηᵀ(Σm φφᵀ)η
    for a in range(nk):
        ea = q[s0 + a]
        eda = qd[s0 + a]
        phe += m1[k, 0, a] * ea
        phed += m1[k, 0, a] * eda
        u = 0.0
        ux = 0.0
        up = 0.0
        ud = 0.0
        for b in range(nk):
            eb = q[s0 + b]
            up += m2[k, 0, a, b] * eb
            if fs:
                u += m2[k, 1, a, b] * eb
                ux += m2[k, 2, a, b] * eb
                ud += m2[k, 1, a, b] * qd[s0 + b]
        V[0, a] = u
        V[1, a] = ux
        V[2, a] = up
        ese += u * ea
        esed += u * eda
        edsed += ud * eda
        exse += ux * ea
        epe += up * ea
    # quartic and cubic terms (foreshortening): ½∂I/∂η, f, the last three terms of h_a,
    # Σm φᵀη η̇ᵀSη̇ and the elastic block E
    q4 = 0.0
    ggd = 0.0
    for a in range(nk):
        t1 = 0.0            # H_abcd η_bη_cη_d
        tz = 0.0            # H_abcd η_b η̇_cη̇_d
        gf = 0.0            # −½G_abc η_bη_c + G_bac η_bη_c
        gs = 0.0            # (G_bac − G_abc) η_c η̇_b
        if fs:
            for b in range(nk):
                eb = q[s0 + b]
                edb = qd[s0 + b]
                for cc in range(nk):
                    ec = q[s0 + cc]
                    edc = qd[s0 + cc]
                    gf += (G[k, b, a, cc] - 0.5 * G[k, a, b, cc]) * eb * ec
                    gs += (G[k, b, a, cc] - G[k, a, b, cc]) * ec * edb
                    ggd += G[k, a, b, cc] * q[s0 + a] * edb * edc
                    hy = 0.0
                    hz = 0.0
                    for d in range(nk):
                        hy += H[k, a, b, cc, d] * q[s0 + d]
                        hz += H[k, a, b, cc, d] * qd[s0 + d]
                    t1 += hy * eb * ec
                    tz += hz * eb * edc
        V[3, a] = -V[1, a] + 0.5 * t1 + V[2, a]
        V[4, a] = m1[k, 1, a] + gf
        V[5, a] = -psid * psid * V[3, a] + 2.0 * psid * gs + tz
        q4 += t1 * q[s0 + a]
        for b in range(a, nk):
            e = m2[k, 0, a, b]
            if fs:
                for cc in range(nk):
                    acc = 0.0
                    for d in range(nk):
                        acc += H[k, a, cc, b, d] * q[s0 + d]
                    e += acc * q[s0 + cc]
            E[a, b] = e
    # Σm s (local, then world), I, 2ψ̇ Σm s·ṡ
    clx = m0[k, 1] - 0.5 * ese
    cly = phe
    acx = c * clx - s * cly
    acy = s * clx + c * cly
    inertia = m0[k, 2] - exse + 0.25 * q4 + epe
    ssd = 0.0
    for a in range(nk):
        ssd += V[3, a] * qd[s0 + a]
    # Σm w: −ψ̇² c + 2ψ̇ (Σm ṡ)^⊥ − η̇ᵀ(ΣmS)η̇ ê₁, Σm ṡ = (−ηᵀ(ΣmS)η̇, Σm φᵀη̇)
    wx = -psid * psid * clx - 2.0 * psid * phed - edsed
    wy = -psid * psid * cly - 2.0 * psid * esed
    cmx = m * cox + c * wx - s * wy
    cmy = m * coy + s * wx + c * wy
    rot_h = -acy * cox + acx * coy + 2.0 * psid * ssd + ggd
    rot_g = -acy * g[0] + acx * g[1]
    _rigid_block(s0, Jo, Jpsi, m, inertia, acx, acy, cmx, cmy, rot_h, rot_g, g, has_g,
                 M, h, Qg)
    for a in range(nk):
        ia = s0 + a
        exl = -V[0, a]
        eyl = m1[k, 0, a]
        aex = c * exl - s * eyl
        aey = s * exl + c * eyl
        for i in range(s0):
            M[i, ia] += Jo[0, i] * aex + Jo[1, i] * aey + Jpsi[i] * V[4, a]
        for b in range(a, nk):
            M[ia, s0 + b] += E[a, b]
        h[ia] += aex * cox + aey * coy + V[5, a]
        if has_g:
            Qg[ia] += aex * g[0] + aey * g[1]


@_jit_raw
def rod_sums(k, s0, nk, P, MP, RS, RV, RD, RA, Jo, Jpsi, M, h, Qg, V, E, c, s, cox, coy,
             psid, g, has_g):
    """Add the P mass points of link k's rod (its local kinematics in RS, RV, RD, RA from
    :func:`rod_local`) to M, h, Q_g through sums over the points in the hub frame, as
    :func:`beam_invariants` does for the floating-frame beams (the same formulas, with the
    sums taken over the points at run time instead of from invariants):

        M_ij = m Jo_i·Jo_j + (Jψ_j Jo_i + Jψ_i Jo_j)·(A c)^⊥ + Jψ_i Jψ_j I      (i, j < s0)
        M_ia = Jo_i·A e_a + Jψ_i f_a,     M_ab = Σm d_a·d_b
        h_i  = Jo_i·(m c_o + A Σm w) + Jψ_i ((A c)^⊥·c_o + 2ψ̇ Σm s·ṡ + Σm s^⊥·a)
        h_a  = A e_a·c_o − ψ̇² Σm d_a·s + 2ψ̇ Σm d_a·ṡ^⊥ + Σm d_a·a
        Qg_i = m Jo_i·g + Jψ_i (A c)^⊥·g,  Qg_a = A e_a·g

    with w = −ψ̇²s + 2ψ̇ṡ^⊥ + a (v^⊥ = (−v_y, v_x)), c = Σm s, I = Σm|s|², e_a = Σm d_a,
    f_a = Σm s^⊥·d_a, d_a = ∂s/∂η_a. The point-by-point sums cost O(P·(s0 + ne)²) per
    link, these O(P·ne²) plus O(s0²) once (two_link_free's second rod: 36 entries of M per
    point before, 6 now). Scratch: V = ws.inv_vec (rows: e_x, e_y, f, Σm d·s,
    Σm d·ṡ^⊥, Σm d·a), E = ws.inv_E. Not inlined, as :func:`beam_invariants`."""
    m = 0.0
    cx = 0.0
    cy = 0.0
    vx = 0.0
    vy = 0.0
    ax = 0.0
    ay = 0.0
    inertia = 0.0
    ssd = 0.0
    spa = 0.0
    for p in range(P):
        mp = MP[k, p]
        px = RS[p, 0]
        py = RS[p, 1]
        pvx = RV[p, 0]
        pvy = RV[p, 1]
        pax = RA[p, 0]
        pay = RA[p, 1]
        m += mp
        cx += mp * px
        cy += mp * py
        vx += mp * pvx
        vy += mp * pvy
        ax += mp * pax
        ay += mp * pay
        inertia += mp * (px * px + py * py)
        ssd += mp * (px * pvx + py * pvy)
        spa += mp * (px * pay - py * pax)
    for a in range(nk):                 # in locals, as rod_local's sums
        v0 = 0.0
        v1 = 0.0
        v2 = 0.0
        v3 = 0.0
        v4 = 0.0
        v5 = 0.0
        for p in range(P):
            dx = MP[k, p] * RD[p, 0, a]
            dy = MP[k, p] * RD[p, 1, a]
            v0 += dx
            v1 += dy
            v2 += RS[p, 0] * dy - RS[p, 1] * dx
            v3 += dx * RS[p, 0] + dy * RS[p, 1]
            v4 += dy * RV[p, 0] - dx * RV[p, 1]
            v5 += dx * RA[p, 0] + dy * RA[p, 1]
        V[0, a] = v0
        V[1, a] = v1
        V[2, a] = v2
        V[3, a] = v3
        V[4, a] = v4
        V[5, a] = v5
        for b in range(a, nk):
            e = 0.0
            for p in range(P):
                e += MP[k, p] * (RD[p, 0, a] * RD[p, 0, b] + RD[p, 1, a] * RD[p, 1, b])
            E[a, b] = e
    acx = c * cx - s * cy                       # A c
    acy = s * cx + c * cy
    # Σm w = −ψ̇² c + 2ψ̇ (Σm ṡ)^⊥ + Σm a (local), then m c_o + A Σm w
    wx = -psid * psid * cx - 2.0 * psid * vy + ax
    wy = -psid * psid * cy + 2.0 * psid * vx + ay
    cmx = m * cox + c * wx - s * wy
    cmy = m * coy + s * wx + c * wy
    rot_h = -acy * cox + acx * coy + 2.0 * psid * ssd + spa
    rot_g = -acy * g[0] + acx * g[1]
    _rigid_block(s0, Jo, Jpsi, m, inertia, acx, acy, cmx, cmy, rot_h, rot_g, g, has_g,
                 M, h, Qg)
    for a in range(nk):
        ia = s0 + a
        aex = c * V[0, a] - s * V[1, a]
        aey = s * V[0, a] + c * V[1, a]
        for i in range(s0):
            M[i, ia] += Jo[0, i] * aex + Jo[1, i] * aey + Jpsi[i] * V[2, a]
        for b in range(a, nk):
            M[ia, s0 + b] += E[a, b]
        h[ia] += (aex * cox + aey * coy - psid * psid * V[3, a] + 2.0 * psid * V[4, a]
                  + V[5, a])
        if has_g:
            Qg[ia] += aex * g[0] + aey * g[1]


@_jit_raw
def rod_local(q, qd, s0, nk, k, P, model, ws):
    """The rod rung's local kinematics of link k (model/rod.py) into ws.rod_s (positions in
    the hub frame), ws.rod_sd (their rates ṡ), ws.rod_ds (∂s/∂η) and ws.rod_a
    (velocity-product accelerations) at its P points and tip (row P): with θ_i = T_iη,
    ε_i = C_iη at the points and
    f_i = (1 + ε_i)(cos θ_i, sin θ_i),

        s_j = (r_h, 0) + Σ_i W_ji f_i,   ∂s_j/∂η_a = Σ_i W_ji ∂f_i/∂η_a,
        a_j = Σ_i W_ji [2ε̇_iθ̇_i (−sin θ_i, cos θ_i) − (1 + ε_i)θ̇_i² (cos θ_i, sin θ_i)].
    """
    T = model.rod_T
    C = model.rod_C
    W = model.rod_W
    G = ws.rod_g
    RS = ws.rod_s
    RD = ws.rod_ds
    RA = ws.rod_a
    for i in range(P):
        th = 0.0
        thd = 0.0
        ep = 0.0
        epd = 0.0
        for a in range(nk):
            th += T[k, i, a] * q[s0 + a]
            thd += T[k, i, a] * qd[s0 + a]
            ep += C[k, i, a] * q[s0 + a]
            epd += C[k, i, a] * qd[s0 + a]
        ct = math.cos(th)
        st = math.sin(th)
        fac = 1.0 + ep
        for a in range(nk):
            G[i, 0, a] = C[k, i, a] * ct - fac * st * T[k, i, a]
            G[i, 1, a] = C[k, i, a] * st + fac * ct * T[k, i, a]
        G[i, 0, nk] = -2.0 * epd * thd * st - fac * thd * thd * ct
        G[i, 1, nk] = 2.0 * epd * thd * ct - fac * thd * thd * st
        G[i, 0, nk + 1] = fac * ct
        G[i, 1, nk + 1] = fac * st
        G[i, 0, nk + 2] = epd * ct - fac * thd * st       # ḟ: the rate of f
        G[i, 1, nk + 2] = epd * st + fac * thd * ct
    RV = ws.rod_sd
    # every sum in a local (an array element summed in place is a chain of stores and
    # loads the compiler cannot keep in registers: the arrays may alias; 20 % of this
    # function on two_link_free)
    for j in range(P + 1):
        for a in range(nk):
            dx = 0.0
            dy = 0.0
            for i in range(P):
                w = W[k, j, i]
                dx += w * G[i, 0, a]
                dy += w * G[i, 1, a]
            RD[j, 0, a] = dx
            RD[j, 1, a] = dy
        sx = model.hub_radius[k]
        sy = 0.0
        ax = 0.0
        ay = 0.0
        vx = 0.0
        vy = 0.0
        for i in range(P):
            w = W[k, j, i]
            ax += w * G[i, 0, nk]
            ay += w * G[i, 1, nk]
            sx += w * G[i, 0, nk + 1]
            sy += w * G[i, 1, nk + 1]
            vx += w * G[i, 0, nk + 2]
            vy += w * G[i, 1, nk + 2]
        RV[j, 0] = vx
        RV[j, 1] = vy
        RA[j, 0] = ax
        RA[j, 1] = ay
        RS[j, 0] = sx
        RS[j, 1] = sy


@_jit_inline
def _mass_point(m, na, Jx, Jy, cx, cy, g, has_g, M, h, Qg):
    """A mass point's share of M, h and Q_grav (its Jacobian rows Jx, Jy over the first
    ``na`` coordinates, its velocity-product acceleration (cx, cy))."""
    if has_g:
        for i in range(na):
            Qg[i] += m * (Jx[i] * g[0] + Jy[i] * g[1])
    for i in range(na):
        h[i] += m * (Jx[i] * cx + Jy[i] * cy)
        mjx = m * Jx[i]
        mjy = m * Jy[i]
        for j in range(i, na):
            M[i, j] += mjx * Jx[j] + mjy * Jy[j]


@_jit_inline
def chain_terms(q, qd, model, ws):
    """Fill ws' M (n, n), h (n,), Qg (n,) at (q, q̇): chain.Chain.kinematics in loops; the
    last tip frame's (o, c_o, ψ, ψ̇) go to ws.tip, its Jacobians stay in ws.Jo / ws.Jpsi.

    Per mass point only the leading ``model.ext[k, p]`` elastic coordinates can be non-zero
    in φ(x_p) and S(x_p) (finite elements and differences grow from the root), so the loops
    stop there.
    """
    n = model.n
    nl = model.nl
    ij = model.i_joint
    e0 = model.e0
    ne = model.ne
    bodies = model.bodies
    joff = model.joint_offset
    rh = model.hub_radius
    npt = model.npt
    X = model.abscissa
    MP = model.point_mass
    PHI = model.phi
    SS = model.S
    SLOPE = model.slope_tip
    g = model.gravity
    fs = model.foreshortening
    Mdrive = model.M_drive
    EXT = model.ext
    M = ws.M
    h = ws.h
    Qg = ws.Qg
    Jo = ws.Jo
    Jpsi = ws.Jpsi
    Seta = ws.Seta
    Jx = ws.Jx
    Jy = ws.Jy
    Jtx = ws.Jtx
    Jty = ws.Jty
    if not fs:                  # beam_point leaves Sη alone then
        for a in range(Seta.shape[0]):
            Seta[a] = 0.0
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
    psi = model.base_angle
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
        if model.rod[k]:            # the rod rung: its exact local kinematics
            rod_local(q, qd, s0, nk, k, P, model, ws)
            RS = ws.rod_s
            RD = ws.rod_ds
            RA = ws.rod_a
            RV = ws.rod_sd
            rod_sums(k, s0, nk, P, MP, RS, RV, RD, RA, Jo, Jpsi, M, h, Qg, ws.inv_vec,
                     ws.inv_E, c, s, cox, coy, psid, g, has_g)
            for p in range(P, P + 1):          # the tip: the next frame's origin
                Asx = c * RS[p, 0] - s * RS[p, 1]
                Asy = s * RS[p, 0] + c * RS[p, 1]
                Adx = c * RV[p, 0] - s * RV[p, 1]
                Ady = s * RV[p, 0] + c * RV[p, 1]
                cx = cox - psid2 * Asx - 2.0 * psid * Ady + c * RA[p, 0] - s * RA[p, 1]
                cy = coy - psid2 * Asy + 2.0 * psid * Adx + s * RA[p, 0] + c * RA[p, 1]
                for i in range(s0):
                    Jx[i] = Jo[0, i] - Asy * Jpsi[i]
                    Jy[i] = Jo[1, i] + Asx * Jpsi[i]
                for a in range(nk):
                    Jx[s0 + a] = c * RD[p, 0, a] - s * RD[p, 1, a]
                    Jy[s0 + a] = s * RD[p, 0, a] + c * RD[p, 1, a]
                tox = ox + Asx
                toy = oy + Asy
                tcx = cx
                tcy = cy
                for i in range(nact):
                    Jtx[i] = Jx[i]
                    Jty[i] = Jy[i]
        elif model.invariant[k]:
            beam_invariants(q, qd, s0, nk, k, fs, model.inv_mass, model.inv_phi,
                            model.inv_mat, model.inv_G, model.inv_H, Jo, Jpsi, M, h, Qg,
                            ws.inv_vec, ws.inv_E, c, s, cox, coy, psid, g, has_g)
        for p in range(0 if not (model.invariant[k] or model.rod[k]) else
                       (P + 1 if model.rod[k] else P), P + 1):
            ext = EXT[k, p]
            Asx, Asy, Adx, Ady, ax_acc = beam_point(q, qd, s0, ext, PHI, SS, k, p, fs,
                                                    rh[k] + X[k, p], c, s, Seta)
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
                _mass_point(MP[k, p], na, Jx, Jy, cx, cy, g, has_g, M, h, Qg)
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
    # the last tip frame (its Jacobians stay in ws.Jo, ws.Jpsi): the tool's frame
    tip = ws.tip
    tip[0] = ox
    tip[1] = oy
    tip[2] = cox
    tip[3] = coy
    tip[4] = psi
    tip[5] = psid


@_jit_raw
def cholesky_solve(A, b, nf, L, y, x):
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
def fill_forces(t, q, qd, z, model, ws):
    """Fill ws' M and f = Q_input + Q_coupling + Q_grav − h − K q − D q̇ − M[:, p] q̈_p at
    (t, q, q̇, z), with the prescribed coordinates of q, q̇ set from their programs at time t,
    and the actuator state rates ż into ws.zd."""
    n = model.n
    K = model.K
    D = model.D
    presc = model.presc
    mcode = model.motion_code
    mpar = model.motion_par
    tidx = model.act_coord
    tcode = model.prog_code
    tpar = model.prog_par
    ttimes = model.prog_times
    tvalues = model.prog_values
    tlen = model.prog_len
    akind = model.act_kind
    apar = model.act_par
    azi = model.act_state
    bidx = model.backlash_idx
    bpar = model.backlash_par
    M = ws.M
    h = ws.h
    Qg = ws.Qg
    pdd = ws.pdd
    f = ws.f
    zd = ws.zd
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
    _bearing_forces(t, qd, z, model, ws, f)
    for j in range(npr):
        for i in range(n):
            f[i] -= M[i, presc[j]] * pdd[j]


@_jit_inline
def _bearing_forces(t, qd, z, model, ws, f):
    """f += J_bᵀF_b of every air bearing on the table (model/bearings.py, the numpy
    reference): F_b = −μ(r_b)N v_b/√(|v_b|² + v_s²) at the bearing point p of a body frame
    kept by chain_terms, r_b = o + A p, v_b = J_b q̇, J_b = J_o + (E A p) J_ψ,
    N = m g₀ + b|τ| (τ: the loading actuator's torque)."""
    bix = model.bearing_idx
    bpr = model.bearing_par
    fr = ws.frames
    fj = ws.frame_jac
    n = model.n
    for b in range(bix.shape[0]):
        k = bix[b, 0]
        j = bix[b, 1]
        ja = bix[b, 2]
        c = math.cos(fr[k, j, 4])
        s = math.sin(fr[k, j, 4])
        ax = c * bpr[b, 0] - s * bpr[b, 1]
        ay = s * bpr[b, 0] + c * bpr[b, 1]
        vx = 0.0
        vy = 0.0
        for i in range(n):
            vx += (fj[k, j, 0, i] - ay * fj[k, j, 2, i]) * qd[i]
            vy += (fj[k, j, 1, i] + ax * fj[k, j, 2, i]) * qd[i]
        load = bpr[b, 2]
        if ja >= 0:
            Lj = model.prog_len[ja]
            u = eval_torque_c(model.prog_code[ja], model.prog_par[ja],
                              model.prog_times[ja, :Lj], model.prog_values[ja, :Lj], t)
            zj = z[model.act_state[ja]] if model.act_state[ja] >= 0 else 0.0
            tau = actuator_torque_c(model.act_kind[ja], model.act_par[ja], u,
                                    qd[model.act_coord[ja]], zj)
            load += bpr[b, 4] * abs(tau)
        mu = friction_coefficient(b, fr[k, j, 0] + ax, fr[k, j, 1] + ay, bpr[b, 5],
                                  model.bearing_spots)
        fx, fy = friction_force(vx, vy, mu * load, bpr[b, 3])
        for i in range(n):
            f[i] += (fj[k, j, 0, i] - ay * fj[k, j, 2, i]) * fx + (
                fj[k, j, 1, i] + ax * fj[k, j, 2, i]) * fy


@_jit_raw
def rhs_into(t, x, out, model, ws):
    """out = ẋ for x = [q_free, q̇_free, z] (chain.Chain.rhs, compiled, no allocation)."""
    free = model.free
    q = ws.q
    qd = ws.qd
    M = ws.M
    Mff = ws.Mff
    ff = ws.ff
    L = ws.L
    y = ws.y
    acc = ws.acc
    f = ws.f
    nf = free.shape[0]
    nz = model.nz
    for i in range(nf):
        q[free[i]] = x[i]
        qd[free[i]] = x[nf + i]
    fill_forces(t, q, qd, x[2 * nf:], model, ws)
    for a in range(nf):
        ff[a] = f[free[a]]
        for b in range(nf):
            Mff[a, b] = M[free[a], free[b]]
    if not cholesky_solve(Mff, ff, nf, L, y, acc):
        for a in range(nf):
            acc[a] = np.nan
    for a in range(nf):
        out[a] = x[nf + a]
        out[nf + a] = acc[a]
    zd = ws.zd
    for a in range(nz):
        out[2 * nf + a] = zd[a]


def forces(t, q, qd, z, model_args, ws_args):
    """:func:`fill_forces` for Python callers (the model and workspace as plain tuples, see
    :mod:`layout`): the workspace then holds M, f, ż and the frames at (t, q, q̇, z)
    (prescribed entries of q, q̇ from their programs, as :func:`fill_forces` sets them).

    Through :func:`rhs` (whose solve for q̈ it does not need, ~0.3 µs): a compiled
    function of its own inlining :func:`fill_forces` was another copy of the whole kernel
    for numba to type and LLVM to optimize, ~20 s of CPU on a cold cache, for an
    evaluation whose call from Python costs more than the solve."""
    model = Model._make(model_args)
    free = model.free
    nf = free.shape[0]
    x = np.zeros(2 * nf + max(len(z), model.nz))
    x[:nf] = q[free]
    x[nf:2 * nf] = qd[free]
    x[2 * nf:2 * nf + len(z)] = z
    rhs(float(t), x, model_args, ws_args)


@_jit
def rhs(t, x, model_args, ws_args):
    """ẋ for x = [q_free, q̇_free, z] as a new array (model and workspace as plain
    tuples, see :mod:`layout`)."""
    model, ws = named(model_args, ws_args)
    out = np.empty(x.shape[0])
    rhs_into(t, x, out, model, ws)
    return out


@_jit_raw
def deflection_ratio(x, model):
    """max over beams of |w(L)|/L (elastic coordinates are never prescribed)."""
    nl = model.nl
    e0 = model.e0
    ne = model.ne
    npt = model.npt
    PHI = model.phi
    free = model.free
    nf = free.shape[0]
    worst = 0.0
    for k in range(nl):
        w = 0.0
        for i in range(nf):
            j = free[i] - e0[k]
            if j >= 0 and j < ne[k]:
                w += PHI[k, npt[k], j] * x[i]
        r = abs(w) / model.abscissa[k, npt[k]]   # the tip row: the beam length
        if r > worst:
            worst = r
    return worst


@_jit_raw
def energies(Q, QD, model_args, ws_args, energy, tip, psi):
    """Per sample k: energy[k] = ½q̇ᵀM(q)q̇ + ½qᵀKq + Σ ½k_b·max(|Δ| − b, 0)² (kinetic,
    beam/joint elastic, engaged backlash; chain.Chain.energy without gravity),
    tip[k] = the last tip frame's origin and psi[k] its angle (rad), from one
    :func:`chain_terms` pass per sample."""
    model, ws = named(model_args, ws_args)
    n = model.n
    K = model.K
    bidx = model.backlash_idx
    bpar = model.backlash_par
    M = ws.M
    for k in range(Q.shape[0]):
        q = Q[k]
        qd = QD[k]
        chain_terms(q, qd, model, ws)
        e = 0.0
        for i in range(n):
            a = 0.0
            b = 0.0
            for j in range(n):
                a += M[i, j] * qd[j]
                b += K[i, j] * q[j]
            e += 0.5 * (qd[i] * a + q[i] * b)
        for j in range(bidx.shape[0]):
            d = abs(q[bidx[j, 0]] - q[bidx[j, 1]]) - bpar[j, 0]
            if d > 0.0:
                e += 0.5 * bpar[j, 1] * d * d
        energy[k] = e
        tip[k, 0] = ws.tip[0]
        tip[k, 1] = ws.tip[1]
        psi[k] = ws.frames[model.nl - 1, 1, 4]
