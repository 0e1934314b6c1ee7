"""Batch simulation of a scene without ROS: build the model, set the initial state, integrate,
and return named output columns plus a run summary (like scipy's result object)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chain import Chain
from .errors import SceneError
from .integrate import Integration, integrate
from .linear import reduced_coordinates, tangent_stiffness


@dataclass
class SimResult:
    """Samples of a run and its summary."""
    scene_name: str
    chain: Chain
    run: Integration
    columns: dict           # name -> (N,) array, 't' first

    def summary(self) -> dict:
        r = self.run
        sim = float(r.t[-1]) if len(r.t) else 0.0
        return {"scene": self.scene_name, "status": r.status, "message": r.message,
                "success": r.success, "sim_time_s": sim, "wall_time_s": r.wall_time_s,
                "real_time_factor": sim / r.wall_time_s if r.wall_time_s > 0 else float("inf"),
                "rhs_evaluations": r.rhs_evaluations, "steps": r.steps, "dt": r.dt,
                "rung": self.chain.fidelity.rung, "coordinates": list(self.chain.names),
                "integrator": self.chain.fidelity.integrator}


def static_equilibrium(chain: Chain, q0: np.ndarray, tol=1e-10, max_iter=50) -> np.ndarray:
    """Static configuration under gravity with the drives held at their initial angles.

    Solves f(q) = Q_grav(q) − K q = 0 for the free (non-drive) coordinates by Newton's
    method with the tangent stiffness (seed 002 starts from this deflected state).
    """
    keep = reduced_coordinates(chain, "locked")
    q = q0.copy()
    if len(keep) == 0 or not chain.has_gravity:
        return q
    zero = np.zeros(chain.n)
    for it in range(max_iter):
        kin = chain.kinematics(q, zero)
        res = (kin.Qg - kin.h - chain.K @ q)[keep]
        Kt = tangent_stiffness(chain, q, keep)
        dq = np.linalg.solve(Kt, res)
        q[keep] += dq
        if np.max(np.abs(dq)) < tol * max(1.0, np.max(np.abs(q[keep]))):
            _check_stable(chain, q, keep)
            return q
    raise SceneError(f"initial.static_equilibrium: Newton did not converge in {max_iter} "
                     f"iterations (last correction {np.max(np.abs(dq)):.3g}); the arm may be "
                     f"too flexible for the small-deflection model under this load")


def _check_stable(chain: Chain, q: np.ndarray, keep: np.ndarray) -> None:
    """An equilibrium the arm cannot rest in (beyond buckling) is not a valid start."""
    Kt = tangent_stiffness(chain, q, keep)
    w, V = np.linalg.eigh(0.5 * (Kt + Kt.T))
    if w[0] <= 0.0:
        worst = chain.names[keep[int(np.argmax(np.abs(V[:, 0])))]]
        raise SceneError(
            f"initial.static_equilibrium: got an unstable equilibrium (tangent stiffness "
            f"eigenvalue {w[0]:.3g} along {worst}: the load exceeds the buckling load of the "
            f"small-deflection model), expected a stable one; stiffen the beam (EI), lighten "
            f"the load, or start from another joint angle")


def initial_state(chain: Chain):
    """(q0, q̇0) from the scene, optionally at static equilibrium."""
    q0, qd0 = chain.initial_q()
    if len(chain.presc_idx):
        p = chain.prescribed_state(0.0)
        q0[chain.presc_idx], qd0[chain.presc_idx] = p[0], p[1]
    if chain.scene.initial.static_equilibrium:
        q0 = static_equilibrium(chain, q0)
    return q0, qd0


def simulate(scene, duration=None, progress=None, chain=None) -> SimResult:
    """Run ``scene`` (fidelity already applied) for ``duration`` seconds."""
    chain = chain or Chain(scene)
    fid = scene.fidelity
    T = scene.duration if duration is None else duration
    if not T > 0:
        raise SceneError(f"duration: got {T}, expected > 0 s")
    q0, qd0 = initial_state(chain)
    x0 = np.concatenate([q0[chain.free], qd0[chain.free]])
    run = integrate(chain, x0, T, fid.integrator, fid.dt, fid.rtol, fid.atol, fid.output_dt,
                    fid.max_deflection_ratio, progress)
    return SimResult(scene.name, chain, run, output_columns(chain, run))


def output_columns(chain: Chain, run: Integration) -> dict:
    """Named columns: t, every coordinate and rate, tip_x/tip_y, tip deflections, energy."""
    cols = {"t": run.t}
    for j, name in enumerate(chain.names):
        cols[name] = run.q[:, j]
    for j, name in enumerate(chain.names):
        cols[f"{name}_rate"] = run.qd[:, j]
    N = len(run.t)
    tip = np.empty((N, 2))
    energy = np.empty(N)
    for k in range(N):
        e = chain.energy(run.q[k], run.qd[k])
        energy[k] = e["total"]
        tip[k] = e["tip"]
    cols["tip_x"], cols["tip_y"] = tip[:, 0], tip[:, 1]
    defl = np.array([chain.tip_deflections(q) for q in run.q])
    for j, lm in enumerate(chain.links):
        cols[f"{lm.name}_tip_deflection"] = defl[:, j]
    cols["energy"] = energy
    return cols
