"""``flexarm explain``: the model that was built from a scene, and what was left out."""

from __future__ import annotations

import numpy as np

from flexarm_ros.model.chain import Chain
from flexarm_ros.model.linear import natural_modes
from flexarm_ros.model.rod import kept_modes


def _tolerance_method(chain, state) -> str:
    """How ``--tolerance`` will choose this model's step (sim/accuracy.py); ``state``: the
    initial (q, q̇, z)."""
    if chain.fidelity.integrator == "trapezoid":
        return ("by the linearized model stepped by the rule against its exact response "
                "(a divisor of the output period)")
    if chain.scene.walls:
        return ("by the contact stepper's pilot runs over the whole run, never above its "
                "automatic contact step")
    from flexarm_ros.model.linear import ABOVE_STABLE_SHARE
    from flexarm_ros.model.explicit import explicit_integrator, stability
    integrator = explicit_integrator(chain.fidelity)
    rate, limit, auto = stability(chain, *state, integrator)
    if not rate > 0:
        return "by step-halving pilot runs"
    return (f"by step-halving pilot runs up to the stable step {auto:.4g} s, "
            f"and above it (up to {ABOVE_STABLE_SHARE * limit:.4g} s, "
            f"{ABOVE_STABLE_SHARE:g} of {integrator.upper()}'s stability limit) only where "
            f"a pilot run at that step meets the tolerance")


def _trapezoid_note(chain) -> str:
    """How the trapezoid's automatic step is chosen (sim.simulate), where it applies."""
    from flexarm_ros.model.linear import trapezoid_step_by_error
    if not trapezoid_step_by_error(chain):
        return ""
    from flexarm_ros.model.autofidelity import DEFAULT_TOLERANCE_M
    return (f" (chosen for the default tip tolerance {DEFAULT_TOLERANCE_M:g} m by the "
            f"linearized model, among the divisors of the output period)")


