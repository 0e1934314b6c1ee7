"""The arm alone, stepped from outside: the ROS simulator node's core and the batch
co-simulation's plant (ros2_control habit: time is an argument, ``step(dt)``).

Inputs are held constant over each step (zero-order hold, as a real amplifier between
control ticks): joint torques at the gearbox outputs (N·m) for a joint with a DC motor or
none — the motor driver turns voltage commands into these torques, and the electrical
drive is left out of the plant — and the servovalve current (A above the null bias) for a
hydraulic joint, whose actuator stays in the plant: its load pressure is integrated with
the arm. The mechanics of the drive train stay in the plant too (reflected inertia J_eq,
viscous C_eq, backlash, joint flexibility), as do prescribed motions.

Why the hydraulic actuator is in the plant (session 13): its oil column is a spring,
k_h = η D_m² 4β/V_t ≈ 3.2e4 N·m/rad on seed 002's arm, against ~0.3 kg·m² at the joint:
ω_h·T ≈ 1.9 at the 6 ms control period. A torque computed by the driver with the joint
rate held over the period and then held by the plant is a zero-order-hold coupling across
that spring, and it diverged (the load pressure reached the supply within three ticks of
the valve step, t = 0.133 s). On the bench the valve current is what the amplifier
holds; the pressure answers the arm continuously — as here.

The plant steps RK4, or RKN4 where the scene names ``fidelity.integrator: rkn4`` and has
no wall (:func:`plant_integrator`; the contact stepper is RK4's); any other integrator of a
scene applies to batch runs only, and the simulator node says so when it starts.

Sensors are sampled on their own grids inside a step (the step is cut at every sample
time), from the model at that instant (see :mod:`sensors`); contact is integrated through
its events (:class:`contact.ContactStepper`). Nothing non-finite ever leaves: a diverging
state raises :class:`SimulationDiverged` before any sample of it is returned.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.model import drives
from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import contact as kcontact
from flexarm_ros.model.compiled import loops as kloops
from flexarm_ros.model.compiled import sensors as ksensors
from flexarm_ros.model.compiled.layout import Workspace
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.contact import PHASES, build_contact
from flexarm_ros.sim.contact_stepper import ContactStepper, SampleBuffer
from flexarm_ros.errors import SceneError, SimulationDiverged
from flexarm_ros.sim.budget import check_work
from flexarm_ros.sim.guard import DivergenceGuard
from flexarm_ros.sim.step import choose_step
from flexarm_ros.scene import Input, Program
from flexarm_ros.scene.sections import ENCODER_REVOLUTIONS, INT32_MAX
from flexarm_ros.model.linear import smooth_rhs
from flexarm_ros.model.sensors import build_sensors, measure, sample_grid_ns, true_value
from flexarm_ros.model.statics import initial_state


def plant_grid_ns(scene) -> int:
    """The grid the plant stops on (ns): the gcd of every sensor's sample period and the
    batch output period fidelity.output_dt. The closed-loop batch run records the state
    there; a step ends on it only where the model is not smooth, and then the step divides
    the output period anyway, so the twin steps as a plant without it would."""
    return sample_grid_ns([1.0 / s.rate_hz for s in scene.sensors]
                          + [scene.fidelity.output_dt])


def plant_integrator(scene) -> str:
    """The integrator the plant steps ``scene`` with: rkn4 where the scene names it and has
    no wall, else rk4 (the contact stepper's; the implicit and adaptive integrators are
    batch-only: a tick-by-tick plant has no use for an error-controlled step)."""
    from flexarm_ros.model.explicit import explicit_integrator
    return "rk4" if scene.walls else explicit_integrator(scene.fidelity)


def in_plant(drive) -> bool:
    """Whether a joint's drive is integrated by the plant (a hydraulic actuator; see the
    module text) rather than by the motor driver (a DC motor)."""
    return drive is not None and drive.type == "hydraulic"


def plant_scene(scene):
    """The scene with the motor driver's drives removed: every non-prescribed joint takes a
    held input (constant 0 until :meth:`Plant.set_inputs`) — a torque (N·m), or for a
    hydraulic joint, whose actuator stays, the servovalve current (A above the null
    bias)."""
    links = []
    for lk in scene.links:
        if not in_plant(lk.joint.drive):
            # the rotor's reflected inertia (drive.rotor_inertia) stays on the coordinate
            lk = dataclasses.replace(lk, joint=dataclasses.replace(
                lk.joint, drive=None, drive_inertia=lk.joint.total_drive_inertia))
        links.append(lk)
    motions = {inp.joint: inp for inp in scene.inputs if inp.motion is not None}
    inputs = []
    for j, lk in enumerate(links, start=1):
        held = (Input(joint=j, current=Program(type="constant")) if in_plant(lk.joint.drive)
                else Input(joint=j, torque=Program(type="constant")))
        inputs.append(motions.get(j) or held)
    return dataclasses.replace(scene, links=tuple(links), inputs=tuple(inputs))


@dataclass
class Sample:
    """One sensor reading: time (s), measured value (instrument units), true SI value."""
    sensor: str
    t: float
    value: float
    true: float


class Plant:
    """A scene's arm advanced by :meth:`step` with held joint torques. ``duration``: the
    run's length, s, when known: a run that would need more RK4 steps than
    ``fidelity.max_steps`` is refused here (:func:`budget.check_work`)."""

    def __init__(self, scene, duration: float | None = None):
        self.scene = scene
        # rung auto is chosen on the scene as given (its drives and input programs are the
        # excitation; plant_scene replaces them by held torques)
        from flexarm_ros.model.autofidelity import resolve
        resolved, self.auto = resolve(scene)
        self.chain = ch = Chain(plant_scene(resolved))
        self.contact = build_contact(ch)
        q0, qd0, z0 = initial_state(ch)       # a hydraulic actuator's holding pressure
        self.q_initial = q0.copy()
        self.x = np.concatenate([q0[ch.free], qd0[ch.free], z0])
        self.t = 0.0
        self.k = 0                                   # grid index of self.t
        self.sensors = build_sensors(ch, scene)
        for k, sn in enumerate(scene.sensors):
            if not 1e9 / sn.rate_hz >= 1000:
                raise SceneError(f"sensors[{k}].rate_hz: got {sn.rate_hz:g} Hz, expected at "
                                 f"most 1e+06 Hz (a sample period of at least 1 µs)")
        self.grid_ns = plant_grid_ns(scene)
        if self.grid_ns < 1000:     # as flexarm simulate refuses it
            raise SceneError(
                f"sensors: the sample periods and fidelity.output_dt share no common grid "
                f"coarser than 1 µs (got {self.grid_ns} ns), expected rates whose periods "
                f"are multiples of a common step (e.g. 4000, 1000 and 250 Hz)")
        self._every = [int(round(1e9 / s.spec.rate_hz)) for s in self.sensors]
        # which sensors are due at a grid instant depends only on t mod the periods' lcm
        self._cycle = math.lcm(*self._every) if self._every else 1
        self._due_at: dict = {}
        self._rng = {s.name: np.random.default_rng(s.spec.seed) for s in self.sensors}
        # every accelerometer reads its true value (no sensitivity, noise or ADC): its
        # measured value is the true one (what _measure would return)
        self._plain = all(s.spec.sensitivity is None and not s.spec.noise_std > 0 and
                          s.spec.adc_range is None for s in self.sensors
                          if s.spec.kind == "accelerometer")
        self._act = {a.link: j for j, a in enumerate(ch.actuators)}
        # accelerometers read by the compiled kernel (numba backend; else the numpy path)
        self._acc = None
        if ch.backend == "numba" and any(s.spec.kind == "accelerometer" for s in self.sensors):
            self._acc = ksensors.pack(ch, self.sensors)
            self._acc_out = np.empty(len(self._acc[0]))
            self._acc_row = {int(j): r for r, j in enumerate(self._acc[0])}
        # the links whose held input is a valve current (their actuator is in the plant)
        self._valve = {a.link: j for j, a in enumerate(ch.actuators)
                       if a.kind == drives.HYDRAULIC}
        self.inputs = np.zeros(len(ch.links))
        fid = ch.fidelity
        # the step (fidelity.dt checked against the stability limit). A smooth model steps
        # each control period in equal steps no longer than h, its grid instants from the
        # steps' dense output (Hermite); otherwise the step divides the output period and
        # the plant steps grid interval by grid interval
        self.integrator = plant_integrator(ch.scene)
        self.dense = (self.contact is None and not len(ch.presc_idx) and smooth_rhs(ch))
        self.h = h = choose_step(ch, self.x, self.integrator, fid.dt, fid.output_dt,
                                 contact=self.contact, dense=self.dense)
        self._periods: dict = {}                     # grid intervals -> (RK4 steps, buffer)
        # the closed-loop batch run's record: the state at every grid instant whose index
        # is a multiple of trace_every (None: no record)
        self.trace: list | None = None
        self.trace_every = 1
        self.trace_contact: list | None = None   # with a wall: (R row, phase) per record
        if duration is not None:        # the work budget of a run of that length
            check_work(ch, self.x, h, duration, self.integrator, self.contact)
        self.guard = DivergenceGuard(ch, fid.max_deflection_ratio, self.integrator, h)
        self.guard.check(0.0, self.x)
        self.ws = kchain.workspace(ch.kernel_args)
        self._frames_at = None                       # (t, k) of the frames in self.ws
        self.stepper = (ContactStepper(ch, self.contact, self.x, h, self.guard)
                        if self.contact is not None else None)
        if self.stepper is not None:
            # the stepper imports its root finder on the first event; in a twin that runs
            # against the wall clock that import (~0.4 s) would stall the impact's tick
            import scipy.optimize  # noqa: F401
        self.contact_sample = None
        self._bufs: dict = {}                        # SampleBuffer per tick length
        if self.stepper is not None:
            self.contact_sample = self.stepper.sample()

    # ------------------------------------------------------------------- inputs
    def set_inputs(self, inputs) -> None:
        """The held inputs, joint order, from now until the next call: N·m, or A above
        the null bias for a hydraulic joint (:func:`plant_scene`)."""
        u = np.asarray(inputs, float)
        if u.shape != (len(self.chain.links),) or not np.all(np.isfinite(u)):
            raise SceneError(f"inputs: got {u!r}, expected {len(self.chain.links)} finite "
                             f"values (N·m, or A for a servovalve; joint order)")
        self.inputs = u.copy()
        prog_par = self.chain.model.prog_par
        for link, j in self._act.items():
            prog_par[j, 0] = u[link]                     # a constant program's value
            self.chain.actuators[j].enc[1][0] = u[link]   # the numpy path's copy

    @property
    def torques(self) -> np.ndarray:
        """The joint torques acting now (N·m, joint order): the held input, or a
        hydraulic actuator's η_t D_m P_L from the pressure in the state."""
        if not self._valve:
            return self.inputs
        tau = self.inputs.copy()
        ch = self.chain
        nf = len(ch.free)
        q, qd = ch.full_state(self.t, self.x)
        for link, j in self._valve.items():
            a = ch.actuators[j]
            tau[link] = drives.actuator_torque(a.kind, a.par, self.inputs[link],
                                               float(qd[a.coord]), float(self.x[2 * nf
                                                                              + a.state]))
        return tau

    def held(self) -> str:
        """The held inputs with their units, for messages."""
        return ", ".join(f"{v:.4g} {'A' if k in self._valve else 'N·m'}"
                         for k, v in enumerate(self.inputs))

    # --------------------------------------------------------------------- stepping
    def step(self, dt: float) -> list[Sample]:
        """Advance by ``dt`` (a whole number of sensor-grid periods when sensors are
        declared); returns the sensor samples taken in (t, t + dt], in time order."""
        return [Sample(name, t, v, tr) for t, names, vals, trues in self.step_rows(dt)
                for name, v, tr in zip(names, vals, trues)]

    def step_rows(self, dt: float) -> list[tuple]:
        """:meth:`step` with the readings grouped by instant: ``(t, names, values, trues)``
        per grid instant at which a sensor is due, in time order (``names``: a tuple, the
        same object for the same set of due sensors — a caller may key on it). The
        simulator's tick reads these (no object per reading)."""
        rows: list = []
        if self.grid_ns:
            n = dt * 1e9 / self.grid_ns
            if abs(n - round(n)) > 1e-6 or round(n) < 1:
                raise SceneError(f"step: got dt = {dt} s, expected a whole number of sensor "
                                 f"grid periods ({self.grid_ns * 1e-9:g} s)")
            if self.stepper is not None:
                return self._step_contact(int(round(n)))
            if self.dense:
                return self._step_dense(int(round(n)))
            for _ in range(int(round(n))):
                self.k += 1
                self._advance(self.k * self.grid_ns * 1e-9)
                self._record(self.x)
                row = self._read_due()
                if row is not None:
                    rows.append(row)
        else:
            self._advance(self.t + dt)
        return rows

    def _record(self, x) -> None:
        if self.trace is not None and self.k % self.trace_every == 0:
            self.trace.append(x.copy())

    def steps_per_period(self, n: int) -> int:
        """RK4 steps the smooth plant takes over ``n`` grid intervals: the fewest equal
        steps no longer than its step h."""
        T = n * self.grid_ns * 1e-9
        return max(1, int(math.ceil(T / self.h - 1e-9)))

    def _step_dense(self, n: int) -> list[tuple]:
        """``n`` grid intervals of a smooth model in one compiled call
        (:func:`~flexarm_ros.model.compiled.loops.rk4_period`): equal steps no longer than
        h over the whole span, the grid instants from the steps' dense output; then the
        sensors due at each instant, read as :meth:`step_rows` reads them."""
        per = self._periods.get(n)
        if per is None:
            per = self._periods[n] = (self.steps_per_period(n), np.empty((n, len(self.x))))
        nsteps, xs = per
        ch = self.chain
        code, t_fail, _, _, x_last, x_bad = kloops.rk4_period(
            self.x, self.k, self.grid_ns, n, nsteps, ch.fidelity.max_deflection_ratio,
            xs, ch.kernel_args, self.ws, self.integrator == "rkn4")
        if code != kchain.OK:
            self.guard.last = x_last
            self.guard.check(t_fail, x_bad)
        if not math.isfinite(float(xs.sum())):
            # the numpy test nothing non-finite gets past (see _advance)
            self.guard.last = self.x
            bad = xs[~np.all(np.isfinite(xs), axis=1)]
            self.guard.check(float((self.k + n) * self.grid_ns * 1e-9), bad[0])
        rows: list = []
        g = self.grid_ns
        for i in range(n):
            self.k += 1
            self.t = self.k * g * 1e-9
            self.x = xs[i].copy()
            self._record(self.x)
            row = self._read_due()
            if row is not None:
                rows.append(row)
        return rows

    def _step_contact(self, n: int) -> list[tuple]:
        """``n`` sensor-grid periods with a wall: one :meth:`ContactStepper.advance` to the
        end (its steps divide the output period, never cross the end), which writes the
        grid instants on the way (dense samples: state, contact quantities, q̈ and the
        accelerometers from each sample's own evaluation). Rows as :meth:`step_rows`."""
        g = self.grid_ns
        ts = (self.k + np.arange(1, n + 1)) * (g * 1e-9)
        buf = self._bufs.get(n)
        if buf is None:
            buf = self._bufs[n] = SampleBuffer(ts, len(self.x), len(self.chain.free),
                                               self._acc[1:] if self._acc else None)
        buf.reset(ts)
        st = self.stepper
        st.advance(float(ts[-1]), buf)
        if not math.isfinite(float(buf.X[:n].sum())):
            # the numpy test nothing non-finite gets past (see _advance; the last row is
            # the stepper's state)
            self.guard.last = self.x
            bad = buf.X[:n][~np.all(np.isfinite(buf.X[:n]), axis=1)]
            self.guard.check(float(ts[-1]), bad[0] if len(bad) else st.x)
        acc = None
        if self._acc is not None:
            buf.complete(self.chain, self.ws)           # rows the reference wrote
            acc = buf.ACC.tolist()
            self._frames_at = None                  # the workspace holds another state
        rows: list = []
        numpy_acc = self._acc is None
        tl = ts.tolist()
        for i in range(n):
            self.k += 1
            self._record(buf.X[i])
            if self.trace_contact is not None and self.k % self.trace_every == 0:
                self.trace_contact.append((buf.R[i].copy(), int(buf.phase[i])))
            if numpy_acc:       # the numpy read-out takes q̈ from the current sample
                self._set_row(buf, i)
            row = self._read_due(None if acc is None else acc[i], tl[i], buf.X[i])
            if row is not None:
                rows.append(row)
        self._set_row(buf, n - 1)
        return rows

    def load_event_kernels(self) -> None:
        """Load (or, on a fresh machine, compile) the compiled functions that only events
        call, now: the accelerometers of the rows the Python reference stepper writes
        around an impact (:meth:`SampleBuffer.complete`). Measured without this: the
        impact tick of a realtime two_link_case1 took 37 ms (30 ms loading
        ``sensors.table`` from numba's cache) and 11 s on a fresh machine. Leaves the
        workspace's frames invalid (call it on a copy, as
        :meth:`~flexarm_ros.twin.cores.SimulatorCore._warm_up` does)."""
        if self.stepper is None or self._acc is None:
            return
        buf = SampleBuffer(np.array([self.t]), len(self.x), len(self.chain.free),
                           self._acc[1:])
        buf.X[0], buf.QDD[0] = self.x, 0.0
        buf.ref_rows[0], buf.k = True, 1
        buf.complete(self.chain, self.ws)
        self._frames_at = None

    def _set_row(self, buf, i) -> None:
        """The plant's state and contact sample from row i of a SampleBuffer."""
        R = buf.R
        self.t = float(buf.ts[i])
        self.x = buf.X[i].copy()
        self.contact_sample = (int(buf.phase[i]), R[i, kcontact.R_LN], R[i, kcontact.R_LT],
                               R[i, kcontact.R_GAP],
                               R[i, kcontact.R_RX:kcontact.R_RY + 1].copy(),
                               R[i, kcontact.R_VX:kcontact.R_VY + 1].copy(),
                               buf.QDD[i].copy())

    def _advance(self, t_end):
        dt = t_end - self.t
        if self.stepper is not None:
            self.stepper.advance(t_end)
            x_new = self.stepper.x
        else:
            n = max(1, int(math.ceil(dt / self.h - 1e-9)))
            code, t_fail, x_last, x_bad = kloops.rk4_span(
                self.x, self.t, dt / n, n, self.chain.fidelity.max_deflection_ratio,
                self.chain.kernel_args, self.ws, self.integrator == "rkn4")
            if code != kchain.OK:
                self.guard.last = x_last
                self.guard.check(t_fail, x_bad)
            x_new = x_last
        if not np.all(np.isfinite(x_new)):
            # the compiled loops' own finiteness tests can be optimized away under fast
            # math: this numpy test is the one nothing non-finite gets past (the plant
            # keeps its last finite state)
            self.guard.last = self.x
            self.guard.check(t_end, x_new)
        self.x = x_new
        if self.stepper is not None:
            self.contact_sample = self.stepper.sample()
        self.t = t_end

    def _due(self, t_ns: int) -> tuple:
        """(sensor indices due at grid time ``t_ns``, any accelerometer among them, all
        of them accelerometers, the readings' names (a tip position gives two), the
        accelerometers' rows in the compiled read-out when all are accelerometers),
        computed once per instant of the sensors' common cycle."""
        key = t_ns % self._cycle
        due = self._due_at.get(key)
        if due is None:
            idx = tuple(j for j, every in enumerate(self._every) if t_ns % every == 0)
            kinds = [self.sensors[j].spec.kind for j in idx]
            names = []
            for j in idx:
                sm = self.sensors[j]
                names += ([f"{sm.name}_x", f"{sm.name}_y"]
                          if sm.spec.kind == "tip_position" else [sm.name])
            only_acc = all(k == "accelerometer" for k in kinds)
            rows = (tuple(self._acc_row[j] for j in idx)
                    if only_acc and self._acc is not None else None)
            due = self._due_at[key] = (idx, "accelerometer" in kinds, only_acc,
                                       tuple(names), rows)
        return due

    def _read_due(self, acc_row=None, t=None, x=None) -> tuple | None:
        """The sensors due at grid index self.k, at (t, x) (default: now): ``(t, names,
        measured values, true values)``, or None when none is due; ``acc_row``: the
        accelerometers' readings of this instant when already computed
        (:meth:`_step_contact`)."""
        t_ns = self.k * self.grid_ns
        due, any_acc, only_acc, names, acc_rows = self._due(t_ns)
        if not due:
            return None
        if t is None:
            t, x = self.t, self.x
        ch = self.chain
        qdd = None
        kin = None
        if acc_row is not None and any_acc:
            self._acc_out[:] = acc_row
            if only_acc:            # nothing else due: no state assembly
                trues = [float(acc_row[r]) for r in acc_rows]
                if self._plain:
                    return t, names, trues, trues
                sensors, measure_ = self.sensors, self._measure
                return t, names, [measure_(sensors[j], v) for j, v in zip(due, trues)], trues
        q, qd = ch.full_state(t, x)
        if acc_row is None and any_acc:
            qdd = self.accelerations()
            if self._acc is not None:       # compiled: frames from one kernel evaluation
                self._frames_now()
                ksensors.readings(q, qd, qdd, ch.kernel_args, self.ws, *self._acc[1:],
                                  self._acc_out)
        vals, trues = [], []
        for j in due:
            sm = self.sensors[j]
            kind = sm.spec.kind
            if kind == "accelerometer" and self._acc is not None:
                val = float(self._acc_out[self._acc_row[j]])
            else:
                if kin is None and kind in ("accelerometer", "tip_position"):
                    kin = ch.kinematics(q, qd, frames_only=True)
                val = true_value(sm, ch, q, qd, qdd, self.q_initial, kin)
            if kind == "tip_position":
                vals += [val[0], val[1]]
                trues += [val[0], val[1]]
                continue
            if kind == "encoder" and abs(val) > INT32_MAX:
                raise SimulationDiverged(
                    f"encoder {sm.name} counts", t, val,
                    "check the drive's input and the joint's damping; the scene's encoders "
                    f"are sized for ±{ENCODER_REVOLUTIONS} output revolutions",
                    detail=f"{val:.0f} counts leave the int32 range (±{INT32_MAX}) of the "
                           f"encoder_counts message (std_msgs/Int32MultiArray)")
            vals.append(self._measure(sm, val))
            trues.append(val)
        return t, names, vals, trues

    def _measure(self, sm, val: float) -> float:
        """Instrument output of one reading: :func:`sensors.measure` on a scalar (the same
        arithmetic and the same draw from the sensor's own noise stream)."""
        sn = sm.spec
        if sn.kind in ("encoder", "tip_position"):
            return float(val)
        v = float(val)
        if sn.sensitivity is not None:
            v = v * sn.sensitivity
        if sn.noise_std > 0:
            v = v + float(self._rng[sm.name].normal(0.0, sn.noise_std, 1)[0])
        if sn.adc_range is not None:
            lo, hi = sn.adc_range
            v = min(max(v, lo), hi)
            if sn.adc_bits is not None:
                lsb = (hi - lo) / (2 ** sn.adc_bits - 1)
                v = lo + float(np.round((v - lo) / lsb)) * lsb
        return v

    # --------------------------------------------------------------------- readings
    def accelerations(self) -> np.ndarray:
        """q̈ of every coordinate now (contact included)."""
        ch = self.chain
        if self.stepper is not None:
            qdd = np.empty(ch.n)
            qdd[ch.free] = self.contact_sample[6]
            if len(ch.presc_idx):
                qdd[ch.presc_idx] = ch.prescribed_state(self.t)[2]
            return qdd
        return ch.full_qdd(self.t, self.x)

    def joint_names(self) -> list[str]:
        return [lm.name + "_joint" for lm in self.chain.links]

    def joint_state(self):
        """(angles, rates) of the link-side joint coordinates (rad, rad/s)."""
        q, qd = self.chain.full_state(self.t, self.x)
        idx = [lm.i_joint for lm in self.chain.links]
        return q[idx], qd[idx]

    def drive_state(self):
        """(angles, rates) of the drive coordinates (motor side where declared)."""
        q, qd = self.chain.full_state(self.t, self.x)
        idx = self.chain.drive_index()
        return q[idx], qd[idx]

    def tip_position(self) -> np.ndarray:
        """(x, y) of the last beam tip (m) now (the compiled kernel's frame when available,
        else :meth:`Chain.tip_position`)."""
        ch = self.chain
        if ch.backend != "numba":
            return ch.tip_position(ch.full_state(self.t, self.x)[0])
        self._frames_now()
        return Workspace._make(self.ws).frames[-1, 1, 0:2].copy()

    def _frames_now(self) -> None:
        """The kernel's frames (``ws.frames``, ``ws.frame_jac``) at the current state, evaluated
        once per state (the accelerometers and the tip of one instant share them)."""
        if self._frames_at == (self.t, self.k):
            return
        ch = self.chain
        q, qd = ch.full_state(self.t, self.x)
        kchain.forces(float(self.t), q, qd, self.x[2 * len(ch.free):], ch.kernel_args, self.ws)
        self._frames_at = (self.t, self.k)

    def contact_state(self) -> dict:
        """phase, normal/friction force (N), gap (m), tool position/velocity; phase 'free'
        and zeros without a wall."""
        if self.contact_sample is None:
            return {"phase": "free", "normal_force": 0.0, "friction_force": 0.0,
                    "gap": math.inf, "tool": self.tip_position(), "tool_velocity":
                    np.zeros(2)}
        ph, fn, ft, gap, r, v, _ = self.contact_sample
        return {"phase": PHASES[ph], "normal_force": fn, "friction_force": ft, "gap": gap,
                "tool": r, "tool_velocity": v}


def check_plant_work(scene, duration=None) -> None:
    """The budget of a twin run (``flexarm run``) before its graph starts: builds the plant
    the simulator node will step and checks ``duration`` s (None or 0: the scene's; inf:
    no end, not checked). Also surfaces the plant's own scene errors early."""
    T = duration or scene.duration
    if math.isfinite(T):
        Plant(scene, duration=T)
