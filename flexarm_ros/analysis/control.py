"""Control metrics of a channel that tracks a command (a step or a ramp in its target).

All functions take plain arrays (times in s, strictly increasing; values in the channel's
unit). :func:`tracking_metrics` measures one record against its own target; ``flexarm
compare`` (:mod:`flexarm_ros.analysis.compare`) runs it on the run and on the reference and
judges the differences.

Definitions (the textbook ones, e.g. Ogata, *Modern Control Engineering*, Sec. 5-3;
Franklin, Powell & Emami-Naeini, Sec. 3.4):

* The target is a command, held between its samples (zero-order hold): at an output
  instant t the target is its last sample at or before t.
* **The command.** The last change of the target decides it. ``final`` = the target at
  the end. The final hold starts at the first sample from which the target stays within
  :func:`target_tolerance` of ``final``. Before the hold the target moved (walking back
  from the hold while it keeps moving the same way): one sample apart it is a **step**,
  applied at the first sample at its new value; longer, a **ramp**, from the last sample at
  the old value to the hold. A target constant over the output's span is a step at the
  span's start when it was set there (its last change before, or its first sample, at
  most one output sample before the span) and differs from the output's first value by
  more than the output's resolution (:func:`step_threshold`): a setpoint given at t = 0,
  as the twin's position controller does. Otherwise there is **no step** (regulation, or
  a step before the analysed span: only the final and RMS tracking errors are measured).
  A target still moving at the last sample is a ramp that does not end (no overshoot,
  rise or settling time).
* ``initial`` = the output at the command's onset (interpolated), ``step = final -
  initial`` (the change the loop has to make), direction d = sign(step).
* **Final error** = |y(T) - target(T)| at the last output sample T.
* **RMS tracking error** = sqrt(mean((y - target)^2)) over every output sample.
* **Overshoot** = max(0, max_t (y(t) - final)·d) / |step| over t >= onset: how far the
  output goes beyond the final target in the direction of travel, as a fraction of the
  step (0.163 = 16.3 %).
* **Rise time** = t90 - t10, the first times (after the onset, interpolated linearly
  between samples) the output has made 10 % and 90 % of the step.
* **Settling time** = the time, from the onset, after which the output stays within
  ±``band``·|step| (default 2 %) of the final target: the last exit from the band,
  interpolated on the band edge. Null when the output is outside the band at the end
  (a steady-state error larger than the band: the final error says how large).

Closed forms the tests check: y = 1 - exp(-t/τ) has rise time τ ln 9, settling time
τ ln 50 and no overshoot; a second-order step response with damping ζ < 1 overshoots by
exp(-πζ/sqrt(1 - ζ²)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.analysis.spectra import checked_series

__all__ = ["COMMAND_KINDS", "METRIC_KEYS", "RISE_FROM", "RISE_TO", "SETTLING_BAND",
           "Command", "detect_command", "noise_sigma", "step_threshold",
           "target_tolerance", "tracking_metrics"]

#: The settling band, a fraction of the step: ±2 % around the final target.
SETTLING_BAND = 0.02
#: Rise time from 10 % to 90 % of the step.
RISE_FROM, RISE_TO = 0.10, 0.90
#: ``Command.kind``: a jump, a ramp segment, or no step (regulation).
COMMAND_KINDS = ("step", "ramp", "none")
#: The metrics of one record (``tracking_metrics(...)["metrics"]``), in report order.
METRIC_KEYS = ("final_error", "overshoot", "rise_time_s", "settling_time_s",
               "rms_tracking_error")
#: A target moves when it changes by more than this fraction of max(1, max|target|): far
#: above the rounding of a number written with ten significant digits (5e-11).
_TARGET_REL = 1e-9
#: An output differs from a constant target by a step when the gap exceeds this many
#: standard deviations of the output's noise (:func:`noise_sigma`).
_NOISE_SIGMAS = 5.0


@dataclass(frozen=True)
class Command:
    """What the target commands over a record (module docstring).

    ``kind``: ``step``, ``ramp`` or ``none``; ``onset_s``: when the command's last change
    starts (the first sample at the new value of a step, the last sample at the old value
    of a ramp, the record's start for a setpoint held from it); ``hold_s``: when the target
    reaches its final value (None: a ramp still moving at the end); ``initial``: the output
    at the onset; ``final``: the target at the end; ``step = final - initial``; ``why``:
    for ``none`` and an unfinished ramp, why there are no step metrics."""

    kind: str
    onset_s: float | None
    hold_s: float | None
    initial: float | None
    final: float
    step: float | None
    why: str | None = None

    def as_dict(self) -> dict:
        return {"kind": self.kind, "onset_s": _num(self.onset_s), "hold_s": _num(self.hold_s),
                "initial": _num(self.initial), "final_target": _num(self.final),
                "step": _num(self.step)}


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def noise_sigma(y) -> float:
    """A robust estimate of the white noise on a record: the median absolute deviation
    of its second differences, 1.4826 MAD / sqrt(6) (a smooth signal's second differences
    are ~0, white noise of std σ gives second differences of std σ sqrt(6))."""
    y = np.asarray(y, dtype=float)
    if y.size < 3:
        return 0.0
    d2 = np.diff(y, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def target_tolerance(target) -> float:
    """The change below which a target counts as not moving: 1e-9 of max(1, max|target|)
    (commands are exact numbers; this is above the rounding of a 10-digit CSV cell)."""
    target = np.asarray(target, dtype=float)
    return _TARGET_REL * max(1.0, float(np.max(np.abs(target))) if target.size else 1.0)


def step_threshold(target, y, quantum: float = 0.0) -> float:
    """The smallest output change that counts as a step: the largest of the target's
    tolerance, the measurement quantum (one encoder count) and 5 σ of the output's noise."""
    return max(target_tolerance(target), float(quantum), _NOISE_SIGMAS * noise_sigma(y))


def _held(tt, target, t):
    """The target at the instants ``t``, each its last sample at or before (zero-order
    hold; the first sample before the target starts)."""
    idx = np.searchsorted(tt, t, side="right") - 1
    return target[np.clip(idx, 0, tt.size - 1)]


def detect_command(t, y, tt, target, quantum: float = 0.0) -> Command:
    """The command of the target ``(tt, target)`` against the output ``(t, y)`` over the
    output's span (module docstring). ``quantum``: the output's resolution (one encoder
    count in the output's unit; 0 when unknown)."""
    t, y = checked_series(t, y, name="output", min_samples=2)
    tt, target = checked_series(tt, target, name="target", min_samples=1)
    # the target over the output's span, with the value it holds at the span's start
    inside = (tt > t[0]) & (tt <= t[-1])
    ts = np.concatenate(([t[0]], tt[inside]))
    gs = np.concatenate((_held(tt, target, t[:1]), target[inside]))
    tol = target_tolerance(gs)
    final = float(gs[-1])
    off = np.abs(gs - final) > tol
    h = int(np.flatnonzero(off)[-1]) + 1 if off.any() else 0     # first sample of the hold
    if h == 0:                          # constant target: a setpoint from the start, or none
        initial = float(y[0])
        step = final - initial
        thr = step_threshold(gs, y, quantum)
        if abs(step) <= thr:
            return Command("none", None, None, initial, final, None,
                           f"the target is constant ({final:.6g}) and equal to the output's "
                           f"first value within {thr:.3g} (no step or ramp to respond to)")
        # when was this setpoint given? the target's last change before the span, else
        # its first sample; a step before the span is not in the analysed response
        before = (tt <= t[0]) & (np.abs(target - final) > tol)
        given = float(tt[np.flatnonzero(before)[-1] + 1]) if before.any() else float(tt[0])
        if given < t[0] - float(np.median(np.diff(t))):
            return Command("none", None, None, initial, final, None,
                           f"the target ({final:.6g}) was set at {given:.6g} s, before the "
                           f"analysed span starting at {t[0]:.6g} s: the step response is "
                           f"not in the span (widen --window to include it)")
        return Command("step", float(t[0]), float(t[0]), initial, final, step)
    d = math.copysign(1.0, final - gs[h - 1])
    i = h - 1
    while i > 0 and (gs[i] - gs[i - 1]) * d > tol:
        i -= 1
    kind = "step" if h - i == 1 else "ramp"
    onset = float(ts[h] if kind == "step" else ts[i])
    initial = float(np.interp(onset, t, y))
    if ts[h] >= t[-1]:                  # the target arrives at the last output instant
        return Command(kind, onset, None, initial, final, final - initial,
                       "the command still moves at the end of the span (no final hold "
                       "to settle in): no overshoot, rise or settling time")
    step = final - initial
    thr = step_threshold(gs, y, quantum)
    if abs(step) <= thr:
        return Command("none", onset, float(ts[h]), initial, final, None,
                       f"the last command change ends where the output was at its onset "
                       f"(within {thr:.3g}): no step to respond to")
    return Command(kind, onset, float(ts[h]), initial, final, step)


def _first_crossing(t, s, level):
    """First time s rises through ``level`` (s[i] < level <= s[i+1], interpolated), or
    t[0] when s starts at or above it, None when it never gets there."""
    if s[0] >= level:
        return float(t[0])
    hit = np.flatnonzero((s[:-1] < level) & (s[1:] >= level))
    if hit.size == 0:
        return None
    i = int(hit[0])
    return float(t[i] + (t[i + 1] - t[i]) * (level - s[i]) / (s[i + 1] - s[i]))


def tracking_metrics(t, y, tt, target, *, quantum: float = 0.0,
                     band: float = SETTLING_BAND) -> dict:
    """The control metrics of the output ``(t, y)`` against its target ``(tt, target)``.

    Returns ``{"command": Command, "metrics": {key: float or None}, "why": {key: reason},
    "end_error": y(T) - target(T) (signed)}``, ``metrics`` with the keys of
    :data:`METRIC_KEYS` (definitions in the module docstring): the final and RMS tracking
    errors always; overshoot, rise and settling time only for a step or a ramp that ends
    (else None, the reason under ``why``).

    Raises:
        ValueError: invalid records (fewer than 2 output samples, non-increasing times).
    """
    t, y = checked_series(t, y, name="output", min_samples=2)
    tt, target = checked_series(tt, target, name="target", min_samples=1)
    if not (math.isfinite(band) and 0.0 < band < 1.0):
        raise ValueError(f"band must be a fraction in (0, 1), got {band!r}")
    e = y - _held(tt, target, t)
    m = {k: None for k in METRIC_KEYS}
    why: dict = {}
    m["final_error"] = float(abs(e[-1]))
    end = float(e[-1])
    m["rms_tracking_error"] = float(np.sqrt(np.mean(e * e)))
    cmd = detect_command(t, y, tt, target, quantum)
    if cmd.kind == "none" or cmd.hold_s is None:
        for k in ("overshoot", "rise_time_s", "settling_time_s"):
            why[k] = cmd.why
        return {"command": cmd, "metrics": m, "why": why, "end_error": end}
    after = t >= cmd.onset_s
    ta, ya = t[after], y[after]
    d = math.copysign(1.0, cmd.step)
    size = abs(cmd.step)
    s = (ya - cmd.initial) * d / size                   # progress: 0 at the onset, 1 on target
    m["overshoot"] = max(0.0, float(np.max((ya - cmd.final) * d)) / size)
    t10 = _first_crossing(ta, s, RISE_FROM)
    t90 = _first_crossing(ta, s, RISE_TO)
    if t10 is None or t90 is None:
        reached = float(np.max(s))
        why["rise_time_s"] = (f"the output makes at most {100 * reached:.3g} % of the step, "
                              f"never {100 * RISE_TO:g} %")
    else:
        m["rise_time_s"] = t90 - t10
    dev = ya - cmd.final
    edge = band * size
    out = np.abs(dev) > edge
    if out[-1]:
        why["settling_time_s"] = (f"not within ±{100 * band:g} % of the step "
                                  f"(±{edge:.3g}) of the final target at the end of the "
                                  f"span (final error {m['final_error']:.3g})")
    elif not out.any():
        m["settling_time_s"] = 0.0
    else:
        k = int(np.flatnonzero(out)[-1])               # last sample outside the band
        level = math.copysign(edge, dev[k])
        frac = (dev[k] - level) / (dev[k] - dev[k + 1]) if dev[k] != dev[k + 1] else 1.0
        m["settling_time_s"] = float(ta[k] + (ta[k + 1] - ta[k]) * frac - cmd.onset_s)
    return {"command": cmd, "metrics": m, "why": why, "end_error": end}
