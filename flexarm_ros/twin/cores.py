"""The three pieces of the test bench as plain objects, without middleware: the plant
(simulator), the power electronics (motor driver) and the computer (controller).

Each takes time as an argument and exchanges plain message dictionaries of the topic
contract (:mod:`topics`), so the ROS nodes are adapters (messages in, call, messages out)
and :func:`cosim.cosimulate` wires the very same objects in one loop: a lockstep ROS run
and the batch co-simulation produce the same messages.

Order of one control tick k (t_k = k·T): the simulator publishes the state at t_k; the
controller answers with commands; the driver turns them into joint torques; the
simulator holds those torques over (t_k, t_k+1] and steps.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.bag import messages as msg
from flexarm_ros.control.joint_pd import EncoderVelocity, JointPD, MotorVoltageMap
from flexarm_ros.control.kinematics import PlanarTwoLink
from flexarm_ros.control.sanding import SandingTask
from flexarm_ros.model import drives
from flexarm_ros.model.chain import Chain
from flexarm_ros.errors import SceneError
from flexarm_ros.sim.plant import Plant
from flexarm_ros.model.programs import encode, eval_torque
from flexarm_ros.model.statics import initial_state
from flexarm_ros.twin import topics as T


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def control_period(scene) -> float:
    return 1.0 / scene.control.rate_hz


# ============================================================================ simulator
class SimulatorCore:
    """The plant and its sensors at hardware rates (topic contract in :mod:`topics`).

    ``outputs()`` gives the messages of the current instant (joint states from the
    quantized encoders, counts, sensor batches collected since the previous tick, contact,
    ground truth, clock); ``step(torques)`` holds the torques over one control period."""

    def __init__(self, scene):
        self.scene = scene
        self.plant = Plant(scene)
        self.period = control_period(scene)
        g = self.plant.grid_ns
        if g and abs(self.period * 1e9 / g - round(self.period * 1e9 / g)) > 1e-6:
            raise SceneError(f"control.rate_hz: got {scene.control.rate_hz}, expected a rate "
                             f"whose period is a multiple of the sensor grid {g * 1e-9:g} s")
        ch = self.plant.chain
        self.names = [lm.name for lm in ch.links]
        self.encoders = {sm.link: sm for sm in self.plant.sensors if sm.spec.kind == "encoder"}
        self.groups = {}
        for kind, topic in (("accelerometer", T.ACCEL_BATCH), ("strain", T.STRAIN_BATCH),
                            ("potentiometer", T.POT_BATCH)):
            sens = [sm for sm in self.plant.sensors if sm.spec.kind == kind]
            if sens:
                rates = {sm.spec.rate_hz for sm in sens}
                if len(rates) > 1:
                    raise SceneError(f"sensors: {kind}s at several rates {sorted(rates)}, "
                                     f"expected one rate per batch topic")
                self.groups[topic] = [sm.name for sm in sens]
        self.batch = {topic: [] for topic in self.groups}
        self.counts = {link: 0 for link in self.encoders}
        self._prev_angle = None
        self.k = 0

    @property
    def t(self) -> float:
        return self.plant.t

    def _encoder_angles(self):
        """Joint angles as the controller sees them: from the encoder counts where an
        encoder is declared (quantized), else the model's angle."""
        q, _ = self.plant.joint_state()
        ang = q.copy()
        q0 = self.plant.q_initial
        for link, sm in self.encoders.items():
            lm = self.plant.chain.links[link]
            i0 = lm.i_motor if lm.i_motor >= 0 else lm.i_joint
            ang[link] = q0[i0] + self.counts[link] / sm.gain
        return ang

    def outputs(self) -> list[tuple]:
        """(topic, type, message) of this instant, in publication order."""
        t_ns = _ns(self.t)
        out = [(T.CLOCK, T.TYPES[T.CLOCK], msg.clock(t_ns))]
        ang = self._encoder_angles()
        if self._prev_angle is None or self.k == 0:
            vel = np.zeros_like(ang)
        else:
            vel = (ang - self._prev_angle) / self.period
        self._prev_angle = ang
        names = [f"{n}_joint" for n in self.names]
        out.append((T.JOINT_STATES, T.TYPES[T.JOINT_STATES],
                    msg.joint_state(t_ns, names, ang, vel, self.plant.torques)))
        if self.encoders:
            counts = [int(self.counts[link]) for link in sorted(self.encoders)]
            out.append((T.ENCODER_COUNTS, T.TYPES[T.ENCODER_COUNTS],
                        msg.int32_multiarray(np.array(counts, dtype=np.int64), "joint")))
        for topic, names_ in self.groups.items():
            rows = self.batch[topic]
            if rows:
                out.append((topic, T.TYPES[topic],
                            msg.float64_multiarray(np.array(rows), ("sample", "channel"))))
            self.batch[topic] = []
        cs = self.plant.contact_state()
        if self.plant.contact is not None:
            out.append((T.TOOL_CONTACT, T.TYPES[T.TOOL_CONTACT],
                        {"data": cs["phase"] != "free"}))
            out.append((T.TOOL_WRENCH, T.TYPES[T.TOOL_WRENCH],
                        msg.wrench_stamped(t_ns, "wall", (cs["normal_force"],
                                                          cs["friction_force"], 0.0),
                                           (0.0, 0.0, 0.0))))
        q, qd = self.plant.joint_state()
        qm, qdm = self.plant.drive_state()
        gt_names = names + [f"{n}_drive" for n in self.names]
        out.append((T.GT_JOINT_STATES, T.TYPES[T.GT_JOINT_STATES],
                    msg.joint_state(t_ns, gt_names, np.concatenate([q, qm]),
                                    np.concatenate([qd, qdm]),
                                    np.concatenate([self.plant.torques,
                                                    self.plant.torques]))))
        tip = self.plant.tip_position()
        out.append((T.GT_TIP, T.TYPES[T.GT_TIP],
                    msg.point_stamped(t_ns, "world", (tip[0], tip[1], 0.0))))
        ch = self.plant.chain
        qf, qdf = ch.full_state(self.t, self.plant.x)
        applied = np.zeros(ch.n)          # input torque on each coordinate, 0 where none acts
        for link, j in self.plant._act.items():
            applied[ch.actuators[j].coord] = self.plant.torques[link]
        out.append((T.GT_COORDINATES, T.TYPES[T.GT_COORDINATES],
                    msg.joint_state(t_ns, ch.names, qf, qdf, applied)))
        return out

    def step(self, torques) -> None:
        """Hold ``torques`` (N·m, joint order) over one control period."""
        self.plant.set_torques(torques)
        samples = self.plant.step(self.period)
        by_time: dict = {}
        for s in samples:
            by_time.setdefault(s.t, {})[s.sensor] = s.value
        for t in sorted(by_time):
            vals = by_time[t]
            for link, sm in self.encoders.items():
                if sm.name in vals:
                    self.counts[link] = int(vals[sm.name])
            for topic, names in self.groups.items():
                if names[0] in vals:
                    self.batch[topic].append([vals[n] for n in names])
        self.k += 1


