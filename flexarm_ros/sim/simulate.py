"""Batch simulation of a scene without ROS: build the model, set the initial state, integrate,
and return named output columns plus a run summary (like scipy's result object)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.model import drives
from flexarm_ros.model.chain import Chain
from flexarm_ros.model.linear import trapezoid_step_by_error
from flexarm_ros.model.contact import PHASE_CODE, PHASES, build_contact
from flexarm_ros.model.sensors import (build_sensors, output_period, sample_grid_ns,
                                       sensor_tables)
from flexarm_ros.model.statics import initial_state, initial_x
from flexarm_ros.sim.budget import check_output
from flexarm_ros.sim.contact_run import integrate_with_contact
from flexarm_ros.sim.integrate import Integration, integrate

__all__ = ["SimResult", "actuator_columns", "contact_columns", "integrate_with_contact",
           "output_columns", "simulate"]


@dataclass
class SimResult:
    """Samples of a run and its summary."""
    scene_name: str
    chain: Chain
    run: Integration
    columns: dict           # name -> (N,) array, 't' first
    sensor_tables: dict = None   # rate (Hz) -> {'t': …, sensor columns} (declared sensors)
    contact: object = None       # contact.ContactRun of a scene with a wall
    accuracy: object = None      # accuracy.StepChoice when fidelity.tolerance chose the step
    auto: object = None          # autofidelity.AutoChoice when the scene said rung auto
    check: object = None         # accuracy.PosteriorCheck of an auto or assessed run
    assessed: object = None      # autofidelity.AutoChoice of fidelity.estimate (named rung)
    warning: str | None = None   # what the user should know of this run (summary "warning")
    truth: object = None         # truth.TopCheck: the run against the top rung (tolerance,
    #                              rung auto, estimate)
    escalated: list = None       # rung auto: the models tried before the one that met it

    def summary(self) -> dict:
        r = self.run
        sim = float(r.t[-1]) if len(r.t) else 0.0
        out = {"scene": self.scene_name, "status": r.status, "message": r.message,
               "success": r.success, "sim_time_s": sim, "wall_time_s": r.wall_time_s,
               "real_time_factor": sim / r.wall_time_s if r.wall_time_s > 0 else float("inf"),
               "rhs_evaluations": r.rhs_evaluations, "steps": r.steps, "dt": r.dt,
               "rung": self.chain.fidelity.rung, "coordinates": list(self.chain.names),
               "integrator": self.chain.fidelity.integrator,
               # the refinement the model has (fidelity.refine 0 takes the rung's default;
               # flexarm explain names the same number)
               "refine": self.chain.links[0].beam.refine, "step_s": r.dt,
               # a closed loop has no a-priori step choice: its tolerance is certified
               # by the check after the run alone (twin/batch.simulate_closed_loop)
               "tolerance_m": (self.accuracy.tolerance_m if self.accuracy else
                               self.chain.fidelity.tolerance or None),
               "tolerance_source": (self.accuracy.source if self.accuracy else
                                    "checked after the run (closed loop: the scene's step)"
                                    if self.chain.fidelity.tolerance else None),
               "estimated_tip_error_m": (self.accuracy.estimated_tip_error_m
                                         if self.accuracy else None)}
        if self.chain.fidelity.rung == "rod":
            from flexarm_ros.model.rod import kept_modes
            # the rod's bending coordinates per beam (fidelity.rod_modes; all its terms
            # when 0) and its Gauss points (fidelity.rod_points; 0 takes the default)
            beam = self.chain.links[0].beam
            out["rod_modes"] = kept_modes(self.chain.fidelity.rod_modes, beam.refine)
            out["rod_points"] = len(beam.x)
        if self.accuracy:
            if self.accuracy.method == "linear":
                how = "the linearized model stepped by the trapezoidal rule against its " \
                      "exact response ("
            elif self.accuracy.method == "pilot above the stable step":
                how = "a pilot run at the step above the stable one against a finer one ("
            else:
                how = "step halving (" + (
                    "the contact stepper's, pilots over the whole run; "
                    if self.contact is not None else
                    f"{self.chain.fidelity.integrator}'s; ")
            out["estimate"] = (f"a priori: {how}temporal only, the rung's own spatial error "
                               f"not included)")
            if self.accuracy.method != "linear" and self.contact is None:
                out["stable_step_s"] = self.accuracy.stable_step_s     # RK4_AUTO/|λ|max
        if self.auto is not None or self.assessed is not None:
            from flexarm_ros.sim.accuracy import auto_summary
            out.update(auto_summary(self.auto or self.assessed, self.check,
                                    key="auto" if self.auto is not None else "assessment"))
            if self.assessed is not None and self.accuracy:
                # the tolerance chose the step: its own (temporal) figure beside the estimate
                out["tolerance_m"] = self.accuracy.tolerance_m
                out["step_estimate_m"] = self.accuracy.estimated_tip_error_m
        if self.truth is not None:
            from flexarm_ros.sim.accuracy import truth_summary
            out.update(truth_summary(self, out))
        if self.warning:
            out["warning"] = "; ".join(w for w in (out.get("warning"), self.warning) if w)
        return out


def simulate(scene, duration=None, progress=None, chain=None) -> SimResult:
    """Run ``scene`` (fidelity already applied) for ``duration`` seconds. A run with a
    tolerance, rung auto or an estimate is checked against the top rung over the whole run
    (:mod:`flexarm_ros.sim.truth`); rung auto that the check shows short of its tolerance
    runs again on the rod (:func:`_escalate`)."""
    T = scene.duration if duration is None else duration
    if not (T > 0 and math.isfinite(T)):
        raise SceneError(f"duration: got {T}, expected a finite number > 0 s")
    fid = scene.fidelity
    checked = fid.tolerance > 0 or fid.rung == "auto" or fid.estimate
    res = _simulate(scene, T, progress, chain)
    if not checked:
        return res
    tol = _tolerance_of(res)
    res.truth = _truth().top_check(scene, res.columns, T, tol, _simulate)
    if res.auto is not None and res.truth.ok and not all(
            res.truth.met(res.auto.tolerance_m, fid.tolerance_metric).values()):
        res = _escalate(scene, T, progress, res)
    return res


def _truth():
    from flexarm_ros.sim import truth      # lazily: a run without a check never needs it
    return truth


def _tolerance_of(res) -> float:
    """The tolerance a run was asked to meet (0: none): rung auto's, or fidelity.tolerance."""
    if res.auto is not None:
        return res.auto.tolerance_m
    return res.chain.fidelity.tolerance or 0.0


