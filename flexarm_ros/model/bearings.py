"""Air bearings rubbing the table: regularized Coulomb friction at a body's bearing point
(docs/physics.md §8.5).

Seed 000's rig floats RB2 (the middle motor and gearbox) and RB4 (the tool body) on air
bearings over a horizontal table. The source names their contact with the table as what
its model leaves out: they touch it "at a few high spots" (seed 000 lines 3853-3860: the
random friction is said to delay Case 1's impact by 0.07 s), in Case 2 the middle bearing
"tips over and binds with the table" (lines 3936-3938), and in Case 3 the friction keeps the
arm from returning to its oscillation centre, so the measured angles drift (lines
3990-4003). A scene's ``bearings:`` section turns that contact on; without it the bodies
float free.

The law, for a bearing at point r_b of a body with mass m, velocity v_b = J_b q̇:

    F = −μ(r_b) N v_b / √(|v_b|² + v_s²),     N = m g₀ + b |τ|,     Q = J_bᵀ F,
    μ(r_b) = μ + Σ_i μ_i exp(−|r_b − c_i|²/ρ_i²),

with g₀ = 9.81 m/s² (:data:`~flexarm_ros.scene.STANDARD_GRAVITY`: the table is
horizontal, the scene's in-plane ``gravity`` is zero and says nothing about the weight), τ
the torque of the drive whose housing the body carries (the next joint's; b = 0 elsewhere)
v_s the regularization speed, and the sum runs over the bearing's high spots (centre c_i
on the table, size ρ_i): the source's friction is "random, present only at certain high
points" (lines 4000-4001), and only a friction that depends on where the body is can move
the oscillation centre of Case 3 for good — a uniform μ is symmetric in the swing and
settles the centre where the first cycles leave it.

Why this regularization: it is smooth (C∞) in the planar velocity and isotropic, so the
force turns with the direction of sliding, |F| < μN always, and F → −(μN/v_s) v_b near rest
(the stick: a stiff viscous drag that holds the body within v_s of rest against any load
below μN). ``tanh(|v|/v_s) v/|v|`` has the same limits but a direction undefined at v = 0,
and a set-valued stick would need an event-driven or complementarity stepper for every
rung; this law is one more generalized force, so every rung, both lanes (the numpy
reference and the compiled kernel) and every integrator carry it unchanged. Its cost: the
stick adds a rate μN/(v_s m_eff) to the linearization, which the step must resolve
(1/s: 0.1 for the seed-000 values, far below the drives' rates).

The binding term is the simplest load dependence the source supports: a bearing that tips
under an uneven load presses its rim on the table harder the more load the arm puts on it;
the in-plane torque the housed gearbox passes to the next link stands for that load
(stall torque while the arm pushes the wall in Cases 1 and 2, nearly nothing while it
coasts). It is a proxy — the real tipping moment is out of the plane — and is off (b = 0)
unless a scene sets it.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.compiled import jit
from flexarm_ros.scene import STANDARD_GRAVITY, housed_drive

#: slots of a bearing's parameter row (:func:`encode`): bearing point in the body frame
#: (m), weight m g₀ (N), v_s (m/s), binding b (1/m), μ
PX, PY, WEIGHT, V_SLIP, BINDING, MU = range(6)
N_PAR = 6
#: slots of a high spot's row: its bearing, centre (m), radius ρ (m), μ_i
SPOT_BEARING, SPOT_X, SPOT_Y, SPOT_RADIUS, SPOT_MU = range(5)


@jit
def friction_force(vx, vy, mu_load, v_slip):
    """(F_x, F_y) = −μN v/√(|v|² + v_s²) for the bearing point's velocity (vx, vy) (m/s),
    μN = ``mu_load`` (N) and v_s = ``v_slip`` (m/s)."""
    k = mu_load / math.sqrt(vx * vx + vy * vy + v_slip * v_slip)
    return -k * vx, -k * vy


@jit
def friction_coefficient(b, x, y, mu, spots):
    """μ(r_b) = μ + Σ_i μ_i exp(−|r_b − c_i|²/ρ_i²) of bearing ``b`` at (x, y) (m) over the
    rows of ``spots`` that belong to it."""
    for i in range(spots.shape[0]):
        if int(spots[i, 0]) == b:
            dx = x - spots[i, 1]
            dy = y - spots[i, 2]
            mu += spots[i, 4] * math.exp(-(dx * dx + dy * dy) / (spots[i, 3] * spots[i, 3]))
    return mu


def encode(scene, actuators) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scene's bearings as the kernel's arrays: ``idx`` (nb, 3) int — link, body (0
    hub, 1 tip), the actuator (index into ``actuators``) whose torque loads it, or −1 —,
    ``par`` (nb, :data:`N_PAR`) float (slots :data:`PX` … :data:`MU`) and ``spots`` (ns, 5)
    (slots :data:`SPOT_BEARING` … :data:`SPOT_MU`). Bearings with μ = 0 and no high spot
    are left out: they float free and cost nothing."""
    names = [lk.name for lk in scene.links]
    rows, pars, spots = [], [], []
    for br in scene.bearings:
        if br.friction == 0.0 and not any(sp.friction > 0.0 for sp in br.high_spots):
            continue
        k = names.index(br.link)
        body = getattr(scene.links[k], br.body)
        p = body.cg if br.position is None else br.position
        ja = -1
        j = housed_drive(scene, k, br.body)
        if br.binding > 0.0 and j is not None:
            ja = next((i for i, a in enumerate(actuators) if a.link == j), -1)
        spots += [(len(rows), sp.point[0], sp.point[1], sp.radius, sp.friction)
                  for sp in br.high_spots if sp.friction > 0.0]
        rows.append((k, 0 if br.body == "hub" else 1, ja))
        pars.append((p[0], p[1], body.mass * STANDARD_GRAVITY, br.slip_velocity,
                     br.binding if ja >= 0 else 0.0, br.friction))
    return (np.array(rows, dtype=np.int64).reshape(-1, 3),
            np.array(pars, float).reshape(-1, N_PAR), np.array(spots, float).reshape(-1, 5))


