"""The compiled lane of the closed-loop batch run (:mod:`flexarm_ros.twin.batch`): the
cores' controller, driver and plant packed into arrays for
:func:`flexarm_ros.model.compiled.closed_loop.run_ticks`, which runs the whole loop in
compiled code; ticks in chunks so that progress can be told between them.

Where it applies (:func:`eligible`): the numba backend; a plant that steps its periods
densely (smooth model, no wall, no prescribed motion — not with backlash, a servovalve or
a current limit); a controller in ``open_loop`` or ``position`` mode with fixed targets;
accelerometers at one rate. Everything else runs on the cores (the reference lane).
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.model.compiled import closed_loop as kloop
from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import sensors as ksensors

#: ticks per compiled call (progress is told between calls)
CHUNK_TICKS = 2000


def eligible(sim, ctl) -> str | None:
    """None when the compiled lane runs this loop, else why not (one phrase)."""
    plant = sim.plant
    ch = plant.chain
    if ch.backend != "numba":
        return "the numpy backend (no numba)"
    if plant.contact is not None:
        return "a wall (the contact stepper runs in Python between compiled stretches)"
    if not plant.dense:
        return ("a plant stepped grid interval by grid interval (backlash, a servovalve, a "
                "current limit or a prescribed motion)")
    if ctl.mode not in ("open_loop", "position"):
        return f"control.mode {ctl.mode!r} (its task runs in Python)"
    if getattr(ctl, "shaper", None) is not None:
        return "a shaped target (its staircase runs on the cores)"
    if getattr(ctl, "reference", None) is not None:
        return "a move program (its reference runs on the cores)"
    if getattr(ctl, "lqg", None) is not None:
        return "an LQG controller (its estimator runs on the cores)"
    if getattr(ctl, "changes", None):
        return "gain or target changes (control.changes run on the cores)"
    if ctl.status != "ok":
        return f"the controller's status: {ctl.status}"
    rates = {sm.spec.rate_hz for sm in plant.sensors if sm.spec.kind == "accelerometer"}
    if len(rates) > 1:
        return "accelerometers at several rates"
    free = list(ch.free)
    for lm in ch.links:
        if lm.i_joint not in free:
            return f"a prescribed joint ({lm.name})"
    return None


def _programs(ctl, n):
    """The open-loop programs as padded arrays (code −1: no program, 0 V)."""
    enc = [p for p in ctl.programs]
    L = max([len(p[2]) for p in enc if p is not None] + [1])
    code = np.full(n, -1, dtype=np.int64)
    par = np.zeros((n, 8))
    times = np.zeros((n, L))
    values = np.zeros((n, L))
    lens = np.ones(n, dtype=np.int64)
    for k, p in enumerate(enc):
        if p is None:
            continue
        code[k], par[k] = p[0], p[1]
        lens[k] = len(p[2])
        times[k, :lens[k]], values[k, :lens[k]] = p[2], p[3]
    return code, par, times, values, lens


def run_compiled(sim, ctl, drv, K: int, progress=None):
    """The loop of ``K`` ticks in compiled calls; returns what
    :func:`~flexarm_ros.twin.batch._run_reference` returns (the sensor part as (states at
    every grid instant, accelerometers there))."""
    from flexarm_ros.twin.loop_record import LoopRecord, output_every
    plant = sim.plant
    ch = plant.chain
    n = len(ch.links)
    free = list(ch.free)
    g = plant.grid_ns
    J = int(round(sim.period * 1e9 / g))
    nsteps = plant.steps_per_period(J)
    # what the controller reads
    ang_free = np.array([free.index(lm.i_joint) for lm in ch.links], dtype=np.int64)
    enc_on = np.zeros(n, dtype=np.bool_)
    enc_free = np.zeros(n, dtype=np.int64)
    enc_gain = np.ones(n)
    enc_init = np.zeros(n)
    enc_q0 = np.zeros(n)
    enc_every = np.ones(n, dtype=np.int64)
    for link, q0, gain in sim._enc_zero:
        sm = sim.encoders[link]
        enc_on[link] = True
        enc_free[link] = free.index(sm.coord)
        enc_gain[link] = sm.gain
        enc_init[link] = plant.q_initial[sm.coord]
        enc_q0[link] = q0
        enc_every[link] = int(round(1e9 / sm.spec.rate_hz))
    counts = np.array([sim.counts.get(k, 0) for k in range(n)], dtype=np.int64)
    # the controller
    period = sim.period
    mode = kloop.OPEN_LOOP if ctl.mode == "open_loop" else kloop.POSITION
    code, par, times, values, lens = _programs(ctl, n)
    kp = kd = q_cmd = c1 = c2 = np.zeros(n)
    alpha = 0.0
    if mode == kloop.POSITION:
        kp, kd = ctl.pd.kp.copy(), ctl.pd.kd.copy()
        q_cmd = np.asarray(ctl.q_cmd, float).copy()
        mm = ctl.pd.motor
        c1 = mm.resistance / (mm.torque_constant * mm.gear_ratio)
        c2 = mm.back_emf_constant * mm.gear_ratio
        fc = ctl.velocity.cutoff_hz
        alpha = 1.0 if fc is None or math.isinf(fc) else \
            1.0 - math.exp(-2.0 * math.pi * fc * period)
    q_prev, qd_f = np.zeros(n), np.zeros(n)
    # the driver
    kind = np.array(drv.kind, dtype=np.int64)
    dpar = np.array(drv.par)
    z = drv.z.astype(float).copy()
    rate_free = np.array([free.index(i) for i in ch.drive_index()], dtype=np.int64)
    act_prog = np.full(n, -1, dtype=np.int64)
    for link, j in plant._act.items():
        act_prog[link] = j
    # accelerometers
    acc_idx, *acc = ksensors.pack(ch, plant.sensors)
    acc_every = 0
    if len(acc_idx):
        acc_every = int(round(1e9 / plant.sensors[int(acc_idx[0])].spec.rate_hz))
    # outputs
    X = np.empty((K * J + 1, len(plant.x)))
    X[0] = plant.x
    ACC = np.zeros((K * J + 1, len(acc_idx)))
    U, TAU, CUR = np.zeros((K, n)), np.zeros((K, n)), np.zeros((K, n))
    held = np.zeros(1, dtype=np.int64)
    bad = np.zeros(len(plant.x))
    x = plant.x.copy()
    max_ratio = ch.fidelity.max_deflection_ratio
    nystrom = plant.integrator == "rkn4"
    for k0 in range(0, K, CHUNK_TICKS):
        k1 = min(K, k0 + CHUNK_TICKS)
        status, k_fail, t_fail = kloop.run_ticks(
            k0, k1, J, g, nsteps, max_ratio, x, ch.kernel_args, plant.ws, nystrom, period,
            mode, code, par, times, values, lens, ctl.limit, kp, kd, q_cmd, alpha, c1, c2,
            ang_free, enc_on, enc_free, enc_gain, enc_init, enc_q0, enc_every, counts,
            q_prev, qd_f, kind, dpar, z, drv.torque_limit, drv.valve, rate_free, act_prog,
            acc_every, *acc, X, ACC, U, TAU, CUR, held, bad)
        if status != kchain.OK:
            _fail(sim, status, int(k_fail), float(t_fail), x, bad, U)
        if progress is not None:
            progress(k1 / K)
    rec = LoopRecord(np.arange(K) * (J * g * 1e-9), U, TAU, CUR,
                     None if mode == kloop.OPEN_LOOP else np.tile(q_cmd, (K, 1)),
                     None, 0, int(held[0]), ctl.status)
    if mode == kloop.POSITION and ctl.scene.control.tip_target is not None:
        rec.tip_target = np.tile(np.asarray(ctl.scene.control.tip_target, float), (K, 1))
    plant.x = x
    every = output_every(plant)
    steps = nsteps * K
    calls = (4 * nsteps + (1 if J > 1 else 0)) * K
    return (X[::every], None, (X, ACC if len(acc_idx) else None), rec, (steps, calls))


def _fail(sim, status, k, t, x, bad, U):
    """The plant's divergence as the reference lane names it (the guard's words, the
    commands held)."""
    plant = sim.plant
    if status == kloop.ENCODER_RANGE:
        raise SimulationDiverged(
            "encoder counts", t, math.nan,
            "check the drive's input and the joint's damping; the scene's encoders are "
            "sized for the drive's range",
            detail="the counts leave the int32 range of the encoder_counts message "
                   "(std_msgs/Int32MultiArray)")
    plant.guard.last = x
    held = ", ".join(f"{v:.4g}" for v in U[k])
    try:
        plant.guard.check(t, bad)
    except SimulationDiverged as exc:
        raise SimulationDiverged(
            exc.quantity, exc.time, exc.last_value,
            f"check the joint inputs (commands [{held}] from t = "
            f"{k * sim.period:.6g} s); else {exc.suggestion}", detail=exc.detail) from None
    raise SimulationDiverged("state", t, math.nan, "reduce the step (fidelity.dt)",
                             detail=f"the plant's period stopped with status {status}")
