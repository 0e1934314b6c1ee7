"""Input shapers: impulse sequences whose convolution with a step leaves a damped mode at
rest after the last impulse (Singer & Seering, "Preshaping command inputs to reduce system
vibration", J. Dyn. Sys. Meas. Control 112, 1990; Singhose, Seering & Singer 1994 for
the robustness). For a mode of natural frequency ω and damping ratio ζ, with
ω_d = ω√(1 − ζ²) and K = exp(−ζπ/√(1 − ζ²)):

    ZV    A = [1, K] / (1 + K)                       t = [0, T/2]
    ZVD   A = [1, 2K, K²] / (1 + K)²                 t = [0, T/2, T]
    ZVDD  A = [1, 3K, 3K², K³] / (1 + K)³            t = [0, T/2, T, 3T/2]

with T = 2π/ω_d the damped period. Several modes: the shapers convolved (every pair of
impulses, times added, amplitudes multiplied). :func:`residual` is the percentage
vibration V(ω, ζ) a sequence leaves (the closed form of Singer & Seering, Eq. 4), the
independent check of every sequence here.
"""

from __future__ import annotations

import math

import numpy as np

SHAPERS = ("zv", "zvd", "zvdd")
#: impulses closer than this (s) are merged when sequences are convolved
MERGE_S = 1e-12


def shaper(kind: str, freq_hz: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """(times s, amplitudes) of shaper ``kind`` for one mode (module doc)."""
    if kind not in SHAPERS:
        raise ValueError(f"shaper: got {kind!r}, expected one of {', '.join(SHAPERS)}")
    if not (freq_hz > 0 and math.isfinite(freq_hz)) or not 0 <= zeta < 1:
        raise ValueError(f"shaper: got f = {freq_hz} Hz, ζ = {zeta}, expected f > 0 and "
                         f"0 <= ζ < 1 (an oscillating mode)")
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