def _escalate(scene, T, progress, first: SimResult) -> SimResult:
    """Rung auto whose check (the top rung over the whole run) shows its tolerance not met:
    the model-form error of the floating-frame rungs, which the linearized analysis cannot
    see. The run again on the rod with 3, 4, … coordinates per beam, fewer than the
    reference's terms: for each count first the lowest modes of the reference's rod
    (fidelity.rod_modes, on as many Gauss points as the Legendre rod of that count: the
    check after the run holds the quadrature too; the better basis where the beams bend
    little: two_link_free), then the Legendre rod of that many terms (where they bend
    far: spin_up) — the first whose check meets the tolerance in the bound measures; else
    the last tried, said not met."""
    from flexarm_ros.model.rod import gauss_points
    truth = _truth()
    tol = first.auto.tolerance_m
    metric = scene.fidelity.tolerance_metric
    tried = [(first.auto.label, first.truth.estimate)]
    res = first
    top = int(first.truth.reference.split()[-1])
    candidates = []
    for n in range(3, top):
        candidates.append((f"rod {top} (lowest {n} modes)",
                           dict(refine=top, rod_modes=n, rod_points=gauss_points(n))))
        candidates.append((f"rod {n}", dict(refine=n)))
    for label, over in candidates:
        sc = scene.with_fidelity(rung="rod", dt=0.0, tolerance=0.0, **over)
        try:
            res = _simulate(sc, T, progress, None)
        except InputError:
            continue
        res.truth = truth.top_check(scene, res.columns, T, tol, _simulate)
        if not res.truth.ok:
            break
        if all(res.truth.met(tol, metric).values()):
            break
        tried.append((label, res.truth.estimate))
    res.auto = first.auto
    res.escalated = tried
    return res


