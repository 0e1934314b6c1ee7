"""Compiled integration loops over :mod:`chain`'s right-hand side: fixed-step RK4 and the
implicit trapezoidal rule (Newmark average acceleration), whole integrations in compiled code."""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.compiled import jit as _jit, jit_inline as _jit_inline, jit_raw as _jit_raw
from flexarm_ros.model.compiled.layout import Model
from flexarm_ros.model.compiled.chain import (
    DEFLECTION, NEWTON, NON_FINITE, OK, STAGE_EPS, deflection_ratio, fill_forces, eval_torque_c,
    named, rhs, rhs_into, workspace)


@_jit_inline
def _rk4_step(t, h, x, xn, tmp, k1, k2, k3, k4, model, ws, k1_given=False, nystrom=False):
    """One RK4 step x → xn from time t; actuator states clamped to their bounds. Returns
    False when xn is not finite. With ``k1_given`` the first stage is already in k1 (the
    previous step's ẋ at its end, :func:`_rk4_dense`).

    With ``nystrom`` the positions q (the first nf entries of x, whose rates are the next
    nf) are stepped by the fourth-order Runge–Kutta–Nyström formulas (Nyström 1925;
    Hairer, Nørsett & Wanner I, Sec. II.14; Kreyszig, *Advanced Engineering Mathematics*,
    Sec. 21.3) and the rest (q̇, actuator states) by RK4's stages and weights:

        Q₂ = Q₃ = q + h/2·q̇ + h²/8·a₁,   Q₄ = q + h·q̇ + h²/2·a₃,
        q₁ = q + h·q̇ + h²/6·(a₁ + a₂ + a₃),

    a_i the accelerations of stage i. Fourth order like RK4 (same four right-hand sides),
    with an error constant about half of RK4's on the arm's oscillations
    (:mod:`flexarm_ros.sim.step`, ``rkn4_step``). Without it the loops below are RK4's
    exactly (nq = 0)."""
    m = x.shape[0]
    nq = model.free.shape[0] if nystrom else 0
    nz = model.nz
    zlo = model.z_lo
    zhi = model.z_hi
    hh = h * h
    if not k1_given:
        rhs_into(t + STAGE_EPS * h, x, k1, model, ws)
    for i in range(nq):
        tmp[i] = x[i] + 0.5 * h * x[nq + i] + 0.125 * hh * k1[nq + i]
    for i in range(nq, m):
        tmp[i] = x[i] + 0.5 * h * k1[i]
    rhs_into(t + 0.5 * h, tmp, k2, model, ws)
    for i in range(nq, m):                  # Nyström: the positions of stage 2 again
        tmp[i] = x[i] + 0.5 * h * k2[i]
    rhs_into(t + 0.5 * h, tmp, k3, model, ws)
    for i in range(nq):
        tmp[i] = x[i] + h * x[nq + i] + 0.5 * hh * k3[nq + i]
    for i in range(nq, m):
        tmp[i] = x[i] + h * k3[i]
    rhs_into(t + (1.0 - STAGE_EPS) * h, tmp, k4, model, ws)
    finite = True
    for i in range(nq):
        xn[i] = x[i] + h * x[nq + i] + (hh / 6.0) * (k1[nq + i] + k2[nq + i] + k3[nq + i])
        if not math.isfinite(xn[i]):
            finite = False
    for i in range(nq, m):
        xn[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if not math.isfinite(xn[i]):
            finite = False
    for a in range(nz):     # actuator states held within their bounds
        i = m - nz + a
        xn[i] = min(max(xn[i], zlo[a]), zhi[a])
    return finite


@_jit_inline
def _rk4_run(x, t0, h, nsteps, max_ratio, model, ws, xn, tmp, k1, k2, k3, k4, nystrom=False):
    """``nsteps`` RK4 steps of size h from (t0, x), advancing x in place: the one loop of
    :func:`rk4_span` and :func:`rk4_loop`. Returns (status, steps taken, time reached); on
    NON_FINITE or DEFLECTION x is the last good state and xn the offending one."""
    m = x.shape[0]
    for j in range(nsteps):
        t = t0 + j * h
        if not _rk4_step(t, h, x, xn, tmp, k1, k2, k3, k4, model, ws, False, nystrom):
            return NON_FINITE, j + 1, t + h
        if deflection_ratio(xn, model) > max_ratio:
            return DEFLECTION, j + 1, t + h
        for i in range(m):
            x[i] = xn[i]
    return OK, nsteps, t0 + nsteps * h


def rk4_span(x0, t0, h, nsteps, max_ratio, model_args, ws_args, nystrom):
    """``nsteps`` fixed RK4 steps (RKN4 with ``nystrom``) of size h from (t0, x0): the
    co-simulation plant's advance. Returns (status, time, last good state, offending
    state). Python around the compiled core, as every entry point that only allocates
    (docs/decisions/0032-each-kernel-compiled-once.md)."""
    x = np.array(x0, dtype=float)
    sc = np.empty((6, x.shape[0]))
    status, t = _rk4_span(x, sc, t0, h, nsteps, max_ratio, model_args, ws_args, nystrom)
    return status, t, x, (x if status == OK else sc[0].copy())


@_jit_raw
def _rk4_span(x, sc, t0, h, nsteps, max_ratio, model_args, ws_args, nystrom):
    """:func:`rk4_span`'s loop without reference counting (x advanced in place, sc[0] the
    offending state on failure, sc[1:] the stages)."""
    model, ws = named(model_args, ws_args)
    status, _, t = _rk4_run(x, t0, h, nsteps, max_ratio, model, ws, sc[0], sc[1], sc[2],
                            sc[3], sc[4], sc[5], nystrom)
    return status, t


def rk4_loop(x0, h, per, k0, n_out, out_dt, max_ratio, xs, model_args, ws_args, nystrom):
    """Fixed-step RK4 (RKN4 with ``nystrom``) over output intervals k0..n_out−1 (x0 at
    t = k0·out_dt), ``per`` steps each (:func:`_rk4_run` from k·out_dt), storing the state
    into xs[k + 1].

    Returns (status, time, steps, last good state, offending state): status OK,
    NON_FINITE or DEFLECTION. Python around the compiled core.
    """
    x = np.array(x0, dtype=float)
    sc = np.empty((6, x.shape[0]))
    status, t, steps = _rk4_loop(x, sc, h, per, k0, n_out, out_dt, max_ratio, xs, model_args,
                                 ws_args, nystrom)
    return status, t, steps, x, (x if status == OK else sc[0].copy())


@_jit_raw
def _rk4_loop(x, sc, h, per, k0, n_out, out_dt, max_ratio, xs, model_args, ws_args, nystrom):
    """:func:`rk4_loop`'s loop without reference counting (as :func:`_rk4_span`)."""
    model, ws = named(model_args, ws_args)
    m = x.shape[0]
    steps = 0
    for k in range(k0, n_out):
        status, done, t = _rk4_run(x, k * out_dt, h, per, max_ratio, model, ws, sc[0], sc[1],
                                   sc[2], sc[3], sc[4], sc[5], nystrom)
        steps += done
        if status != OK:
            return status, t, steps
        for i in range(m):
            xs[k + 1, i] = x[i]
    return OK, n_out * out_dt, steps


@_jit_inline
def hermite(theta, h, x0, f0, x1, f1, out):
    """Cubic Hermite interpolant on a step [t, t + h] at t + θh from the end states and
    their derivatives (ẋ from the right-hand side at both ends): third order like the
    interpolated RK4 step itself, so the sampled state keeps the integrator's O(h⁴)."""
    t2 = theta * theta
    t3 = t2 * theta
    a0 = 2.0 * t3 - 3.0 * t2 + 1.0
    b0 = (t3 - 2.0 * t2 + theta) * h
    a1 = 3.0 * t2 - 2.0 * t3
    b1 = (t3 - t2) * h
    for i in range(out.shape[0]):
        out[i] = a0 * x0[i] + b0 * f0[i] + a1 * x1[i] + b1 * f1[i]


def rk4_dense(x0, t0, h, t_stop, out_dt, k_next, max_ratio, xs, model_args, ws_args,
              nystrom):
    """Fixed-step RK4 (RKN4 with ``nystrom``, :func:`_rk4_step`) from (t0, x0) to ``t_stop``
    with steps of ``h`` independent of the output period (the last step shortened to end
    on ``t_stop``); the outputs xs[k] at k·out_dt, from k = ``k_next`` on, inside a step
    come from :func:`hermite` on that step, one on a step's end is the step's own state.
    The step may exceed the output period.

    Returns (status, time, steps, rhs evaluations, next output index, last good state,
    offending state). Python around the compiled core."""
    x = np.array(x0, dtype=float)
    sc = np.empty((9, x.shape[0]))
    status, t, steps, calls, k = _rk4_dense(x, sc, t0, h, t_stop, out_dt, k_next, max_ratio,
                                            xs, model_args, ws_args, nystrom)
    return status, t, steps, calls, k, x, (x if status == OK else sc[0].copy())


@_jit_raw
def _rk4_dense(x, sc, t0, h, t_stop, out_dt, k_next, max_ratio, xs, model_args, ws_args,
               nystrom):
    """:func:`rk4_dense`'s loop without reference counting (x advanced in place, sc[0] the
    offending state on failure)."""
    model, ws = named(model_args, ws_args)
    m = x.shape[0]
    xn = sc[0]
    tmp = sc[1]
    k1 = sc[2]
    k2 = sc[3]
    k3 = sc[4]
    k4 = sc[5]
    f0 = sc[6]
    f1 = sc[7]
    row = sc[8]
    n_out = xs.shape[0] - 1
    k = k_next
    t = t0
    steps = 0
    calls = 0
    eps = 1e-12 * max(1.0, t_stop)
    have_f1 = False
    while t < t_stop - eps:
        hh = min(h, t_stop - t)
        if have_f1:     # first same as last: ẋ at the previous step's end (no input jump
            for i in range(m):      # inside a call: the caller splits at them)
                k1[i] = f1[i]
        if not _rk4_step(t, hh, x, xn, tmp, k1, k2, k3, k4, model, ws, have_f1, nystrom):
            return NON_FINITE, t + hh, steps, calls, k
        steps += 1
        calls += 3 if have_f1 else 4
        have_f1 = False
        if deflection_ratio(xn, model) > max_ratio:
            return DEFLECTION, t + hh, steps, calls, k
        t1 = t + hh
        if k <= n_out and k * out_dt < t1 - eps:
            for i in range(m):                  # an output inside the step: ẋ at both ends
                f0[i] = k1[i]
            rhs_into(t + (1.0 - STAGE_EPS) * hh, xn, f1, model, ws)   # left limit at a jump
            calls += 1
            have_f1 = True
            while k <= n_out and k * out_dt < t1 - eps:
                hermite((k * out_dt - t) / hh, hh, x, f0, xn, f1, row)
                for i in range(m):
                    xs[k, i] = row[i]
                k += 1
        if k <= n_out and abs(k * out_dt - t1) <= eps:
            for i in range(m):
                xs[k, i] = xn[i]
            k += 1
        for i in range(m):
            x[i] = xn[i]
        t = t1
    return OK, t, steps, calls, k


@_jit_inline
def _rk4_period(x, k0, g_ns, J, nsteps, max_ratio, model, ws, xs, sc, nystrom):
    """One control period of the plant with its inputs held: ``nsteps`` equal RK4 steps
    (RKN4 with ``nystrom``) from t₀ = k₀·g to t₁ = (k₀ + J)·g (g = ``g_ns`` ns, the sensor
    and output grid), x advanced in place; the state at every grid instant t₀ + j·g,
    j = 1..J, into xs[j − 1]: a step's own state on its end, else the cubic Hermite
    interpolant of the step that holds it (:func:`hermite`, ẋ at both ends; O(h⁴), as the
    batch run's dense output, :func:`rk4_dense`). Grid instants are (k₀ + j)·g_ns·1e-9 s
    exactly as the plant computes them. ``sc``: (9, m) scratch.

    Returns (status, time reached, steps, rhs evaluations); on NON_FINITE or DEFLECTION x
    is the last good state and sc[0] the offending one."""
    m = x.shape[0]
    xn = sc[0]
    tmp = sc[1]
    k1 = sc[2]
    k2 = sc[3]
    k3 = sc[4]
    k4 = sc[5]
    f1 = sc[6]
    row = sc[8]
    t0 = float(k0 * g_ns) * 1e-9
    t_end = float((k0 + J) * g_ns) * 1e-9
    h = (t_end - t0) / nsteps
    eps = 1e-12 * max(1.0, t_end)
    j = 1
    calls = 0
    t = t0
    for s in range(nsteps):
        t1 = t_end if s == nsteps - 1 else t0 + (s + 1) * h
        hh = t1 - t
        if not _rk4_step(t, hh, x, xn, tmp, k1, k2, k3, k4, model, ws, False, nystrom):
            return NON_FINITE, t1, s + 1, calls + 4
        calls += 4
        if deflection_ratio(xn, model) > max_ratio:
            return DEFLECTION, t1, s + 1, calls
        tj = float((k0 + j) * g_ns) * 1e-9
        if j <= J and tj < t1 - eps:
            # samples inside the step: ẋ at its end too (left limit: same held inputs)
            rhs_into(t + (1.0 - STAGE_EPS) * hh, xn, f1, model, ws)
            calls += 1
            while j <= J and tj < t1 - eps:
                hermite((tj - t) / hh, hh, x, k1, xn, f1, row)
                for i in range(m):
                    xs[j - 1, i] = row[i]
                j += 1
                tj = float((k0 + j) * g_ns) * 1e-9
        if j <= J and abs(tj - t1) <= eps:
            for i in range(m):
                xs[j - 1, i] = xn[i]
            j += 1
        for i in range(m):
            x[i] = xn[i]
        t = t1
    return OK, t_end, nsteps, calls


def rk4_period(x0, k0, g_ns, J, nsteps, max_ratio, xs, model_args, ws_args, nystrom):
    """:func:`_rk4_period` from a copy of x0: the plant's control period when its model is
    smooth (:meth:`flexarm_ros.sim.plant.Plant.step_rows`). Returns (status, time, steps,
    rhs evaluations, last good state, offending state). Python around the compiled core."""
    x = np.array(x0, dtype=float)
    sc = np.empty((9, x.shape[0]))
    status, t, steps, calls = rk4_period_raw(x, k0, g_ns, J, nsteps, max_ratio, xs, sc,
                                              model_args, ws_args, nystrom)
    return status, t, steps, calls, x, (x if status == OK else sc[0].copy())


@_jit_raw
def rk4_period_raw(x, k0, g_ns, J, nsteps, max_ratio, xs, sc, model_args, ws_args,
                    nystrom):
    """:func:`rk4_period` without reference counting."""
    model, ws = named(model_args, ws_args)
    return _rk4_period(x, k0, g_ns, J, nsteps, max_ratio, model, ws, xs, sc, nystrom)


@_jit
def _torque_jumps(t, model):
    """True when a torque program differs just before and just after time t."""
    for j in range(model.act_coord.shape[0]):
        Lj = model.prog_len[j]
        code = model.prog_code[j]
        par = model.prog_par[j]
        times = model.prog_times[j, :Lj]
        values = model.prog_values[j, :Lj]
        a = eval_torque_c(code, par, times, values, t - 1e-12)
        b = eval_torque_c(code, par, times, values, t + 1e-12)
        if a != b:
            return True
    return False


@_jit
def trapezoid_loop(x, acc0, h, per, k0, n_out, out_dt, max_ratio, xs, model_args, ws_args,
                   Sinv, tol, max_iter):
    """Implicit trapezoidal rule (Newmark average acceleration, β = 1/4, γ = 1/2) from output
    interval k0; modified Newton on the new accelerations with the frozen iteration matrix
    Sinv = (M + h/2·D + h²/4·K_t)⁻¹ of the free coordinates.

    q₁ = q₀ + h v₀ + h²/4 (a₀ + a₁),  v₁ = v₀ + h/2 (a₀ + a₁),  M(q₁) a₁ = f(t₁, q₁, v₁).
    Unconditionally stable, second order, no numerical damping (energy of a linear system
    is conserved exactly). Returns (status, output interval, steps, iterations, x, a); on
    NEWTON the state is the one at the start of that output interval, so the caller can
    refresh Sinv there and resume.
    """
    model, ws = named(model_args, ws_args)
    free = model.free
    nf = free.shape[0]
    q = ws.q
    qd = ws.qd
    M = ws.M
    f = ws.f
    qf = x[:nf].copy()
    vf = x[nf:].copy()
    a0 = acc0.copy()
    a1 = np.empty(nf)
    r = np.empty(nf)
    sc = np.empty(nf)
    q1 = np.empty(nf)
    v1 = np.empty(nf)
    xk = np.empty(2 * nf)
    steps = 0
    iters = 0
    for k in range(k0, n_out):
        qs = qf.copy()
        vs = vf.copy()
        as_ = a0.copy()
        t0 = k * out_dt
        for j in range(per):
            t = t0 + j * h
            if _torque_jumps(t, model):     # right limit of the input at the step start
                for i in range(nf):
                    xk[i] = qf[i]
                    xk[nf + i] = vf[i]
                rhs_into(t + STAGE_EPS * h, xk, ws.xdot, model, ws)
                for i in range(nf):
                    a0[i] = ws.xdot[nf + i]
            for i in range(nf):
                a1[i] = a0[i]
            converged = False
            for it in range(max_iter):
                for i in range(nf):
                    q1[i] = qf[i] + h * vf[i] + 0.25 * h * h * (a0[i] + a1[i])
                    v1[i] = vf[i] + 0.5 * h * (a0[i] + a1[i])
                    q[free[i]] = q1[i]
                    qd[free[i]] = v1[i]
                fill_forces(t + (1.0 - STAGE_EPS) * h, q, qd, x[:0], model, ws)
                for i in range(nf):
                    ma = 0.0
                    for jj in range(nf):
                        ma += M[free[i], free[jj]] * a1[jj]
                    r[i] = ma - f[free[i]]
                    # magnitude of the terms that cancel in the residual (round-off scale)
                    sc[i] = (abs(ma) + abs(f[free[i]]) + abs(ws.h[free[i]])
                             + abs(ws.Qg[free[i]]))
                dmax = 0.0
                amax = 0.0
                fscale = 0.0
                for i in range(nf):
                    d = 0.0
                    fs_i = 0.0
                    for jj in range(nf):
                        d -= Sinv[i, jj] * r[jj]
                        fs_i += abs(Sinv[i, jj]) * sc[jj]
                    a1[i] += d
                    dmax = max(dmax, abs(d))
                    amax = max(amax, abs(a1[i]))
                    fscale = max(fscale, fs_i)
                iters += 1
                if not math.isfinite(dmax):
                    break
                # relative to the accelerations and to the force terms that cancel in them,
                # with an absolute floor: a correction that moves q by < 1e-14 is round-off
                if dmax <= tol * (amax + fscale) or 0.25 * h * h * dmax < 1e-14:
                    converged = True
                    break
            if not converged:
                for i in range(nf):
                    xk[i] = qs[i]
                    xk[nf + i] = vs[i]
                return NEWTON, k, steps, iters, xk, as_
            steps += 1
            for i in range(nf):
                qf[i] = q1[i]
                vf[i] = v1[i]
                a0[i] = a1[i]
                xk[i] = q1[i]
                xk[nf + i] = v1[i]
            if deflection_ratio(xk, model) > max_ratio:
                return DEFLECTION, k, steps, iters, xk, a0
        for i in range(nf):
            xs[k + 1, i] = qf[i]
            xs[k + 1, nf + i] = vf[i]
    for i in range(nf):
        xk[i] = qf[i]
        xk[nf + i] = vf[i]
    return OK, n_out, steps, iters, xk, a0


def warm_up(integrator, model, x0, xs, dense=None):
    """Compile (or load from cache) the loop of ``integrator`` with zero steps, so that
    wall-time measurements count integration only (``model`` the plain tuple); for rk4,
    ``dense`` True/False loads only the dense-output or the grid loop (None: both; each
    load costs tens of ms of a short process's start-up)."""
    ws = workspace(model)
    x = np.array(x0, float)
    if integrator in ("rk4", "rkn4"):
        if dense is not True:
            rk4_loop(x, 1e-3, 1, 0, 0, 1e-3, 1.0, xs, model, ws, False)
        if dense is not False:
            rk4_dense(x, 0.0, 1e-3, 0.0, 1e-3, xs.shape[0], 1.0, xs, model, ws, False)
    elif integrator == "trapezoid":
        nf = Model._make(model).free.shape[0]
        trapezoid_loop(x, np.zeros(nf), 1e-3, 1, 0, 0, 1e-3, 1.0, xs, model, ws,
                       np.eye(nf), 1e-10, 1)
    else:
        rhs(0.0, x, model, ws)
