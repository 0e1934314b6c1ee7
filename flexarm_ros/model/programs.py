"""Time programs: joint torques u(t) and prescribed joint motions (θ, θ̇, θ̈)(t).

Programs are pure functions of time; components never read a clock (time is an argument).
A program is encoded once (:func:`encode`) into a type code, a parameter vector and
breakpoint arrays; :func:`eval_torque` and :func:`eval_motion` evaluate that encoding and
are written in scalar Python that numba compiles unchanged, so the compiled integration
loop and the pure-numpy path share one implementation.
"""

from __future__ import annotations

import math

import numpy as np

CODES = {"constant": 0, "step": 5, "pulse": 1, "square": 2, "piecewise_constant": 3,
         "piecewise_linear": 4, "hold": 10, "spin_up": 11, "smooth_step": 12}


def encode(prog, theta0: float = 0.0):
    """(code, params[8], times, values) of a :class:`scene.Program`.

    params = [value, amplitude, start, width, frequency_hz, phase (cycles), offset, theta0]
    with, for motions, width := ramp_time and frequency_hz := omega.
    """
    code = CODES[prog.type]
    p = np.array([prog.value, prog.amplitude, prog.start, prog.width, prog.frequency_hz,
                  prog.phase_deg / 360.0, prog.offset, theta0])
    if prog.type in ("spin_up", "smooth_step"):
        p[3] = prog.ramp_time
        p[4] = prog.omega
    times = np.array(prog.times if prog.times else (0.0,), float)
    values = np.array(prog.values if prog.values else (0.0,), float)
    return code, p, times, values


def eval_torque(code, p, times, values, t):
    """Program value at time t: constant; step (offset, + amplitude from start); pulse [start, start+width); square wave
    (offset ± amplitude, phase in cycles, from start); piecewise constant (value i from
    times[i]); piecewise linear (held at the ends)."""
    if code == 0:
        return p[0]
    if code == 5:
        return p[6] + (p[1] if t >= p[2] else 0.0)
    if code == 1:
        return p[1] if (t >= p[2] and t < p[2] + p[3]) else 0.0
    if code == 2:
        if t < p[2]:
            return 0.0
        ph = (p[4] * (t - p[2]) + p[5]) % 1.0
        return p[6] + (p[1] if ph < 0.5 else -p[1])
    if code == 3:
        if t < times[0]:
            return 0.0
        k = 0
        for i in range(times.shape[0]):
            if times[i] <= t:
                k = i
        return values[k]
    if code == 4:
        if t <= times[0]:
            return values[0]
        last = times.shape[0] - 1
        if t >= times[last]:
            return values[last]
        for i in range(last):
            if t < times[i + 1]:
                fr = (t - times[i]) / (times[i + 1] - times[i])
                return values[i] + fr * (values[i + 1] - values[i])
    return 0.0


def eval_motion(code, p, t):
    """(θ, θ̇, θ̈) of a prescribed motion; θ0 = p[7].

    spin_up (Kane, Ryan & Banerjee, J. Guidance 10(2) 1987): with Ω = p[4], T = p[3],
    θ = (Ω/T)[t²/2 + (T/2π)²(cos(2πt/T) − 1)] for t < T, then Ω(t − T/2).
    smooth_step (cycloidal): θ = A[τ − sin(2πτ)/2π], τ = (t − start)/T in [0, 1].
    hold: θ0.
    """
    th0 = p[7]
    if code == 11:
        W = p[4]
        T = p[3]
        if t < T:
            a = 2.0 * math.pi / T
            th = W / T * (t * t / 2.0 + (math.cos(a * t) - 1.0) / (a * a))
            return th0 + th, W / T * (t - math.sin(a * t) / a), W / T * (1.0 - math.cos(a * t))
        return th0 + W * (t - T / 2.0), W, 0.0
    if code == 12:
        A = p[1]
        T = p[3]
        tau = (t - p[2]) / T
        if tau <= 0.0:
            return th0, 0.0, 0.0
        if tau >= 1.0:
            return th0 + A, 0.0, 0.0
        w = 2.0 * math.pi
        return (th0 + A * (tau - math.sin(w * tau) / w), A / T * (1.0 - math.cos(w * tau)),
                A / (T * T) * w * math.sin(w * tau))
    return th0, 0.0, 0.0


def torque_breakpoints(prog, t_end: float) -> list[float]:
    """Times in (0, t_end) where a torque program jumps (adaptive integrators restart there)."""
    kind = prog.type
    pts: list[float] = []
    if kind == "pulse":
        pts = [prog.start, prog.start + prog.width]
    elif kind == "step":
        pts = [prog.start]
    elif kind == "square":
        half = 0.5 / prog.frequency_hz
        ph = (prog.phase_deg / 360.0) % 1.0
        # phase crosses 0.5 and 1.0 every half period
        first = prog.start + ((0.5 - ph) % 0.5) / prog.frequency_hz
        pts = [prog.start] + list(np.arange(first, t_end, half))
    elif kind in ("piecewise_constant", "piecewise_linear"):
        pts = list(prog.times)
    return sorted(p for p in pts if 0.0 < p < t_end)
