"""Rigid-arm kinematics of the planar two-link arm and Newton–Raphson inverse kinematics.

Seed 000 (Hariharesan 1998, Sec. 5.6.3) commands the tool tip to a point of the workspace:
"an inverse kinematic routine (using the Newton–Raphson technique) was used to calculate
the angular orientations q1(t) and q2(t) of the beams for the tip to reach the desired
position"; the two angles then become the commanded angles cQ_i of the joint PD law
(Eq. 5.16, :mod:`flexarm_ros.control.joint_pd`). The beams are treated as rigid here: the
commanded angles are those of the undeformed arm.

Conventions (REP 103, the same as the physics core): angles in radians, q1 is the angle of
link 1 from the world x axis, q2 the angle of link 2 relative to link 1 (joint angle), both
counterclockwise positive; the link lengths run joint axis to joint axis (link 1: hub
radius + beam length + joint-2 offset) and joint axis to tool point (link 2)::

    x = bx + l1 cos q1 + l2 cos(q1 + q2)
    y = by + l1 sin q1 + l2 sin(q1 + q2)

No middleware here: :class:`PlanarTwoLink` is plain numpy and never raises on a bad target;
failure is data (:class:`IKResult` with ``success`` False and a message).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["IKResult", "PlanarTwoLink"]

_ELBOWS = ("up", "down")


@dataclass(frozen=True)
class IKResult:
    """Outcome of :meth:`PlanarTwoLink.inverse`.

    q: (2,) joint angles [q1, q2] (rad), always finite: the solution when ``success``, else
    the closest configuration found (for an unreachable target, the arm pointing at it,
    stretched or folded). success: the residual is below ``tol``. iterations: Newton steps
    taken. residual: |target − forward(q)| (m). message: what happened, in words.
    """
    q: np.ndarray = field(repr=True)
    success: bool
    iterations: int
    residual: float
    message: str


class PlanarTwoLink:
    """Rigid kinematics of a planar two-link arm (seed 000 Sec. 5.6.3).

    Parameters
    ----------
    l1, l2 : float
        Link lengths (m), > 0: joint 1 to joint 2, joint 2 to the tool point.
    base : (2,) float
        Position of joint 1 in the world frame (m).

    The reachable workspace is the annulus |l1 − l2| <= |p − base| <= l1 + l2.
    """

    def __init__(self, l1: float, l2: float, base=(0.0, 0.0)):
        l1, l2 = float(l1), float(l2)
        if not (l1 > 0.0 and l2 > 0.0 and math.isfinite(l1) and math.isfinite(l2)):
            raise ValueError(f"PlanarTwoLink: link lengths got l1 = {l1}, l2 = {l2}, "
                             f"expected finite values > 0 m")
        base = np.asarray(base, dtype=float).reshape(2)
        if not np.all(np.isfinite(base)):
            raise ValueError(f"PlanarTwoLink: base got {base.tolist()}, expected finite (x, y) m")
        self.l1, self.l2, self.base = l1, l2, base

    # ------------------------------------------------------------------ workspace
    @property
    def r_min(self) -> float:
        """Inner radius |l1 − l2| of the reachable annulus (m)."""
        return abs(self.l1 - self.l2)

    @property
    def r_max(self) -> float:
        """Outer radius l1 + l2 of the reachable annulus (m)."""
        return self.l1 + self.l2

    def reachable(self, target, margin: float = 0.0) -> bool:
        """True when the distance of ``target`` from the base lies in
        [r_min + margin, r_max − margin]."""
        target = np.asarray(target, dtype=float).reshape(2)
        if not np.all(np.isfinite(target)):
            return False
        r = float(np.hypot(*(target - self.base)))
        return self.r_min + margin <= r <= self.r_max - margin

    # ------------------------------------------------------------------ forward
    def forward(self, q) -> np.ndarray:
        """Tool point (x, y) in m, shape (2,) (or (..., 2) for q of shape (..., 2)):
        x = bx + l1 cos q1 + l2 cos(q1+q2), y = by + l1 sin q1 + l2 sin(q1+q2)."""
        q = np.asarray(q, dtype=float)
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        x = self.base[0] + self.l1 * np.cos(q1) + self.l2 * np.cos(q12)
        y = self.base[1] + self.l1 * np.sin(q1) + self.l2 * np.sin(q12)
        return np.stack([x, y], axis=-1)

    def elbow_position(self, q) -> np.ndarray:
        """Joint-2 position (m), shape (2,)."""
        q = np.asarray(q, dtype=float)
        return self.base + self.l1 * np.array([math.cos(q[0]), math.sin(q[0])])

    def jacobian(self, q) -> np.ndarray:
        """(2, 2) tool-point Jacobian d(x, y)/d(q1, q2) (m/rad):
        [[−l1 s1 − l2 s12, −l2 s12], [l1 c1 + l2 c12, l2 c12]]; det = l1 l2 sin q2, singular
        with the arm stretched or folded (q2 = 0, π)."""
        q = np.asarray(q, dtype=float)
        s1, c1 = math.sin(q[0]), math.cos(q[0])
        s12, c12 = math.sin(q[0] + q[1]), math.cos(q[0] + q[1])
        return np.array([[-self.l1 * s1 - self.l2 * s12, -self.l2 * s12],
                         [self.l1 * c1 + self.l2 * c12, self.l2 * c12]])

    # ------------------------------------------------------------------ inverse
    def analytic_inverse(self, target, elbow: str = "up") -> IKResult:
        """Closed-form two-link solution (law of cosines), the independent check of
        :meth:`inverse`.

        cos q2 = (r² − l1² − l2²)/(2 l1 l2), q2 = ∓acos(·),
        q1 = atan2(dy, dx) − atan2(l2 sin q2, l1 + l2 cos q2).

        elbow: "up" puts the elbow on the counterclockwise side of the base→target ray
        (q2 <= 0; above the ray for a target on the +x side), "down" on the clockwise side
        (q2 >= 0). Unreachable targets give ``success`` False (see :meth:`inverse`).
        """
        if elbow not in _ELBOWS:
            raise ValueError(f"analytic_inverse: elbow got {elbow!r}, expected one of {_ELBOWS}")
        bad = self._check_target(target)
        if bad is not None:
            return bad
        d = np.asarray(target, dtype=float).reshape(2) - self.base
        r = float(np.hypot(*d))
        c2 = (r * r - self.l1 ** 2 - self.l2 ** 2) / (2.0 * self.l1 * self.l2)
        q2 = math.acos(min(1.0, max(-1.0, c2)))
        if elbow == "up":
            q2 = -q2
        q1 = math.atan2(d[1], d[0]) - math.atan2(self.l2 * math.sin(q2),
                                                  self.l1 + self.l2 * math.cos(q2))
        q = np.array([q1, q2])
        res = float(np.hypot(*(self.forward(q) - self.base - d)))
        return IKResult(q, True, 0, res, f"closed-form solution, elbow {elbow}")

    def inverse(self, target, q_guess=(0.0, 0.5), tol: float = 1e-10, max_iter: int = 50,
                elbow: str | None = None, damping: float = 0.05,
                max_step: float = 0.5) -> IKResult:
        """Joint angles that put the tool point on ``target``, by Newton–Raphson
        (seed 000 Sec. 5.6.3) with a damped least-squares step and a backtracking line
        search. Never raises and never returns NaN for a bad target.

        Iteration, e = target − forward(q), J = jacobian(q):
            Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ e,
        λ = 0 away from singularities (the plain Newton step J⁻¹ e), and
        λ² = damping² (1 − (σ_min/ε)²) when the smallest singular value σ_min of J drops
        below ε = 0.05·min(l1, l2) (Chiaverini's damped least squares), so the step stays
        bounded with the arm stretched or folded. |Δq| is capped at ``max_step`` rad and
        halved until |e| decreases. A start exactly on the singular line (e.g. a straight
        arm and a target closer in along the same ray, where Jᵀe = 0) is kicked off it
        by bending joint 2 by 0.2 rad (towards ``elbow`` when given).

        Parameters
        ----------
        target : (2,) m, world frame.
        q_guess : (2,) rad, start (the current joint angles of the arm, typically).
        tol : residual |e| in m to declare success.
        max_iter : Newton steps allowed.
        elbow : None keeps the branch Newton–Raphson lands on (continuity with the guess);
            "up"/"down" (see :meth:`analytic_inverse`) mirrors the solution onto that
            branch when it landed on the other.
        damping : λ at a singularity (rad·m scale, dimensionless here).
        max_step : cap on |Δq| (rad).

        Returns
        -------
        IKResult; q2 is wrapped to (−π, π] (the elbow branch is its sign), q1 stays on the
        turn of the guess (no 2π jumps in a commanded angle). An unreachable target
        (|target − base| outside [|l1 − l2|, l1 + l2]) returns success False, with the
        message naming the target, the reachable annulus and the distance, and q pointing
        the arm at the target.
        """
        if elbow is not None and elbow not in _ELBOWS:
            raise ValueError(f"inverse: elbow got {elbow!r}, expected None or one of {_ELBOWS}")
        bad = self._check_target(target)
        if bad is not None:
            return bad
        target = np.asarray(target, dtype=float).reshape(2)
        q = np.asarray(q_guess, dtype=float).reshape(2).copy()
        if not np.all(np.isfinite(q)):
            q = np.array([0.0, 0.5])
        eps = 0.05 * min(self.l1, self.l2)
        kick = 0.2 if elbow != "up" else -0.2

        e = target - self.forward(q)
        err = float(np.hypot(*e))
        it = 0
        while err > tol and it < max_iter:
            it += 1
            J = self.jacobian(q)
            sig_min = float(np.linalg.svd(J, compute_uv=False)[-1])
            lam2 = 0.0 if sig_min >= eps else damping ** 2 * (1.0 - (sig_min / eps) ** 2)
            dq = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(2), e)
            nrm = float(np.hypot(*dq))
            if nrm < 1e-3 * err / max(self.r_max, 1e-12) and sig_min < eps:
                # Stuck on the singular line: J^T e ~ 0 with a radial error. Bend joint 2.
                q[1] += kick if abs(q[1]) < 0.5 * math.pi else -kick
                e = target - self.forward(q)
                err = float(np.hypot(*e))
                continue
            if nrm > max_step:
                dq *= max_step / nrm
            step = 1.0
            for _ in range(30):
                q_new = q + step * dq
                e_new = target - self.forward(q_new)
                err_new = float(np.hypot(*e_new))
                if err_new < err:
                    break
                step *= 0.5
            else:
                break
            q, e, err = q_new, e_new, err_new

        if err <= tol:
            msg = f"converged in {it} Newton–Raphson iterations"
        else:
            # Reachable but Newton–Raphson stalled (e.g. a target on the annulus edge, where
            # convergence is only linear): take the closed-form branch nearest the current q.
            branch = "up" if _wrap(q[1]) < 0 else "down"
            sol = self.analytic_inverse(target, branch)
            if sol.residual <= tol or sol.residual < err:
                q = _near(sol.q, q)
                err = sol.residual
                msg = (f"Newton–Raphson stalled after {it} iterations; closed-form solution "
                       f"(elbow {branch}) used")
            else:
                msg = f"Newton–Raphson did not converge in {it} iterations"
        q[1] = q2w = _wrap(q[1])
        if elbow is not None and ((elbow == "up" and q2w > 0) or (elbow == "down" and q2w < 0)):
            q = _near(self._mirror(q, target), q)
            q[1] = _wrap(q[1])          # _near may have moved the mirrored q2 by 2π
            err = float(np.hypot(*(target - self.forward(q))))
            msg += f"; mirrored onto the elbow-{elbow} branch"
        return IKResult(q, bool(err <= tol), it, err, msg)

    # ------------------------------------------------------------------ helpers
    def _mirror(self, q, target) -> np.ndarray:
        """The other elbow branch: reflect the arm about the base→target ray
        (q1 → 2φ − q1, q2 → −q2)."""
        d = target - self.base
        phi = math.atan2(d[1], d[0])
        return np.array([2.0 * phi - q[0], -q[1]])

    def _check_target(self, target) -> IKResult | None:
        """None for a reachable finite target, else the failed IKResult."""
        t = np.asarray(target, dtype=float).reshape(-1)
        if t.size != 2 or not np.all(np.isfinite(t)):
            return IKResult(np.zeros(2), False, 0, math.inf,
                            f"target {t.tolist()} invalid: expected a finite (x, y) in m")
        d = t - self.base
        r = float(np.hypot(*d))
        slack = 1e-12 * self.r_max
        if self.r_min - slack <= r <= self.r_max + slack:
            return None
        phi = math.atan2(d[1], d[0])
        if r > self.r_max:
            q = np.array([phi, 0.0])
            where, gap = "beyond the outer radius", r - self.r_max
        else:
            q = np.array([phi if self.l1 >= self.l2 else phi + math.pi, math.pi])
            where, gap = "inside the inner radius", self.r_min - r
        res = float(np.hypot(*(t - self.forward(q))))
        return IKResult(q, False, 0, res,
                        f"target ({t[0]:.6g}, {t[1]:.6g}) m unreachable: its distance from "
                        f"the base ({self.base[0]:.6g}, {self.base[1]:.6g}) m is {r:.6g} m, "
                        f"{where} by {gap:.6g} m; the reachable annulus is "
                        f"[{self.r_min:.6g}, {self.r_max:.6g}] m "
                        f"(l1 = {self.l1:.6g} m, l2 = {self.l2:.6g} m)")


def _near(q, ref) -> np.ndarray:
    """q with each angle shifted by a multiple of 2π to lie nearest ``ref``."""
    q = np.asarray(q, dtype=float).copy()
    q += 2.0 * math.pi * np.round((np.asarray(ref, dtype=float) - q) / (2.0 * math.pi))
    return q


def _wrap(a: float) -> float:
    """Angle wrapped to (−π, π]."""
    return math.pi - (math.pi - a) % (2.0 * math.pi)
