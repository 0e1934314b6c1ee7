"""Joint PD law, static DC-motor voltage map and the joint position controller of seed 000.

Seed 000 (Hariharesan 1998, Sec. 5.6.3; simulation only in the source):

* Eq. 5.16, the joint law: T_i(t) = −damp_i · s_i − spring_i · (q_i(t) − cQ_i), with s_i
  the joint rate q̇_i and cQ_i the commanded angle. Written here with per-joint gains
  kp = spring, kd = damp and an optional commanded rate:
  T_i = −kd_i (q̇_i − q̇_cmd,i) − kp_i (q_i − q_cmd,i).
  Sign convention: T_i is the torque the drive applies to joint i at the gearbox output,
  positive in the direction of positive q_i (counterclockwise, REP 103), so a positive
  error q_i − q_cmd,i gives a negative (restoring) torque.
* Eq. 5.17, the voltage that makes the motor deliver T_i, from the steady (quasi-static
  current) motor equation of Sec. 5.3.1 (Eq. 5.11 without the J_eq, C_eq terms):
  V_i = (R_i / (K_t,i n_i)) T_i + K_b,i n_i q̇_i,
  the exact inverse of T_i = n_i K_t,i (V_i − K_b,i n_i q̇_i) / R_i.
  The gearbox inertia J_eq and damping C_eq are not compensated (as in the source).

Style (ros2_control): components are plain objects, time is an argument
(``update(t, dt, ...)``), nothing reads a clock, nothing imports rclpy; a ROS controller
node is a thin adapter over :class:`JointPositionController`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EncoderVelocity", "JointPD", "JointPositionController", "MotorVoltageMap"]


def _vec(name, value, n=None, positive=False, nonneg=False):
    v = np.atleast_1d(np.asarray(value, dtype=float)).copy()
    if v.ndim != 1 or (n is not None and v.size != n):
        raise ValueError(f"{name}: got shape {v.shape}, expected ({n if n else 'n'},)")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: got {v.tolist()}, expected finite values")
    if positive and not np.all(v > 0.0):
        raise ValueError(f"{name}: got {v.tolist()}, expected > 0")
    if nonneg and not np.all(v >= 0.0):
        raise ValueError(f"{name}: got {v.tolist()}, expected >= 0")
    return v


class MotorVoltageMap:
    """Static DC-motor + gearbox map between output torque and armature voltage
    (seed 000 Eq. 5.17 and Sec. 5.3.1), per joint.

    voltage:  V = (R / (K_t n)) T + K_b n q̇                       (Eq. 5.17)
    torque:   T = n K_t (V − K_b n q̇) / R                          (its inverse; quasi-static
              current i = (V − K_b n q̇)/R, torque n K_t i at the gearbox output, the
              ``dc_motor`` drive of the physics core with inductance 0)

    Parameters (vectors, one entry per joint, or scalars broadcast)
    ----------
    gear_ratio : n (motor turns per output turn), > 0.
    torque_constant : K_t (N·m/A), > 0.
    back_emf_constant : K_b (V·s/rad), > 0.
    resistance : R (Ω), > 0.
    supply_voltage : |V| is clipped to this (V), None for no limit.

    After :meth:`voltage`, ``saturated`` holds one bool per joint (the demand exceeded the
    supply and was clipped) and ``unclipped`` the demanded voltage.
    """

    def __init__(self, gear_ratio, torque_constant, back_emf_constant, resistance,
                 supply_voltage=None):
        self.gear_ratio = _vec("gear_ratio", gear_ratio, positive=True)
        n = self.gear_ratio.size
        b = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (n,))  # noqa: E731
        self.torque_constant = _vec("torque_constant", b(torque_constant), n, positive=True)
        self.back_emf_constant = _vec("back_emf_constant", b(back_emf_constant), n,
                                      positive=True)
        self.resistance = _vec("resistance", b(resistance), n, positive=True)
        if supply_voltage is None:
            self.supply_voltage = np.full(n, math.inf)
        else:
            sv = np.asarray(supply_voltage, dtype=float)
            self.supply_voltage = np.broadcast_to(sv, (n,)).astype(float)
            if not np.all(self.supply_voltage > 0.0):
                raise ValueError(f"supply_voltage: got {self.supply_voltage.tolist()}, "
                                 f"expected > 0 V or None")
        self.saturated = np.zeros(n, dtype=bool)
        self.unclipped = np.zeros(n)

    @classmethod
    def from_drives(cls, drives) -> "MotorVoltageMap":
        """Build from the scene's ``dc_motor`` drives (objects with gear_ratio,
        torque_constant, back_emf_constant, resistance, supply_voltage attributes), in
        joint order."""
        drives = list(drives)
        for k, d in enumerate(drives):
            if getattr(d, "type", "dc_motor") != "dc_motor":
                raise ValueError(f"drives[{k}].type: got {d.type!r}, expected 'dc_motor'")
        sv = [getattr(d, "supply_voltage", None) for d in drives]
        # η·K_t where the drive has a gear efficiency (a scene's Drive), else K_t
        kt = [getattr(d, "output_torque_constant", d.torque_constant) for d in drives]
        return cls([d.gear_ratio for d in drives], kt,
                   [d.back_emf_constant for d in drives], [d.resistance for d in drives],
                   [math.inf if v is None else v for v in sv])

    @property
    def n_joints(self) -> int:
        """Number of joints (entries per vector)."""
        return self.gear_ratio.size

    @property
    def back_emf_damping(self) -> np.ndarray:
        """K_t K_b n² / R (N·m·s/rad): the damping the back-EMF adds at a fixed voltage."""
        return (self.torque_constant * self.back_emf_constant * self.gear_ratio ** 2
                / self.resistance)

    def voltage(self, torque, qd) -> np.ndarray:
        """Armature voltages (V) that make the motors deliver ``torque`` (N·m, gearbox
        output) at joint rates ``qd`` (rad/s): V = (R/(K_t n)) T + K_b n q̇ (Eq. 5.17),
        clipped to ±supply_voltage; sets ``saturated`` and ``unclipped``."""
        T = np.asarray(torque, dtype=float)
        w = np.asarray(qd, dtype=float)
        v = (self.resistance / (self.torque_constant * self.gear_ratio)) * T \
            + self.back_emf_constant * self.gear_ratio * w
        self.unclipped = v
        self.saturated = np.abs(v) > self.supply_voltage
        return np.clip(v, -self.supply_voltage, self.supply_voltage)

    def torque(self, voltage, qd) -> np.ndarray:
        """Output torque (N·m) of the quasi-static motor at ``voltage`` (V, clipped to the
        supply) and joint rate ``qd`` (rad/s): T = n K_t (V − K_b n q̇)/R."""
        v = np.clip(np.asarray(voltage, dtype=float), -self.supply_voltage, self.supply_voltage)
        w = np.asarray(qd, dtype=float)
        return (self.gear_ratio * self.torque_constant
                * (v - self.back_emf_constant * self.gear_ratio * w) / self.resistance)


class JointPD:
    """Seed 000 Eq. 5.16, per joint: T = −kd (q̇ − q̇_cmd) − kp (q − q_cmd).

    kp ("spring_i" in the source, N·m/rad) and kd ("damp_i", N·m·s/rad) are vectors with
    one entry per joint (scalars broadcast when the other is a vector). T is the drive
    torque at the gearbox output on joint i, positive along +q_i. ``motor``: an optional
    :class:`MotorVoltageMap`; with it, :meth:`voltage` returns the Eq. 5.17 volts.
    """

    def __init__(self, kp, kd, motor: MotorVoltageMap | None = None):
        kp = np.atleast_1d(np.asarray(kp, dtype=float))
        kd = np.atleast_1d(np.asarray(kd, dtype=float))
        n = max(kp.size, kd.size, motor.n_joints if motor is not None else 1)
        for name, v in (("kp", kp), ("kd", kd)):
            if v.size not in (1, n):
                raise ValueError(f"{name}: got {v.size} values, expected 1 or {n} (one per "
                                 f"joint)")
        self.kp = _vec("kp", np.broadcast_to(kp, (n,)), n, nonneg=True)
        self.kd = _vec("kd", np.broadcast_to(kd, (n,)), n, nonneg=True)
        if motor is not None and motor.n_joints != n:
            raise ValueError(f"motor: got {motor.n_joints} joints, expected {n} (as kp, kd)")
        self.motor = motor

    @property
    def n_joints(self) -> int:
        """Number of joints (entries per vector)."""
        return self.kp.size

    def torque(self, q, qd, q_cmd, qd_cmd=0.0) -> np.ndarray:
        """Joint torques (N·m): T = −kd (q̇ − q̇_cmd) − kp (q − q_cmd) (Eq. 5.16;
        the source has q̇_cmd = 0)."""
        q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
        return -self.kd * (qd - np.asarray(qd_cmd, dtype=float)) \
            - self.kp * (q - np.asarray(q_cmd, dtype=float))

    def voltage(self, q, qd, q_cmd, qd_cmd=0.0) -> np.ndarray:
        """Eq. 5.16 then Eq. 5.17: the motor voltages (V) for the PD torque."""
        if self.motor is None:
            raise ValueError("JointPD.voltage: no motor map, expected JointPD(kp, kd, motor=...)")
        return self.motor.voltage(self.torque(q, qd, q_cmd, qd_cmd), qd)


class EncoderVelocity:
    """Joint rate from quantized encoder angles: backward difference through a first-order
    low-pass filter (stateful).

        raw_k = (q_k − q_{k−1}) / dt,   qd_k = qd_{k−1} + α (raw_k − qd_{k−1}),
        α = 1 − exp(−2π f_c dt)   (exact zero-order-hold discretization of
        τ q̇_f' + q̇_f = raw, τ = 1/(2π f_c)).

    A quantum Δ of the encoder gives a raw rate spike Δ/dt; the filter spreads it, so the
    rate noise is about Δ·2π f_c (for dt ≪ τ). The first call (or after :meth:`reset`)
    only stores q and returns zeros (or ``qd0``). cutoff_hz: f_c > 0 (Hz); None or inf
    disables the filter (plain backward difference).
    """

    def __init__(self, cutoff_hz: float | None, qd0=None):
        if cutoff_hz is not None and not (cutoff_hz > 0.0):
            raise ValueError(f"cutoff_hz: got {cutoff_hz}, expected > 0 Hz or None")
        self.cutoff_hz = cutoff_hz
        self._qd0 = None if qd0 is None else np.asarray(qd0, dtype=float)
        self.reset()

    def reset(self) -> None:
        """Forget the previous reading: the next update restarts the difference."""
        self._q_prev = None
        self._t_prev = None
        self.qd = None if self._qd0 is None else self._qd0.copy()

    def update(self, t: float, dt: float, q) -> np.ndarray:
        """Filtered rate (rad/s) after a new encoder reading ``q`` (rad) taken ``dt`` s
        after the previous one, at time ``t`` (recorded, not used otherwise)."""
        q = np.asarray(q, dtype=float).copy()
        if self._q_prev is None:
            self._q_prev, self._t_prev = q, t
            if self.qd is None:
                self.qd = np.zeros_like(q)
            return self.qd.copy()
        if not dt > 0.0:
            raise ValueError(f"EncoderVelocity.update: dt got {dt}, expected > 0 s")
        raw = (q - self._q_prev) / dt
        if self.cutoff_hz is None or math.isinf(self.cutoff_hz):
            self.qd = raw
        else:
            a = 1.0 - math.exp(-2.0 * math.pi * self.cutoff_hz * dt)
            self.qd = self.qd + a * (raw - self.qd)
        self._q_prev, self._t_prev = q, t
        return self.qd.copy()


class JointPositionController:
    """Seed 000's joint position controller: Eq. 5.16 torque, Eq. 5.17 volts.

    ``update(t, dt, q_meas, qd_meas, q_cmd, qd_cmd=0) -> volts``:
      1. q̇ = qd_meas, or, with ``encoder_velocity`` set, q̇ = encoder_velocity.update(t, dt,
         q_meas) (a real controller reads quantized encoder angles; qd_meas may be None);
      2. T = −kd (q̇ − q̇_cmd) − kp (q_meas − q_cmd)                (Eq. 5.16);
      3. V = clip((R/(K_t n)) T + K_b n q̇, ±V_supply)               (Eq. 5.17).
    After a call: ``torque`` (N·m demanded), ``qd`` (rate used), ``saturated`` (bool per
    joint), ``voltage`` (V sent). Tip targets reach it through
    :meth:`flexarm_ros.control.kinematics.PlanarTwoLink.inverse` (q_cmd).
    """

    def __init__(self, pd: JointPD, motor: MotorVoltageMap | None = None,
                 encoder_velocity: EncoderVelocity | None = None):
        motor = motor if motor is not None else pd.motor
        if motor is None:
            raise ValueError("JointPositionController: no motor map, expected motor=... or "
                             "JointPD(kp, kd, motor=...)")
        if motor.n_joints != pd.n_joints:
            raise ValueError(f"JointPositionController: motor has {motor.n_joints} joints, "
                             f"the PD law {pd.n_joints}")
        self.pd, self.motor, self.encoder_velocity = pd, motor, encoder_velocity
        n = pd.n_joints
        self.torque = np.zeros(n)
        self.qd = np.zeros(n)
        self.voltage = np.zeros(n)
        self.saturated = np.zeros(n, dtype=bool)

    def reset(self) -> None:
        """Reset the velocity filter (after a pause or a jump of the encoder reading)."""
        if self.encoder_velocity is not None:
            self.encoder_velocity.reset()

    def update(self, t: float, dt: float, q_meas, qd_meas, q_cmd, qd_cmd=0.0) -> np.ndarray:
        """Motor voltages (V, one per joint) for this control period; see the class doc."""
        if self.encoder_velocity is not None:
            qd = self.encoder_velocity.update(t, dt, q_meas)
        else:
            if qd_meas is None:
                raise ValueError("JointPositionController.update: qd_meas is None, expected "
                                 "joint rates (or construct with encoder_velocity=...)")
            qd = np.asarray(qd_meas, dtype=float)
        self.qd = qd
        self.torque = self.pd.torque(q_meas, qd, q_cmd, qd_cmd)
        self.voltage = self.motor.voltage(self.torque, qd)
        self.saturated = self.motor.saturated.copy()
        return self.voltage.copy()