def _simulate(scene, T, progress=None, chain=None) -> SimResult:
    """:func:`simulate` without the check against the top rung."""
    auto = None
    if chain is not None and chain.auto is not None:
        scene, auto = chain.scene, chain.auto
    elif scene.fidelity.rung == "auto":         # the model and step for this run's length
        from flexarm_ros.model.autofidelity import resolve
        scene, auto = resolve(scene, T, output_period(scene))
    chain = chain or Chain(scene)
    fid = scene.fidelity
    if fid.output_dt > T:
        raise SceneError(f"fidelity.output_dt: got {fid.output_dt} s, expected at most the "
                         f"run's duration {T:g} s (the output would hold the start sample "
                         f"only)")
    q_init = initial_state(chain)[0]
    x0 = initial_x(chain)
    sensors = build_sensors(chain)
    out_dt = fid.output_dt
    if sensors:
        grid_ns = sample_grid_ns([fid.output_dt] + [1.0 / s.spec.rate_hz for s in sensors])
        if grid_ns < 1000:
            raise SceneError(
                f"sensors: the sample periods and fidelity.output_dt share no common grid "
                f"coarser than 1 µs (got {grid_ns} ns), expected rates whose periods are "
                f"multiples of a common step (e.g. 4000, 1000 and 250 Hz)")
        out_dt = grid_ns * 1e-9
    check_output(T, fid.output_dt, out_dt, chain)
    contact = build_contact(chain)
    choice = _step_for_tolerance(chain, contact, x0, T, out_dt) if fid.tolerance else None
    if choice is None and fid.dt == 0 and trapezoid_step_by_error(chain):
        choice = _trapezoid_automatic_step(chain, T, out_dt)
    assessed = None
    # rung auto estimates anyway; lawson4's estimate is the check against the top rung
    # alone (simulate): the a-priori analysis follows RK4's and RKN4's steps
    if fid.estimate and auto is None and fid.integrator != "lawson4":
        from flexarm_ros.model.autofidelity import assess
        assessed = assess(scene.with_fidelity(dt=choice.step_s) if choice else scene, T,
                          out_dt)
    if contact is None:
        run = integrate(chain, x0, T, fid.integrator, choice.step_s if choice else fid.dt,
                        fid.rtol, fid.atol, out_dt, fid.max_deflection_ratio, progress)
        crun = None
    else:
        acc = None
        if chain.backend == "numba" and any(s.spec.kind == "accelerometer" for s in sensors):
            from flexarm_ros.model.compiled import sensors as ksensors
            acc = ksensors.pack(chain, sensors)[1:]
        run, crun = integrate_with_contact(chain, contact, x0, T, out_dt, progress, acc,
                                           dt=choice.step_s if choice else None)
    tables = (sensor_tables(chain, run, sensors, q_init, crun.qdd if crun else None,
                            crun.acc if crun else None) if sensors else {})
    every = int(round(fid.output_dt / out_dt))
    if every != 1:
        run = _decimate(run, every)
    cols = output_columns(chain, run)
    if crun is not None:
        cols.update(contact_columns(crun, every))
    check = None
    if (auto is not None or assessed is not None) and contact is not None:
        # with a wall the top rung's check does not run (sim/truth.WALL_NOTE): the check
        # within the model's class, a finer model over the whole run, impacts included
        from flexarm_ros.sim.accuracy import posterior_check
        check = posterior_check(scene, auto or assessed, cols, run.dt, T)
    return SimResult(scene.name, chain, run, cols, tables, crun, choice, auto, check,
                     assessed)


