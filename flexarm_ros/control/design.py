"""Vibration control designed on the model: the position loop linearized at the move's
target pose, its modes, and input shapers for the modes that carry deflection
(``flexarm design``).

The loop is the twin's own (:class:`flexarm_ros.twin.cores.ControllerCore`): the joint PD
T = −k_d q̇ − k_p (q − q*) on the encoder coordinates (the drive coordinate: motor side
where the joint has one), turned into a voltage by the static motor map
u = R/(η n K_t)·T + K_b n q̇ (seed 000 Eq. 5.17). Linearized about the target pose q* at
rest (:func:`flexarm_ros.model.statespace.linearize` of the scene with its joints at q*),
the plant ẋ = A x + B u with the law u = −F_p x − F_d v + G δq* and the controller's
velocity filter on each drive coordinate's rate, v̇ = ω_c (q̇ − v) with ω_c = 2π
``control.velocity_filter_hz`` (:class:`flexarm_ros.control.joint_pd.EncoderVelocity`,
whose rate both the PD's damping and the motor map's back-EMF term use), gives the
closed loop on (x, v)

    A_cl = [[A − B F_p, −B F_d], [ω_c E, −ω_c I]]        (E picks the drive rates),

whose eigenvalues λ are the loop's modes: f = |λ|/2π, ζ = −Re λ/|λ|. Without the filter
states the lowest mode of two_link_position came out 2.9 % from the pole identified from
the twin's free decay (its damping 0.478 against 0.503); with them, within 0.3 %
(test/test_vibration_design.py). The sampling (1 kHz against modes of a few Hz) is left
out.

A mode *carries deflection in the move* when its share of the step response of the last
link's tip deflection — the modal residue |c vᵢ|·|wᵢᵀ b| / |λᵢ| for the target step b —
is at least :data:`DEFLECTION_SHARE` of the largest; those are shaped unless ``modes``
names how many (the lowest first).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from flexarm_ros.errors import InputError, SceneError

#: a mode whose step-response share of the tip deflection is below this fraction of the
#: largest is left unshaped
DEFLECTION_SHARE = 0.01
#: modes above this fraction of the control rate are not shaped (the loop's sampling)
MAX_RATE_SHARE = 0.05


@dataclasses.dataclass(frozen=True)
class LoopMode:
    """One oscillating mode of the closed loop."""
    frequency_hz: float           # natural frequency |λ|/2π
    damping_ratio: float          # −Re λ / |λ|
    damped_hz: float              # Im λ / 2π
    share: float                  # of the largest step-response residue in the deflection


def require_position(scene):
    """The scene's control section, or InputError unless it is a position loop (what a
    design starts from; before the controller is built, which needs its targets)."""
    ctl = scene.control
    if ctl is None or ctl.mode != "position":
        raise InputError(f"control.mode: got {ctl.mode if ctl else None!r}, expected "
                         f"'position' (a design shapes or replaces the joint PD's move)")
    return ctl


def plant_at(scene, q_goal):
    """(chain, ss): the plant of ``scene`` linearized at rest at the joint angles
    ``q_goal`` (voltages in, no controller, no input programs)."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.statespace import linearize
    from flexarm_ros.scene.keys import set_keys
    at = {f"links[{k}].joint.initial_angle": float(q) for k, q in enumerate(q_goal)}
    at.update({f"links[{k}].joint.initial_rate": 0.0 for k in range(len(q_goal))})
    for k, lk in enumerate(scene.links):
        if lk.joint.initial_angle_deg is not None:
            at[f"links[{k}].joint.initial_angle_deg"] = None
    pose = set_keys(dataclasses.replace(scene, control=None, inputs=()), at)
    chain = Chain(pose)
    return chain, linearize(chain)


