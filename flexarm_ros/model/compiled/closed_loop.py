"""The closed loop of the test bench in one compiled call: the controller, the motor driver
and the plant, tick by tick, with the arithmetic of the Python cores
(:mod:`flexarm_ros.twin.cores`), for the batch commands (:mod:`flexarm_ros.twin.batch`).

One control tick k at t_k = k·J·g (J grid intervals of g ns per period):

1. the joint angles the controller reads: q₀ + counts/gain of the encoder where one is
   declared (counts = ⌊gain·(θ − θ_init) + 10⁻⁹⌋, updated at the encoder's sample
   instants), else the model's joint angle;
2. the command: ``open_loop`` — the input program at t_k within ±the command limit;
   ``position`` — seed 000 Eq. 5.16 and 5.17 on the encoder angles, the rate from the
   filtered backward difference q̇_k = q̇_{k−1} + α (Δq/T − q̇_{k−1}), α = 1 − e^(−2πf_cT)
   (:class:`~flexarm_ros.control.joint_pd.EncoderVelocity`, zero on the first tick):
   T_i = −kd_i q̇_i − kp_i (q_i − q_cmd,i), V_i = (R/(K_t n))_i T_i + (K_b n)_i q̇_i,
   clipped to ±the supply;
3. the driver: the effort to hold, from the drive rate at t_k (seed 000 Eq. 5.11,
   :func:`~flexarm_ros.model.drives.actuator_torque`), the armature current advanced over
   the period with command and rate held (:func:`~flexarm_ros.model.drives.advance_state`),
   held within the torque limit; a servovalve's current passes to the plant;
4. the plant: the period in equal RK4 steps with the efforts held, the grid instants from
   the steps' dense output (:func:`~flexarm_ros.model.compiled.loops._rk4_period`), the
   encoders and accelerometers read where due.

The controller's and the encoders' arithmetic is compiled without fast-math contraction
(:data:`~flexarm_ros.model.compiled.jit_exact`), so it gives the bits numpy gives: a count
is a floor, and one ulp could flip it. Tests hold the run equal to the cores' reference
lane and to a lockstep twin's bag (test_closed_loop.py).
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model import drives
from flexarm_ros.model.compiled import jit as _jit, jit_exact as _jit_exact
from flexarm_ros.model.compiled.chain import OK, eval_torque_c, rhs_into
from flexarm_ros.model.compiled.layout import named
from flexarm_ros.model.compiled.loops import rk4_period_raw
from flexarm_ros.model.compiled.sensors import fill_readings

#: status of a run whose encoder left the int32 range of encoder_counts (the plant's
#: SimulationDiverged of the same name)
ENCODER_RANGE = 11
INT32_MAX = 2 ** 31 - 1

OPEN_LOOP, POSITION = 0, 1


@_jit_exact
def encoder_count(gain, theta, theta_init):
    """⌊gain·(θ − θ_init) + 10⁻⁹⌋ (:func:`flexarm_ros.model.sensors.true_value`)."""
    return math.floor(gain * (theta - theta_init) + 1e-9)


@_jit_exact
def encoder_angle(q0, counts, gain):
    """The joint angle the controller reads from an encoder: q₀ + counts/gain."""
    return q0 + counts / gain


@_jit_exact
def filtered_rate(q, q_prev, qd, period, alpha):
    """One step of the encoder-rate filter: q̇ + α ((q − q_prev)/T − q̇)."""
    return qd + alpha * ((q - q_prev) / period - qd)


@_jit_exact
def pd_volts(q, qd, q_cmd, kp, kd, c1, c2, vlim):
    """Eq. 5.16 then Eq. 5.17, one joint: T = −kd q̇ − kp (q − q_cmd), V = c1 T + c2 q̇
    within ±vlim (c1 = R/(K_t n), c2 = K_b n)."""
    torque = -kd * (qd - 0.0) - kp * (q - q_cmd)
    v = c1 * torque + c2 * qd
    return min(max(v, -vlim), vlim)


@_jit
def run_ticks(k0, k1, J, g_ns, nsteps, max_ratio, x, model_args, ws_args, nystrom, period,
              mode, prog_code, prog_par, prog_times, prog_values, prog_len, cmd_lim,
              kp, kd, q_cmd, alpha, c1, c2, ang_free, enc_on, enc_free, enc_gain, enc_init,
              enc_q0, enc_every, counts, q_prev, qd_f, drv_kind, drv_par, drv_z, tau_lim,
              valve, rate_free, act_prog, acc_every, ints, flt, phi, slope, S,
              X, ACC, U, TAU, CUR, held, bad):
    """Control ticks k0..k1−1 (module doc), the state ``x``, encoder ``counts``, the rate
    filter (``q_prev``, ``qd_f``) and the driver's states ``drv_z`` carried in place from
    one call to the next; ``held[0]`` counts the ticks whose torque the driver held at its
    limit. X[k·J + j] is the state at grid instant k·J + j (row 0 the start, written by
    the caller), ACC its accelerometers where due, U/TAU/CUR the tick's command, held
    effort and current at t_k.

    Returns (status, tick, time): OK, or NON_FINITE / DEFLECTION from the plant's period
    (x the last good state, ``bad`` the offending one; the tick that failed) or
    ENCODER_RANGE."""
    model, ws = named(model_args, ws_args)
    nj = cmd_lim.shape[0]
    m = x.shape[0]
    nf = model.free.shape[0]
    xs = np.empty((J, m))
    sc = np.empty((9, m))
    xdot = np.empty(m)
    qdd = np.empty(model.n)
    ang = np.empty(nj)
    cmd = np.empty(nj)
    tau = np.empty(nj)
    for k in range(k0, k1):
        t = float(k * J * g_ns) * 1e-9
        for i in range(nj):
            if enc_on[i]:
                ang[i] = encoder_angle(enc_q0[i], float(counts[i]), enc_gain[i])
            else:
                ang[i] = x[ang_free[i]]
        if mode == OPEN_LOOP:
            for i in range(nj):
                v = 0.0
                if prog_code[i] >= 0:
                    L = prog_len[i]
                    v = eval_torque_c(prog_code[i], prog_par[i], prog_times[i, :L],
                                      prog_values[i, :L], t)
                cmd[i] = min(max(v, -cmd_lim[i]), cmd_lim[i])
        else:
            for i in range(nj):
                if k == 0:
                    qd_f[i] = 0.0
                else:
                    qd_f[i] = filtered_rate(ang[i], q_prev[i], qd_f[i], period, alpha)
                q_prev[i] = ang[i]
                cmd[i] = pd_volts(ang[i], qd_f[i], q_cmd[i], kp[i], kd[i], c1[i], c2[i],
                                  cmd_lim[i])
        beyond = False
        for i in range(nj):
            U[k, i] = cmd[i]
            w = x[nf + rate_free[i]]
            kind = drv_kind[i]
            if kind == drives.DC_CURRENT:
                CUR[k, i] = drv_z[i]
            elif kind == drives.DC_QUASI_STATIC:
                CUR[k, i] = drives.motor_current(kind, drv_par[i], cmd[i], w, 0.0)
            else:
                CUR[k, i] = 0.0
            if valve[i]:
                tau[i] = cmd[i]
            else:
                tau[i] = drives.actuator_torque(kind, drv_par[i], cmd[i], w, drv_z[i])
                drv_z[i] = drives.advance_state(kind, drv_par[i], cmd[i], w, drv_z[i],
                                                period)
                if abs(tau[i]) > tau_lim[i]:
                    beyond = True
        if beyond:
            held[0] += 1
        for i in range(nj):
            if beyond and not valve[i]:
                tau[i] = min(max(tau[i], -tau_lim[i]), tau_lim[i])
            TAU[k, i] = tau[i]
            if act_prog[i] >= 0:
                model.prog_par[act_prog[i], 0] = tau[i]
        status, t_reached, _, _ = rk4_period_raw(x, k * J, g_ns, J, nsteps, max_ratio, xs,
                                                  sc, model_args, ws_args, nystrom)
        if status != OK:
            for a in range(m):
                bad[a] = sc[0, a]
            return status, k, t_reached
        for j in range(J):
            kg = k * J + j + 1
            t_ns = kg * g_ns
            for a in range(m):
                X[kg, a] = xs[j, a]
            for i in range(nj):
                if enc_on[i] and t_ns % enc_every[i] == 0:
                    c = encoder_count(enc_gain[i], xs[j, enc_free[i]], enc_init[i])
                    if abs(c) > INT32_MAX:
                        return ENCODER_RANGE, k, float(t_ns) * 1e-9
                    counts[i] = int(c)
            if acc_every > 0 and t_ns % acc_every == 0:
                ts = float(t_ns) * 1e-9
                rhs_into(ts, xs[j], xdot, model, ws)
                for a in range(nf):
                    qdd[model.free[a]] = xdot[nf + a]
                fill_readings(ws.q, ws.qd, qdd, model, ws, ints, flt, phi, slope, S, ACC[kg])
    return OK, k1, float(k1 * J * g_ns) * 1e-9