def bearing_point(frame_o, frame_Jo, psi, frame_Jpsi, px, py):
    """(r, J) of the bearing point (px, py) in a body frame (origin, its Jacobian, angle,
    the angle's Jacobian): r = o + A(ψ)p, J = J_o + (E A p) J_ψ."""
    c, s = math.cos(psi), math.sin(psi)
    ax, ay = c * px - s * py, s * px + c * py
    J = frame_Jo + np.outer(np.array([-ay, ax]), frame_Jpsi)
    return frame_o + np.array([ax, ay]), J


def _one(chain, b, kin, qd, torques):
    """(r, v, F, J) of bearing b at the frames ``kin``: its point, velocity, force, Jacobian."""
    k, j, ja = chain.bearing_idx[b]
    par = chain.bearing_par[b]
    fr = (kin.hub_frames if j == 0 else kin.tip_frames)[k]
    r, J = bearing_point(fr.o, fr.Jo, fr.psi, fr.Jpsi, par[PX], par[PY])
    v = J @ qd
    load = par[WEIGHT] + (par[BINDING] * abs(torques[ja]) if ja >= 0 else 0.0)
    mu = friction_coefficient(b, r[0], r[1], par[MU], chain.bearing_spots)
    F = np.array(friction_force(v[0], v[1], mu * load, par[V_SLIP]))
    return r, v, F, J


def generalized_forces(chain, kin, qd, torques) -> np.ndarray:
    """Q = Σ_b J_bᵀ F_b (n,) of every bearing of ``chain`` (the numpy reference lane) at
    the frames ``kin`` and rates q̇; ``torques`` the actuators' torques (N·m) for the
    binding load."""
    Q = np.zeros(chain.n)
    for b in range(len(chain.bearing_idx)):
        _, _, F, J = _one(chain, b, kin, qd, torques)
        Q += J.T @ F
    return Q


def bearing_states(chain, q, qd, z, t) -> list[dict]:
    """Per bearing at (t, q, q̇, z): the point (m), its velocity (m/s), the friction force
    (N) and the dissipated power −F·v (W) — for tests, studies and reports."""
    kin = chain.kinematics(q, qd, frames_only=True)
    torques = chain.actuator_torques(t, qd, z)
    out = []
    for b in range(len(chain.bearing_idx)):
        r, v, F, _ = _one(chain, b, kin, qd, torques)
        out.append({"point": r, "velocity": v, "force": F, "power": -float(F @ v)})
    return out