def explain(scene, chain=None) -> str:
    """A human-readable account of the model: coordinates, rung, forces kept and omitted
    (``chain``: the scene's model when the caller has built it)."""
    from flexarm_ros.model.statics import initial_state
    if chain is None:
        chain = Chain(scene)        # rung auto: the choice over the scene's duration
    state = initial_state(chain)    # (q, q̇, z); sets a hydraulic drive's null bias
    fid = chain.fidelity
    lines = [f"scene {scene.name}: {scene.description.strip()}".rstrip(": "),
             f"rung {fid.rung} (refine {chain.links[0].beam.refine}"
             + (": the rung's default, as fidelity.refine is 0" if fid.refine == 0 else "")
             + (f"; {fid.modal_basis} modes" if fid.rung == "modal" else "")
             + (f"; its lowest {fid.rod_modes} bending modes" if fid.rung == "rod"
                and kept_modes(fid.rod_modes, chain.links[0].beam.refine)
                < chain.links[0].beam.refine else "")
             + (f"; {fid.rod_points} Gauss points" if fid.rung == "rod" and fid.rod_points
                else "")
             + "), integrator "
             f"{fid.integrator}" + (f", dt {fid.dt:.4g} s" if fid.dt else
                                    f", the step chosen for a tip tolerance of "
                                    f"{fid.tolerance:g} m when the run starts "
                                    + _tolerance_method(chain, state)
                                    + " (flexarm simulate; its --json names the step and "
                                    "the estimate)"
                                    if fid.tolerance and chain.auto is None else
                                    ", automatic step" + _trapezoid_note(chain))
             + (" — chosen by rung auto" if chain.auto is not None else "")]
    if chain.auto is not None:
        lines.extend(chain.auto.explain().splitlines())
    if scene.walls and fid.integrator != "rk4":
        lines.append(f"integrator {fid.integrator} with a wall: flexarm simulate refuses it "
                     f"(the contact stepper steps RK4), flexarm run's plant steps rk4")
    elif fid.integrator not in ("rk4", "rkn4"):
        lines.append(f"integrator {fid.integrator}: batch runs only; flexarm run's plant "
                     f"steps rk4")
    lines.append(f"{chain.n} generalized coordinates:")
    for lm in chain.links:
        b = lm.beam
        idx = np.arange(chain.n)
        coords = [chain.names[i] for i in idx[lm.eta]]
        lines.append(f"  {lm.name}: joint {chain.names[lm.i_joint]}"
                     + (f", motor {chain.names[lm.i_motor]}" if lm.i_motor >= 0 else "")
                     + f"; beam L = {b.length} m, {b.n} elastic coordinate(s) "
                       f"[{', '.join(coords[:6])}{', …' if len(coords) > 6 else ''}], "
                       f"{len(b.x)} mass points")
        sheet = lm.link.beam.datasheet()
        if sheet:
            lines.append(f"    beam from the datasheet: {sheet}")
        drive = lm.link.joint.drive
        if drive is not None and drive.type == "dc_motor" and (
                drive.rotor_inertia or drive.gear_efficiency):
            jt = lm.link.joint
            parts = []
            if drive.rotor_inertia:
                parts.append(f"rotor J_m {drive.rotor_inertia:.4g} kg·m² → n²·J_m "
                             f"{drive.reflected_rotor_inertia:.4g} kg·m² + drive_inertia "
                             f"{jt.drive_inertia:.4g} = {jt.total_drive_inertia:.4g} kg·m² on "
                             f"the drive coordinate")
            if drive.gear_efficiency:
                parts.append(f"gear efficiency {drive.gear_efficiency:g} → output torque "
                             f"{drive.gear_ratio * drive.output_torque_constant:.4g} N·m/A "
                             f"(η·n·K_t)")
            lines.append(f"    drive from the datasheet: {'; '.join(parts)}")
    kept, omitted = [], []
    (kept if chain.has_gravity else omitted).append(
        "gravity" + (f" {tuple(scene.gravity)} m/s²" if chain.has_gravity else
                     " (horizontal plane: gravity vector is zero)"))
    (kept if fid.foreshortening else omitted).append(
        "foreshortening / geometric stiffening" + ("" if fid.foreshortening else
                                                   " (switched off: linear floating frame)"))
    flex = [lm.name for lm in chain.links if lm.link.joint.flexibility is not None]
    (kept if flex else omitted).append(
        f"joint flexibility ({', '.join(flex)})" if flex else
        "joint flexibility (no joint declares it)")
    bl = [f"{lm.name} {lm.link.joint.backlash.width:g} rad" for lm in chain.links
          if lm.link.joint.backlash is not None]
    (kept if bl else omitted).append(
        f"backlash ({', '.join(bl)}; motor-side coordinate)" if bl else
        "backlash (no joint declares it: no motor-side coordinate)")
    damped = bool(np.any(chain.D))
    (kept if damped else omitted).append("damping" if damped else "damping (none declared)")
    presc = [chain.names[i] for i in chain.presc_idx]
    if presc:
        kept.append(f"prescribed motion of {', '.join(presc)} (not integrated)")
    for a in chain.actuators:
        lm = chain.links[a.link]
        drive = lm.link.joint.drive
        if drive is None:
            kept.append(f"torque program on {chain.names[a.coord]}")
        elif drive.type == "dc_motor":
            L, R = drive.inductance or 0.0, drive.resistance
            how = (f"current integrated as a state, L/R = {L / R * 1e3:.3g} ms"
                   if a.state >= 0 else
                   "current quasi-static" + (f" (L/R = {L / R * 1e3:.3g} ms neglected)"
                                             if L > 0 else " (no inductance given)"))
            kept.append(f"DC motor on {chain.names[a.coord]} (ratio {drive.gear_ratio:g}, "
                        f"{how}; voltage program)")
        else:
            kept.append(f"hydraulic servovalve + actuator on {chain.names[a.coord]} (load "
                        f"pressure a state; valve current program)")
    if not chain.actuators:
        omitted.append("drives (no joint declares one)")
    if scene.walls:
        for k, w in enumerate(scene.walls):
            kept.append(f"wall walls[{k}] (point {list(w.point)} m, normal {list(w.normal)}): "
                        f"{scene.fidelity.contact} contact, Coulomb friction "
                        f"{w.friction:g}; events (impact, stick/slip, separation) located "
                        f"inside RK4 steps of half the stable step, samples interpolated "
                        f"within steps")
    else:
        omitted.append("contact (no wall in this scene)")
    if len(chain.bearing_idx):
        for k, j, ja in chain.bearing_idx:
            br = next(b for b in scene.bearings
                      if b.link == chain.links[k].name and b.body == ("hub", "tip")[j])
            kept.append(f"air bearing under {br.link} {br.body} on the table: regularized "
                        f"Coulomb friction μ {br.friction:g} (v_s {br.slip_velocity:g} m/s)"
                        + (f", {len(br.high_spots)} high spot(s)" if br.high_spots else "")
                        + (f", binding {br.binding:g} 1/m on the housed drive's torque"
                           if ja >= 0 else ""))
    else:
        omitted.append("air-bearing friction (no bearings: the bodies float free on the "
                       "table)")
    if scene.sensors:
        kept.append("sensors: " + ", ".join(f"{s.name} ({s.kind}, {s.rate_hz:g} Hz)"
                                             for s in scene.sensors))
    else:
        omitted.append("sensors (none declared)")
    lines.append("modelled: " + "; ".join(kept))
    lines.append("left out: " + "; ".join(omitted))
    m = natural_modes(chain, state[0], joints="locked")
    f = ", ".join(f"{v:.4g}" for v in m.frequencies_hz[:4])
    where = " at the static deflection" if scene.initial.static_equilibrium else ""
    sets = ("sets the explicit step's stability limit; the scene fixes the step"
            if scene.fidelity.dt > 0 else "sets the explicit step")
    lines.append(f"first frequencies{where}, drives locked: {f} Hz (highest "
                 f"{m.frequencies_hz[-1]:.4g} Hz {sets})")
    from flexarm_ros.model.limits import joint_limits
    ctl = scene.twin_control
    lines.append(f"ROS twin: control every {1e3 / ctl.rate_hz:.4g} ms "
                 f"({ctl.rate_hz:.6g} Hz), efforts held over it; commands older "
                 f"than {ctl.watchdog_s:g} s trip the driver to 0 "
                 f"(V, N·m; a servovalve to closed)")
    lines.append(_loop_line(scene))
    lines.append("wire limits (ROS twin: commands and efforts beyond them are rejected):")
    lines.extend(f"  {lim.text()}" for lim in joint_limits(scene))
    from flexarm_ros.model import drives
    for a in chain.actuators:
        if a.kind == drives.HYDRAULIC:
            bias = a.par[drives.HYD_VALVE_BIAS]
            lines.append(f"  {chain.links[a.link].name}: the wire carries the valve current "
                         f"minus the null bias I0 = {bias * 1e3:.4g} mA (0 holds the start; "
                         f"a closed valve is {-bias:.4g} A; positive current turns the joint "
                         f"positive); the simulate CSV's {chain.links[a.link].name}"
                         f"_valve_current includes I0")
    for a in scene.assumptions:
        lines.append(f"assumption {a.key}: {a.note}")
    return "\n".join(lines)


