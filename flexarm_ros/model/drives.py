"""Actuator models: DC motor + gearbox, hydraulic servovalve + rotary actuator.

Each actuator turns an input u (torque N·m, voltage V or valve current A) and the rate w of
its drive coordinate (rad/s, gearbox output side) into a torque on that coordinate, and may
carry one first-order state z (armature current A, or load pressure Pa). The functions are
scalar Python that numba compiles unchanged (like :mod:`programs`), so the compiled loops,
the numpy reference and the motor-driver node share one implementation.

Parameter vector ``par`` (:func:`encode`), by kind:

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


def encode(drive, motor_current: str = "dynamic"):
    """(kind, par[N_PAR], has_state) of a :class:`scene.Drive` (None → ideal torque)."""
    par = np.zeros(N_PAR)
    if drive is None:
        return IDEAL, par, False
    if drive.type == "dc_motor":
        L = drive.inductance or 0.0
        par[:7] = [drive.gear_ratio, drive.torque_constant, drive.back_emf_constant,
                   drive.resistance, L, drive.supply_voltage or INF, drive.current_limit or INF]
        dynamic = L > 0.0 and motor_current == "dynamic"
        return (DC_CURRENT if dynamic else DC_QUASI_STATIC), par, dynamic
    par[:7] = [drive.displacement, drive.torque_efficiency or 1.0, drive.leakage or 0.0,
               drive.valve_gain, drive.supply_pressure, drive.total_volume, drive.bulk_modulus]
    return HYDRAULIC, par, True


def state_bounds(kind, par) -> tuple[float, float]:
    """(lower, upper) bound of an actuator's state: ±i_limit (A), ±P_s (Pa). The
    integrators clamp the state into them after every step (fixed-step methods would
    otherwise overshoot a bound by a fraction of a step's change)."""
    if kind == DC_CURRENT:
        return -par[6], par[6]
    if kind == HYDRAULIC:
        return -par[4], par[4]
    return -INF, INF


@jit
def _clip(v, lim):
    return min(max(v, -lim), lim)


@jit
def motor_current(kind, par, u, w, z):
    """Armature current (A) of a DC drive: the state, or quasi-static (V − K_b n w)/R,
    limited to ±i_limit."""
    if kind == DC_CURRENT:
        return _clip(z, par[6])
    return _clip((_clip(u, par[5]) - par[2] * par[0] * w) / par[3], par[6])


@jit
def actuator_torque(kind, par, u, w, z):
    """Torque (N·m) on the drive coordinate."""
    if kind == IDEAL:
        return u
    if kind == HYDRAULIC:
        return par[1] * par[0] * _clip(z, par[4])
    return par[0] * par[1] * motor_current(kind, par, u, w, z)


@jit
def valve_flow(par, i, p_load):
    """Servovalve flow Q = K_v i √(P_s − sgn(i) P_L) (m³/s), zero when the pressure
    difference across the open orifice vanishes."""
    dp = par[4] - p_load if i >= 0.0 else par[4] + p_load
    return par[3] * i * math.sqrt(dp) if dp > 0.0 else 0.0


@jit
def actuator_rate(kind, par, u, w, z):
    """dz/dt of the actuator's state (0 for stateless kinds)."""
    if kind == DC_CURRENT:
        dz = (_clip(u, par[5]) - par[3] * z - par[2] * par[0] * w) / par[4]
        lim = par[6]
        if (z >= lim and dz > 0.0) or (z <= -lim and dz < 0.0):
            return 0.0
        return dz
    if kind == HYDRAULIC:
        q = valve_flow(par, u + par[7], z)
        dz = 4.0 * par[6] / par[5] * (q - par[0] * w - par[2] * z)
        ps = par[4]
        if (z >= ps and dz > 0.0) or (z <= -ps and dz < 0.0):
            return 0.0
        return dz
    return 0.0


def hydraulic_hold(par, torque):
    """(P_L, i_bias) holding ``torque`` at rest: P_L = T/(η_t D_m), and the valve current
    whose flow feeds the leakage, K_v i √(P_s − P_L) = C_tm P_L."""
    p = torque / (par[1] * par[0])
    if abs(p) >= par[4]:
        return p, math.nan
    flow = par[2] * p
    i = flow / (par[3] * math.sqrt(par[4] - p)) if flow >= 0.0 else \
        flow / (par[3] * math.sqrt(par[4] + p))
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
