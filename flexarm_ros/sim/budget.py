"""The work budget: no run silently takes forever.

Before a fixed-step integration (RK4, the trapezoidal rule, the contact stepper, the
twin's plant) :func:`check_work` estimates its steps, duration / step, and refuses a run
that needs more than ``fidelity.max_steps`` (default 1e8; ``--max-steps``) with a
:class:`~flexarm_ros.errors.WorkTooLarge` (a SceneError: exit 2) that says what sets the
step and what to change:

* a fixed step given by the user (``fidelity.dt`` / ``--dt``) or a tiny output period;
* else the eigenvalue of largest |λ| of the linearized first-order system, the coordinate
  with the largest participation factor |wᵢvᵢ| in it (left and right eigenvectors:
  ``link1_y10``, ``link1_current``…; the right eigenvector alone blames link 1 for a damper
  on joint 2, whose mode it spreads over M⁻¹e₂) and the scene keys of that coordinate
  with their values (a beam's length, EI, mass per length and damping; a joint's drive
  inertia, gear ratio…; a motor's L, R, K_b, K_t), so the culprit of a collapsed step
  (``mass_per_length: 1e-12``, damping 1e12, ``inductance: 1e-12``) is named;
* with a wall: the arm held on the wall (impulse contact) when that sets the step.

Integrators whose step is not known before (the adaptive solve_ivp methods, the compliant
contact) are watched as they go by :class:`Pace`: every :data:`WINDOW` steps the steps
still needed at the pace of the last window are projected, and a run whose projection
exceeds the budget stops with the same explanation at its current state.
"""

from __future__ import annotations

import math
import time

import numpy as np

from flexarm_ros.errors import WorkTooLarge

#: steps between two projections of an adaptive or contact run's pace
WINDOW = 1000
#: samples a batch run may hold in memory (output grid, sensor grid)
MAX_OUTPUT_SAMPLES = 10_000_000


def check_output(duration, output_dt, grid_dt, chain) -> None:
    """Refuse a run whose output (or sensor) grid would hold more than
    :data:`MAX_OUTPUT_SAMPLES` samples (``grid_dt``: the common grid of the output period
    and the sensor periods)."""
    n = duration / grid_dt
    if n <= MAX_OUTPUT_SAMPLES:
        return
    if grid_dt < output_dt * (1 - 1e-9):
        rates = ", ".join(f"sensors[{k}].rate_hz = {s.rate_hz:g}"
                          for k, s in enumerate(chain.scene.sensors))
        raise WorkTooLarge(
            f"sensors: the sample grid {grid_dt:.3g} s common to fidelity.output_dt = "
            f"{output_dt:g} s and {rates} needs {n:.3g} samples over the duration "
            f"{duration:g} s, "
            f"expected at most {MAX_OUTPUT_SAMPLES:.3g}: choose rates whose periods share a "
            f"coarser grid, or a shorter duration")
    raise WorkTooLarge(
        f"fidelity.output_dt: got {output_dt:g} s, {n:.3g} samples over the duration "
        f"{duration:g} s, "
        f"expected at most {MAX_OUTPUT_SAMPLES:.3g} samples in a run: a larger output_dt or "
        f"a shorter duration")


def check_work(chain, x0, h, duration, integrator="rk4", contact=None) -> None:
    """Refuse (WorkTooLarge) a fixed-step run of ``duration`` s at step ``h`` s that needs
    more than ``chain.fidelity.max_steps`` steps. ``contact``: the scene's wall contact
    (its held-arm rate may be what set ``h``). An endless run (duration inf) is not
    checked (it runs until stopped, with progress)."""
    max_steps = chain.fidelity.max_steps
    if not math.isfinite(duration) or not h > 0:
        return
    steps = duration / h
    if steps <= max_steps:
        return
    raise WorkTooLarge(
        f"fidelity.max_steps: the run needs {steps:.3g} {integrator} steps (duration "
        f"{duration:g} s / step {h:.3g} s), expected at most {max_steps:.3g}. "
        + why_step(chain, x0, h, integrator, contact)
        + " (or raise fidelity.max_steps / --max-steps to run it anyway)")


#: where a fixed-step run predicted to take long says so as it starts (None: silent, the
#: library's default and the ensemble workers'; ``flexarm simulate`` sets its stderr, with
#: or without --quiet)
FORECAST_STREAM = None
#: wall seconds above which the forecast is said
FORECAST_S = 60.0
#: steps of the first compiled call, which times the run's pace
FORECAST_STEPS = 1000