def _step_for_tolerance(chain, contact, x0, T, out_dt):
    """fidelity.tolerance → the step of RK4 or of the contact stepper
    (:mod:`flexarm_ros.sim.accuracy`), or a SceneError where the estimate does not apply."""
    from flexarm_ros.sim.accuracy import step_for_tolerance
    check_tolerance_applies(chain, contact)
    fid = chain.fidelity
    tol = fid.tolerance
    if fid.integrator == "trapezoid":
        from flexarm_ros.sim.accuracy import trapezoid_step_for_tolerance
        return trapezoid_step_for_tolerance(chain, T, tol, out_dt)
    return step_for_tolerance(chain, x0, T, tol, out_dt, fid.max_deflection_ratio, contact)


def _trapezoid_automatic_step(chain, T, out_dt):
    """The trapezoidal rule's automatic step (fidelity.dt 0, no tolerance): chosen by its
    error estimate on the linearized model for rung auto's default tip tolerance
    (:func:`~flexarm_ros.sim.accuracy.trapezoid_step_for_tolerance`), not the output
    period, which had missed seed 001's link by more than its signal (the issue's 3.7e-4
    m for a 2.9e-4 m peak on FEM 8 and 16). The step still divides the output period: the
    nonlinear rule diverged above 1 ms on the seed 001 links (docs/accuracy.md). None
    (the output period) where no such step exists within TRAPEZOID_MAX_PER per interval."""
    import dataclasses

    from flexarm_ros.model.autofidelity import DEFAULT_TOLERANCE_M
    from flexarm_ros.sim.accuracy import trapezoid_step_for_tolerance
    try:
        choice = trapezoid_step_for_tolerance(chain, T, DEFAULT_TOLERANCE_M, out_dt)
    except InputError:
        return None
    return dataclasses.replace(choice, source="default")


def check_tolerance_applies(chain, contact) -> None:
    """SceneError (one line: key, value, expectation) where fidelity.tolerance cannot choose
    this model's step: with an adaptive integrator, the trapezoid with a wall, backlash,
    together with fidelity.dt, or a bound outside (MIN_TOLERANCE_M, ∞). ``flexarm
    explain`` asks the same before it describes the choice."""
    from flexarm_ros.sim.accuracy import check_tolerance
    fid = chain.fidelity
    tol = fid.tolerance
    check_tolerance(tol, "the estimate is round-off")
    if fid.integrator == "lawson4":
        raise SceneError(f"fidelity.tolerance: got {tol:g} m with integrator 'lawson4' "
                         f"(the seed 001 scenes' default), expected integrator rk4, rkn4 "
                         f"or trapezoid: lawson4 steps at the output period (or a --dt "
                         f"dividing it) with no step chosen for a tolerance; add "
                         f"--integrator rk4, or see its error against the geometrically "
                         f"exact rung with --estimate")
    if fid.integrator not in ("rk4", "rkn4", "trapezoid"):
        raise SceneError(f"fidelity.tolerance: got {tol:g} m with integrator "
                         f"{fid.integrator!r}, expected integrator rk4, rkn4 or trapezoid "
                         f"(the adaptive integrators take --rtol/--atol)")
    if fid.integrator == "trapezoid" and contact is not None:
        raise SceneError(f"fidelity.tolerance: got {tol:g} m with integrator 'trapezoid' "
                         f"and a wall, expected integrator rk4 (the contact stepper is RK4's)")
    if chain.backlash:
        k = next(i for i, lk in enumerate(chain.scene.links) if lk.joint.backlash is not None)
        raise SceneError(f"fidelity.tolerance: got {tol:g} m for a model with backlash "
                         f"(links[{k}].joint.backlash), expected 0: a dead zone stepped over "
                         f"makes the error irregular in the step (two_link_case3_backlash, "
                         f"1 s: 1.4e-6, 3.1e-7, 4.3e-7 m at 250, 125, 83 µs), so no "
                         f"step-halving estimate holds; set --dt (docs/accuracy.md)")
    if fid.dt > 0:
        raise SceneError(f"fidelity.tolerance: got {tol:g} m together with fidelity.dt = "
                         f"{fid.dt:g} s, expected one of them (the tolerance chooses the step)")