def _feedback(scene, q_goal):
    """(F, G, ss, rates): the plant of ``scene`` linearized at rest at the joint angles
    ``q_goal`` (voltages in) and the twin's PD law on it, u = −F x + G δq* with the rates
    unfiltered (module doc; :func:`_loop` adds the velocity filter); ``rates``: the state
    index of each actuated drive coordinate's rate, in the inputs' order."""
    ctl = require_position(scene)
    chain, ss = plant_at(scene, q_goal)
    nf = len(chain.free)
    free = list(chain.free)
    F = np.zeros((len(ss.inputs), ss.A.shape[0]))
    G = np.zeros((len(ss.inputs), len(scene.links)))
    rates = []
    for j, a in enumerate(chain.actuators):
        d = scene.links[a.link].joint.drive
        if d is None or d.type != "dc_motor" or (d.inductance or 0.0) > 0.0:
            raise InputError(f"links[{a.link}].joint.drive: a design needs a dc_motor with "
                             f"a quasi-static current (inductance 0 or none) on every joint")
        lm = chain.links[a.link]
        coord = lm.i_motor if lm.i_motor >= 0 else lm.i_joint
        i = free.index(coord)
        gain = d.resistance / (d.gear_ratio * d.output_torque_constant)   # V per N·m
        F[j, i] = gain * ctl.kp[a.link]
        F[j, nf + i] = gain * ctl.kd[a.link] - d.back_emf_constant * d.gear_ratio
        G[j, a.link] = gain * ctl.kp[a.link]
        rates.append(nf + i)
    return F, G, ss, rates


def _loop(scene, q_goal):
    """(A_cl, B_cl, C_cl, D_cl, state names, state units, ss) of the position loop on
    (x, v): the plant's state x and, where ``control.velocity_filter_hz`` is finite, the
    filtered drive rates v the PD and the motor map read (module doc)."""
    F, G, ss, rate_cols = _feedback(scene, q_goal)
    fc = scene.control.velocity_filter_hz
    if fc is None or not math.isfinite(fc):
        return (ss.A - ss.B @ F, ss.B @ G, ss.C - ss.D @ F, ss.D @ G, list(ss.states),
                list(ss.state_units), ss)
    n = ss.A.shape[0]
    m = len(rate_cols)
    Fp, Fd = F.copy(), F[:, rate_cols]
    Fp[:, rate_cols] = 0.0
    E = np.zeros((m, n))
    E[np.arange(m), rate_cols] = 1.0
    wc = 2.0 * math.pi * fc
    A = np.block([[ss.A - ss.B @ Fp, -ss.B @ Fd], [wc * E, -wc * np.eye(m)]])
    B = np.vstack([ss.B @ G, np.zeros((m, G.shape[1]))])
    C = np.hstack([ss.C - ss.D @ Fp, -ss.D @ Fd])
    names = [f"{ss.states[c]}_filtered" for c in rate_cols]
    units = [ss.state_units[c] for c in rate_cols]
    return A, B, C, ss.D @ G, list(ss.states) + names, list(ss.state_units) + units, ss


def closed_loop(scene, q_goal):
    """(A_cl, B_ref, C_defl, StateSpace) of the position loop of ``scene`` linearized at
    the joint angles ``q_goal`` (module doc): A_cl on (x, v); B_ref maps a target step
    δq* to the state's rate; C_defl is the last link's tip deflection row; the plant's
    StateSpace."""
    A, B, C, _, _, _, ss = _loop(scene, q_goal)
    row = ss.outputs.index(f"{scene.links[-1].name}_tip_deflection")
    return A, B, C[row], ss