class Forecast:
    """``update(steps_done)`` after each compiled call of a fixed-step run of
    ``total_steps``: the first call that took a measurable time (>= 20 ms, or the whole
    run) sets the pace; a run whose steps at that pace need more than :data:`FORECAST_S`
    says so once on :data:`FORECAST_STREAM` (steps, estimated time) — before a run of
    minutes goes silent under --quiet. Costs one clock read per compiled call."""

    def __init__(self, total_steps: float, integrator: str, h: float, duration: float):
        self.total, self.integrator, self.h, self.duration = total_steps, integrator, h, \
            duration
        self.t0 = time.perf_counter()
        self.done = FORECAST_STREAM is None or not math.isfinite(total_steps)

    def update(self, steps: int) -> None:
        if self.done or steps <= 0:
            return
        wall = time.perf_counter() - self.t0
        if wall < 0.02 and steps < self.total:
            return
        self.done = True
        estimate = wall / steps * self.total
        if estimate > FORECAST_S:
            print(f"flexarm: this run needs {self.total:.3g} {self.integrator} steps "
                  f"(duration {self.duration:g} s / step {self.h:.3g} s), about "
                  f"{_duration_text(estimate)} at the pace of its first {steps} steps; "
                  f"Ctrl-C stops it (exit 130)", file=FORECAST_STREAM, flush=True)


