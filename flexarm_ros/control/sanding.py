"""Sanding task: a tool-point trajectory against a wall, with a force-through-position law.

Seed 000 (Hariharesan 1998, Sec. 5.6.3, Figs. 5.26–5.28; simulation only in the source):
"a sanding like operation was simulated where the tip of the manipulator was forced to move
along the constraint surface by varying the commanded position of the tip in time. The
control law discussed above [Eq. 5.16 on inverse-kinematics angles] was used in this case
also." The wall is the line x = −25 mm; the simulated arm goes through free flight, impact,
sliding with friction, separation and a friction-induced direction reversal (near
t = 2.25 s), with the tip y between about 1.0 and 1.35 m. The source gives neither the
trajectory timing nor gains; this module supplies a documented task in that spirit.

Pipeline (each block plain numpy, time an argument, no clock, no rclpy)::

    SandingTask.update(t, dt, tip_xy, in_contact, F_meas) -> (tip_target_xy, phase)
    PlanarTwoLink.inverse(tip_target_xy, q_guess=q_meas) -> q_cmd
    JointPositionController.update(t, dt, q_meas, qd_meas, q_cmd) -> volts

Geometry. The wall is the line x = wall_x; the free side is the side of ``approach_from``
(n = +1 when approach_from[0] > wall_x, else −1). The commanded tool point is pushed
*through* the wall by an offset, so that the position-controlled arm, pulled towards a
point it cannot reach, presses on the wall:

    target_x = wall_x − n · offset                       (offset > 0: behind the wall)

Force-through-position law (an integral force loop acting on the commanded position),
active in ``press``, ``slide_forward``, ``reverse`` and ``slide_back``:

    e = clip(F_set − F_meas, −e_max, e_max)
    offset ← clip(offset + kp_force · e · dt, offset_min, offset_max)

With an effective tool-point stiffness K (closed-loop arm in series with the wall) the
normal force is F ≈ K · offset, so the loop settles at offset = F_set/K with the time
constant 1/(kp_force · K); with a sampled loop it is stable for kp_force · K · dt < 2. The
clips bound what a lost contact (F_meas = 0) can wind up (offset_max is the deepest the
command goes behind the wall) and what an impact spike can unwind: the error is limited to
±e_max (``force_error_limit``, default F_set), so the command moves at most
kp_force·e_max m/s whatever the force reading does during a bounce.

Phases, in order (``phase`` is one of :attr:`SandingTask.PHASES`):

* ``approach``: the target moves from ``approach_from`` to the wall point (wall_x, y_start)
  along a smoothstep s(τ) = 3τ² − 2τ³, τ = (t − t0)/approach_time, then keeps going
  through the wall at ``search_speed`` (up to offset_max). Contact (``in_contact``)
  switches to ``press``; none within ``search_timeout`` after the approach time switches
  to ``lift_off`` with a message.
* ``press``: y moves to y_start at ``speed`` if it is not there yet; the force law runs.
  Leaves for ``slide_forward`` once |F_meas − F_set| <= force_tolerance·F_set has held
  for ``press_time`` (after ``press_timeout`` without it: ``lift_off``, message).
* ``slide_forward``: y runs from y_start to y_end at ``speed`` (force law on). At y_end one
  stroke is done: ``reverse`` if strokes remain, else ``lift_off``.
* ``reverse``: the commanded turn-around: y held at the end for ``reverse_time`` (force
  law on), then ``slide_back`` (or ``slide_forward`` after a back stroke). (The
  friction-induced reversal of the source is a physical effect of the arm, not this.)
* ``slide_back``: y from y_end back to y_start at ``speed``; then ``reverse`` or
  ``lift_off`` as above.
* ``lift_off``: the target retreats along the normal to wall_x + n·lift_distance (y kept)
  over ``lift_time`` (smoothstep); force law off. ``done`` once there and out of contact.
* ``done``: the target holds.

``strokes`` counts passes (one forward or one back): 2 gives forward then back.
Attributes after each update: ``phase``, ``offset`` (m), ``strokes_done``,
``transitions`` (list of (t, phase) entries, the first one at the first update),
``message`` (why the task ended early, else "").
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SandingTask"]


def _smoothstep(tau: float) -> float:
    tau = min(max(tau, 0.0), 1.0)
    return tau * tau * (3.0 - 2.0 * tau)


class SandingTask:
    """State machine commanding the tool point for a sanding pass (see the module doc for
    the law and the phases).

    Parameters
    ----------
    wall_x : float, m. Wall line x = wall_x (seed 000: −0.025).
    y_start, y_end : float, m. Ends of the stroke along the wall (y_start != y_end).
    speed : float, m/s > 0. Commanded sliding speed along y (also used to reach y_start).
    normal_force : float, N > 0. Set point F_set of the normal force.
    approach_from : (x, y) m. Where the approach starts (the tool point at the start); its
        side of the wall is the free side.
    approach_time : float, s > 0. Duration of the smoothstep move to (wall_x, y_start).
    kp_force : float, m/(N·s) > 0. Gain of the force-through-position law.
    strokes : int >= 1. Passes along the wall (forward, back, forward, ...).
    initial_offset : float, m. Offset set on first contact if the command is shallower
        (a feed-forward, e.g. F_set/K for an estimated stiffness K); default 0.
    offset_min, offset_max : float, m. Clip of the offset (offset_min < offset_max);
        offset_min defaults to −offset_max, so the command may also stop short of the
        nominal wall line when the real wall stands proud of it.
    search_speed : float, m/s > 0. Speed through the wall after the approach time.
    search_timeout : float, s. No contact this long after the approach time: lift off.
    press_time : float, s >= 0. Force within tolerance this long before sliding.
    press_timeout : float, s > 0. Longest press phase before giving up (lift off).
    force_tolerance : float > 0. Relative band |F − F_set| <= tol·F_set for press_time.
    reverse_time : float, s >= 0. Dwell at each end before sliding back.
    lift_distance : float, m > 0. Retreat from the wall line along the normal.
    lift_time : float, s > 0. Duration of the retreat.
    force_error_limit : float, N > 0. Clip e_max of the force error in the law (default
        normal_force).
    """

    PHASES = ("approach", "press", "slide_forward", "reverse", "slide_back", "lift_off",
              "done")
    FORCE_PHASES = ("press", "slide_forward", "reverse", "slide_back")

    def __init__(self, wall_x: float, y_start: float, y_end: float, speed: float,
                 normal_force: float, approach_from, approach_time: float, kp_force: float,
                 strokes: int = 2, initial_offset: float = 0.0, offset_min: float | None = None,
                 offset_max: float = 0.05, search_speed: float = 0.02,
                 search_timeout: float = 2.0, press_time: float = 0.2,
                 press_timeout: float = 10.0, force_tolerance: float = 0.1,
                 reverse_time: float = 0.1, lift_distance: float = 0.05,
                 lift_time: float = 1.0, force_error_limit: float | None = None):
        approach_from = np.asarray(approach_from, dtype=float).reshape(-1)
        if offset_min is None:
            offset_min = -offset_max
        if force_error_limit is None:
            force_error_limit = normal_force
        checks = [
            ("wall_x", wall_x, math.isfinite(wall_x), "finite m"),
            ("y_start", y_start, math.isfinite(y_start), "finite m"),
            ("y_end", y_end, math.isfinite(y_end) and y_end != y_start, "finite m, != y_start"),
            ("speed", speed, speed > 0.0, "> 0 m/s"),
            ("normal_force", normal_force, normal_force > 0.0, "> 0 N"),
            ("approach_from", approach_from.tolist(),
             approach_from.size == 2 and bool(np.all(np.isfinite(approach_from)))
             and approach_from[0] != wall_x,
             "finite (x, y) m off the wall line"),
            ("approach_time", approach_time, approach_time > 0.0, "> 0 s"),
            ("kp_force", kp_force, kp_force > 0.0, "> 0 m/(N·s)"),
            ("strokes", strokes, int(strokes) == strokes and strokes >= 1, "an integer >= 1"),
            ("offset_max", offset_max, offset_max > offset_min, f"> offset_min = {offset_min} m"),
            ("initial_offset", initial_offset, offset_min <= initial_offset <= offset_max,
             "within [offset_min, offset_max]"),
            ("search_speed", search_speed, search_speed > 0.0, "> 0 m/s"),
            ("search_timeout", search_timeout, search_timeout >= 0.0, ">= 0 s"),
            ("press_time", press_time, press_time >= 0.0, ">= 0 s"),
            ("press_timeout", press_timeout, press_timeout > 0.0, "> 0 s"),
            ("force_tolerance", force_tolerance, force_tolerance > 0.0, "> 0"),
            ("reverse_time", reverse_time, reverse_time >= 0.0, ">= 0 s"),
            ("lift_distance", lift_distance, lift_distance > 0.0, "> 0 m"),
            ("lift_time", lift_time, lift_time > 0.0, "> 0 s"),
            ("force_error_limit", force_error_limit, force_error_limit > 0.0, "> 0 N"),
        ]
        for name, value, ok, expected in checks:
            if not ok:
                raise ValueError(f"SandingTask.{name}: got {value}, expected {expected}")
        self.wall_x, self.y_start, self.y_end = float(wall_x), float(y_start), float(y_end)
        self.speed, self.normal_force = float(speed), float(normal_force)
        self.approach_from, self.approach_time = approach_from, float(approach_time)
        self.kp_force, self.strokes = float(kp_force), int(strokes)
        self.initial_offset = float(initial_offset)
        self.offset_min, self.offset_max = float(offset_min), float(offset_max)
        self.search_speed, self.search_timeout = float(search_speed), float(search_timeout)
        self.press_time, self.press_timeout = float(press_time), float(press_timeout)
        self.force_tolerance, self.reverse_time = float(force_tolerance), float(reverse_time)
        self.lift_distance, self.lift_time = float(lift_distance), float(lift_time)
        self.force_error_limit = float(force_error_limit)
        self.normal_sign = 1.0 if approach_from[0] > wall_x else -1.0
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the start; the next update begins the approach at its time t."""
        self.phase = "approach"
        self.offset = -self.normal_sign * (self.approach_from[0] - self.wall_x)
        self.strokes_done = 0
        self.transitions: list[tuple[float, str]] = []
        self.message = ""
        self.target = self.approach_from.copy()
        self._t0 = None            # start of the task
        self._t_phase = None       # start of the current phase
        self._y = float(self.approach_from[1])
        self._y_from = self._y
        self._in_band_since = None
        self._lift_from = None
        self._last_slide = "slide_back"

    def _enter(self, t: float, phase: str) -> None:
        self.phase, self._t_phase = phase, t
        self.transitions.append((t, phase))

    def _x_of_offset(self) -> float:
        return self.wall_x - self.normal_sign * self.offset

    # ------------------------------------------------------------------ update
    def update(self, t: float, dt: float, tip_xy, in_contact: bool,
               normal_force_measured: float):
        """Advance the task to time ``t`` (s); ``dt`` (s) is the period since the last call
        (integration step of the force law). tip_xy: measured tool point (m; used by
        nothing but kept for adapters and logging), in_contact: tool touching the wall,
        normal_force_measured: N (>= 0, pressing; NaN holds the offset).
        Returns (tip_target_xy (2,) m, phase)."""
        F = float(normal_force_measured)
        valid = math.isfinite(F)        # a non-finite reading freezes the force law
        if self._t0 is None:
            self._t0 = t
            self._enter(t, "approach")
        if self.phase in self.FORCE_PHASES and valid:
            e = min(max(self.normal_force - F, -self.force_error_limit), self.force_error_limit)
            self.offset = min(max(self.offset + self.kp_force * e * dt, self.offset_min),
                              self.offset_max)

        # transitions (at most one chain per call, evaluated in phase order)
        if self.phase == "approach":
            tr = t - self._t_phase
            if in_contact:
                self._y = self._approach_point(tr)[1]
                self.offset = max(self._approach_offset(tr), self.initial_offset)
                self._enter(t, "press")
            elif tr > self.approach_time + self.search_timeout:
                self.message = (f"no contact with the wall x = {self.wall_x:g} m within "
                                f"{self.search_timeout:g} s after the approach (offset "
                                f"{self.offset:.4g} m behind the wall line)")
                self._start_lift(t)
        if self.phase == "press":
            self._y = self._move_towards(self._y, self.y_start, dt)
            in_band = valid and (abs(F - self.normal_force)
                                 <= self.force_tolerance * self.normal_force)
            if in_band and in_contact:
                if self._in_band_since is None:
                    self._in_band_since = t
            else:
                self._in_band_since = None
            if (self._y == self.y_start and self._in_band_since is not None
                    and t - self._in_band_since >= self.press_time):
                self._start_slide(t, "slide_forward")
            elif t - self._t_phase > self.press_timeout:
                self.message = (f"normal force did not settle within ±{self.force_tolerance:g}"
                                f"·{self.normal_force:g} N in {self.press_timeout:g} s "
                                f"(last {F:.4g} N)")
                self._start_lift(t)
        if self.phase in ("slide_forward", "slide_back"):
            y_to = self.y_end if self.phase == "slide_forward" else self.y_start
            dist = abs(y_to - self._y_from)
            s = self.speed * (t - self._t_phase)
            self._y = y_to if s >= dist else self._y_from + math.copysign(s, y_to - self._y_from)
            if self._y == y_to:
                self.strokes_done += 1
                self._last_slide = self.phase
                if self.strokes_done >= self.strokes:
                    self._start_lift(t)
                else:
                    self._enter(t, "reverse")
        if self.phase == "reverse" and t - self._t_phase >= self.reverse_time:
            self._start_slide(t, "slide_back" if self._last_slide == "slide_forward"
                              else "slide_forward")
        if self.phase == "lift_off":
            s = _smoothstep((t - self._t_phase) / self.lift_time)
            lift_to = np.array([self.wall_x + self.normal_sign * self.lift_distance,
                                self._lift_from[1]])
            self.target = self._lift_from + s * (lift_to - self._lift_from)
            if s >= 1.0 and not in_contact:
                self._enter(t, "done")
            return self.target.copy(), self.phase
        if self.phase == "done":
            return self.target.copy(), self.phase

        if self.phase == "approach":
            tr = t - self._t_phase
            self.offset = self._approach_offset(tr)
            self.target = self._approach_point(tr)
            self._y = float(self.target[1])
        else:
            self.target = np.array([self._x_of_offset(), self._y])
        return self.target.copy(), self.phase

    # ------------------------------------------------------------------ helpers
    def _approach_point(self, tr: float) -> np.ndarray:
        wall_pt = np.array([self.wall_x, self.y_start])
        s = _smoothstep(tr / self.approach_time)
        p = self.approach_from + s * (wall_pt - self.approach_from)
        if tr > self.approach_time:
            p[0] = self.wall_x - self.normal_sign * self._approach_offset(tr)
        return p

    def _approach_offset(self, tr: float) -> float:
        if tr <= self.approach_time:
            s = _smoothstep(tr / self.approach_time)
            return -self.normal_sign * (1.0 - s) * (self.approach_from[0] - self.wall_x)
        return min(self.search_speed * (tr - self.approach_time), self.offset_max)

    def _move_towards(self, y: float, y_to: float, dt: float) -> float:
        step = self.speed * dt
        return y_to if abs(y_to - y) <= step else y + math.copysign(step, y_to - y)

    def _start_slide(self, t: float, phase: str) -> None:
        self._y_from = self._y
        self._enter(t, phase)

    def _start_lift(self, t: float) -> None:
        self._lift_from = np.array([self._x_of_offset() if self.phase != "approach"
                                    else self.target[0], self._y])
        self._enter(t, "lift_off")
