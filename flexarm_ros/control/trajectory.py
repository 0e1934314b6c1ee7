"""Joint trajectories for the position controller: a scene's move program
(``control.moves``) and ``trajectory_msgs/JointTrajectory`` messages on
``controller/joint_trajectory``, in the convention of ros2_control's
joint_trajectory_controller.

A trajectory starts at time t₀ from the commanded angles and rates it replaces (q₀, q̇₀)
and passes through points (t₀ + τ_k, q_k[, q̇_k]), τ_k the points' ``time_from_start``,
strictly increasing and > 0. Between points the reference r(t) is

* linear in t where the points give positions only (joint_trajectory_controller's
  positions-only interpolation), its rate the slope;
* the cubic Hermite polynomial where they give velocities too (each segment matches
  q and q̇ at both ends: r(s) = h₀₀ q_a + h₁₀ Δ q̇_a + h₀₁ q_b + h₁₁ Δ q̇_b, s = (t − t_a)/Δ,
  h₀₀ = 2s³ − 3s² + 1, h₁₀ = s³ − 2s² + s, h₀₁ = −2s³ + 3s², h₁₁ = s³ − s²),

and is held at the last point after it (rate 0). An input shaper (``control.shaper``)
filters the whole reference: q_cmd(t) = Σᵢ Aᵢ r(t − tᵢ) (Singer & Seering 1990), the step
of a single target being the special case r = q₀ before t₀ and q* after.

:func:`~flexarm_ros.scene.trajectory_points.check_points` validates a trajectory before it changes anything: names that are
the scene's joints (each once, any order), finite positions and velocities of the right
length, times strictly increasing and > 0, targets within the joints' position limits.
"""

from __future__ import annotations

import numpy as np

from flexarm_ros.scene.trajectory_points import MAX_POINTS, check_points


class Trajectory:
    """r(t), ṙ(t) of the module doc for one trajectory."""

    def __init__(self, t0: float, q0, qd0, times, positions, velocities=None):
        self.t = np.concatenate([[float(t0)], float(t0) + np.asarray(times, float)])
        self.q = np.vstack([np.asarray(q0, float), np.asarray(positions, float)])
        self.cubic = velocities is not None
        if self.cubic:
            self.qd = np.vstack([np.asarray(qd0, float), np.asarray(velocities, float)])

    @property
    def end(self) -> float:
        """The time of the last point, s."""
        return float(self.t[-1])

    @property
    def goal(self) -> np.ndarray:
        """The last point's positions."""
        return self.q[-1].copy()

    def at(self, t: float):
        """(r(t), ṙ(t)): q₀ before t₀, the last point after the end."""
        if t <= self.t[0]:
            return self.q[0].copy(), np.zeros(self.q.shape[1])
        if t >= self.t[-1]:
            return self.q[-1].copy(), np.zeros(self.q.shape[1])
        k = int(np.searchsorted(self.t, t, side="right")) - 1
        ta, tb = self.t[k], self.t[k + 1]
        dt = tb - ta
        qa, qb = self.q[k], self.q[k + 1]
        if not self.cubic:
            s = (t - ta) / dt
            return qa + s * (qb - qa), (qb - qa) / dt
        s = (t - ta) / dt
        va, vb = self.qd[k], self.qd[k + 1]
        h00, h10 = 2 * s ** 3 - 3 * s ** 2 + 1, s ** 3 - 2 * s ** 2 + s
        h01, h11 = -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
        d00, d10 = (6 * s ** 2 - 6 * s) / dt, 3 * s ** 2 - 4 * s + 1
        d01, d11 = (-6 * s ** 2 + 6 * s) / dt, 3 * s ** 2 - 2 * s
        r = h00 * qa + h10 * dt * va + h01 * qb + h11 * dt * vb
        rd = d00 * qa + d10 * va + d01 * qb + d11 * vb
        return r, rd


class Reference:
    """The controller's reference over time: a start (q₀ held) and the trajectories that
    replaced each other, each from its own start time; shaped by an optional shaper."""

    def __init__(self, q0, shaper=None):
        self.q0 = np.asarray(q0, float).copy()
        self.segments: list[Trajectory] = []
        self.shaper = shaper

    def add(self, traj: Trajectory) -> None:
        """``traj`` replaces the reference from its start on."""
        self.segments = [s for s in self.segments if s.t[0] < traj.t[0]]
        self.segments.append(traj)
        # the shaper looks back at most its length: older segments are not needed
        span = self.shaper.times[-1] if self.shaper is not None else 0.0
        while len(self.segments) > 1 and self.segments[1].t[0] <= traj.t[0] - span - 1.0:
            self.segments.pop(0)

    def raw(self, t: float):
        """(r(t), ṙ(t)) before shaping."""
        seg = None
        for s in self.segments:
            if s.t[0] <= t:
                seg = s
        if seg is None:
            return self.q0.copy(), np.zeros_like(self.q0)
        return seg.at(t)

    def at(self, t: float):
        """(q_cmd(t), q̇_cmd(t)): Σ Aᵢ r(t − tᵢ) with the shaper, else r(t)."""
        if self.shaper is None:
            return self.raw(t)
        q, qd = np.zeros_like(self.q0), np.zeros_like(self.q0)
        for ti, a in zip(self.shaper.times, self.shaper.amplitudes):
            # 1 ns late: an impulse within 1 ns of t counts as reached (Shaper.share)
            r, rd = self.raw(t - ti + 1e-9)
            q += a * r
            qd += a * rd
        return q, qd


__all__ = ["MAX_POINTS", "Reference", "Trajectory", "check_points"]