def _duration_text(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


class Pace:
    """The budget of a run whose steps are not known in advance: call :meth:`check`
    after each step with the step count and the time reached."""

    def __init__(self, chain, t_end, integrator, t0=0.0, explain=None):
        self.chain = chain
        self.t_end = t_end
        self.integrator = integrator
        self.max_steps = chain.fidelity.max_steps
        self.window = max(1, min(WINDOW, int(self.max_steps // 10)))
        self.mark = (0, t0)
        self.explain = explain

    def check(self, steps, t, x) -> None:
        if steps - self.mark[0] < self.window and steps <= self.max_steps:
            return
        s0, t0 = self.mark
        span = t - t0
        rate = (steps - s0) / span if span > 0 else math.inf
        projected = steps + max(self.t_end - t, 0.0) * rate
        self.mark = (steps, t)
        if projected <= self.max_steps and steps <= self.max_steps:
            return
        mean = span / (steps - s0) if steps > s0 else 0.0
        why = (self.explain(t, x) if self.explain is not None else
               why_step(self.chain, x, mean, self.integrator, None, adaptive=True))
        raise WorkTooLarge(
            f"fidelity.max_steps: the {self.integrator} run has taken {steps} steps to "
            f"t = {t:.6g} s of {self.t_end:g} s; at its pace over the last {steps - s0} "
            f"(mean step {mean:.3g} s) it needs ~{projected:.3g}, expected at most "
            f"{self.max_steps:.3g}. " + why
            + " (or raise fidelity.max_steps / --max-steps to run it anyway)")


# ---------------------------------------------------------------------------- the cause
def why_step(chain, x0, h, integrator, contact=None, adaptive=False) -> str:
    """One sentence: what sets the step ``h`` and what to change."""
    fid = chain.fidelity
    if not adaptive and fid.dt > 0 and h <= fid.dt * (1 + 1e-9):
        return (f"The step is the fixed fidelity.dt = {fid.dt:g} s (--dt). To fix: a larger "
                f"--dt, or --dt 0 for the automatic step")
    if not adaptive and h >= fid.output_dt * (1 - 1e-9):
        return (f"The step is the output period fidelity.output_dt = {fid.output_dt:g} s. "
                f"To fix: a larger fidelity.output_dt")
    lam, label, kind = dominant_eigenvalue(chain, x0)
    if contact is not None and contact.method == "impulse":
        from flexarm_ros.model.contact import constrained_rate
        held = constrained_rate(contact, x0)
        if held > 1.01 * abs(lam):
            sc = chain.scene
            angles = ", ".join(
                f"links[{k}].joint.initial_angle"
                + (f"_deg = {lk.joint.initial_angle_deg:g} deg"
                   if lk.joint.initial_angle_deg is not None
                   else f" = {lk.joint.initial_angle:g} rad") for k, lk in enumerate(sc.links))
            if any(sc.gravity):
                angles += f"; gravity = {list(sc.gravity)} m/s²"
            # the tip bodies by key and value: a tiny mass or inertia there makes the
            # held arm's highest rate huge (fuzzing found 1e-12 kg; the message named no key)
            tips = ", ".join(f"links[{k}].tip.mass = {lk.tip.mass:g} kg, links[{k}].tip."
                             f"inertia = {lk.tip.inertia:g} kg·m²"
                             for k, lk in enumerate(sc.links))
            return (f"The step is set by the arm held on the wall (walls[0]) in its start "
                    f"configuration ({angles}): its highest rate {held:.3g} 1/s "
                    f"({held / (2 * math.pi):.3g} Hz) with the tool at tool.position = "
                    f"{list(sc.tool.position)} m. To fix: check the start configuration "
                    f"(an arm pointing straight at the wall is stiff along its axis), "
                    f"tool.position and the tip bodies ({tips}), or fidelity.contact: "
                    f"compliant")
    what = describe_coordinate(chain, label, kind)
    return (f"The step is set by the eigenvalue λ = {_fmt_complex(lam)} 1/s (|λ| = "
            f"{abs(lam):.3g} 1/s, {abs(lam) / (2 * math.pi):.3g} Hz) of the linearized "
            f"model, in which {label} takes the largest part ({what}). To fix: "
            + _fix(chain, kind, integrator))


def _fmt_complex(lam) -> str:
    if abs(lam.imag) <= 1e-9 * abs(lam):
        return f"{lam.real:.3g}"
    return f"{lam.real:.3g} ± {abs(lam.imag):.3g}j"


def _jacobian(chain, x0) -> np.ndarray:
    """∂ẋ/∂x at (t = 0, x0) by central differences of the right-hand side."""
    J = np.zeros((len(x0), len(x0)))
    for j in range(len(x0)):
        dx = 1e-6 * max(1.0, abs(x0[j]))
        if chain.backlash:      # stay on one side of the dead zone's kink
            dx = min(dx, 1e-9)
        xp, xm = x0.copy(), x0.copy()
        xp[j] += dx
        xm[j] -= dx
        J[:, j] = (chain.rhs(0.0, xp) - chain.rhs(0.0, xm)) / (2 * dx)
    return J


def dominant_eigenvalue(chain, x0):
    """(λ, state label, kind) of the eigenvalue of largest |λ| of the linearized system
    at x0 (with backlash also with the mesh engaged on either side, where the stiffest
    coupling hides): kind is "coordinate" or "actuator"; the label is the coordinate
    (``link1_y10``) or actuator state (``link1_current``) with the largest participation
    factor |wᵢvᵢ| in the mode (left and right eigenvectors; a coordinate's q and q̇
    together)."""
    free = chain.free
    nf = len(free)
    x0 = np.array(x0, float)
    states = [x0]
    q0, _ = chain.full_state(0.0, x0)
    for im, ij, b, _k, _c in chain.backlash:
        for sign in (1.0, -1.0):
            q = q0.copy()
            q[im] = q0[ij] + sign * (b + 1e-6 * max(b, 1e-3))
            x = x0.copy()
            x[:nf] = q[free]
            states.append(x)
    import scipy.linalg       # lazily: start-up time of runs that never need it
    best = None
    for x in states:
        w, WL, VR = scipy.linalg.eig(_jacobian(chain, x), left=True, right=True)
        k = int(np.argmax(np.abs(w)))
        if best is None or abs(w[k]) > abs(best[0]):
            best = (w[k], WL[:, k], VR[:, k])
    lam, left, right = best
    # participation factors |w_i v_i|: how much state i takes part in the mode (scale
    # free: a damper on a relative joint angle gives a right eigenvector spread over the
    # coupled coordinates, but its left eigenvector sits on the damped one)
    p = np.abs(np.conj(left) * right)
    score_q = p[:nf] + p[nf:2 * nf]
    score_z = p[2 * nf:]
    if score_z.size and score_z.max() > score_q.max():
        return lam, chain.state_names[int(np.argmax(score_z))], "actuator"
    return lam, chain.names[free[int(np.argmax(score_q))]], "coordinate"


def describe_coordinate(chain, label, kind) -> str:
    """The scene keys behind a coordinate or actuator state, with their values."""
    if kind == "actuator":
        j = list(chain.state_names).index(label)
        act = next(a for a in chain.actuators if a.state == j)
        k = act.link
        d = chain.scene.links[k].joint.drive
        where = f"links[{k}].joint.drive"
        if d.type == "dc_motor":
            tau = d.inductance / d.resistance
            return (f"armature current of {chain.links[k].name}'s dc_motor: {where}.inductance "
                    f"= {d.inductance:g} H, {where}.resistance = {d.resistance:g} Ω, L/R = "
                    f"{tau:.3g} s; {where}.gear_ratio = {d.gear_ratio:g}, "
                    f"{where}.back_emf_constant = {d.back_emf_constant:g} V·s/rad, "
                    f"{where}.torque_constant = {d.torque_constant:g} N·m/A")
        return (f"load pressure of {chain.links[k].name}'s hydraulic actuator: "
                f"{where}.bulk_modulus = {d.bulk_modulus:g} Pa, {where}.total_volume = "
                f"{d.total_volume:g} m³, {where}.displacement = {d.displacement:g} m³/rad, "
                f"{where}.leakage = {d.leakage or 0.0:g} m³/(s·Pa)")
    i = chain.names.index(label)
    for k, lm in enumerate(chain.links):
        lk = chain.scene.links[k]
        if i == lm.i_joint or i == lm.i_motor:
            jt = lk.joint
            parts = [f"links[{k}].joint.drive_inertia = {jt.drive_inertia:g} kg·m²",
                     f"links[{k}].joint.drive_damping = {jt.drive_damping:g} N·m·s/rad",
                     f"links[{k}].hub.inertia = {lk.hub.inertia:g} kg·m²"]
            if jt.flexibility is not None:
                f = jt.flexibility
                parts += [f"links[{k}].joint.flexibility.stiffness = {f.stiffness:g} N·m/rad",
                          f"links[{k}].joint.flexibility.motor_inertia = "
                          f"{f.motor_inertia:g} kg·m²",
                          f"links[{k}].joint.flexibility.damping = {f.damping:g} N·m·s/rad"]
            if jt.backlash is not None:
                b = jt.backlash
                parts += [f"links[{k}].joint.backlash.stiffness = {b.stiffness:g} N·m/rad",
                          f"links[{k}].joint.backlash.damping = {b.damping:g} N·m·s/rad"]
            d = jt.drive
            if d is not None and d.type == "dc_motor":
                parts += [f"links[{k}].joint.drive.gear_ratio = {d.gear_ratio:g}",
                          f"links[{k}].joint.drive.torque_constant = {d.torque_constant:g} "
                          f"N·m/A",
                          f"links[{k}].joint.drive.back_emf_constant = "
                          f"{d.back_emf_constant:g} V·s/rad",
                          f"links[{k}].joint.drive.resistance = {d.resistance:g} Ω"]
            elif d is not None:
                parts += [f"links[{k}].joint.drive.displacement = {d.displacement:g} m³/rad",
                          f"links[{k}].joint.drive.bulk_modulus = {d.bulk_modulus:g} Pa"]
            if any(chain.scene.gravity):
                parts.append(f"gravity = {list(chain.scene.gravity)} m/s²")
            return f"joint of {lm.name}: " + ", ".join(parts)
        if lm.eta.start <= i < lm.eta.stop:
            b, tip = lk.beam, lk.tip
            fid = chain.fidelity
            g = (f", gravity = {list(chain.scene.gravity)} m/s²" if any(chain.scene.gravity)
                 else "")
            return (f"beam of {lm.name}, rung {fid.rung} {lm.beam.refine}{g}: "
                    f"links[{k}].beam.length = {b.length:g} m, links[{k}].beam.EI = "
                    f"{b.EI:g} N·m², links[{k}].beam.mass_per_length = {b.mass_per_length:g} "
                    f"kg/m, links[{k}].beam.damping.viscous_per_length = "
                    f"{b.damping.viscous_per_length:g} N·s/m², "
                    f"links[{k}].beam.damping.stiffness_proportional = "
                    f"{b.damping.stiffness_proportional:g} s, links[{k}].tip.mass = "
                    f"{tip.mass:g} kg, links[{k}].tip.inertia = {tip.inertia:g} kg·m²")
    return "a coordinate of the model"


def _fix(chain, kind, integrator) -> str:
    fid = chain.fidelity
    if kind == "actuator":
        return ("fidelity.motor_current: quasi_static (a DC motor whose L/R is far below the "
                "mechanical time scales), --integrator radau or bdf (implicit), or check "
                "the drive's parameters above")
    explicit = integrator in ("rk4", "rkn4", "rk45", "dop853", "lsoda")
    tips = []
    if fid.rung in ("fem", "fd", "modal"):
        tips.append("a coarser rung or refinement (--rung, --refine: the modal rung keeps "
                    "the low modes exactly with few coordinates)")
    if explicit:
        tips.append("an implicit integrator (--integrator trapezoid when the model has no "
                    "actuator states, else radau or bdf) that has no stability limit")
    tips.append("or check the parameters above")
    return ", ".join(tips)
