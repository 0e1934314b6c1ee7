"""``flexarm compare``: a twin run beside a reference (an experiment or another run).

Steps (every number in the result comes from :mod:`.metrics` and :mod:`.spectra`):

1. Channels: :func:`flexarm_ros.analysis.channels.load_channels` on both files; the
   compared names are ``channels`` or every name both have (in the run's order). Units
   must agree. ``wall_gap`` is derived for the reference from its tip position with the
   run's scene when the scene has a wall.
2. Time alignment: ``offset_s`` is the shift with ``run(t + offset_s) ~ reference(t)``
   (positive: the run lags); the run's times become ``t_run - offset_s``. ``'none'`` = 0,
   a number = that, ``'auto'`` = the median of
   :func:`~flexarm_ros.analysis.metrics.estimate_offset` (Pearson cross-correlation with
   parabolic peak refinement, +-``max_shift_s``) over the compared channels that give
   one, rounded to the nanosecond (the stamp resolution of a bag).
3. Per channel, on the span both cover after alignment (cut to ``window``): the run is
   interpolated linearly onto the reference times and
   :func:`~flexarm_ros.analysis.metrics.channel_errors` gives the RMS, peak, relative RMS
   and signed peak-to-peak amplitude errors; each record (put on a uniform grid when its
   sampling is not) gives its dominant frequency by
   :func:`~flexarm_ros.analysis.spectra.dominant_frequency` (Hann window, linear detrend,
   4x zero padding, Gaussian peak interpolation; searched from 3 bins, ``3 fs / N``, up to
   Nyquist) with resolution ``fs / N`` and stated bound ``0.1 fs / N`` (one bin outside
   the validity domain); ``frequency_error = (f_run - f_ref) / f_ref`` (seed 000 Fig. 5.8
   compares FFT peaks; seed 002 Gannon Tables 4.3 / 4.5 normalize by the experiment).
   A dimensionless channel taking only 0 and 1 in both records (``contact``) is a flag:
   no frequency (null, :data:`BOOLEAN_REASON`), its ``events`` instead
   (:func:`~flexarm_ros.analysis.metrics.step_events`: rises, falls, duty, first rise).
4. Pass/fail (Gannon 1986 Ch. IV after Petroka: |relative error| <= 10 %): a channel
   passes when ``|amplitude_error| <= threshold`` and, for the twin's vibration channels
   (accelerometers, strain gauges, elastic beam coordinates, tip position; flagged in
   either record),
   ``|frequency_error| <= threshold``. The tip block adds Gannon's normalized tip-amplitude
   error ``max_i |p_run(t_i) - p_ref(t_i)| / L`` (Table 4.2; L = the arm length, the sum of
   the scene's hub radii and beam lengths) and the tip frequency error, both against the
   threshold. The comparison passes when every evaluated criterion does.
   A channel with a target (a command: ``<name>_target``, ``tip_target_x/_y``, a twin
   bag's ``controller/joint_targets``; each record's own, else the other's) gets a
   ``control`` block: :func:`~flexarm_ros.analysis.control.tracking_metrics` of each
   record over the span (final error, overshoot, rise and settling time, RMS tracking
   error), their differences and tolerances. When the reference's command is a step or a
   ramp the channel is judged by those (``judged_by: control``): the final end errors
   within max(``final_band`` x |step|, one encoder count), the overshoots within
   max(``overshoot_points``, ``threshold`` x the reference's), rise and settling times
   within max(``threshold`` x the reference's, one sample period), the RMS tracking
   errors within max(``threshold`` x the reference's, one count); its frequency and
   amplitude are then reported, not judged (nor the tip frequency of such a tip channel).
5. Contact (seed 000 Sec. 5): impact time = first rise of ``contact`` through 0.5 (else
   the first fall of ``wall_gap`` through ``IMPACT_GAP_M``, else the first rise of
   ``normal_force`` above 0), bounce height = largest ``wall_gap`` within
   ``BOUNCE_WINDOW_S`` after it. Reported, not
   pass criteria (the seed states no tolerance).

The result is a plain dict (:func:`to_json` prints it): every error figure sits under a
key containing ``error``, relative errors are fractions, and a figure that cannot be
computed is ``null`` with its reason under ``null_reasons`` of the same block. The key
sets live in :mod:`flexarm_ros.analysis.comparison` (with :class:`Comparison`, which
the report draws), documented in ``docs/compare.md`` and pinned by
``test/test_compare.py``. The command (summary table, ``--report``) is
:mod:`flexarm_ros.analysis.compare_cli`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import statistics

import numpy as np

from flexarm_ros.analysis import metrics as M
from flexarm_ros.analysis import control as K
from flexarm_ros.analysis.channels import (ChannelSet, add_wall_gap, load_channels, same_unit,
                                           target_names)
from flexarm_ros.analysis.comparison import (CHANNEL_KEYS, CONTACT_KEYS, CONTROL_KEYS,
                                             CONTROL_SIDE_KEYS, FINAL_BAND, FREQ_DETREND,
                                             FREQ_MIN_BINS, FREQ_WINDOW, FREQ_ZERO_PAD,
                                             OVERSHOOT_POINTS, SCHEMA, TIP_KEYS, Comparison)
from flexarm_ros.analysis.spectra import MIN_SAMPLES, crop, dominant_frequency, uniform_record
from flexarm_ros.io.experiment import CompareInputError, load_channel_map

__all__ = ["BOUNCE_WINDOW_S", "DEFAULT_MAX_SHIFT_S", "IMPACT_GAP_M", "IMPACT_SOURCES",
           "arm_length", "compare", "compare_files", "encoder_quantum", "parse_offset",
           "parse_window", "to_json"]

#: Seconds after the impact searched for the bounce (seed 000: the tip leaves the wall by
#: ~5 mm and is driven back within a few tenths of a second).
BOUNCE_WINDOW_S = 0.25
#: Impact detection, in order of preference (the first channel both records have): the
#: contact flag rising through 0.5, the wall gap falling through ``IMPACT_GAP_M``, the
#: normal force rising through 0.
IMPACT_SOURCES = ("contact", "wall_gap", "normal_force")
#: A wall gap below this counts as touching (m): well above the round-off the contact
#: solver leaves on a resting tool (~1e-13 m), well below the ~mm approach per ms.
IMPACT_GAP_M = 1e-6
#: Why a 0/1 channel has no frequency figures (``null_reasons``).
BOOLEAN_REASON = ("boolean channel (only 0 and 1): a step signal has no dominant frequency; "
                  "see events (rises, falls, duty)")
#: Default search range of the automatic offset, s.
DEFAULT_MAX_SHIFT_S = 0.5


# ----------------------------------------------------------------------------- helpers

def _num(x):
    """A JSON-safe float (None for non-finite)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _put(block, key, value, reasons, why):
    """``block[key] = value`` when finite, else None with ``reasons[key] = why``."""
    v = _num(value)
    block[key] = v
    if v is None:
        reasons[key] = why
    return v