# ============================================================================== driver
class DriverCore:
    """The motor driver of every joint: DC motor + gearbox (seed 000 Eq. 5.11 with the
    armature current, seed 001 Sec. 4) or hydraulic servovalve (seed 002), turning commands
    (V, A; N·m for a joint without a drive) into joint torques held over the next period.

    The electrical / hydraulic state is advanced over the period with the command and the
    drive rate held (zero-order hold) by :func:`drives.advance_state`, which integrates the
    plant's own :func:`drives.actuator_rate` (the current exactly, the pressure by RK4
    sub-steps).
    A command older than ``control.watchdog_s`` drops to 0 V (closed valve); NaN, inf or
    wrong-length commands are rejected (counted) and never reach the plant."""

    def __init__(self, scene):
        self.scene = scene
        chain = Chain(scene)
        q0, qd0, z0 = initial_state(chain)         # hydraulic hold pressure and null bias
        self.n = len(scene.links)
        self.kind = [drives.IDEAL] * self.n
        self.par = [np.zeros(drives.N_PAR) for _ in range(self.n)]
        self.z = np.zeros(self.n)
        for a in chain.actuators:
            self.kind[a.link] = a.kind
            self.par[a.link] = a.par.copy()
            if a.state >= 0:
                self.z[a.link] = z0[a.state]
        for k, lk in enumerate(scene.links):      # a quasi-static motor keeps no state
            if lk.joint.drive is not None and self.kind[k] == drives.IDEAL:
                self.kind[k], self.par[k], _ = drives.encode(lk.joint.drive, "dynamic")
        self.command = np.zeros(self.n)
        self.t_command = 0.0
        self.watchdog = scene.control.watchdog_s
        self.rejected = 0
        self.tripped = False
        self.torque = np.array([self._torque(k, 0.0, self.command[k]) for k in range(self.n)])

    def accept(self, t: float, command) -> bool:
        """Take a command vector; False (counted, ignored) when malformed."""
        c = np.asarray(command, dtype=float) if _is_numeric(command) else None
        if c is None or c.shape != (self.n,) or not np.all(np.isfinite(c)):
            self.rejected += 1
            return False
        self.command = c.copy()
        self.t_command = t
        self.tripped = False
        return True

    def _effective(self, t: float) -> np.ndarray:
        if t - self.t_command > self.watchdog + 1e-12:
            self.tripped = True
            cmd = np.zeros(self.n)
            for k in range(self.n):          # closed valve: no current at all
                if self.kind[k] == drives.HYDRAULIC:
                    cmd[k] = -self.par[k][drives.HYD_VALVE_BIAS]
            return cmd
        return self.command

    def _torque(self, k, w, u):
        return drives.actuator_torque(self.kind[k], self.par[k], u, w, self.z[k])

    def update(self, t: float, dt: float, drive_rates) -> np.ndarray:
        """Joint torques (N·m) to hold over (t, t + dt], given the drive-coordinate rates
        now; advances the drive states to t + dt."""
        self.t_now = t
        u = self._effective(t)
        w = np.asarray(drive_rates, float)
        tau = np.zeros(self.n)
        for k in range(self.n):
            tau[k] = self._torque(k, w[k], u[k])
            self.z[k] = drives.advance_state(self.kind[k], self.par[k], u[k], w[k], self.z[k],
                                             dt)
        self.torque = tau
        return tau

    def motor_states(self, t_ns: int, drive_angles, drive_rates) -> dict:
        """motor_driver/motor_states: motor-shaft angle and speed (× gear ratio) and the
        armature current (A) or load pressure (Pa) in ``effort``."""
        dc = (drives.DC_CURRENT, drives.DC_QUASI_STATIC)
        n = [self.par[k][drives.DC_GEAR_RATIO] if self.kind[k] in dc else 1.0
             for k in range(self.n)]
        eff = []
        u = self._effective(self.t_now) if hasattr(self, "t_now") else self.command
        for k in range(self.n):
            if self.kind[k] == drives.DC_QUASI_STATIC:
                eff.append(drives.motor_current(self.kind[k], self.par[k], u[k],
                                                drive_rates[k], 0.0))
            else:
                eff.append(self.z[k])
        names = [f"{lk.name}_motor" for lk in self.scene.links]
        return msg.joint_state(t_ns, names, np.multiply(n, drive_angles),
                               np.multiply(n, drive_rates), eff)