def loop_modes(scene, q_goal, q_start, control_rate_hz: float) -> list[LoopMode]:
    """The oscillating modes of the loop at ``q_goal``, lowest first, each with its share
    of the tip deflection in the step from ``q_start`` (module doc)."""
    A, Bref, c, _ = closed_loop(scene, q_goal)
    lam, V = np.linalg.eig(A)
    if np.max(lam.real) > 0:
        worst = lam[np.argmax(lam.real)]
        raise SceneError(f"control: the position loop linearized at the target pose is "
                         f"unstable (eigenvalue {worst.real:.4g}{worst.imag:+.4g}j 1/s), "
                         f"expected a stable loop to design on: lower control.kp / raise "
                         f"control.kd")
    W = np.linalg.inv(V)
    b = Bref @ (np.asarray(q_goal, float) - np.asarray(q_start, float))
    out = []
    res = np.abs(c @ V) * np.abs(W @ b) / np.maximum(np.abs(lam), 1e-300)
    top = 0.0
    picked = []
    for k, l in enumerate(lam):
        if l.imag <= 0 or abs(l) / (2 * math.pi) > MAX_RATE_SHARE * control_rate_hz:
            continue
        picked.append(k)
        top = max(top, res[k])
    for k in sorted(picked, key=lambda k: abs(lam[k])):
        w = abs(lam[k])
        out.append(LoopMode(w / (2 * math.pi), -lam[k].real / w, lam[k].imag / (2 * math.pi),
                            float(res[k] / top) if top > 0 else 0.0))
    return out


def design_shaper(scene, kind: str, q_goal, q_start, modes: int | None = None):
    """(times, amplitudes, the shaped LoopModes): shaper ``kind`` on each mode that
    carries deflection (or the lowest ``modes``), convolved, on the control grid."""
    from flexarm_ros.control.shapers import convolve, on_grid, shaper
    rate = scene.control.rate_hz
    found = loop_modes(scene, q_goal, q_start, rate)
    if modes is None:
        chosen = [m for m in found if m.share >= DEFLECTION_SHARE]
    else:
        if modes > len(found):
            raise InputError(f"--modes: got {modes}, expected at most {len(found)} (the "
                             f"loop's oscillating modes below {MAX_RATE_SHARE * rate:g} Hz)")
        chosen = found[:modes]
    if not chosen:
        raise InputError("--shaper: the loop has no oscillating mode that carries the last "
                         "link's deflection in this move, expected one to shape")
    try:
        parts = [shaper(kind, m.frequency_hz, m.damping_ratio) for m in chosen]
    except ValueError as exc:
        raise InputError(f"--shaper: {exc}") from None
    times, amps = convolve(*parts)
    times, amps = on_grid(times, amps, 1.0 / rate)
    return times, amps, chosen


def closed_loop_statespace(scene, q_goal):
    """The position loop about ``q_goal`` as a StateSpace: inputs the joint targets (rad),
    the plant's outputs, states the plant's and the filtered drive rates
    (:func:`_loop`)."""
    from flexarm_ros.model.statespace import StateSpace
    A, B, C, D, states, units, ss = _loop(scene, q_goal)
    names = [f"{lk.name}_joint_target" for lk in scene.links]
    x0 = np.concatenate([np.asarray(ss.x0, float), np.zeros(len(states) - len(ss.states))])
    return StateSpace(A, B, C, D, states, names, ss.outputs, x0, units,
                      ["rad"] * len(names), ss.output_units)


def shaper_record(scene, kind: str, q_goal, q_start, modes: int | None = None,
                  version: str = "") -> tuple[dict, list]:
    """(the ``control.shaper`` mapping, the shaped LoopModes) of :func:`design_shaper`,
    with the ``design`` line that records what it was designed on (``flexarm design`` and
    ``fx.design`` write the same)."""
    times, amps, chosen = design_shaper(scene, kind, q_goal, q_start, modes)
    what = ", ".join(f"{m.frequency_hz:.4g} Hz ζ {m.damping_ratio:.3g}" for m in chosen)
    pose = ", ".join(f"{q:.6g}" for q in q_goal)
    design = (f"{kind} on the position loop's modes {what} (the PD loop linearized at the "
              f"target joint angles [{pose}] rad), impulses on the "
              f"{scene.control.rate_hz:g} Hz control grid; flexarm design {version}")
    return {"times": [float(t) for t in times], "amplitudes": [float(a) for a in amps],
            "design": design, "frequencies_hz": [float(m.frequency_hz) for m in chosen],
            "damping_ratios": [float(m.damping_ratio) for m in chosen]}, chosen
