"""Input shapers: impulse sequences whose convolution with a step leaves a damped mode at
rest after the last impulse (Singer & Seering, "Preshaping command inputs to reduce system
vibration", J. Dyn. Sys. Meas. Control 112, 1990; Singhose, Seering & Singer 1994 for
the robustness). For a mode of natural frequency ω and damping ratio ζ, with
ω_d = ω√(1 − ζ²) and K = exp(−ζπ/√(1 − ζ²)):

    ZV    A = [1, K] / (1 + K)                       t = [0, T/2]
    ZVD   A = [1, 2K, K²] / (1 + K)²                 t = [0, T/2, T]
    ZVDD  A = [1, 3K, 3K², K³] / (1 + K)³            t = [0, T/2, T, 3T/2]

with T = 2π/ω_d the damped period; EI (extra-insensitive, Singhose, Seering & Singer,
"Residual vibration reduction using vector diagrams", J. Mech. Design 116, 1994): three
impulses that leave V = 5 % at the design frequency, with V' = 0 there, and V = 0 at one
frequency on either side — undamped A = [(1+V)/4, (1−V)/2, (1+V)/4], t = [0, T/2, T];
damped, the same six conditions solved numerically from that start. Several modes: the shapers convolved (every pair of
impulses, times added, amplitudes multiplied). :func:`residual` is the percentage
vibration V(ω, ζ) a sequence leaves (the closed form of Singer & Seering, Eq. 4), the
independent check of every sequence here.
"""

from __future__ import annotations

import math

import numpy as np

SHAPERS = ("zv", "zvd", "zvdd", "ei")
#: the extra-insensitive shaper's residual at its design frequency (Singhose, Seering &
#: Singer 1994: 5 %)
EI_VTOL = 0.05
#: impulses closer than this (s) are merged when sequences are convolved
MERGE_S = 1e-12


