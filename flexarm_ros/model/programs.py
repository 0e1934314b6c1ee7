"""Time programs: joint torques u(t) and prescribed joint motions (θ, θ̇, θ̈)(t).

Programs are pure functions of time; components never read a clock (time is an argument).
"""

from __future__ import annotations

import math

import numpy as np


def torque_value(prog, t: float) -> float:
    """Value of a torque program at time ``t`` (see :class:`scene.Program`)."""
    kind = prog.type
    if kind == "constant":
        return prog.value
    if kind == "pulse":
        return prog.amplitude if prog.start <= t < prog.start + prog.width else 0.0
    if kind == "square":
        if t < prog.start:
            return 0.0
        phase = (prog.frequency_hz * (t - prog.start) + prog.phase_deg / 360.0) % 1.0
        return prog.offset + (prog.amplitude if phase < 0.5 else -prog.amplitude)
    if kind == "piecewise_constant":
        times = prog.times
        if t < times[0]:
            return 0.0
        k = int(np.searchsorted(times, t, side="right")) - 1
        return prog.values[k]
    if kind == "piecewise_linear":
        return float(np.interp(t, prog.times, prog.values))
    raise ValueError(f"torque program type {kind!r} has no value")


def torque_breakpoints(prog, t_end: float) -> list[float]:
    """Times in (0, t_end) where a torque program jumps (integrators step onto them)."""
    kind = prog.type
    pts: list[float] = []
    if kind == "pulse":
        pts = [prog.start, prog.start + prog.width]
    elif kind == "square":
        half = 0.5 / prog.frequency_hz
        shift = (prog.phase_deg / 360.0) % 1.0 / prog.frequency_hz
        first = prog.start + (half - shift) % half if shift else prog.start + half
        pts = [prog.start] + list(np.arange(first, t_end, half))
    elif kind in ("piecewise_constant", "piecewise_linear"):
        pts = list(prog.times)
    return sorted(p for p in pts if 0.0 < p < t_end)


def motion_state(prog, theta0: float, t: float) -> tuple[float, float, float]:
    """(θ, θ̇, θ̈) of a prescribed-motion program at time ``t``.

    spin_up (Kane, Ryan & Banerjee, J. Guidance 10(2) 1987, Eq. 38):
    θ = (Ω/T)[t²/2 + (T/2π)²(cos(2πt/T) − 1)] for t < T, then Ω(t − T/2).
    smooth_step (cycloidal): θ = A[τ − sin(2πτ)/2π], τ = (t − t0)/T clipped to [0, 1].
    """
    kind = prog.type
    if kind == "hold":
        return theta0, 0.0, 0.0
    if kind == "spin_up":
        W, T = prog.omega, prog.ramp_time
        if t < T:
            a = 2 * math.pi / T
            th = W / T * (t * t / 2 + (math.cos(a * t) - 1) / a**2)
            return theta0 + th, W / T * (t - math.sin(a * t) / a), W / T * (1 - math.cos(a * t))
        return theta0 + W * (t - T / 2), W, 0.0
    if kind == "smooth_step":
        A, T = prog.amplitude, prog.ramp_time
        tau = (t - prog.start) / T
        if tau <= 0:
            return theta0, 0.0, 0.0
        if tau >= 1:
            return theta0 + A, 0.0, 0.0
        w = 2 * math.pi
        return (theta0 + A * (tau - math.sin(w * tau) / w), A / T * (1 - math.cos(w * tau)),
                A / T**2 * w * math.sin(w * tau))
    raise ValueError(f"motion program type {kind!r} has no state")
