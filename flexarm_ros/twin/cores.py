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
from flexarm_ros.control.trajectory import Reference, Trajectory
from flexarm_ros.model import drives
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.limits import joint_limits
from flexarm_ros.errors import InputError, SceneError, SimulationDiverged
from flexarm_ros.sim.plant import Plant
from flexarm_ros.model.programs import encode, eval_torque
from flexarm_ros.model.statics import initial_state
from flexarm_ros.twin import topics as T
from flexarm_ros.twin.validation import Validator


def to_ns(t: float) -> int:
    return int(round(t * 1e9))


def control_period(scene) -> float:
    return 1.0 / scene.twin_control.rate_hz


# ============================================================================ simulator
class SimulatorCore:
    """The plant and its sensors at hardware rates (topic contract in :mod:`topics`).

    ``outputs()`` gives the messages of the current instant (joint states from the
    quantized encoders, counts, sensor batches collected since the previous tick, contact,
    ground truth, clock); ``step(torques)`` holds the torques over one control period.

    ``validator`` checks an effort command (one finite value per joint within its torque
    limit, :mod:`flexarm_ros.model.limits`) before the node steps with it. A diverging
    plant raises :class:`SimulationDiverged` from ``step`` before any message of the
    diverged state can be built: every sample is checked, and the plant checks its state
    after every sensor-grid interval."""

    def __init__(self, scene, duration: float | None = None, warm_up: bool = True):
        self.scene = scene
        # with a finite ``duration`` the work budget is checked before the first step
        # (:func:`flexarm_ros.sim.budget.check_work`), as ``flexarm simulate`` does
        self.plant = Plant(scene, duration=duration)
        self.validator = Validator(scene, "effort")
        self.period = control_period(scene)
        g = self.plant.grid_ns
        if g and abs(self.period * 1e9 / g - round(self.period * 1e9 / g)) > 1e-6:
            raise SceneError(f"control.rate_hz: got {scene.twin_control.rate_hz}, expected a rate "
                             f"whose period is a multiple of the sensor grid {g * 1e-9:g} s")
        ch = self.plant.chain
        self.names = [lm.name for lm in ch.links]
        self._joint_names = [f"{n}_joint" for n in self.names]
        self._gt_names = self._joint_names + [f"{n}_drive" for n in self.names]
        self.encoders = {sm.link: sm for sm in self.plant.sensors if sm.spec.kind == "encoder"}
        self.groups = {}
        for topic, kind in T.BATCH_KINDS.items():
            sens = [sm for sm in self.plant.sensors if sm.spec.kind == kind]
            if sens:
                rates = {sm.spec.rate_hz for sm in sens}
                if len(rates) > 1:
                    raise SceneError(f"sensors: {kind}s at several rates {sorted(rates)}, "
                                     f"expected one rate per batch topic")
                self.groups[topic] = T.batch_columns([sm.spec for sm in sens])
        self.batch = {topic: [] for topic in self.groups}
        self.counts = {link: 0 for link in self.encoders}
        self._prev_angle = None
        self._prev_k = 0
        self._plans: dict = {}                  # due sensors' names -> _plan
        self._i_joint = [lm.i_joint for lm in ch.links]
        self._i_drive = ch.drive_index()
        self._enc_links = sorted(self.encoders)
        q0 = self.plant.q_initial              # (link, the encoder's zero angle, counts/rad)
        self._enc_zero = [(link, float(q0[ch.links[link].i_motor if ch.links[link].i_motor
                                          >= 0 else ch.links[link].i_joint]), sm.gain)
                          for link, sm in self.encoders.items()]
        self.k = 0
        self.sink: list | None = None      # the sensor rows of every step, when a list
        if warm_up:                 # a twin's first tick must not compile (a batch may)
            self._warm_up()

    def _warm_up(self) -> None:
        """One tick and one set of messages on a copy of this core, thrown away: numba
        compiles (cold cache: ~40 s) or loads (~70 ms) the kernels a tick calls here, at
        start-up, not inside the first tick — where it counted as ticking (the README's
        first `flexarm run` on a fresh machine reported a real-time factor of 0.01) and,
        in realtime, made the first tick late by that much; and those only an impact
        calls (:meth:`Plant.load_event_kernels`). Nothing of the copy is kept."""
        import copy
        shadow = copy.deepcopy(self)
        try:
            shadow.step(np.zeros(len(self.names)))
            shadow.outputs()
            shadow.plant.load_event_kernels()     # what only an impact calls
        except (InputError, SimulationDiverged):    # the real first tick will say it
            pass

    @property
    def t(self) -> float:
        return self.plant.t

    def _encoder_angles(self, q: list) -> list:
        """Joint angles as the controller sees them: from the encoder counts where an
        encoder is declared (quantized), else the model's angle (``q``: the link-side
        joint angles now). A list of floats."""
        ang = list(q)
        for link, q0, gain in self._enc_zero:
            ang[link] = q0 + self.counts[link] / gain
        return ang

    def bench_view(self) -> tuple:
        """What the controller and the driver read now, without messages: the joint angles
        of ``joint_states`` (encoder counts where an encoder is declared), the tool's
        contact flag and normal force (``tool/contact``, ``tool/wrench``; False and 0 without
        a wall), and the ground truth's drive-coordinate rates and joint torques — the
        values :meth:`outputs` puts in those messages."""
        plant = self.plant
        ch = plant.chain
        qf, qdf = ch.full_state(plant.t, plant.x)
        qfl = qf.tolist()
        ang = self._encoder_angles([qfl[i] for i in self._i_joint])
        contact, fn = False, 0.0
        if plant.contact is not None:
            cs = plant.contact_state()
            contact, fn = cs["phase"] != "free", cs["normal_force"]
        return ang, contact, fn, qdf[self._i_drive], plant.torques.tolist()

    def view_state(self) -> tuple:
        """What a view of the arm draws now: (t_ns, the full coordinate vector q in
        ``Chain.names`` order, in contact, normal force N, friction force N) — the values
        of ``ground_truth/coordinates`` and ``tool/wrench`` at this instant."""
        plant = self.plant
        q = plant.chain.full_state(plant.t, plant.x)[0]
        contact, fn, ft = False, 0.0, 0.0
        if plant.contact is not None:
            cs = plant.contact_state()
            contact, fn, ft = cs["phase"] != "free", cs["normal_force"], cs["friction_force"]
        return to_ns(self.t), q, contact, fn, ft

    def outputs(self, ground_truth: bool = True, build=msg) -> list[tuple]:
        """(topic, type, message) of this instant, in publication order. With
        ``ground_truth=False`` the analysis-only topics ``ground_truth/tip`` and
        ``ground_truth/coordinates`` are left out (``ground_truth/joint_states`` stays: it
        is the driver's input). The joint rate is the backward difference of the encoder
        angles since the previous call (one control period, or more when ticks were
        stepped without publishing). ``build``: the message constructors — the dicts of
        :mod:`~flexarm_ros.bag.messages`, or a :class:`~flexarm_ros.bag.cdr_fixed.CdrBuilder`
        for the same messages as CDR bytes (the simulator node's wire path). The state is
        assembled once (:meth:`Chain.full_state`) for every message of the instant."""
        plant = self.plant
        ch = plant.chain
        t_ns = to_ns(self.t)
        TY = T.TYPES
        out = [(T.CLOCK, TY[T.CLOCK], build.clock(t_ns))]
        # the handful of values per message as Python floats: the same IEEE arithmetic
        # as numpy's, without its per-call cost on 2-element arrays
        qf, qdf = ch.full_state(plant.t, plant.x)
        qfl, qdfl = qf.tolist(), qdf.tolist()
        q = [qfl[i] for i in self._i_joint]
        qd = [qdfl[i] for i in self._i_joint]
        ang = self._encoder_angles(q)
        if self._prev_angle is None or self.k == 0:
            vel = [0.0] * len(ang)
        else:
            span = self.period * (self.k - self._prev_k)
            vel = [(a - b) / span for a, b in zip(ang, self._prev_angle)]
        self._prev_angle, self._prev_k = ang, self.k
        torques = plant.torques.tolist()
        out.append((T.JOINT_STATES, TY[T.JOINT_STATES],
                    build.joint_state(t_ns, self._joint_names, ang, vel, torques)))
        if self.encoders:
            counts = [int(self.counts[link]) for link in self._enc_links]
            out.append((T.ENCODER_COUNTS, TY[T.ENCODER_COUNTS],
                        build.int32_multiarray(np.array(counts, dtype=np.int64), "joint")))
        for topic in self.groups:
            rows = self.batch[topic]
            if rows:
                out.append((topic, TY[topic],
                            build.float64_multiarray(np.array(rows), ("sample", "channel"))))
            self.batch[topic] = []
        if plant.contact is not None:
            cs = plant.contact_state()
            out.append((T.TOOL_CONTACT, TY[T.TOOL_CONTACT],
                        build.boolean(cs["phase"] != "free")))
            out.append((T.TOOL_WRENCH, TY[T.TOOL_WRENCH],
                        build.wrench_stamped(t_ns, "wall", (cs["normal_force"],
                                                            cs["friction_force"], 0.0),
                                             (0.0, 0.0, 0.0))))
        out.append((T.GT_JOINT_STATES, TY[T.GT_JOINT_STATES],
                    build.joint_state(t_ns, self._gt_names,
                                      q + [qfl[i] for i in self._i_drive],
                                      qd + [qdfl[i] for i in self._i_drive],
                                      torques + torques)))
        if not ground_truth:
            return out
        tip = plant.tip_position()
        out.append((T.GT_TIP, TY[T.GT_TIP],
                    build.point_stamped(t_ns, "world", (tip[0], tip[1], 0.0))))
        applied = np.zeros(ch.n)          # input torque on each coordinate, 0 where none acts
        for link, j in plant._act.items():
            applied[ch.actuators[j].coord] = torques[link]
        out.append((T.GT_COORDINATES, TY[T.GT_COORDINATES],
                    build.joint_state(t_ns, ch.names, qf, qdf, applied)))
        return out

    def _plan(self, names: tuple) -> tuple:
        """Where the readings of one instant go, for the due sensors ``names``: (position,
        link) of each encoder's count, (topic, positions) of each batch row (a batch
        topic's row when its first sensor is due; its sensors share one rate)."""
        at = {n: i for i, n in enumerate(names)}
        encoders = [(at[sm.name], link) for link, sm in self.encoders.items()
                    if sm.name in at]
        groups = [(topic, [at[n] for n in group]) for topic, group in self.groups.items()
                  if group[0] in at]
        return encoders, groups

    def step(self, torques) -> None:
        """Hold ``torques`` (joint order: N·m, or A for a hydraulic joint's servovalve,
        whose actuator is in the plant) over one control period."""
        self.plant.set_inputs(torques)
        try:
            rows = self.plant.step_rows(self.period)
        except SimulationDiverged as exc:           # name the input held over the period
            raise SimulationDiverged(
                exc.quantity, exc.time, exc.last_value,
                f"check the joint inputs (held [{self.plant.held()}] from t = "
                f"{self.t:.6g} s); else {exc.suggestion}", detail=exc.detail) from None
        isfinite = math.isfinite
        for t, names, vals, trues in rows:               # one per grid instant, in order
            if not (all(map(isfinite, vals)) and all(map(isfinite, trues))):
                bad = next(n for n, v, tr in zip(names, vals, trues)
                           if not (isfinite(v) and isfinite(tr)))
                raise SimulationDiverged(
                    f"sensor {bad}", t, float("nan"),
                    f"check the joint inputs (held [{self.plant.held()}]); reduce the "
                    f"step (fidelity.dt)", detail="a sensor reading became non-finite")
            plan = self._plans.get(names)
            if plan is None:
                plan = self._plans[names] = self._plan(names)
            encoders, groups = plan
            for pos, link in encoders:
                self.counts[link] = int(vals[pos])
            for topic, positions in groups:
                self.batch[topic].append([vals[i] for i in positions])
        if self.sink is not None:
            self.sink.extend(rows)
        self.k += 1


