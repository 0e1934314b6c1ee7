"""The initial state of a scene: its configuration, the static equilibrium under gravity
when the scene starts there, and the stability check of that equilibrium."""

from __future__ import annotations

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model import drives
from flexarm_ros.model.rung_chain import RungChain
from flexarm_ros.model.linear import reduced_coordinates, tangent_stiffness


def static_equilibrium(chain: RungChain, q0: np.ndarray, tol=1e-10, max_iter=50) -> np.ndarray:
    """Static configuration under gravity with the drives held at their initial angles.

    Solves f(q) = Q_grav(q) − K q = 0 for the free (non-drive) coordinates by Newton's
    method with the tangent stiffness (seed 002 starts from this deflected state).
    """
    keep = reduced_coordinates(chain, "locked")
    q = q0.copy()
    if len(keep) == 0 or not chain.has_gravity:
        return q
    zero = np.zeros(chain.n)
    lengths = np.array([lm.beam.length for lm in chain.links])
    limit = chain.fidelity.max_deflection_ratio
    for it in range(max_iter):
        kin = chain.kinematics(q, zero)
        res = (kin.Qg - kin.h - chain.K @ q)[keep]
        Kt = tangent_stiffness(chain, q, keep)
        try:
            dq = np.linalg.solve(Kt, res)
        except np.linalg.LinAlgError:
            raise SceneError(f"initial.static_equilibrium: got a singular tangent stiffness "
                             f"(Newton iteration {it + 1}), expected a load the beams carry: "
                             f"check {_loads(chain, 0)}") from None
        q[keep] += dq
        ratios = chain.small_deflection_ratios(q) if np.all(
            np.isfinite(q)) else np.full(len(lengths), np.inf)
        worst = int(np.argmax(ratios))
        if not ratios[worst] <= limit:
            raise SceneError(
                f"initial.static_equilibrium: gravity bends {chain.links[worst].name} to "
                f"|w(L)|/L = {ratios[worst]:.3g}, expected at most "
                f"fidelity.max_deflection_ratio = {limit:g} (the small-deflection model): "
                f"check {_loads(chain, worst)}")
        if np.max(np.abs(dq)) < tol * max(1.0, np.max(np.abs(q[keep]))):
            _check_stable(chain, q, keep)
            return q
    raise SceneError(f"initial.static_equilibrium: Newton did not converge in {max_iter} "
                     f"iterations (last correction {np.max(np.abs(dq)):.3g}); the arm may be "
                     f"too flexible for the small-deflection model under this load")


def _loads(chain: RungChain, k: int) -> str:
    """The gravity and the scene values that load link ``k``'s beam (its stiffness and
    everything it carries), as ``key = value`` text."""
    sc = chain.scene
    parts = [f"gravity = {list(sc.gravity)} m/s²",
             f"links[{k}].beam.EI = {sc.links[k].beam.EI:g} N·m²"]
    for j in range(k, len(sc.links)):
        parts.append(f"links[{j}].beam.length = {sc.links[j].beam.length:g} m")
    for j in range(k, len(sc.links)):
        lk = sc.links[j]
        parts += [f"links[{j}].beam.mass_per_length = {lk.beam.mass_per_length:g} kg/m",
                  f"links[{j}].tip.mass = {lk.tip.mass:g} kg",
                  f"links[{j}].tip.cg = {list(lk.tip.cg)} m"]
        if j > k:
            parts.append(f"links[{j}].hub.mass = {lk.hub.mass:g} kg")
    return ", ".join(parts)


def _check_stable(chain: RungChain, q: np.ndarray, keep: np.ndarray) -> None:
    """An equilibrium the arm cannot rest in (beyond buckling) is not a valid start."""
    Kt = tangent_stiffness(chain, q, keep)
    w, V = np.linalg.eigh(0.5 * (Kt + Kt.T))
    if w[0] <= 0.0:
        worst = chain.names[keep[int(np.argmax(np.abs(V[:, 0])))]]
        raise SceneError(
            f"initial.static_equilibrium: got an unstable equilibrium (tangent stiffness "
            f"eigenvalue {w[0]:.3g} along {worst}: the load exceeds the buckling load of the "
            f"small-deflection model), expected a stable one; stiffen the beam (EI), lighten "
            f"the load, or start from another joint angle: check "
            f"{_loads(chain, chain._link_of(keep[int(np.argmax(np.abs(V[:, 0])))]))}")


def initial_state(chain: RungChain):
    """(q0, q̇0, z0) from the scene, optionally at static equilibrium.

    Actuator states start at zero current; a hydraulic actuator starts at the load pressure
    that holds the initial configuration, and (with ``null_bias``, the default) its valve
    gets the null current that feeds the leakage at that pressure, so the arm rests until
    the program moves it.
    """
    q0, qd0 = chain.initial_q()
    if len(chain.presc_idx):
        p = chain.prescribed_state(0.0)
        q0[chain.presc_idx], qd0[chain.presc_idx] = p[0], p[1]
    chain.check_mass_matrix(q0)       # before anything solves with M (modes, statics, runs)
    if chain.scene.initial.static_equilibrium:
        q0 = static_equilibrium(chain, q0)
    z0 = np.zeros(chain.nz)
    hyd = [a for a in chain.actuators if a.kind == drives.HYDRAULIC]
    if hyd:
        f = chain.static_forces(q0)
        for a in hyd:
            p_hold, i_bias = drives.hydraulic_hold(a.par, -f[a.coord])
            if not np.isfinite(i_bias):
                lk = chain.scene.links[a.link]
                d = lk.joint.drive
                raise SceneError(
                    f"links[{a.link}].joint.drive.supply_pressure: got "
                    f"{a.par[drives.HYD_SUPPLY_PRESSURE]:.6g} Pa, expected more than the {abs(p_hold):.6g} Pa needed "
                    f"to hold {lk.name} at its initial angle (the holding torque / "
                    f"(torque_efficiency × displacement): links[{a.link}].joint.drive."
                    f"torque_efficiency = {d.torque_efficiency or 1.0:g}, links[{a.link}]."
                    f"joint.drive.displacement = {d.displacement:g} m³/rad)")
            z0[a.state] = p_hold
            drive = chain.scene.links[a.link].joint.drive
            a.par[drives.HYD_VALVE_BIAS] = i_bias if drive.null_bias in (None, True) else 0.0
    return q0, qd0, z0


def initial_x(chain: RungChain) -> np.ndarray:
    """The first-order initial state x0 = [q_free, q̇_free, z] (see :func:`initial_state`)."""
    q0, qd0, z0 = initial_state(chain)
    return np.concatenate([q0[chain.free], qd0[chain.free], z0])