def _loop_line(scene) -> str:
    """How the batch commands run the scene: its controller in the loop (with its gains and
    targets) or its input programs alone."""
    ctl = scene.control
    if ctl is None:
        return ("batch runs (simulate, sweep, calibrate, ...): the input programs, applied "
                "continuously (no control section)")
    head = (f"batch runs (simulate, sweep, calibrate, ...): the controller in the loop, "
            f"control.mode {ctl.mode} at {ctl.rate_hz:.6g} Hz (--open-loop: the programs "
            f"alone)")
    if ctl.mode == "open_loop":
        return head + "; it sends the input programs sampled at its rate"
    parts = [f"kp {list(ctl.kp)} N·m/rad", f"kd {list(ctl.kd)} N·m·s/rad",
             f"rate filter {ctl.velocity_filter_hz:g} Hz"]
    if ctl.tip_target is not None:
        parts.append(f"tool target {list(ctl.tip_target)} m")
    if ctl.joint_target:
        parts.append(f"joint targets {list(ctl.joint_target)} rad")
    if ctl.mode == "sanding" and ctl.sanding is not None:
        parts.append(f"sanding force {ctl.sanding.normal_force:g} N along x = "
                     f"{ctl.sanding.wall_x:g} m")
    return head + ": " + ", ".join(parts)