def contact_columns(crun, every: int = 1) -> dict:
    """contact_phase (free/impact/sliding/sticking), gap (m), contact_normal_force and
    contact_friction_force (N), contact_normal_impulse (cumulative N·s, impacts included),
    tool_x/tool_y (m), tool_vx/tool_vy (m/s). A sample is
    'impact' when an impact happened in the output interval before it."""
    sl = slice(None, None, every)
    ph = crun.phase.copy()
    if every > 1:   # keep an impact visible on the decimated grid
        hits = np.nonzero(ph == PHASE_CODE["impact"])[0]
        ph[np.minimum(((hits + every - 1) // every) * every, len(ph) - 1)] = PHASE_CODE[
            "impact"]
    return {"contact_phase": np.array(PHASES, dtype=object)[ph[sl]],
            "gap": crun.gap[sl], "contact_normal_force": crun.normal_force[sl],
            "contact_friction_force": crun.friction_force[sl],
            "contact_normal_impulse": crun.normal_impulse[sl],
            "tool_x": crun.tool[sl, 0], "tool_y": crun.tool[sl, 1],
            "tool_vx": crun.tool_velocity[sl, 0], "tool_vy": crun.tool_velocity[sl, 1]}


def _decimate(run: Integration, every: int) -> Integration:
    """The run's samples at every ``every``-th output time."""
    return dataclasses.replace(run, t=run.t[::every], q=run.q[::every], qd=run.qd[::every],
                               z=run.z[::every])


def output_columns(chain: Chain, run: Integration, actuators: bool = True) -> dict:
    """Named columns: t, every coordinate and rate, tip_x/tip_y, tip deflections, energy,
    and (``actuators``) the drives' columns from the input programs
    (:func:`actuator_columns`)."""
    cols = {"t": run.t}
    for j, name in enumerate(chain.names):
        cols[name] = run.q[:, j]
    for j, name in enumerate(chain.names):
        cols[f"{name}_rate"] = run.qd[:, j]
    energy, tip = chain.energies(run.t, run.q, run.qd, run.z)
    cols["tip_x"], cols["tip_y"] = tip[:, 0], tip[:, 1]
    for lm in chain.links:   # w(L): φ(L)ᵀη, or the rod's exact tip in its hub frame
        cols[f"{lm.name}_tip_deflection"] = lm.beam.tip_deflections(run.q[:, lm.eta])
    cols["energy"] = energy
    if actuators:
        cols.update(actuator_columns(chain, run))
    return cols


def actuator_columns(chain: Chain, run: Integration) -> dict:
    """Per actuator: the program input (``<link>_torque_cmd`` N·m, ``<link>_voltage`` V or
    ``<link>_valve_current`` A, after saturation/bias as applied), the output torque
    ``<link>_drive_torque`` (N·m) and the state (``<link>_current`` A / ``<link>_pressure``
    Pa; a quasi-static motor's current is reported too)."""
    cols = {}
    u = chain.actuator_input_series(run.t)
    for j, a in enumerate(chain.actuators):
        name = chain.links[a.link].name
        w = run.qd[:, a.coord]
        z = run.z[:, a.state] if a.state >= 0 else np.zeros(len(run.t))
        uj = np.ascontiguousarray(u[:, j])
        current, torque = np.empty(len(uj)), np.empty(len(uj))
        drives.drive_columns(a.kind, a.par, uj, np.ascontiguousarray(w, float),
                             np.ascontiguousarray(z, float), current, torque)
        if a.kind == drives.IDEAL:
            cols[f"{name}_torque_cmd"] = uj
        elif a.kind == drives.HYDRAULIC:
            cols[f"{name}_valve_current"] = uj + a.par[drives.HYD_VALVE_BIAS]
            cols[f"{name}_pressure"] = np.clip(z, *drives.state_bounds(a.kind, a.par))
        else:
            v_max = a.par[drives.DC_SUPPLY_VOLTAGE]
            cols[f"{name}_voltage"] = np.clip(uj, -v_max, v_max)
            cols[f"{name}_current"] = current
        cols[f"{name}_drive_torque"] = torque
    return cols