# ============================================================================== driver
class DriverCore:
    """The motor driver of every joint: DC motor + gearbox (seed 000 Eq. 5.11 with the
    armature current, seed 001 Sec. 4) or the servo-amplifier of a hydraulic servovalve
    (seed 002), turning commands (V, A; N·m for a joint without a drive) into the efforts
    held over the next period: joint torques, or a servovalve's current, whose actuator
    (load pressure) the plant integrates with the arm (:mod:`flexarm_ros.sim.plant`: a
    torque held across the oil column's stiffness diverged).

    A DC motor's armature current is advanced over the period with the command and the
    drive rate held (zero-order hold) by :func:`drives.advance_state`, which integrates the
    plant's own :func:`drives.actuator_rate` exactly; a hydraulic joint's load pressure
    is the plant's, read back from its torque for ``motor_states``. A command older than
    ``control.watchdog_s`` drops to 0 V (a closed valve: minus the null bias). A command
    is validated where it enters (``accept``, :class:`~flexarm_ros.twin.validation.Validator`):
    wrong length, NaN/inf or beyond the joint's command limit (V, A or N·m,
    :mod:`flexarm_ros.model.limits`) is rejected (counted by reason) and changes nothing.
    The published torque never exceeds the joint's torque limit (the simulator would
    reject it): it is held there (``held`` counts the periods), which only a DC drive
    without ``current_limit`` turned beyond its no-load speed can reach."""

    def __init__(self, scene, plant: Plant | None = None):
        """``plant``: the simulator's plant of the same scene, when at hand (a batch run):
        its model gives the hydraulic actuators' parameters and holding pressures, so no
        second model is built (an eigen-solve per modal beam; test_closed_loop checks the
        two ways agree)."""
        self.scene = scene
        self.n = len(scene.links)
        self.kind = [drives.IDEAL] * self.n
        self.par = [np.zeros(drives.N_PAR) for _ in range(self.n)]
        self.z = np.zeros(self.n)
        if plant is None:
            chain = Chain(scene)
            q0, qd0, z0 = initial_state(chain)     # hydraulic hold pressure and null bias
            actuators = chain.actuators
        else:
            chain = plant.chain                    # the plant keeps the hydraulic drives
            z0 = plant.x[2 * len(chain.free):]
            motions = {inp.joint - 1 for inp in scene.inputs if inp.motion is not None}
            actuators = [a for a in chain.actuators if a.kind == drives.HYDRAULIC]
            for k, lk in enumerate(scene.links):
                d = lk.joint.drive
                if d is not None and d.type != "hydraulic" and k not in motions:
                    self.kind[k], self.par[k], _ = drives.encode(
                        d, scene.fidelity.motor_current)
        for a in actuators:
            self.kind[a.link] = a.kind
            self.par[a.link] = a.par.copy()
            if a.state >= 0:
                self.z[a.link] = z0[a.state]
        for k, lk in enumerate(scene.links):      # a quasi-static motor keeps no state
            if lk.joint.drive is not None and self.kind[k] == drives.IDEAL:
                self.kind[k], self.par[k], _ = drives.encode(lk.joint.drive, "dynamic")
        # joints whose effort is the valve current (the plant integrates their actuator)
        self.valve = np.array([kd == drives.HYDRAULIC for kd in self.kind], bool)
        self.command = np.zeros(self.n)
        self.t_command = 0.0
        self.watchdog = scene.twin_control.watchdog_s
        self.validator = Validator(scene, "command")
        self.torque_limit = np.array([lim.torque_limit for lim in joint_limits(scene)])
        self.held = 0
        self.tripped = False
        self.torque = np.array([self._torque(k, 0.0, self.command[k]) for k in range(self.n)])
        for k in range(self.n):     # load the compiled drive functions a tick calls, now
            drives.advance_state(self.kind[k], self.par[k], 0.0, 0.0, float(self.z[k]), 1e-3)
            drives.motor_current(self.kind[k], self.par[k], 0.0, 0.0, 0.0)

    @property
    def rejected(self) -> int:
        return self.validator.rejected

    def accept(self, t: float, command) -> bool:
        """Take a command vector; False (counted by reason in ``validator``, nothing
        changed) when it is not one finite value per joint within the command limits."""
        if self.validator.check(command) is not None:
            return False
        self.command = np.array([float(v) for v in command])
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
        if self.valve[k]:                       # the valve current: the plant's actuator
            return u
        return drives.actuator_torque(self.kind[k], self.par[k], u, w, self.z[k])

    def update(self, t: float, dt: float, drive_rates, drive_torques=None) -> np.ndarray:
        """The efforts to hold over (t, t + dt] — joint torques (N·m), or for a hydraulic
        joint the valve current (A above the null bias: the servo-amplifier's output; the
        plant integrates the actuator, :mod:`flexarm_ros.sim.plant`) — given the
        drive-coordinate rates now; advances the DC drives' states to t + dt. A hydraulic
        joint's load pressure is read back from its torque now, ``drive_torques`` (the
        ground truth's drive efforts, N·m): P_L = τ / (η_t D_m)."""
        self.t_now = t
        u = self._effective(t)
        w = np.asarray(drive_rates, float)
        tau = np.zeros(self.n)
        valve = self.valve
        for k in range(self.n):
            tau[k] = self._torque(k, w[k], u[k])
            if valve[k]:
                if drive_torques is not None:
                    p = self.par[k]
                    self.z[k] = float(drive_torques[k]) / (
                        p[drives.HYD_TORQUE_EFFICIENCY] * p[drives.HYD_DISPLACEMENT])
                continue
            self.z[k] = drives.advance_state(self.kind[k], self.par[k], u[k], w[k], self.z[k],
                                             dt)
        if np.any((np.abs(tau) > self.torque_limit) & ~valve):   # never beyond the limit
            self.held += 1
            tau = np.where(valve, tau, np.clip(tau, -self.torque_limit, self.torque_limit))
        self.torque = tau
        return tau

    def motor_states(self, t_ns: int, drive_angles, drive_rates, build=msg):
        """motor_driver/motor_states: motor-shaft angle and speed (× gear ratio) and the
        armature current (A) or load pressure (Pa) in ``effort`` — a message dict, or with
        ``build=CdrBuilder()`` its CDR bytes (:mod:`flexarm_ros.bag.cdr_fixed`)."""
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
        return build.joint_state(t_ns, names, np.multiply(n, drive_angles),
                                 np.multiply(n, drive_rates), eff)