def _rate(t) -> float | None:
    return None if t.size < 2 else 1.0 / float(np.median(np.diff(t)))


def _peak(t, y):
    t, y = uniform_record(t, y)
    if t.size < MIN_SAMPLES:
        raise ValueError(f"{t.size} samples in the span, need at least {MIN_SAMPLES}")
    fs = (t.size - 1) / (t[-1] - t[0])
    return dominant_frequency(t, y, window=FREQ_WINDOW, detrend=FREQ_DETREND,
                              zero_pad=FREQ_ZERO_PAD, f_min=FREQ_MIN_BINS * fs / t.size)


def parse_window(text):
    """``'START:END'`` (s, either side may be empty) -> (start, end) or None."""
    if text is None:
        return None
    try:
        lo, hi = str(text).split(":")
        a = float(lo) if lo.strip() else -math.inf
        b = float(hi) if hi.strip() else math.inf
    except ValueError:
        raise CompareInputError(f"--window: got {text!r}, expected START:END in seconds of "
                                f"the reference clock, e.g. 2.1:2.5 or 1.0:") from None
    if not b > a or math.isnan(a) or math.isnan(b):
        raise CompareInputError(f"--window: got {text!r}, expected START < END")
    return a, b


def parse_offset(text):
    """``'auto'``, ``'none'`` or seconds -> 'auto' | 'none' | float."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value = float(text)
    elif str(text).strip().lower() in ("auto", "none"):
        return str(text).strip().lower()
    else:
        try:
            value = float(text)
        except ValueError:
            raise CompareInputError(f"--offset: got {text!r}, expected 'auto', 'none' or "
                                    f"a number of seconds (positive: the run lags)") from None
    if not math.isfinite(value):
        raise CompareInputError(f"--offset: got {text!r}, expected a finite number of "
                                f"seconds")
    return value


# ----------------------------------------------------------------------------- steps

def _select(run: ChannelSet, ref: ChannelSet, channels) -> list[str]:
    if channels:
        names = []
        for n in channels:
            for cs in (run, ref):
                if n not in cs:
                    raise CompareInputError(
                        f"{cs.path}: no channel {n!r}; channels: {', '.join(cs.names)}")
            if n not in names:
                names.append(n)
    else:
        names = [n for n in run.names if n in ref]
        if not names:
            raise CompareInputError(
                f"{ref.path}: no channel in common with {run.path}; reference channels: "
                f"{', '.join(ref.names)}; run channels: {', '.join(run.names)} (rename "
                f"columns or topics with --map MAP.yaml)")
    for n in names:
        if not same_unit(run[n].unit, ref[n].unit):
            raise CompareInputError(
                f"{ref.path}: channel {n!r} is in {ref[n].unit!r}, the run "
                f"({run.path}) in {run[n].unit!r}; expected the same unit (rescale with a "
                f"map entry: scale, unit)")
    return names


def _auto_offset(run, ref, names, max_shift):
    estimates, failures = {}, {}
    for n in names:
        a, b = run[n], ref[n]
        try:
            estimates[n] = M.estimate_offset(b.t, b.y, a.t, a.y, max_shift)
        except ValueError as exc:
            failures[n] = str(exc)
    return estimates, failures


def _offset(run, ref, names, mode, max_shift, warnings_out):
    periods = [1.0 / r for n in names for r in (_rate(run[n].t), _rate(ref[n].t)) if r]
    info = {"mode": "given" if isinstance(mode, float) else mode, "offset_s": 0.0,
            "method": "", "max_shift_s": None, "estimates_s": {},
            "sample_period_s": _num(min(periods)) if periods else None}
    if mode == "none":
        info["method"] = "none: the two clocks are taken as they are"
        return 0.0, info
    if isinstance(mode, float):
        info["offset_s"] = mode
        info["method"] = "given (--offset)"
        return mode, info
    info["max_shift_s"] = max_shift
    estimates, failures = _auto_offset(run, ref, names, max_shift)
    info["estimates_s"] = {k: _num(v) for k, v in estimates.items()}
    if not estimates:
        why = "; ".join(f"{k}: {v}" for k, v in list(failures.items())[:3])
        warnings_out.append(f"automatic offset failed on every channel ({why}); offset 0 "
                            f"used: pass --offset SECONDS or --offset none")
        info["method"] = "auto failed on every channel; 0 used"
        return 0.0, info
    off = round(statistics.median(estimates.values()) * 1e9) / 1e9
    info["offset_s"] = off
    info["method"] = (f"auto: median of the cross-correlation estimates of "
                      f"{len(estimates)} channel(s) within +-{max_shift:g} s, rounded to 1 ns")
    return off, info


def _frequencies(blk, why, run_rec, ref_rec):
    """The dominant frequencies of both records (over the span), their resolution, bound
    and the frequency error into ``blk``; reasons for the null ones into ``why``."""
    peaks = {}
    for side, (t, y) in (("run", run_rec), ("reference", ref_rec)):
        try:
            peaks[side] = _peak(t, y)
        except ValueError as exc:
            why[f"frequency_{side}_hz"] = f"{side}: {exc}"
    pr, pf = peaks.get("run"), peaks.get("reference")
    _put(blk, "frequency_run_hz", pr.frequency_hz if pr else None, why,
         why.get("frequency_run_hz"))
    _put(blk, "frequency_reference_hz", pf.frequency_hz if pf else None, why,
         why.get("frequency_reference_hz"))
    got = [p for p in (pr, pf) if p is not None]
    _put(blk, "frequency_resolution_hz", max((p.resolution_hz for p in got), default=None),
         why, "no spectral peak in either record")
    _put(blk, "frequency_bound_hz", max((p.bound_hz for p in got), default=None), why,
         "no spectral peak in either record")
    if pr and pf:
        try:
            blk["frequency_error"] = _num(M.frequency_error(pf.frequency_hz, pr.frequency_hz))
        except ValueError as exc:
            why["frequency_error"] = str(exc)
    else:
        why["frequency_error"] = why.get("frequency_reference_hz") or why.get(
            "frequency_run_hz")


def _channel_block(name, run_ch, ref_ch, off, window, threshold, vibration, control=None):
    """One channel's block; ``control(span)`` -> ``(control block, criteria, judged)``
    (:func:`_control_block`) for a channel that may have a target."""
    blk = {k: None for k in CHANNEL_KEYS}
    blk["judged_by"] = "oscillation"
    why = {}
    blk["unit"] = ref_ch.unit or run_ch.unit
    boolean = (same_unit(blk["unit"], "1") and M.is_boolean(run_ch.y)
               and M.is_boolean(ref_ch.y))
    blk["signal"] = "boolean" if boolean else "continuous"
    tr = run_ch.t - off
    a, b = max(ref_ch.t[0], tr[0]), min(ref_ch.t[-1], tr[-1])
    if window is not None:
        a, b = max(a, window[0]), min(b, window[1])
    crit = {}
    if not b > a:
        msg = (f"no common time span: reference [{ref_ch.t[0]:g}, {ref_ch.t[-1]:g}] s, "
               f"run [{tr[0]:g}, {tr[-1]:g}] s after the offset"
               + ("" if window is None else f", window [{window[0]:g}, {window[1]:g}] s"))
        for k in ("frequency_run_hz", "frequency_reference_hz", "frequency_resolution_hz",
                  "frequency_bound_hz", "frequency_error", "rms_error", "peak_error",
                  "relative_rms_error", "amplitude_error"):
            why[k] = msg
        blk.update(samples_run=0, samples_reference=0, criteria={}, null_reasons=why)
        if control is not None:
            blk["control"] = control(None)[0]
        return blk
    blk["span_s"] = [_num(a), _num(b)]
    t_ref, y_ref = crop(ref_ch.t, ref_ch.y, a, b)
    t_run, y_run = crop(tr, run_ch.y, a, b)
    blk["samples_run"], blk["samples_reference"] = int(t_run.size), int(t_ref.size)
    blk["sample_rate_run_hz"] = _num(_rate(run_ch.t))
    blk["sample_rate_reference_hz"] = _num(_rate(ref_ch.t))
    # pointwise errors: the run interpolated onto the reference instants
    try:
        tp, yp = crop(tr, run_ch.y, a, b, pad=True)
        errs = M.channel_errors(t_ref, y_ref, tp, yp)
    except ValueError as exc:
        errs = {}
        for k in ("rms_error", "peak_error", "relative_rms_error", "amplitude_error"):
            why[k] = str(exc)
    _put(blk, "rms_error", errs.get("rms_error"), why, why.get("rms_error"))
    _put(blk, "peak_error", errs.get("peak_error"), why, why.get("peak_error"))
    _put(blk, "relative_rms_error", errs.get("relative_rms_error"), why,
         why.get("relative_rms_error", "the reference is zero over the span (RMS 0)"))
    _put(blk, "amplitude_error", errs.get("amplitude_error"), why,
         why.get("amplitude_error", "the reference does not vary over the span "
                                    "(peak-to-peak 0)"))
    if boolean:     # a flag: events and duty instead of a dominant frequency
        blk["events"] = {side: M.step_events(t, y) if t.size else None
                         for side, (t, y) in (("run", (t_run, y_run)),
                                              ("reference", (t_ref, y_ref)))}
        for k in ("frequency_run_hz", "frequency_reference_hz", "frequency_resolution_hz",
                  "frequency_bound_hz", "frequency_error"):
            why[k] = BOOLEAN_REASON
    else:
        _frequencies(blk, why, (t_run, y_run), (t_ref, y_ref))
    # criteria
    if blk["amplitude_error"] is not None:
        crit["amplitude_error"] = M.passes(blk["amplitude_error"], threshold)
    elif math.isinf(errs.get("amplitude_error", 0.0)):
        crit["amplitude_error"] = False          # a flat reference, a run that swings
        why["amplitude_error"] = ("the reference does not vary over the span (peak-to-peak "
                                  "0) but the run does: relative error unbounded (fails)")
    if vibration:
        if blk["frequency_error"] is not None:
            crit["frequency_error"] = M.passes(blk["frequency_error"], threshold)
    if control is not None:
        blk["control"], ctl_crit, judged = control((a, b))
        if judged:          # a step or ramp response: the control criteria, not FFT / p-p
            blk["judged_by"] = "control"
            crit = ctl_crit
    return _verdict(blk, crit, why, "no criterion could be evaluated")


# ----------------------------------------------------------------------------- control

def encoder_quantum(scene, name: str) -> float | None:
    """One encoder count as a link-side angle (rad) for a joint-angle channel
    (``<link>_joint``, ``<link>_joint_measured``) whose joint the scene's encoder reads:
    2π / (lines × quadrature × gear ratio on a motor shaft). None otherwise."""
    if scene is None:
        return None
    base = name[:-len("_measured")] if name.endswith("_measured") else name
    for k, lk in enumerate(scene.links):
        if base != f"{lk.name}_joint":
            continue
        for sn in scene.sensors:
            if sn.kind == "encoder" and sn.joint == k + 1:
                drive = lk.joint.drive
                ratio = drive.gear_ratio if sn.on_motor_shaft and drive is not None else 1.0
                return 2.0 * math.pi / (sn.lines_per_rev * sn.quadrature * ratio)
    return None


def _target(run, ref, name):
    """``({side: its own target channel or None}, {side: the record whose target it
    uses})`` for channel ``name``: each record's own target channel
    (:func:`~flexarm_ros.analysis.channels.target_names`), else the other's; None when
    neither has one."""
    cands = target_names(name)
    own = {side: next((c for c in cands if c in cs), None)
           for side, cs in (("run", run), ("reference", ref))}
    if own["run"] is None and own["reference"] is None:
        return None
    src = {side: side if own[side] is not None else ("reference" if side == "run" else "run")
           for side in own}
    for side, cs in (("run", run), ("reference", ref)):
        if own[side] is not None and not same_unit(cs[own[side]].unit, cs[name].unit):
            raise CompareInputError(
                f"{cs.path}: target channel {own[side]!r} is in {cs[own[side]].unit!r}, "
                f"the channel {name!r} it commands in {cs[name].unit!r}; expected the same "
                f"unit")
    return own, src


def _control_block(name, run, ref, off, span, threshold, quantum, final_band,
                   overshoot_points):
    """The ``control`` block of a channel with a target (None without one): each record's
    :func:`~flexarm_ros.analysis.control.tracking_metrics` over the span (run on the
    reference clock), their differences, the tolerances and the control criteria.
    Returns ``(block, criteria, judged)``."""
    found = _target(run, ref, name)
    if found is None:
        return None, {}, False
    own, src = found
    blk = {k: None for k in CONTROL_KEYS}
    why: dict = {}
    blk["target_channel"] = {side: own[src[side]] for side in ("run", "reference")}
    blk["target_from"] = src
    blk["quantum"] = _num(quantum)
    if quantum is None:
        why["quantum"] = ("no encoder of the scene measures this channel (its resolution is "
                          "taken as 0)")
    q = quantum or 0.0
    recs = {"run": (run, off), "reference": (ref, 0.0)}
    res, periods = {}, []
    for side, (cs, shift) in recs.items():
        side_blk = {k: None for k in CONTROL_SIDE_KEYS}
        blk[side] = side_blk
        tcs, tshift = recs[src[side]]
        tch = tcs[own[src[side]]]
        ch = cs[name]
        if span is None:
            res[side] = None
            for k in CONTROL_SIDE_KEYS:
                why[f"{side}.{k}"] = "no common time span"
            continue
        t, y = crop(ch.t - shift, ch.y, span[0], span[1])
        if t.size >= 2:
            periods.append(float(np.median(np.diff(t))))
        try:
            r = K.tracking_metrics(t, y, tch.t - tshift, tch.y, quantum=q)
        except ValueError as exc:
            res[side] = None
            for k in CONTROL_SIDE_KEYS:
                why[f"{side}.{k}"] = f"{side}: {exc}"
            continue
        res[side] = r
        side_blk["command"] = r["command"].as_dict()
        for k in K.METRIC_KEYS:
            _put(side_blk, k, r["metrics"][k], why, r["why"].get(k))
            if side_blk[k] is None:
                why[f"{side}.{k}"] = why.pop(k)
    ref_cmd = res["reference"]["command"] if res.get("reference") else None
    judged = ref_cmd is not None and ref_cmd.kind in ("step", "ramp")
    diff = {k: None for k in K.METRIC_KEYS}
    tol = {k: None for k in K.METRIC_KEYS}
    blk["difference"], blk["tolerance"] = diff, tol
    crit = {}
    if not judged:
        reason = (ref_cmd.why if ref_cmd is not None else
                  why.get("reference.final_error", "no reference metrics"))
        for k in K.METRIC_KEYS:
            why[f"tolerance.{k}"] = (f"not judged by the control criteria: {reason}")
    dt = max(periods) if periods else 0.0
    step = abs(ref_cmd.step) if judged and ref_cmd.step is not None else None
    for k in K.METRIC_KEYS:
        a = blk["run"][k] if res.get("run") else None
        b = blk["reference"][k] if res.get("reference") else None
        if k == "final_error" and res.get("run") and res.get("reference"):
            d = abs(res["run"]["end_error"] - res["reference"]["end_error"])
        elif a is not None and b is not None:
            d = a - b
        else:
            d = None
        if d is None:
            other = why.get(f"run.{k}") if a is None else why.get(f"reference.{k}")
            why[f"difference.{k}"] = (
                f"in neither record: {why.get(f'reference.{k}')}" if a is None and b is None
                else f"{'the run' if a is None else 'the reference'} has none: "
                     f"{other or 'not computed'}")
        diff[k] = _num(d)
        if not judged:
            continue
        if k == "final_error":
            t_k = max(final_band * step, q)
        elif k == "overshoot":
            t_k = max(overshoot_points, threshold * b) if b is not None else None
        elif k in ("rise_time_s", "settling_time_s"):
            t_k = max(threshold * b, dt) if b is not None else None
        else:
            t_k = max(threshold * b, q) if b is not None else None
        tol[k] = _num(t_k)
        if t_k is None:
            why[f"tolerance.{k}"] = f"the reference has none: {why.get(f'reference.{k}')}"
        crit_name = k[:-2] if k.endswith("_s") else k
        if a is None and b is None:
            continue                      # in neither record: not evaluated
        crit[crit_name] = d is not None and t_k is not None and abs(d) <= t_k
    blk["null_reasons"] = why
    return blk, crit, judged


def _verdict(blk: dict, crit: dict, why: dict, none_reason: str) -> dict:
    """Close a result block: its criteria, pass = all of them (None, with ``none_reason``,
    when none could be evaluated) and the reasons of its null figures."""
    blk["criteria"] = crit
    blk["pass"] = all(crit.values()) if crit else None
    if not crit:
        why["pass"] = none_reason
    blk["null_reasons"] = why
    return blk


def _impact(cs: ChannelSet, source: str):
    ch = cs[source]
    if source == "wall_gap":
        return M.event_time(ch.t, ch.y, IMPACT_GAP_M, direction=-1)
    if source == "contact":
        return M.event_time(ch.t, ch.y, 0.5, direction=+1)
    return M.event_time(ch.t, ch.y, 0.0, direction=+1)


def _contact_block(run, ref, off, scene):
    blk = {k: None for k in CONTACT_KEYS}
    why = {}
    blk["bounce_window_s"] = BOUNCE_WINDOW_S
    source = next((s for s in IMPACT_SOURCES
                   if s in run and s in ref), None)
    if source is None:
        reason = ("the scene has no wall" if scene is not None and not scene.walls else
                  "neither contact, wall_gap nor normal_force is in both records")
        for k in CONTACT_KEYS[1:-1]:
            if k != "bounce_window_s":
                why[k] = reason
        blk["null_reasons"] = why
        return blk
    blk["impact_source"] = source
    t_run = _impact(run, source)
    t_ref = _impact(ref, source)
    _put(blk, "impact_time_run_s", t_run, why, f"no impact in the run ({source})")
    _put(blk, "impact_time_reference_s", t_ref, why, f"no impact in the reference ({source})")
    _put(blk, "impact_time_error_s", None if t_run is None or t_ref is None
         else (t_run - off) - t_ref, why, "no impact in one of the records")
    if "wall_gap" in run and "wall_gap" in ref:
        heights = {}
        for side, cs, ti in (("run", run, t_run), ("reference", ref, t_ref)):
            g = cs["wall_gap"]
            try:
                heights[side] = M.bounce_height(g.t, g.y, ti, BOUNCE_WINDOW_S)
            except ValueError as exc:
                heights[side] = None
                why[f"bounce_height_{side}_m"] = str(exc)
            if ti is None:
                why[f"bounce_height_{side}_m"] = f"no impact in the {side}"
        hr, hf = heights["run"], heights["reference"]
        _put(blk, "bounce_height_run_m", hr, why, why.get("bounce_height_run_m"))
        _put(blk, "bounce_height_reference_m", hf, why, why.get("bounce_height_reference_m"))
        if hr is not None and hf is not None:
            blk["bounce_height_abs_error_m"] = _num(hr - hf)
            if hf != 0.0:
                blk["bounce_height_error"] = _num(M.relative_error(hf, hr))
            else:
                why["bounce_height_error"] = ("the reference tip does not bounce (height "
                                              "0): no relative error")
        else:
            why["bounce_height_abs_error_m"] = why["bounce_height_error"] = \
                "no bounce height in one of the records"
    else:
        for k in ("bounce_height_run_m", "bounce_height_reference_m",
                  "bounce_height_abs_error_m", "bounce_height_error"):
            why[k] = ("wall_gap is not in both records (needs a wall and the tool point: "
                      "the tip, or the coordinates when the tool is offset from it)")
    blk["null_reasons"] = why
    return blk


def arm_length(scene) -> float | None:
    """Gannon's normalizing arm length (m): the distance from the first joint to the
    recorded tip (the last beam's tip) of the straight, undeformed arm, i.e. the hub
    radii and beam lengths plus the joint offsets of the tip bodies between the links."""
    if scene is None:
        return None
    x, y = 0.0, 0.0
    for k, lk in enumerate(scene.links):
        x += lk.beam.hub_radius + lk.beam.length
        if k + 1 < len(scene.links):
            x += lk.tip.joint_offset[0]
            y += lk.tip.joint_offset[1]
    return float(np.hypot(x, y))


def _tip_block(run, ref, off, scene, names, blocks, window, threshold):
    blk = {k: None for k in TIP_KEYS}
    why = {}
    crit = {}
    L = arm_length(scene)
    blk["arm_length_m"] = L
    if L is None:
        why["arm_length_m"] = "no scene (arm length unknown)"
    have = all(n in run and n in ref for n in ("tip_x", "tip_y"))
    if not have:
        why["normalized_amplitude_error"] = why["normalized_rms_amplitude_error"] = \
            "tip_x and tip_y are not in both records"
    elif L is not None:
        rx, ry, fx, fy = run["tip_x"], run["tip_y"], ref["tip_x"], ref["tip_y"]
        t = fx.t if np.array_equal(fx.t, fy.t) else None
        a = max(fx.t[0], rx.t[0] - off, ry.t[0] - off, fy.t[0])
        b = min(fx.t[-1], rx.t[-1] - off, ry.t[-1] - off, fy.t[-1])
        if window is not None:
            a, b = max(a, window[0]), min(b, window[1])
        if t is None or not b > a:
            why["normalized_amplitude_error"] = why["normalized_rms_amplitude_error"] = (
                "the reference tip_x and tip_y are not sampled together" if t is None else
                "no common time span of the tip records")
        else:
            ti = t[(t >= a) & (t <= b)]
            ref_pts = np.column_stack([np.interp(ti, fx.t, fx.y), np.interp(ti, fy.t, fy.y)])
            run_pts = np.column_stack([np.interp(ti, rx.t - off, rx.y),
                                       np.interp(ti, ry.t - off, ry.y)])
            blk["normalized_amplitude_error"] = _num(
                M.normalized_amplitude_error(ref_pts, run_pts, L, reduce="max"))
            blk["normalized_rms_amplitude_error"] = _num(
                M.normalized_amplitude_error(ref_pts, run_pts, L, reduce="rms"))
            crit["normalized_amplitude_error"] = M.passes(blk["normalized_amplitude_error"],
                                                          threshold)
    elif L is None:
        why["normalized_amplitude_error"] = why["normalized_rms_amplitude_error"] = \
            why["arm_length_m"]
    # the tip frequency: the tip coordinate that oscillates more in the reference
    cands = [n for n in ("tip_x", "tip_y") if n in names and n in ref]
    amps = {}
    for n in cands:
        try:
            a0, b0 = blocks[n]["span_s"] or (None, None)
            if a0 is None:
                continue
            tt, yy = crop(ref[n].t, ref[n].y, a0, b0)
            amps[n] = _peak(tt, yy).amplitude
        except ValueError:
            continue
    if amps:
        n = max(amps, key=amps.get)
        blk["frequency_channel"] = n
        blk["frequency_error"] = blocks[n]["frequency_error"]
        if blk["frequency_error"] is None:
            why["frequency_error"] = blocks[n]["null_reasons"].get("frequency_error")
        elif blocks[n]["judged_by"] == "control":
            why["frequency_criterion"] = (f"{n} tracks a step or ramp command: judged by the "
                                          f"control criteria; its dominant frequency is "
                                          f"reported, not judged")
        else:
            crit["frequency_error"] = M.passes(blk["frequency_error"], threshold)
    else:
        why["frequency_channel"] = why["frequency_error"] = (
            "no compared tip_x / tip_y channel with a spectral peak")
    return _verdict(blk, crit, why, "no tip criterion could be evaluated")


def _source(cs: ChannelSet) -> dict:
    starts = [c.t[0] for c in cs.channels.values()]
    ends = [c.t[-1] for c in cs.channels.values()]
    return {"path": cs.path, "kind": cs.kind, "scene": cs.scene_name,
            "truncated": bool(cs.truncated), "channels": list(cs.names),
            "start_s": _num(min(starts)), "end_s": _num(max(ends))}


# ----------------------------------------------------------------------------- API

def compare(run: ChannelSet, reference: ChannelSet, *, offset="auto", threshold=M.GANNON_THRESHOLD,
            channels=None, max_shift_s=DEFAULT_MAX_SHIFT_S, window=None,
            final_band=FINAL_BAND, overshoot_points=OVERSHOOT_POINTS) -> Comparison:
    """Compare two loaded inputs (module docstring). ``offset``: 'auto', 'none' or
    seconds; ``window``: (start, end) in s of the reference clock, or None;
    ``final_band``, ``overshoot_points``: the control tolerances that are not
    ``threshold`` (fractions of the step)."""
    offset = parse_offset(offset)
    try:
        threshold = float(threshold)
    except (TypeError, ValueError):
        threshold = math.nan
    if not (math.isfinite(threshold) and threshold > 0):
        raise CompareInputError(f"--threshold: got {threshold!r}, expected a positive "
                                f"fraction such as 0.10")
    if not (isinstance(max_shift_s, (int, float)) and math.isfinite(max_shift_s)
            and max_shift_s > 0):
        raise CompareInputError(f"--max-shift: got {max_shift_s!r}, expected a positive "
                                f"number of seconds")
    for key, v in (("final_band", final_band), ("overshoot_points", overshoot_points)):
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and 0.0 <= v < 1.0):
            raise CompareInputError(f"{key}: got {v!r}, expected a fraction in [0, 1), "
                                    f"e.g. 0.02")
    scene = run.scene if run.scene is not None else reference.scene
    run = dataclasses.replace(run, channels=dict(run.channels))     # inputs stay as given
    reference = dataclasses.replace(reference, channels=dict(reference.channels))
    for cs in (run, reference):
        add_wall_gap(cs.channels, scene)
    names = _select(run, reference, channels)
    warn = list(run.warnings) + list(reference.warnings)
    off, off_info = _offset(run, reference, names, offset, float(max_shift_s), warn)
    def control(n):
        def block(span):
            return _control_block(n, run, reference, off, span, threshold,
                                  encoder_quantum(scene, n), final_band, overshoot_points)
        return block

    blocks = {n: _channel_block(n, run[n], reference[n], off, window, threshold,
                                run[n].vibration or reference[n].vibration, control(n))
              for n in names}
    contact = _contact_block(run, reference, off, scene)
    tip = _tip_block(run, reference, off, scene, names, blocks, window, threshold)
    failed = sorted([f"{n}:{k}" for n, b in blocks.items()
                     for k, ok in b["criteria"].items() if not ok]
                    + [f"tip:{k}" for k, ok in tip["criteria"].items() if not ok])
    evaluated = [b["pass"] for b in blocks.values() if b["pass"] is not None]
    if tip["pass"] is not None:
        evaluated.append(tip["pass"])
    result = {
        "schema": SCHEMA,
        "run": _source(run),
        "reference": _source(reference),
        "threshold": threshold,
        "offset": off_info,
        "window": None if window is None else {"start_s": _num(window[0]),
                                               "end_s": _num(window[1])},
        "frequency_method": {
            "estimator": "peak of the windowed, zero-padded FFT refined by Gaussian "
                         "interpolation (flexarm_ros.analysis.spectra.dominant_frequency)",
            "window": FREQ_WINDOW, "detrend": FREQ_DETREND, "zero_pad": FREQ_ZERO_PAD,
            "search_from_bins": FREQ_MIN_BINS,
            "resolution": "fs / N of the analysed span (about 1 / span)",
            "bound": "0.1 fs / N (one bin within 3 bins of DC or 2 of Nyquist)"},
        "control_method": {
            "applies_to": "channels with a target (<name>_target, tip_target_x/_y, "
                          "controller/joint_targets) whose reference command is a step or "
                          "a ramp: judged_by 'control'",
            "target_hold": "zero-order (the last target sample at or before each instant)",
            "rise": [K.RISE_FROM, K.RISE_TO],
            "settling_band": K.SETTLING_BAND,
            "final_band": final_band,
            "overshoot_points": overshoot_points,
            "relative": threshold,
            "tolerances": (f"|final end error run - reference| <= max({final_band:g} x "
                           f"|reference step|, 1 encoder count); |overshoot difference| <= "
                           f"max({overshoot_points:g}, {threshold:g} x reference overshoot); "
                           f"|rise / settling time difference| <= max({threshold:g} x "
                           f"reference, one sample period); |RMS tracking error difference| "
                           f"<= max({threshold:g} x reference, 1 encoder count)")},
        "channels": blocks,
        "contact": contact,
        "tip": tip,
        "pass": bool(evaluated) and all(evaluated),
        "failed": failed,
        "warnings": warn,
    }
    return Comparison(result=result, run=run, reference=reference, names=names, offset_s=off)


def compare_files(run_path, reference_path, *, map_path=None, **kw) -> Comparison:
    """Load both files (``map_path`` applies to the reference) and :func:`compare`."""
    cmap = load_channel_map(map_path) if map_path is not None else None
    run = load_channels(run_path)
    ref = load_channels(reference_path, cmap)
    window = kw.get("window")
    if window is not None:
        spans = [(float(ch.t[0]), float(ch.t[-1])) for ch in ref.channels.values()
                 if hasattr(ch, "t") and len(ch.t)]
        if spans:
            lo, hi = min(a for a, _ in spans), max(b for _, b in spans)
            if window[0] >= hi or window[1] <= lo:
                from flexarm_ros.errors import InputError
                raise InputError(f"--window: got {window[0]:g}:{window[1]:g} s, expected a "
                                 f"span that overlaps the reference's records "
                                 f"[{lo:g}, {hi:g}] s")
    return compare(run, ref, **kw)


def to_json(result: dict) -> str:
    """The result as stable JSON: sorted keys, two-space indent, no NaN."""
    return json.dumps(result, indent=2, sort_keys=True, allow_nan=False)
