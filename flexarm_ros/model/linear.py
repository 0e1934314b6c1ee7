"""Linearization of the chain about a configuration: natural frequencies and mode shapes.

About a configuration q0 at rest the equations of motion linearize to
``M(q0) δq̈ + K_t δq = 0`` with the tangent stiffness ``K_t = −∂(Q_grav − h − K q)/∂q``
(the elastic K plus gravity's geometric stiffness, by central differences). The mode shapes
are the mass-normalised eigenvectors of the generalized symmetric eigenproblem
K_t v = ω² M v (K_t is symmetrized: at a static equilibrium it is symmetric up to the
differencing error), and ω_i² the Rayleigh quotients v_iᵀK_t v_i of those shapes; a mode
whose ω² is at the round-off of K_t is rigid (0 Hz, :func:`rigid_modes`).
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model.differentiate import REL_STEP, jacobian

#: h·|λ|max above which a fixed RK4 step is refused (re-exported by sim.step)
RK4_STABILITY = 2.78
#: h·|λ|max of the automatic RK4 step (re-exported by sim.step)
RK4_AUTO = 1.5
#: the ceiling of an RK4 step above the stable one RK4_AUTO/|λ|max that a tolerance may
#: take (measured there, never extrapolated), as a share of the stability limit
#: RK4_STABILITY/|λ|max: |λ|max moves with the configuration during a run, hence a margin
ABOVE_STABLE_SHARE = 0.85


def search_above_stable(h_stable, h_first, anchor, accept, aim, evaluate, tries=2,
                        first_floor=1.05):
    """(step, error) of the first candidate above the stable step ``h_stable`` whose
    *evaluated* error is at most ``accept``, or None: no law of the error in h is assumed
    there (the highest modes are outside RK4's asymptotic range). The first candidate is
    ``h_first``; after a miss, the next is where the line through ``anchor`` = (h_a, E_a)
    (a step below with its error) and the miss meets ``aim`` (≤ accept) on log-log axes.
    A later candidate within 5 % of h_stable is not tried (the first not within
    ``first_floor``·h_stable). ``evaluate(h)`` → (the step taken, its error). Used by
    ``--tolerance`` (pilot runs) and rung auto (RK4 on the linear model)."""
    h_a, e_a = anchor
    h_c = h_first
    for k in range(tries):
        if h_c <= (first_floor if k == 0 else 1.05) * h_stable:
            return None
        h_c, e_c = evaluate(h_c)
        if e_c <= accept:
            return h_c, e_c
        if not 0.0 < e_a < e_c:
            return None
        q = math.log(e_c / e_a) / math.log(h_c / h_a)     # the order seen up to h_c
        h_c = h_a * (aim / e_a) ** (1 / q)
    return None
#: largest difference step of :func:`highest_rate` with backlash (the dead zone's kink)
BACKLASH_MAX_STEP = 1e-9
#: a mode is rigid when its ω² is within this fraction of ‖K_t‖₂·‖v‖² (:func:`rigid_modes`)
RIGID_ROUNDOFF = 1e-12


@dataclass(frozen=True)
class Modes:
    """Natural frequencies (Hz, ascending) and mass-normalised mode shapes."""
    frequencies_hz: np.ndarray
    shapes: np.ndarray          # (n_coords, n_modes)
    coordinates: tuple[str, ...]
    joints: str


def reduced_coordinates(chain, joints: str) -> np.ndarray:
    """Coordinates kept in the linear model: ``locked`` removes each drive coordinate
    (the motor angle for a flexible joint, else the joint angle) and every prescribed one;
    ``free`` keeps them all except prescribed motions."""
    if joints not in ("locked", "free"):
        raise SceneError(f"joints: got {joints!r}, expected locked or free")
    drop = set(int(i) for i in chain.presc_idx)
    if joints == "locked":
        drop |= set(chain.drive_index())
    return np.array([i for i in range(chain.n) if i not in drop], dtype=int)


def tangent_stiffness(chain, q0, keep=None, rel_step=REL_STEP) -> np.ndarray:
    """K_t = −∂f/∂q at rest, f = Q_grav − h − K q (central differences), on ``keep``."""
    keep = np.arange(chain.n) if keep is None else keep
    zero = np.zeros(chain.n)

    def force(q):
        kin = chain.kinematics(q, zero)
        return kin.Qg - kin.h - chain.K @ q

    return -jacobian(force, q0, rel_step, columns=keep)[keep]


def rigid_modes(w2, V, Kt) -> np.ndarray:
    """Flags of the rigid-body modes among the eigenpairs (ω², v) of K_t v = ω² M v: those
    whose stiffness is at the round-off of K_t, |ω²| ≤ RIGID_ROUNDOFF·‖K_t‖₂·‖v‖² (v the
    columns of V). A threshold relative to the largest ω² would flag genuine low modes of a
    fine mesh, whose highest ω² lies ~1e10× above the first."""
    return np.abs(w2) <= RIGID_ROUNDOFF * np.linalg.norm(Kt, 2) * np.sum(V * V, axis=0)


def natural_modes(chain, q0=None, joints: str = "locked") -> Modes:
    """Modes of the linearized chain at q0 (default: the scene's initial configuration)."""
    if q0 is None:
        q0 = chain.initial_q()[0]
    keep = reduced_coordinates(chain, joints)
    if len(keep) == 0:
        return Modes(np.zeros(0), np.zeros((chain.n, 0)), tuple(chain.names), joints)
    M = chain.kinematics(q0, np.zeros(chain.n)).M[np.ix_(keep, keep)]
    if chain.has_gravity:
        Kt = tangent_stiffness(chain, q0, keep)
    else:
        Kt = chain.K[np.ix_(keep, keep)]
    Kt = 0.5 * (Kt + Kt.T)
    import scipy.linalg       # lazily: start-up time of runs that never need it
    w2, V = scipy.linalg.eigh(Kt, M)
    V = np.ascontiguousarray(V)
    # ω² as the Rayleigh quotients vᵀK_t v of the mass-normalised shapes: the eigenvalue of
    # a low mode carries the eigen-solve's round-off of the highest, ε·ω²_max, the quotient
    # of its shape does not
    w2 = np.einsum("ik,ij,jk->k", V, Kt, V)
    w2 = np.where(rigid_modes(w2, V, Kt), 0.0, w2)      # rigid-body modes at exactly 0
    order = np.argsort(w2, kind="stable")
    w2, V = w2[order], V[:, order]
    freqs = np.sign(w2) * np.sqrt(np.abs(w2)) / (2 * np.pi)
    shapes = np.zeros((chain.n, len(keep)))
    shapes[keep, :] = V
    return Modes(freqs, shapes, tuple(chain.names), joints)


def highest_rate(chain, q0, qd0, z0=None) -> float:
    """Spectral radius (1/s) of the first-order system's Jacobian about (q0, q̇0, z0): sets
    the stable step of explicit integrators. Computed by central differences of the
    right-hand side. With backlash the mesh is also taken engaged on either side (at the
    start the teeth may be apart, hiding the stiffest coupling)."""
    return max(float(np.abs(np.linalg.eigvals(J)).max()) for J in jacobians(chain, q0, qd0, z0))


def jacobians(chain, q0, qd0, z0=None) -> list[np.ndarray]:
    """The Jacobians ∂ẋ/∂x of the first-order system about (q0, q̇0, z0) that
    :func:`highest_rate` takes its spectral radius over: one, and with backlash one more on
    either side of the dead zone (central differences staying on one side of its kink)."""
    free = chain.free
    z0 = np.zeros(chain.nz) if z0 is None else z0
    states = [q0]
    for im, ij, b, k, c in chain.backlash:
        for sign in (1.0, -1.0):
            q = q0.copy()
            q[im] = q0[ij] + sign * (b + 1e-6 * max(b, 1e-3))
            states.append(q)
    # stay on one side of the dead zone's kink
    max_step = BACKLASH_MAX_STEP if chain.backlash else np.inf
    return [jacobian(lambda x: chain.rhs(0.0, x),
                     np.concatenate([q[free], qd0[free], z0]), max_step=max_step)
            for q in states]


def smooth_rhs(chain) -> bool:
    """True when the model's right-hand side is smooth between input jumps, so its stable
    step, taken from the linearization at the start, holds over the run and RK4 may step
    past the output period (dense output). Not so with backlash (the dead zone's kinks)
    or a hydraulic actuator (the orifice flow ∝ √(P_S − p) stiffens without bound as the
    pressure nears the supply), nor with an actuator state held at a bound (a DC motor's
    current limit: the steps clamp it, an interpolant between them would not — measured,
    the limited torque between step ends fell below the limit): their automatic step stays
    capped by the output period, the outputs on step ends."""
    from flexarm_ros.model import drives
    bounded = any(np.isfinite(drives.state_bounds(a.kind, a.par)).any()
                  for a in chain.actuators if a.state >= 0)
    return (not chain.backlash and not bounded
            and all(a.kind != drives.HYDRAULIC for a in chain.actuators))


def grid_step(h, output_dt, dense=False):
    """The step RK4 takes when asked for h: with ``dense`` output kept as is (outputs inside
    steps come from the step's interpolant; the ẋ it needs at the step's end is the next
    step's first stage, so they cost no evaluation), else shortened to the largest whole
    fraction of the output period."""
    if dense:
        return h
    h = min(h, output_dt)
    return output_dt / np.ceil(output_dt / h - 1e-9)


def trapezoid_step_by_error(chain) -> bool:
    """True where the trapezoid's automatic step (fidelity.dt 0) is chosen by its error
    estimate (:func:`~flexarm_ros.sim.simulate.simulate`): integrator trapezoid, no wall
    (the contact stepper is RK4's), no backlash (its dead zone defeats the estimate), no
    actuator state (the rule carries none). Elsewhere it is the output period."""
    return (chain.fidelity.integrator == "trapezoid" and not chain.scene.walls
            and not chain.backlash and not chain.nz)