def _is_numeric(c) -> bool:
    try:
        np.asarray(c, dtype=float)
        return True
    except (TypeError, ValueError):
        return False


# ========================================================================== controller
def arm_geometry(scene) -> PlanarTwoLink:
    """Rigid-arm link lengths for inverse kinematics: hub radius + beam + joint offset (or
    tool offset on the last link)."""
    if len(scene.links) != 2:
        raise SceneError(f"control.mode: tip targets need a two-link arm, got "
                         f"{len(scene.links)} links")
    l1 = scene.links[0].beam.hub_radius + scene.links[0].beam.length + \
        scene.links[0].tip.joint_offset[0]
    l2 = scene.links[1].beam.hub_radius + scene.links[1].beam.length + scene.tool.position[0]
    return PlanarTwoLink(l1, l2)


class ControllerCore:
    """The bench computer: reads joint states (quantized encoders), contact and wrench;
    returns commands (V per joint; A for a valve; N·m for a joint without a drive).

    open_loop: the scene's input programs; position: joint PD (seed 000 Eq. 5.16) with
    the voltage from the static motor equation (Eq. 5.17), joint targets from
    Newton–Raphson inverse kinematics of ``tip_target``; sanding: the sanding task's tool
    target through the same loop."""

    def __init__(self, scene):
        self.scene = scene
        ctl = scene.control
        self.mode = ctl.mode
        self.n = len(scene.links)
        self.status = "ok"
        by_joint = {inp.joint: inp for inp in scene.inputs if inp.motion is None}
        self.programs = [encode(by_joint[j + 1].program) if j + 1 in by_joint else None
                         for j in range(self.n)]
        if self.mode == "open_loop":
            return
        dr = [lk.joint.drive for lk in scene.links]
        if any(d is None or d.type != "dc_motor" for d in dr):
            raise SceneError("control.mode: position/sanding control needs a dc_motor drive "
                             "on every joint")
        motor = MotorVoltageMap([d.gear_ratio for d in dr], [d.torque_constant for d in dr],
                                [d.back_emf_constant for d in dr], [d.resistance for d in dr],
                                [d.supply_voltage or math.inf for d in dr])
        self.pd = JointPD(ctl.kp, ctl.kd, motor)
        self.velocity = EncoderVelocity(ctl.velocity_filter_hz)
        self.arm = arm_geometry(scene) if (ctl.tip_target is not None or
                                           self.mode == "sanding") else None
        q0 = np.array([lk.joint.angle0 for lk in scene.links])
        self.q_cmd = np.array(ctl.joint_target) if ctl.joint_target else q0.copy()
        if ctl.tip_target is not None and self.mode == "position":
            self.q_cmd = self._ik(ctl.tip_target, q0)
        self.task = None
        if self.mode == "sanding":
            sd = ctl.sanding
            start = self.arm.forward(q0)
            self.task = SandingTask(sd.wall_x, sd.y_start, sd.y_end, sd.speed,
                                    sd.normal_force, start, sd.approach_time, sd.kp_force,
                                    strokes=sd.strokes, offset_max=sd.offset_max,
                                    search_speed=sd.search_speed,
                                    search_timeout=sd.search_timeout,
                                    press_time=sd.press_time, press_timeout=sd.press_timeout,
                                    force_tolerance=sd.force_tolerance,
                                    reverse_time=sd.reverse_time,
                                    lift_distance=sd.lift_distance, lift_time=sd.lift_time)
        self.phase = "position"

    def _ik(self, target, q_guess):
        res = self.arm.inverse(target, q_guess)
        if not res.success:
            self.status = res.message
            return np.asarray(q_guess, float)
        self.status = "ok"
        return res.q

    def update(self, t: float, dt: float, joint_angles, in_contact: bool = False,
               normal_force: float = 0.0) -> np.ndarray:
        """Commands for this control period."""
        if self.mode == "open_loop":
            return np.array([eval_torque(p[0], p[1], p[2], p[3], t) if p is not None else 0.0
                             for p in self.programs])
        q = np.asarray(joint_angles, float)
        qd = self.velocity.update(t, dt, q)
        if self.task is not None:
            target, self.phase = self.task.update(t, dt, self.arm.forward(q), in_contact,
                                                  normal_force)
            self.q_cmd = self._ik(target, self.q_cmd)
        return self.pd.voltage(q, qd, self.q_cmd)
