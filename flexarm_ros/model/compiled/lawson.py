"""Compiled loop of integrator lawson4: RK4 in the integrating factor of the model's
linearization at the start (Lawson 1967), whole integrations in compiled code.

With ẋ = f(t, x) split as ẋ = A x + N(t, x), A the Jacobian ∂f/∂x at the start and
N = f − A x the rest (the inputs, the nonlinear terms), Lawson's fourth-order method
(J. D. Lawson, SIAM J. Numer. Anal. 4(3), 1967; Hochbruck & Ostermann, Acta Numerica 19,
2010, Sec. 2.6) steps, with E = exp(A h/2) and E² = exp(A h):

    K₁ = N(t, x),               X₂ = E (x + h/2·K₁),      K₂ = N(t + h/2, X₂),
    X₃ = E x + h/2·K₂,          K₃ = N(t + h/2, X₃),
    X₄ = E² x + h·E K₃,         K₄ = N(t + h, X₄),
    x₁ = E² x + h/6·(E² K₁ + 2 E (K₂ + K₃) + K₄).

The linear part is stepped exactly: no stability limit from the arm's highest mode and no
phase error on its oscillations, which RK4 accumulates at (ωh)⁴/120 per radian — what put
seed 001's link 14 % off in tip deflection over 3 s at RK4's stable step (its second mode,
172 Hz, carries the deflection a light hub's torque jumps excite; docs/accuracy.md). What
is not exact is the rest N, with RK4's order: the nonlinear terms of a small deflection and
the inputs, piecewise constant between the steps' ends.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.compiled import jit_inline as _jit_inline, jit_raw as _jit_raw
from flexarm_ros.model.compiled.chain import (
    DEFLECTION, NON_FINITE, OK, STAGE_EPS, deflection_ratio, rhs_into)
from flexarm_ros.model.compiled.layout import named, workspace


@_jit_inline
def _matvec(A, x, out):
    n = x.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += A[i, j] * x[j]
        out[i] = s


@_jit_inline
def _rest(t, x, A, out, model, ws, tmp):
    """out = N(t, x) = f(t, x) − A x (tmp: scratch)."""
    rhs_into(t, x, out, model, ws)
    _matvec(A, x, tmp)
    for i in range(x.shape[0]):
        out[i] -= tmp[i]


@_jit_inline
def _lawson_step(t, h, x, xn, A, E, E2, sc, model, ws):
    """One Lawson RK4 step x → xn from time t (sc: 8 scratch rows); actuator states clamped
    to their bounds as RK4's. Returns False when xn is not finite."""
    m = x.shape[0]
    k1, k2, k3, k4 = sc[0], sc[1], sc[2], sc[3]
    tmp, ex, acc, scr = sc[4], sc[5], sc[6], sc[7]
    _rest(t + STAGE_EPS * h, x, A, k1, model, ws, scr)
    for i in range(m):
        acc[i] = x[i] + 0.5 * h * k1[i]
    _matvec(E, acc, tmp)                                  # X₂
    _rest(t + 0.5 * h, tmp, A, k2, model, ws, scr)
    _matvec(E, x, ex)                                     # E x
    for i in range(m):
        tmp[i] = ex[i] + 0.5 * h * k2[i]                  # X₃
    _rest(t + 0.5 * h, tmp, A, k3, model, ws, scr)
    for i in range(m):
        acc[i] = ex[i] + h * k3[i]
    _matvec(E, acc, tmp)                                  # X₄ = E² x + h E K₃
    _rest(t + (1.0 - STAGE_EPS) * h, tmp, A, k4, model, ws, scr)
    for i in range(m):
        acc[i] = x[i] + (h / 6.0) * k1[i]                 # E² (x + h/6 K₁)
    _matvec(E2, acc, xn)
    for i in range(m):
        acc[i] = (h / 3.0) * (k2[i] + k3[i])
    _matvec(E, acc, tmp)
    finite = True
    for i in range(m):
        xn[i] += tmp[i] + (h / 6.0) * k4[i]
        if not math.isfinite(xn[i]):
            finite = False
    nz = model.nz
    for a in range(nz):     # actuator states held within their bounds
        i = m - nz + a
        xn[i] = min(max(xn[i], model.z_lo[a]), model.z_hi[a])
    return finite


def lawson_loop(x0, h, per, k0, n_out, out_dt, max_ratio, xs, A, E, E2, model_args,
                ws_args):
    """Fixed-step Lawson RK4 over output intervals k0..n_out−1 (x0 at t = k0·out_dt),
    ``per`` steps each, storing the state into xs[k + 1]. Returns (status, time, steps,
    last good state, offending state): status OK, NON_FINITE or DEFLECTION. Python around
    the compiled core."""
    x = np.array(x0, dtype=float)
    sc = np.empty((9, x.shape[0]))
    status, t, steps = _lawson_loop(x, sc, h, per, k0, n_out, out_dt, max_ratio, xs, A, E,
                                    E2, model_args, ws_args)
    return status, t, steps, x, (x if status == OK else sc[8].copy())


@_jit_raw
def _lawson_loop(x, sc, h, per, k0, n_out, out_dt, max_ratio, xs, A, E, E2, model_args,
                 ws_args):
    """:func:`lawson_loop`'s loop without reference counting (x advanced in place, sc[8]
    the offending state on failure)."""
    model, ws = named(model_args, ws_args)
    m = x.shape[0]
    xn = sc[8]
    steps = 0
    for k in range(k0, n_out):
        for j in range(per):
            t = k * out_dt + j * h
            steps += 1
            if not _lawson_step(t, h, x, xn, A, E, E2, sc, model, ws):
                return NON_FINITE, t + h, steps
            if deflection_ratio(xn, model) > max_ratio:
                return DEFLECTION, t + h, steps
            for i in range(m):
                x[i] = xn[i]
        for i in range(m):
            xs[k + 1, i] = x[i]
    return OK, n_out * out_dt, steps


def warm_up(model, x0, xs):
    """Compile (or load from cache) :func:`lawson_loop` with zero steps."""
    m = len(x0)
    eye = np.eye(m)
    lawson_loop(np.array(x0, float), 1e-3, 1, 0, 0, 1e-3, 1.0, xs, eye, eye, eye, model,
                workspace(model))