def shaper(kind: str, freq_hz: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(times s, amplitudes) of shaper ``kind`` for one mode (module doc)."""
    if kind not in SHAPERS:
        raise ValueError(f"shaper: got {kind!r}, expected one of {', '.join(SHAPERS)}")
    if not (freq_hz > 0 and math.isfinite(freq_hz)) or not 0 <= zeta < 1:
        raise ValueError(f"shaper: got f = {freq_hz} Hz, ζ = {zeta}, expected f > 0 and "
                         f"0 <= ζ < 1 (an oscillating mode)")
    if kind == "ei":
        return _ei(freq_hz, zeta)
    root = math.sqrt(1.0 - zeta * zeta)
    K = math.exp(-zeta * math.pi / root)
    half = math.pi / (2.0 * math.pi * freq_hz * root)        # T/2 = π/ω_d
    order = SHAPERS.index(kind) + 1                          # binomial order 1, 2, 3
    amps = np.array([math.comb(order, i) * K ** i for i in range(order + 1)])
    return half * np.arange(order + 1), amps / amps.sum()


def convolve(*sequences) -> tuple[np.ndarray, np.ndarray]:
    """The convolution of impulse sequences (times, amplitudes), impulses at equal times
    merged, sorted by time."""
    t, a = np.zeros(1), np.ones(1)
    for ts, amps in sequences:
        t = (t[:, None] + np.asarray(ts)[None, :]).ravel()
        a = (a[:, None] * np.asarray(amps)[None, :]).ravel()
    order = np.argsort(t, kind="stable")
    t, a = t[order], a[order]
    keep_t, keep_a = [t[0]], [a[0]]
    for ti, ai in zip(t[1:], a[1:]):
        if ti - keep_t[-1] <= MERGE_S:
            keep_a[-1] += ai
        else:
            keep_t.append(ti)
            keep_a.append(ai)
    return np.array(keep_t), np.array(keep_a)


def residual(times, amps, freq_hz: float, zeta: float) -> float:
    """V: the vibration left by the sequence after its last impulse, as a fraction of
    the vibration of an unshaped step (Singer & Seering 1990, Eq. 4):
    V = exp(−ζωt_N)·√(C² + S²), C = Σ Aᵢ e^{ζωtᵢ} cos(ω_d tᵢ), S = Σ Aᵢ e^{ζωtᵢ} sin(ω_d tᵢ)."""
    w = 2.0 * math.pi * freq_hz
    wd = w * math.sqrt(1.0 - zeta * zeta)
    t = np.asarray(times, float)
    a = np.asarray(amps, float)
    e = np.exp(zeta * w * (t - t[-1]))
    return float(math.hypot(np.sum(a * e * np.cos(wd * t)), np.sum(a * e * np.sin(wd * t))))


def on_grid(times, amps, period: float) -> tuple[np.ndarray, np.ndarray]:
    """The impulses moved to the nearest multiple of the control ``period`` (where the
    controller applies them), equal times merged."""
    t = np.round(np.asarray(times, float) / period) * period
    return convolve((t, np.asarray(amps, float)))


def _vector(times, amps, w, zeta):
    """Σ Aᵢ e^{ζω(tᵢ − t_N)} e^{iω_d tᵢ}: its modulus is :func:`residual` at ω."""
    t = np.asarray(times, float)
    wd = w * math.sqrt(1.0 - zeta * zeta)
    return np.sum(np.asarray(amps) * np.exp(zeta * w * (t - t[-1])) * np.exp(1j * wd * t))


def _ei_parts(x, w, zeta):
    """(times, amplitudes, ω₁, ω₂) of the EI unknowns ``x`` (times in damped periods)."""
    a1, a2, t2, t3, w1, w2 = x
    T = 2.0 * math.pi / (w * math.sqrt(1.0 - zeta * zeta))
    return (np.array([0.0, t2 * T, t3 * T]), np.array([a1, a2, 1.0 - a1 - a2]),
            w1 * w, w2 * w)


def _ei_conditions(x, w, zeta, vtol):
    """The six EI conditions at ``x`` (:func:`_ei`), each 0 at the solution."""
    t, a, w1, w2 = _ei_parts(x, w, zeta)
    h = 1e-6 * w
    f = w / (2 * math.pi)
    vm = residual(t, a, f, zeta)
    dv = (residual(t, a, (w + h) / (2 * math.pi), zeta)
          - residual(t, a, (w - h) / (2 * math.pi), zeta)) / (2 * h) * w
    z1, z2 = _vector(t, a, w1, zeta), _vector(t, a, w2, zeta)
    return [vm - vtol, dv, z1.real, z1.imag, z2.real, z2.imag]


def _ei(freq_hz, zeta, vtol=EI_VTOL):
    """The EI shaper (module doc): unknowns A₁, A₂ (A₃ = 1 − A₁ − A₂), t₂, t₃ and the two
    zero-vibration frequencies ω₁ < ω < ω₂; conditions V(ω) = vtol, dV/dω(ω) = 0 and
    V(ω₁) = V(ω₂) = 0 (real and imaginary parts)."""
    from scipy.optimize import fsolve
    w = 2.0 * math.pi * freq_hz

    def parts(x):
        return _ei_parts(x, w, zeta)

    def eqs(x):
        return _ei_conditions(x, w, zeta, vtol)
    # undamped start: the zero frequencies of [(1+V)/4, (1-V)/2, (1+V)/4] at T/2 spacing,
    # cos(ω_i T/2) = −(1 − V)/(1 + V)
    c = math.acos(-(1.0 - vtol) / (1.0 + vtol)) / math.pi
    x = [(1 + vtol) / 4, (1 - vtol) / 2, 0.5, 1.0, c, 2.0 - c]
    ok, msg = 1, ""
    # continuation from the undamped solution in steps of ζ (a start far from the damped
    # solution does not converge for ζ ~ 0.5)
    for z in np.linspace(0.0, zeta, max(2, int(math.ceil(zeta / 0.02)) + 1))[1:]:
        x, info, ok, msg = fsolve(lambda y, z=z: _ei_conditions(y, w, z, vtol), x,
                                  full_output=True, xtol=1e-13)
    if not max(abs(v) for v in eqs(x)) <= 1e-9:     # fsolve may stall at round-off
        raise ValueError(f"shaper: the EI conditions did not solve for f = {freq_hz} Hz, "
                         f"ζ = {zeta} ({msg.strip()}); use zvd")
    t, a, _, _ = parts(x)
    if np.any(a <= 0) or not 0 < t[1] < t[2]:
        raise ValueError(f"shaper: the EI solution for ζ = {zeta} has a non-positive "
                         f"impulse; use zvd")
    return t, a


def ei_zero_frequencies(times, amps, freq_hz, zeta):
    """The frequencies (Hz) either side of ``freq_hz`` where the sequence leaves no
    vibration (a check of the EI shaper: the local minima of V)."""
    from scipy.optimize import minimize_scalar
    out = []
    for lo, hi in ((0.5, 1.0), (1.0, 1.5)):
        r = minimize_scalar(lambda f: residual(times, amps, f, zeta),
                            bounds=(lo * freq_hz, hi * freq_hz), method="bounded",
                            options={"xatol": 1e-10 * freq_hz})
        out.append(float(r.x))
    return out
