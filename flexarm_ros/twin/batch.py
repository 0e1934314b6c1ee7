"""One runner of a scene for every batch command: ``flexarm simulate``, ``sweep``,
``uncertainty``, ``sensitivity``, ``calibrate``, ``study`` and the ensemble runner's tasks
all call :func:`run_scene`.

A scene that declares a ``control`` section runs as the ROS twin runs it: the controller
and the motor driver in the loop at ``control.rate_hz``, the efforts held over each period
(zero-order hold), the controller reading what it reads on the wire (quantized encoder
angles, its own filtered rates, the contact flag and normal force). Its trajectory is the
lockstep twin's ground truth (``flexarm run --mode lockstep``): the same cores
(:mod:`~flexarm_ros.twin.cores`) in the same order, without messages. Two lanes run it:

``reference``
    the cores themselves, tick by tick (every scene: walls, sanding, backlash, hydraulic
    actuators, the numpy backend);
``compiled``
    one compiled call for the whole run (:mod:`flexarm_ros.model.compiled.closed_loop`)
    where the plant is smooth (dense period stepping, no wall) and the controller is
    ``open_loop`` or ``position``: the same arithmetic as the cores (tested equal to the
    reference lane and to a lockstep twin's bag).

A scene without ``control`` — or any scene with ``open_loop=True`` (``--open-loop``) —
runs its input programs continuously (:func:`flexarm_ros.sim.simulate.simulate`), the
physics reference of the accuracy tools. A drive that would then see no input is never
left at 0 V silently: the run refuses when the scene's controller is what drives it, and
says so in the summary's ``warning`` otherwise (:func:`idle_drives`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model import drives
from flexarm_ros.sim.integrate import Integration
from flexarm_ros.sim.simulate import SimResult, contact_columns, output_columns, simulate
from flexarm_ros.twin.loop_record import LoopRecord, output_every

LANES = ("auto", "compiled", "reference")


def closed_loop(scene, open_loop: bool = False) -> bool:
    """Whether ``scene`` runs with its controller and driver in the loop: it declares a
    ``control`` section and ``open_loop`` is not asked for."""
    return scene.control is not None and not open_loop


def idle_drives(scene) -> list[int]:
    """Indices of the joints with a drive (DC motor, servovalve) and no input program: in
    an open-loop run they sit at 0 V / the null current."""
    driven = {inp.joint - 1 for inp in scene.inputs}
    return [k for k, lk in enumerate(scene.links)
            if lk.joint.drive is not None and k not in driven]


def _check_open_loop(scene, open_loop: bool) -> str | None:
    """Refuse an open-loop run of a scene whose controller is what drives its arm; the
    warning for drives that no program drives (None when every drive has one)."""
    idle = idle_drives(scene)
    if not idle:
        return None
    names = ", ".join(f"{k + 1} ({scene.links[k].name}, "
                      f"links[{k}].joint.drive.type {scene.links[k].joint.drive.type})"
                      for k in idle)
    if open_loop and scene.control is not None and scene.control.mode != "open_loop":
        raise SceneError(f"--open-loop: got scene {scene.name!r}, whose drives on joints "
                         f"{names} have no input program (inputs:) and are driven by its "
                         f"controller (control.mode {scene.control.mode!r}); expected no "
                         f"--open-loop (the controller in the loop), or input programs "
                         f"for those joints")
    return (f"joints {names} have a drive and no input program: they stay at 0 V (a "
            f"servovalve at its null current) for the whole run; give them inputs: or a "
            f"control section")


def open_loop_scene(scene):
    """``scene`` without its controller (its input programs run alone, continuously):
    ``--open-loop`` as a scene, for the commands that pass scenes around. Refused where the
    controller is what drives the arm (:func:`run_scene`'s rule)."""
    import dataclasses
    if scene.control is None:
        return scene
    _check_open_loop(scene, True)
    return dataclasses.replace(scene, control=None)


def run_scene(scene, duration=None, progress=None, open_loop: bool = False, chain=None,
              lane: str = "auto") -> SimResult:
    """Run ``scene`` (fidelity applied) for ``duration`` s (default: the scene's) the way
    every command runs it (module doc). ``chain``: a prebuilt model for an open-loop run
    (the ladder study's); ``lane``: auto, compiled or reference (closed loop)."""
    if lane not in LANES:
        raise SceneError(f"lane: got {lane!r}, expected one of {', '.join(LANES)}")
    if closed_loop(scene, open_loop):
        return simulate_closed_loop(scene, duration, progress, lane)
    warning = _check_open_loop(scene, open_loop)
    res = simulate(scene, duration, progress=progress, chain=chain)
    if warning:
        res.warning = warning
    return res


def probe_duration(scene, open_loop: bool = False) -> float:
    """The shortest run that shows every channel of ``scene``: two output samples, two
    periods of its slowest sensor, and (closed loop) two control periods."""
    dt = scene.fidelity.output_dt
    T = 2 * max([dt] + [1.0 / s.rate_hz for s in scene.sensors])
    if closed_loop(scene, open_loop):
        T = max(T, 2 * control_period(scene))
    return T


# ================================================================== closed-loop result
@dataclass
class ClosedLoopResult(SimResult):
    """A closed-loop batch run: a :class:`SimResult` with the loop's record."""
    record: LoopRecord = None
    loop: dict = field(default_factory=dict)
    closed_loop = True          # (sim/accuracy.truth_summary: rung auto is not offered)

    def summary(self) -> dict:
        out = super().summary()
        out.update(self.loop)
        return out


def control_period(scene) -> float:
    return 1.0 / scene.twin_control.rate_hz


def _check_closed_loop(scene, T: float) -> int:
    """The number of control ticks of a run of T s, or a SceneError for what a closed-loop
    batch run cannot do."""
    if not (T > 0 and math.isfinite(T)):
        raise SceneError(f"duration: got {T}, expected a finite number > 0 s")
    period = control_period(scene)
    K = int(math.floor(T / period + 1e-9))
    if K < 1:
        raise SceneError(f"duration: got {T:g} s, expected at least one control period "
                         f"({period:g} s, control.rate_hz {scene.twin_control.rate_hz:g})")
    return K


def simulate_closed_loop(scene, duration=None, progress=None, lane: str = "auto"
                         ) -> ClosedLoopResult:
    """The scene with its controller and driver in the loop (module doc) for ``duration``
    s, whole control periods."""
    from flexarm_ros.twin.cores import ControllerCore, DriverCore, SimulatorCore
    T = scene.duration if duration is None else duration
    K = _check_closed_loop(scene, T)
    sim = SimulatorCore(scene, duration=K * control_period(scene), warm_up=False)
    ctl = ControllerCore(scene)
    if ctl.status != "ok":          # an unreachable target: the arm would only hold still
        raise SceneError(f"control.tip_target: got {list(scene.control.tip_target)} m, "
                         f"expected a point the arm reaches ({ctl.status})")
    drv = DriverCore(scene, sim.plant)
    from flexarm_ros.twin.compiled_loop import eligible
    why_not = eligible(sim, ctl)
    if lane == "compiled" and why_not:
        raise SceneError(f"lane: got 'compiled' for scene {scene.name!r}, expected the "
                         f"reference lane: {why_not}")
    use_compiled = lane != "reference" and not why_not
    wall0 = time.perf_counter()
    if use_compiled:
        from flexarm_ros.twin.compiled_loop import run_compiled
        states, contact, rows_or_acc, rec, counts = run_compiled(sim, ctl, drv, K, progress)
    else:
        states, contact, rows_or_acc, rec, counts = _run_reference(sim, ctl, drv, K,
                                                                   progress)
    wall = time.perf_counter() - wall0
    res = _assemble(scene, sim, drv, states, contact, rows_or_acc, rec, counts, wall,
                    "compiled" if use_compiled else "reference", why_not)
    fid = scene.fidelity
    if fid.estimate or fid.tolerance:
        # the closed loop against the top rung with the same controller and driver in its
        # loop, over the whole run (sim/truth.py): the estimate of a named rung, and what
        # certifies a tolerance — a closed loop's step is the scene's (the a-priori step
        # choice replays input programs, and the controller's commands are known only
        # during the run), so the tolerance is met where this check shows it, else said
        # not met with what to change (sim/accuracy.truth_summary)
        from flexarm_ros.sim import truth
        res.truth = truth.top_check(scene, res.columns, K * control_period(scene),
                                    fid.tolerance, _reference_closed_loop,
                                    closed_loop=True)
    return res


def _reference_closed_loop(scene, T):
    """The top rung's closed-loop run for :func:`flexarm_ros.sim.truth.top_check` (one
    function, so that its runs are kept per scene and duration)."""
    return simulate_closed_loop(scene, T)


def _run_reference(sim, ctl, drv, K: int, progress):
    """The cores tick by tick, in the lockstep order of :class:`~flexarm_ros.twin.cosim.
    Lockstep`: the state's readings, the controller's commands, the driver's efforts, the
    plant's period. Returns (states at the output instants, contact rows or None, the
    sensor rows, the loop record, (steps, rhs evaluations))."""
    plant = sim.plant
    period = sim.period
    every = output_every(plant)
    plant.trace, plant.trace_every = [plant.x.copy()], every
    if plant.contact is not None:
        plant.trace_contact = [_contact_row(plant)]
    rows: list = []
    sim.sink = rows
    n = len(sim.names)
    rec = _empty_record(K, n, ctl)
    current_of = _current_reader(drv)
    for k in range(K):
        t = sim.t
        ang, contact, fn, w, torques = sim.bench_view()
        cmd = ctl.update(t, period, ang, contact, fn)
        if not drv.accept(t, cmd):
            rec.rejected += 1
        rec.t[k] = t
        rec.command[k] = drv.command
        rec.current[k] = current_of(w)
        if rec.joint_target is not None:
            rec.joint_target[k] = ctl.q_cmd
        if rec.tip_target is not None:
            rec.tip_target[k] = _tip_target(ctl)
        rec.effort[k] = drv.update(t, period, w, torques)
        sim.step(rec.effort[k])
        if progress is not None and k % 200 == 0:
            progress(k / K)
    rec.held, rec.status = drv.held, ctl.status
    st = plant.stepper
    work = (st.steps, st.calls) if st is not None else (None, None)
    return np.array(plant.trace), plant.trace_contact, rows, rec, work


def _contact_row(plant):
    """The contact row (kcontact's R layout, 10 columns) and phase of the plant now."""
    cs = plant.contact_state()
    wall = plant.contact
    v = np.asarray(cs["tool_velocity"], float)
    r = np.asarray(cs["tool"], float)
    R = np.array([cs["normal_force"], cs["friction_force"], cs["gap"], wall.n @ v,
                  wall.t @ v, r[0], r[1], v[0], v[1], 0.0])
    return R, int(plant.contact_sample[0])


def _empty_record(K: int, n: int, ctl) -> LoopRecord:
    has_q = ctl.mode != "open_loop"
    has_tip = ctl.mode == "sanding" or (has_q and ctl.scene.control.tip_target is not None)
    return LoopRecord(np.zeros(K), np.zeros((K, n)), np.zeros((K, n)), np.zeros((K, n)),
                      np.zeros((K, n)) if has_q else None,
                      np.zeros((K, 2)) if has_tip else None)


def _tip_target(ctl) -> np.ndarray:
    if ctl.task is not None:
        return np.asarray(ctl.task.target, float)
    return np.asarray(ctl.scene.control.tip_target, float)


def _current_reader(drv):
    """The armature current of each joint at the start of a tick (A): a DC motor's state,
    or its quasi-static current; 0 for the other joints."""
    def read(w):
        out = np.zeros(drv.n)
        for k in range(drv.n):
            kind = drv.kind[k]
            if kind == drives.DC_CURRENT:
                out[k] = drv.z[k]
            elif kind == drives.DC_QUASI_STATIC:
                out[k] = drives.motor_current(kind, drv.par[k], drv.command[k], w[k], 0.0)
        return out
    return read


# ============================================================================ assembly
def _assemble(scene, sim, drv, states, contact, rows_or_acc, rec, work, wall, lane,
              why_not) -> ClosedLoopResult:
    """The run's columns (as ``flexarm simulate``'s, plus the loop's), sensor tables and
    summary from what a lane returned."""
    plant = sim.plant
    ch = plant.chain
    fid = ch.fidelity
    N = len(states)
    t = np.arange(N) * (output_every(plant) * plant.grid_ns * 1e-9)
    steps, calls = work
    if steps is None:          # smooth plant: equal steps per period; else h-steps
        per = (plant.steps_per_period(round(sim.period * 1e9 / plant.grid_ns))
               if plant.dense else round(sim.period / plant.h))
        steps = per * len(rec.t)
        calls = 4 * steps
    # the step the plant took: a smooth plant's control period in equal steps, else h
    h = (sim.period / plant.steps_per_period(round(sim.period * 1e9 / plant.grid_ns))
         if plant.dense else plant.h)
    run = Integration.completed(ch, t, states, calls, steps, wall, h)
    cols = output_columns(ch, run, actuators=False)
    cols.update(_drive_columns(ch, drv, run, rec, sim.period))
    if contact is not None:
        cols.update(_contact_columns(contact))
    tables = (_tables_from_rows(plant, rows_or_acc) if isinstance(rows_or_acc, list)
              else _tables_from_states(sim, rows_or_acc))
    ctl_mode = scene.twin_control.mode
    loop = {"loop": "closed", "control_mode": ctl_mode,
            "control_rate_hz": scene.twin_control.rate_hz, "control_ticks": len(rec.t),
            "lane": lane, "commands_rejected": rec.rejected,
            "torque_limit_held_ticks": rec.held, "controller_status": rec.status,
            "plant_integrator": plant.integrator, "plant_step_s": h}
    if lane == "reference" and why_not:
        loop["lane_reason"] = why_not
    if "tool_x_target" in cols and "tool_x" in cols:        # where the tool ended
        end = (float(cols["tool_x"][-1]), float(cols["tool_y"][-1]))
        goal = (float(cols["tool_x_target"][-1]), float(cols["tool_y_target"][-1]))
        loop["tool_end_m"] = list(end)
        loop["tool_target_m"] = list(goal)
        loop["tool_error_m"] = float(np.hypot(end[0] - goal[0], end[1] - goal[1]))
    crun = None
    if contact is not None:
        crun = _contact_run(plant, contact)
    res = ClosedLoopResult(scene.name, ch, run, cols, tables, crun, record=rec, loop=loop)
    if fid.integrator not in ("rk4", "rkn4"):
        res.warning = (f"fidelity.integrator {fid.integrator!r} steps batch open-loop runs "
                       f"only: the closed loop steps the plant with {plant.integrator} "
                       f"(as the twin does); --open-loop runs the programs with "
                       f"{fid.integrator}")
    return res


def _held(rec_values, t, period, K):
    """The per-tick values in effect at the output instants t: tick k's value over
    [t_k, t_k+1), the last one held at the end."""
    k = np.minimum(np.floor(t / period + 1e-9).astype(int), K - 1)
    return rec_values[k]


def _drive_columns(ch, drv, run, rec, period) -> dict:
    """Per joint, as :func:`~flexarm_ros.sim.simulate.actuator_columns` names them: a DC
    motor's ``<link>_voltage`` (V, the command held, within the supply), ``_current`` (A
    at the tick) and ``_drive_torque`` (N·m held); a servovalve's ``_valve_current`` (A,
    null bias included), ``_pressure`` (Pa) and ``_drive_torque`` (N·m, from the load
    pressure); a joint without a drive its ``_torque_cmd`` (N·m held). With a position or
    sanding controller its targets: ``<link>_joint_target`` (rad) and, for a tool-point
    target, ``tool_x_target``/``tool_y_target`` (m) beside the tool point ``tool_x``,
    ``tool_y`` (m)."""
    K = len(rec.t)
    cols = {}
    plant_act = {a.link: a for a in ch.actuators}
    for k, lm in enumerate(ch.links):
        name = lm.name
        u = _held(rec.command[:, k], run.t, period, K)
        tau = _held(rec.effort[:, k], run.t, period, K)
        kind = drv.kind[k]
        if kind in (drives.DC_CURRENT, drives.DC_QUASI_STATIC):
            vmax = drv.par[k][drives.DC_SUPPLY_VOLTAGE]
            cols[f"{name}_voltage"] = np.clip(u, -vmax, vmax)
            cols[f"{name}_current"] = _held(rec.current[:, k], run.t, period, K)
            cols[f"{name}_drive_torque"] = tau
        elif kind == drives.HYDRAULIC:
            a = plant_act[k]
            z = np.ascontiguousarray(run.z[:, a.state], float)
            w = np.ascontiguousarray(run.qd[:, a.coord], float)
            current, torque = np.empty(len(u)), np.empty(len(u))
            drives.drive_columns(a.kind, a.par, np.ascontiguousarray(u, float), w, z,
                                 current, torque)
            cols[f"{name}_valve_current"] = u + a.par[drives.HYD_VALVE_BIAS]
            cols[f"{name}_pressure"] = np.clip(z, *drives.state_bounds(a.kind, a.par))
            cols[f"{name}_drive_torque"] = torque
        elif k in plant_act:
            cols[f"{name}_torque_cmd"] = tau
    if rec.joint_target is not None:
        for k, lm in enumerate(ch.links):
            cols[f"{lm.name}_joint_target"] = _held(rec.joint_target[:, k], run.t, period,
                                                     K)
    if rec.tip_target is not None:
        # the tool point the target refers to (a wall's contact columns hold it already)
        if not ch.scene.walls:
            tool = ch.tool_points(run.t, run.q, run.qd, run.z)
            cols["tool_x"], cols["tool_y"] = tool[:, 0], tool[:, 1]
        cols["tool_x_target"] = _held(rec.tip_target[:, 0], run.t, period, K)
        cols["tool_y_target"] = _held(rec.tip_target[:, 1], run.t, period, K)
    return cols


class _ContactSamples:
    """The contact quantities at the output instants, as ``contact_columns`` reads a
    :class:`~flexarm_ros.sim.contact_stepper.ContactRun`."""

    def __init__(self, rows):
        from flexarm_ros.model.compiled import contact as kcontact
        R = np.array([r for r, _ in rows])
        self.phase = np.array([p for _, p in rows], dtype=np.int64)
        self.normal_force = R[:, kcontact.R_LN]
        self.friction_force = R[:, kcontact.R_LT]
        self.gap = R[:, kcontact.R_GAP]
        self.tool = R[:, kcontact.R_RX:kcontact.R_RY + 1]
        self.tool_velocity = R[:, kcontact.R_VX:kcontact.R_VY + 1]
        self.normal_impulse = R[:, kcontact.S_IMPULSE]


def _contact_columns(rows) -> dict:
    return contact_columns(_ContactSamples(rows))


def _contact_run(plant, rows):
    """A ContactRun of the loop (impacts as the stepper located them)."""
    from flexarm_ros.sim.contact_stepper import ContactRun
    s = _ContactSamples(rows)
    st = plant.stepper
    return ContactRun(s.phase, s.normal_force, s.friction_force, s.gap, s.tool,
                      s.tool_velocity, list(st.impacts), st.max_drift,
                      np.zeros(len(s.phase), dtype=np.int64), np.zeros(len(s.phase)),
                      s.normal_impulse)


def _tables_from_rows(plant, rows) -> dict:
    """Per sample rate, the sensors' table ({'t', '<name>', '<name>_true'; a tip
    position's '<name>_x', '<name>_y'}) from the plant's rows — the readings the twin
    published, noise and ADC included."""
    series: dict = {}
    for t, names, vals, trues in rows:
        for name, v, tr in zip(names, vals, trues):
            s = series.setdefault(name, ([], [], []))
            s[0].append(t)
            s[1].append(v)
            s[2].append(tr)
    tables: dict = {}
    for sm in plant.sensors:
        rate = sm.spec.rate_hz
        table = tables.setdefault(rate, {})
        if sm.spec.kind == "tip_position":
            for axis in ("x", "y"):
                tt, v, _ = series.get(f"{sm.name}_{axis}", ([], [], []))
                table.setdefault("t", np.array(tt, float))
                table[f"{sm.name}_{axis}"] = np.array(v, float)
            continue
        tt, v, tr = series.get(sm.name, ([], [], []))
        table.setdefault("t", np.array(tt, float))
        table[sm.name] = np.array(v, float)
        table[f"{sm.name}_true"] = np.array(tr, float)
    return {rate: tables[rate] for rate in sorted(tables)}


def _tables_from_states(sim, grid) -> dict:
    """The sensors' tables from the compiled lane's states at every grid instant (and the
    accelerometers it read there): :func:`~flexarm_ros.model.sensors.sensor_tables` over
    the instants after the start — the twin reads no sensor at t = 0."""
    from flexarm_ros.model.sensors import sensor_tables
    plant = sim.plant
    if not plant.sensors:
        return {}
    X, ACC = grid
    ch = plant.chain
    t = np.arange(1, len(X)) * (plant.grid_ns * 1e-9)
    run = Integration.completed(ch, t, X[1:], 0, 0, 0.0, plant.h)
    return sensor_tables(ch, run, plant.sensors, plant.q_initial,
                         acc_given=None if ACC is None else ACC[1:])
