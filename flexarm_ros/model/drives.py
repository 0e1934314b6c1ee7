"""Actuator models: DC motor + gearbox, hydraulic servovalve + rotary actuator.

Each actuator turns an input u (torque N·m, voltage V or valve current A) and the rate w of
its drive coordinate (rad/s, gearbox output side) into a torque on that coordinate, and may
carry one first-order state z (armature current A, or load pressure Pa). The functions are
scalar Python that numba compiles unchanged (like :mod:`programs`), so the compiled loops,
the numpy reference and the motor-driver node share one implementation.

Parameter vector ``par`` (:func:`encode`), by kind, its slots named by the ``DC_*`` and
``HYD_*`` constants below (this module is the one place that knows their positions):

* ``IDEAL`` (torque program): unused.
* ``DC_QUASI_STATIC`` / ``DC_CURRENT`` (seed 000 Eq. 5.11; seed 001 Sec. 4):
  par = [n, K_t, K_b, R, L, V_supply, i_limit]. Voltage v = clip(u, ±V_supply);
  quasi-static i = (v − K_b n w)/R, else L di/dt = v − R i − K_b n w;
  torque = n K_t clip(i, ±i_limit). With quasi-static current the torque is Eq. 5.11's
  (K_t n/R) e − (K_t K_b n²/R) θ̇ (J_eq, C_eq sit in the mass and damping matrices).
* ``HYDRAULIC`` (seed 002 Appendix B): par = [D_m, η_t, C_tm, K_v, P_s, V_t, β_e, i_bias].
  Valve i = u + i_bias; Q = K_v i √(P_s − sgn(i) P_L) (the orifice from supply to the high
  side for either sign, symmetric as the source gives no reverse convention);
  Ṗ_L = 4β_e/V_t (Q − D_m w − C_tm P_L); torque = η_t D_m P_L; P_L held within ±P_s.

The current limit and the pressure bound act on the state as on the real hardware: the
derivative is set to zero when the state sits at the bound and would leave it.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.compiled import jit

IDEAL, DC_QUASI_STATIC, DC_CURRENT, HYDRAULIC = 0, 1, 2, 3
N_PAR = 8
INF = math.inf

# slots of par (numba folds these module constants at compile time)
DC_GEAR_RATIO = 0               # n
DC_TORQUE_CONSTANT = 1          # K_t (N·m/A)
DC_BACK_EMF_CONSTANT = 2        # K_b (V·s/rad)
DC_RESISTANCE = 3               # R (Ω)
DC_INDUCTANCE = 4               # L (H)
DC_SUPPLY_VOLTAGE = 5           # V_supply (V)
DC_CURRENT_LIMIT = 6            # i_limit (A)
HYD_DISPLACEMENT = 0            # D_m (m³/rad)
HYD_TORQUE_EFFICIENCY = 1       # η_t
HYD_LEAKAGE = 2                 # C_tm (m³/(s·Pa))
HYD_VALVE_GAIN = 3              # K_v (m³/(s·A·√Pa))
HYD_SUPPLY_PRESSURE = 4         # P_s (Pa)
HYD_TOTAL_VOLUME = 5            # V_t (m³)
HYD_BULK_MODULUS = 6            # β_e (Pa)
HYD_VALVE_BIAS = 7              # i_bias (A): the null current (statics.initial_state)


def encode(drive, motor_current: str = "dynamic"):
    """(kind, par[N_PAR], has_state) of a :class:`scene.Drive` (None → ideal torque)."""
    par = np.zeros(N_PAR)
    if drive is None:
        return IDEAL, par, False
    if drive.type == "dc_motor":
        L = drive.inductance or 0.0
        par[DC_GEAR_RATIO] = drive.gear_ratio
        par[DC_TORQUE_CONSTANT] = drive.output_torque_constant
        par[DC_BACK_EMF_CONSTANT] = drive.back_emf_constant
        par[DC_RESISTANCE] = drive.resistance
        par[DC_INDUCTANCE] = L
        par[DC_SUPPLY_VOLTAGE] = drive.supply_voltage or INF
        par[DC_CURRENT_LIMIT] = drive.current_limit or INF
        dynamic = L > 0.0 and motor_current == "dynamic"
        return (DC_CURRENT if dynamic else DC_QUASI_STATIC), par, dynamic
    par[HYD_DISPLACEMENT] = drive.displacement
    par[HYD_TORQUE_EFFICIENCY] = drive.torque_efficiency or 1.0
    par[HYD_LEAKAGE] = drive.leakage or 0.0
    par[HYD_VALVE_GAIN] = drive.valve_gain
    par[HYD_SUPPLY_PRESSURE] = drive.supply_pressure
    par[HYD_TOTAL_VOLUME] = drive.total_volume
    par[HYD_BULK_MODULUS] = drive.bulk_modulus
    return HYDRAULIC, par, True


@jit
def state_bounds(kind, par):
    """(lower, upper) bound of an actuator's state: ±i_limit (A), ±P_s (Pa). The
    integrators clamp the state into them after every step (fixed-step methods would
    otherwise overshoot a bound by a fraction of a step's change)."""
    if kind == DC_CURRENT:
        return -par[DC_CURRENT_LIMIT], par[DC_CURRENT_LIMIT]
    if kind == HYDRAULIC:
        return -par[HYD_SUPPLY_PRESSURE], par[HYD_SUPPLY_PRESSURE]
    return -INF, INF


@jit
def _clip(v, lim):
    return min(max(v, -lim), lim)


@jit
def motor_current(kind, par, u, w, z):
    """Armature current (A) of a DC drive: the state, or quasi-static (V − K_b n w)/R,
    limited to ±i_limit."""
    if kind == DC_CURRENT:
        return _clip(z, par[DC_CURRENT_LIMIT])
    v = _clip(u, par[DC_SUPPLY_VOLTAGE])
    return _clip((v - par[DC_BACK_EMF_CONSTANT] * par[DC_GEAR_RATIO] * w) / par[DC_RESISTANCE],
                 par[DC_CURRENT_LIMIT])


@jit
def actuator_torque(kind, par, u, w, z):
    """Torque (N·m) on the drive coordinate."""
    if kind == IDEAL:
        return u
    if kind == HYDRAULIC:
        return (par[HYD_TORQUE_EFFICIENCY] * par[HYD_DISPLACEMENT]
                * _clip(z, par[HYD_SUPPLY_PRESSURE]))
    return par[DC_GEAR_RATIO] * par[DC_TORQUE_CONSTANT] * motor_current(kind, par, u, w, z)


@jit
def drive_columns(kind, par, u, w, z, current, torque):
    """current[k], torque[k] = :func:`motor_current` (0 for an ideal or hydraulic drive),
    :func:`actuator_torque` at the k-th sample (u, w, z): a run's drive columns in one compiled call (one Python call per
    sample and column cost ~20 ms on a 2.5 s run at 4 kHz)."""
    dc = kind != IDEAL and kind != HYDRAULIC
    for k in range(u.shape[0]):
        current[k] = motor_current(kind, par, u[k], w[k], z[k]) if dc else 0.0
        torque[k] = actuator_torque(kind, par, u[k], w[k], z[k])


@jit
def valve_flow(par, i, p_load):
    """Servovalve flow Q = K_v i √(P_s − sgn(i) P_L) (m³/s), zero when the pressure
    difference across the open orifice vanishes."""
    ps = par[HYD_SUPPLY_PRESSURE]
    dp = ps - p_load if i >= 0.0 else ps + p_load
    return par[HYD_VALVE_GAIN] * i * math.sqrt(dp) if dp > 0.0 else 0.0


@jit
def actuator_rate(kind, par, u, w, z):
    """dz/dt of the actuator's state (0 for stateless kinds)."""
    if kind == DC_CURRENT:
        dz = (_clip(u, par[DC_SUPPLY_VOLTAGE]) - par[DC_RESISTANCE] * z
              - par[DC_BACK_EMF_CONSTANT] * par[DC_GEAR_RATIO] * w) / par[DC_INDUCTANCE]
        lim = par[DC_CURRENT_LIMIT]
        if (z >= lim and dz > 0.0) or (z <= -lim and dz < 0.0):
            return 0.0
        return dz
    if kind == HYDRAULIC:
        q = valve_flow(par, u + par[HYD_VALVE_BIAS], z)
        dz = 4.0 * par[HYD_BULK_MODULUS] / par[HYD_TOTAL_VOLUME] * (
            q - par[HYD_DISPLACEMENT] * w - par[HYD_LEAKAGE] * z)
        ps = par[HYD_SUPPLY_PRESSURE]
        if (z >= ps and dz > 0.0) or (z <= -ps and dz < 0.0):
            return 0.0
        return dz
    return 0.0


#: RK4 sub-steps of :func:`advance_state` for a state without a closed-form solution
HOLD_SUBSTEPS = 20


@jit
def advance_state(kind, par, u, w, z, dt):
    """The actuator state after ``dt`` with the input u and the drive rate w held
    (zero-order hold, the motor driver between control ticks): :func:`actuator_rate`
    integrated and clamped into :func:`state_bounds`, as the plant's integrators do.

    The armature current's equation is linear in i with time constant τ = L/R, so it is
    solved exactly, i(dt) = i + (di/dt)·τ(1 − e^(−dt/τ)); the load pressure by
    ``HOLD_SUBSTEPS`` RK4 steps, clamped after each.
    """
    lo, hi = state_bounds(kind, par)
    if kind == DC_CURRENT:
        tau = par[DC_INDUCTANCE] / par[DC_RESISTANCE]
        z1 = z - actuator_rate(kind, par, u, w, z) * tau * math.expm1(-dt / tau)
        return min(max(z1, lo), hi)
    if kind == HYDRAULIC:
        h = dt / HOLD_SUBSTEPS
        for _ in range(HOLD_SUBSTEPS):
            k1 = actuator_rate(kind, par, u, w, z)
            k2 = actuator_rate(kind, par, u, w, z + 0.5 * h * k1)
            k3 = actuator_rate(kind, par, u, w, z + 0.5 * h * k2)
            k4 = actuator_rate(kind, par, u, w, z + h * k3)
            z = min(max(z + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4), lo), hi)
        return z
    return z


def hydraulic_hold(par, torque):
    """(P_L, i_bias) holding ``torque`` at rest: P_L = T/(η_t D_m), and the valve current
    whose flow feeds the leakage, K_v i √(P_s − P_L) = C_tm P_L."""
    p = torque / (par[HYD_TORQUE_EFFICIENCY] * par[HYD_DISPLACEMENT])
    ps = par[HYD_SUPPLY_PRESSURE]
    if abs(p) >= ps:
        return p, math.nan
    flow = par[HYD_LEAKAGE] * p
    kv = par[HYD_VALVE_GAIN]
    i = flow / (kv * math.sqrt(ps - p)) if flow >= 0.0 else flow / (kv * math.sqrt(ps + p))
    return p, i


@jit
def backlash_torque(half_width, k, c, delta, delta_rate):
    """Mesh torque of a backlash coupling (motor side minus link side δ): zero inside the
    dead zone |δ| <= b, else k(δ ∓ b) + c δ̇, never pulling (the teeth only push)."""
    if delta > half_width:
        return max(k * (delta - half_width) + c * delta_rate, 0.0)
    if delta < -half_width:
        return min(k * (delta + half_width) + c * delta_rate, 0.0)
    return 0.0