# ========================================================================== controller
def _check_programs(scene, lims) -> None:
    """Open loop: every program within what the motor driver accepts, or a SceneError
    naming the key to change. A voltage program beyond an explicit ``supply_voltage`` is
    saturated there (the drive model clips it the same way in ``flexarm simulate``)."""
    from flexarm_ros.scene.sections import program_range
    for k, inp in enumerate(scene.inputs):
        if inp.motion is not None:
            continue
        j = inp.joint - 1
        lim = lims[j]
        drive = scene.links[j].joint.drive
        if drive is not None and drive.type == "dc_motor" and drive.supply_voltage:
            continue
        peak = max(abs(v) for v in program_range(inp.program))
        if peak > lim.command_limit:
            key = (f"links[{j}].joint.torque_limit" if drive is None else
                   f"links[{j}].joint.drive.supply_voltage")
            raise SceneError(f"inputs[{k}].{inp.kind}: got a program reaching {peak:.6g} "
                             f"{lim.command_unit}, expected within the motor driver's "
                             f"command limit ±{lim.command_limit:.6g} {lim.command_unit} "
                             f"({lim.command_from}); set {key}")


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
        ctl = scene.twin_control
        self.mode = ctl.mode
        self.n = len(scene.links)
        self.status = "ok"
        by_joint = {inp.joint: inp for inp in scene.inputs if inp.motion is None}
        self.programs = [encode(by_joint[j + 1].program) if j + 1 in by_joint else None
                         for j in range(self.n)]
        lims = joint_limits(scene)
        self.limit = np.array([lim.command_limit for lim in lims])
        if self.mode == "open_loop":
            _check_programs(scene, lims)
            return
        dr = [lk.joint.drive for lk in scene.links]
        if any(d is None or d.type != "dc_motor" for d in dr):
            raise SceneError("control.mode: position/sanding control needs a dc_motor drive "
                             "on every joint")
        motor = MotorVoltageMap([d.gear_ratio for d in dr], [d.output_torque_constant for d in dr],
                                [d.back_emf_constant for d in dr], [d.resistance for d in dr],
                                list(self.limit))            # saturates at the wire limit
        self.pd = JointPD(ctl.kp, ctl.kd, motor)
        self.velocity = EncoderVelocity(ctl.velocity_filter_hz)
        self.arm = arm_geometry(scene) if (ctl.tip_target is not None or
                                           self.mode == "sanding") else None
        q0 = np.array([lk.joint.angle0 for lk in scene.links])
        self.q_cmd = np.array(ctl.joint_target) if ctl.joint_target else q0.copy()
        if ctl.tip_target is not None and self.mode == "position":
            self.q_cmd = self._ik(ctl.tip_target, q0)
        # a shaped target step: q_cmd(t) = q0 + S(t − t0)·(q* − q0) (control.shaper;
        # t0 = 0, or the time of a target change)
        self._shape_t0 = 0.0
        self.shaper = ctl.shaper if self.mode == "position" else None
        self.qd_cmd = np.zeros(self.n)
        # a move program, or trajectories arriving on the wire: the reference r(t),
        # shaped by the shaper (flexarm_ros.control.trajectory)
        self.reference = None
        self.position_limits = [lk.joint.position_limits for lk in scene.links]
        if ctl.moves:
            rates = [m.joint_rate for m in ctl.moves]
            self.reference = Reference(q0, self.shaper)
            self.reference.add(Trajectory(0.0, q0, np.zeros(self.n),
                                          [m.time for m in ctl.moves],
                                          [m.joint_target for m in ctl.moves],
                                          rates if any(rates) else None))
            self.q_cmd = np.array(ctl.moves[-1].joint_target, float)
        self.q_start, self.q_goal = q0, self.q_cmd.copy()
        if self.reference is not None:
            self.q_cmd, self.qd_cmd = self.reference.at(0.0)
        elif self.shaper is not None:
            self.q_cmd = self._shaped(0.0)
        # LQG in place of the PD: a Kalman estimate from the encoder angles (control.lqg)
        self.lqg = None
        if self.mode == "position" and ctl.lqg is not None:
            from flexarm_ros.control.lqg import LqgLaw
            if not np.allclose(ctl.lqg.y_goal, self.q_goal, rtol=0.0, atol=1e-9):
                raise SceneError(f"control.lqg.y_goal: got {list(ctl.lqg.y_goal)} rad, "
                                 f"expected the target's joint angles "
                                 f"{self.q_goal.tolist()} (the pose it was designed at; "
                                 f"flexarm design --lqg again for a new target)")
            self.lqg = LqgLaw(ctl.lqg, self.limit)
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
        self.torque_demand = np.zeros(self.n)
        self.changes = list(ctl.changes)   # control.changes not yet applied
        for k, ch in enumerate(self.changes):
            why = self.voltage_limit_error(ch.voltage_limit)
            if why:
                raise SceneError(f"control.changes[{k}].voltage_limit: {why}")

    @property
    def has_targets(self) -> bool:
        """The controller tracks joint targets (position, sanding), published as
        ``controller/joint_targets``."""
        return self.mode != "open_loop"

    def targets(self, t_ns: int, build=msg):
        """``controller/joint_targets``: the commanded joint angles (rad), the commanded
        rates (rad/s; 0 but along a move program or trajectory) and the torque demanded
        at the last update (N·m, Eq. 5.16)."""
        return build.joint_state(t_ns, [f"{lk.name}_joint" for lk in self.scene.links],
                                 self.q_cmd, self.qd_cmd, self.torque_demand)

    def _shaped(self, t: float) -> np.ndarray:
        """The shaped target at ``t``: q₀ + S(t − t₀)·(q* − q₀) (control.shaper; t₀ the
        start of the step: 0, or the time of a target change)."""
        return self.q_start + self.shaper.share(t - self._shape_t0) * (self.q_goal
                                                                       - self.q_start)

    def voltage_limit_error(self, limit) -> str | None:
        """Why ``limit`` (V per joint) cannot be the controller's output limit, or None:
        above a joint's own command limit (the drive's supply)."""
        if not len(limit):
            return None
        top = [lim.command_limit for lim in joint_limits(self.scene)]
        for j, (v, hi) in enumerate(zip(limit, top)):
            if not 0.0 < v <= hi * (1 + 1e-12):
                return (f"got {list(limit)} V, expected 0 < V <= {hi:.6g} V on joint {j + 1} "
                        f"(the drive's command limit)")
        return None

    def retune(self, t: float, kp=(), kd=(), joint_target=(), voltage_limit=(),
               shaper=None) -> dict:
        """Change the joint PD's gains and/or its step target from tick time ``t`` on (a
        ``control.changes`` entry, or a parameter set on the controller node): the new
        target is a step from the current command, shaped by the scene's shaper from
        ``t``, replacing any move program or trajectory. Returns the change as a
        ``control.changes`` mapping (time and what changed). The caller has validated it
        (``Scene`` rules: :meth:`Scene._check_changes`)."""
        if getattr(self, "pd", None) is None or self.lqg is not None:
            raise SceneError("control.changes: expected the joint PD of mode 'position' or "
                             "'sanding'")
        rec = {"time": float(t)}
        if len(kp) or len(kd):
            self.pd = JointPD(kp if len(kp) else self.pd.kp, kd if len(kd) else self.pd.kd,
                              self.pd.motor)
        if len(kp):
            rec["kp"] = [float(v) for v in kp]
        if len(kd):
            rec["kd"] = [float(v) for v in kd]
        if shaper is not None:         # for the steps from here on (this change's too)
            from flexarm_ros.scene.sections import Shaper
            if not isinstance(shaper, Shaper):
                shaper = Shaper(times=tuple(shaper["times"]),
                                amplitudes=tuple(shaper["amplitudes"]),
                                design=shaper.get("design", ""))
            self._next_shaper = shaper
            rec["shaper"] = {"times": list(shaper.times),
                             "amplitudes": list(shaper.amplitudes)}
        if len(voltage_limit):
            self.limit = np.array(voltage_limit, float)
            self.pd.motor.supply_voltage = self.limit.copy()
            rec["voltage_limit"] = self.limit.tolist()
        if len(joint_target):
            if getattr(self, "_next_shaper", None) is not None:
                self.shaper, self._next_shaper = self._next_shaper, None
            self.q_start = self.q_cmd.copy()
            self.q_goal = np.array(joint_target, float)
            self.qd_cmd = np.zeros(self.n)
            self.reference = None
            self._shape_t0 = float(t)
            self.q_cmd = self._shaped(t) if self.shaper is not None else self.q_goal.copy()
            rec["joint_target"] = self.q_goal.tolist()
        return rec

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
        if self.mode == "open_loop":      # an explicit supply_voltage saturates, as in simulate
            return np.clip([eval_torque(p[0], p[1], p[2], p[3], t) if p is not None else 0.0
                            for p in self.programs], -self.limit, self.limit)
        while self.changes and self.changes[0].time <= t:    # control.changes due now
            ch = self.changes.pop(0)
            self.retune(t, ch.kp, ch.kd, ch.joint_target, ch.voltage_limit, ch.shaper)
        q = np.asarray(joint_angles, float)
        qd = self.velocity.update(t, dt, q)
        if self.task is not None:
            target, self.phase = self.task.update(t, dt, self.arm.forward(q), in_contact,
                                                  normal_force)
            self.q_cmd = self._ik(target, self.q_cmd)
        elif self.reference is not None:
            self.q_cmd, self.qd_cmd = self.reference.at(t)
        elif self.shaper is not None:
            self.q_cmd = self._shaped(t)
        if self.lqg is not None:            # the torque the LQG's voltage asks for
            volts = self.lqg.update(q)
            self.torque_demand = self.pd.motor.torque(volts, qd)
            return volts
        self.torque_demand = self.pd.torque(q, qd, self.q_cmd, self.qd_cmd)
        return self.pd.motor.voltage(self.torque_demand, qd)

    def accept_trajectory(self, t_now: float, start_s: float | None, names, times,
                          positions, velocities=None) -> str | None:
        """A trajectory from the wire (``controller/joint_trajectory``), to start at
        ``start_s`` (scene time, s; None or not after ``t_now``: at once, from the
        reference now): None when it replaces the reference, else the reason it was
        rejected — nothing changes then."""
        if self.mode != "position":
            return f"control.mode is {self.mode!r}, expected 'position' to follow a trajectory"
        if self.lqg is not None:
            return "the LQG regulates to the target it was designed at"
        from flexarm_ros.scene.trajectory_points import check_points
        try:
            _, P, V = check_points([f"{lk.name}_joint" for lk in self.scene.links], names,
                                   times, positions, velocities, self.position_limits)
        except ValueError as exc:
            return str(exc)
        t0 = t_now if start_s is None or start_s <= t_now else float(start_s)
        if self.reference is None:
            self.reference = Reference(self.q_start, self.shaper)
            if self.shaper is not None or np.any(self.q_goal != self.q_start):
                # the step it followed so far, as a trajectory from t = 0
                self.reference.add(Trajectory(0.0, self.q_start, np.zeros(self.n),
                                              [1e-9], [self.q_goal], None))
        q0, qd0 = self.reference.raw(t0)
        self.reference.add(Trajectory(t0, q0, qd0, np.asarray(times, float), P, V))
        self.q_goal = P[-1].copy()
        return None
