"""Error measures between a run (the twin) and a reference (an experiment or another run).

All functions take plain arrays: times in seconds (strictly increasing, finite), values
in SI units. Two records need not share a time grid; where a pointwise comparison is
needed the run is linearly interpolated onto the reference times
(:func:`flexarm_ros.analysis.spectra.resample`) on the span both records cover.

Sources of the criteria:

* Gannon, K. P., *Modeling and experimental validation of a single-link flexible
  manipulator*, MS thesis, Naval Postgraduate School, Dec. 1986 (seed 002), Ch. IV
  "Results", Sec. B "Tip Position" (Tables 4.2, 4.3) and Sec. C "Strain" (Tables 4.4,
  4.5), criteria adopted from Petroka's thesis [his Ref. 12]: a +-10 % relative error is
  the pass mark; tip-position amplitude error = sqrt(dX^2 + dY^2) of the theoretical
  minus experimental tip coordinates, normalized by the arm length; frequency error =
  theoretical minus experimental frequency, normalized by the experimental frequency;
  strain amplitude (and strain frequency) errors normalized by the respective
  experimental values. See :func:`normalized_amplitude_error`, :func:`frequency_error`,
  :func:`relative_error` and :func:`passes`.
* Seed 000, Sec. 5 (impact experiments): impact time, the tip bouncing ~5 mm off the
  constraint surface, FFT of the acceleration (Fig. 5.8): :func:`event_time`,
  :func:`bounce_height`, :func:`flexarm_ros.analysis.spectra.spectrum`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal as _sig

from flexarm_ros.analysis.spectra import checked_series, resample

#: Gannon's (after Petroka) pass mark: |relative error| <= 10 %.
GANNON_THRESHOLD = 0.10
#: Minimum overlap, in grid samples, that :func:`estimate_offset` correlates at any lag.
_MIN_OVERLAP = 16


def _overlap(t_ref, t_run):
    a = max(t_ref[0], t_run[0])
    b = min(t_ref[-1], t_run[-1])
    if not b > a:
        raise ValueError(
            f"no overlapping time span: reference covers [{t_ref[0]:g}, {t_ref[-1]:g}] s, "
            f"run covers [{t_run[0]:g}, {t_run[-1]:g}] s")
    return a, b


def _positive(value, name):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def estimate_offset(t_ref, y_ref, t_run, y_run, max_shift_s) -> float:
    """Time shift that best aligns the run onto the reference.

    Sign convention: the returned ``offset`` satisfies ``y_run(t + offset) ≈ y_ref(t)``.
    A positive offset means the run *lags* the reference (its events happen ``offset``
    seconds later); align it with ``t_run_aligned = t_run - offset``.

    Method: both records are linearly interpolated onto one uniform grid spanning their
    overlap, with spacing ``dt = min(median diff(t_ref), median diff(t_run))``. For every
    integer lag ``|L| <= ceil(max_shift_s / dt)`` the Pearson correlation coefficient

        r(L) = cov(ref[i], run[i + L]) / (std(ref[i]) std(run[i + L]))

    is taken over the samples the two share at that lag (normalizing per lag removes the
    bias of the shrinking overlap towards small lags). The integer maximum ``L*`` is
    refined by the parabola through ``r(L*-1), r(L*), r(L*+1)``:
    ``offset = (L* + (r_- - r_+) / (2 (r_- - 2 r_0 + r_+))) dt``.

    For periodic signals the correlation repeats every period: keep ``max_shift_s``
    below half the period or the nearest alias may win.

    Raises:
        ValueError: invalid records, no overlap, ``max_shift_s`` not positive or longer
            than half the overlap, constant signals, or a best alignment at the edge of the
            search range (the true shift may lie beyond ``max_shift_s``).
    """
    t_ref, y_ref = checked_series(t_ref, y_ref, name="reference", min_samples=4)
    t_run, y_run = checked_series(t_run, y_run, name="run", min_samples=4)
    max_shift = _positive(max_shift_s, "max_shift_s")
    a, b = _overlap(t_ref, t_run)
    dt = min(float(np.median(np.diff(t_ref))), float(np.median(np.diff(t_run))))
    n = int(math.floor((b - a) / dt * (1.0 + 1e-12))) + 1
    grid = np.minimum(a + dt * np.arange(n), b)
    k_max = int(math.ceil(max_shift / dt - 1e-9))
    if n < 2 * _MIN_OVERLAP or k_max > n // 2:
        raise ValueError(
            f"max_shift_s = {max_shift:g} s is too long for the overlapping span "
            f"[{a:g}, {b:g}] s sampled at {dt:g} s: it must be at most half the overlap "
            f"({(n // 2) * dt:g} s) and the overlap at least {2 * _MIN_OVERLAP} samples")
    k_max = max(k_max, 2)
    x = resample(t_ref, y_ref, grid)
    z = resample(t_run, y_run, grid)
    x = x - x.mean()
    z = z - z.mean()

    # r(L) for L = -k_max..k_max: pairs (x[i], z[i + L]).
    full = _sig.correlate(z, x, mode="full")            # full[L + n - 1] = sum_i z[i+L] x[i]
    lags = np.arange(-k_max, k_max + 1)
    sxy = full[lags + n - 1]
    cx, cx2 = np.concatenate(([0.0], np.cumsum(x))), np.concatenate(([0.0], np.cumsum(x * x)))
    cz, cz2 = np.concatenate(([0.0], np.cumsum(z))), np.concatenate(([0.0], np.cumsum(z * z)))
    x_lo = np.where(lags >= 0, 0, -lags)                 # x indices [x_lo, x_hi)
    x_hi = np.where(lags >= 0, n - lags, n)
    z_lo, z_hi = x_lo + lags, x_hi + lags                # z indices shifted by L
    m = (x_hi - x_lo).astype(float)
    sx, sx2 = cx[x_hi] - cx[x_lo], cx2[x_hi] - cx2[x_lo]
    sz, sz2 = cz[z_hi] - cz[z_lo], cz2[z_hi] - cz2[z_lo]
    cov = sxy - sx * sz / m
    var = np.maximum(sx2 - sx * sx / m, 0.0) * np.maximum(sz2 - sz * sz / m, 0.0)
    ok = var > 0.0
    if not np.any(ok):
        raise ValueError("cannot align constant signals: reference or run has no variation "
                         "on the overlapping span")
    r = np.full(lags.shape, -np.inf)
    r[ok] = cov[ok] / np.sqrt(var[ok])
    i = int(np.argmax(r))
    if i == 0 or i == lags.size - 1:
        raise ValueError(
            f"best alignment lies at the edge of the search range +-{max_shift:g} s "
            f"(max_shift_s); the true shift may be larger: increase max_shift_s")
    rm, r0, rp = r[i - 1], r[i], r[i + 1]
    frac = 0.0
    den = rm - 2.0 * r0 + rp
    if np.isfinite(den) and den < 0.0:
        frac = 0.5 * (rm - rp) / den
    return float((lags[i] + frac) * dt)


def event_time(t, y, threshold, direction=+1):
    """First time the signal crosses ``threshold`` in the given direction, or None.

    ``direction=+1`` (rising): the first ``i`` with ``y_i < c <= y_{i+1}``;
    ``direction=-1`` (falling): the first ``i`` with ``y_i > c >= y_{i+1}``. The crossing
    time is interpolated linearly, ``t_c = t_i + (t_{i+1} - t_i) (c - y_i) /
    (y_{i+1} - y_i)``. A record that starts already at or beyond the threshold has not
    crossed it at ``t[0]``. Use ``direction=-1, threshold=0`` for the impact time of a
    gap channel (seed 000: tip reaching the constraint surface) and ``direction=+1,
    threshold=0.5`` for a 0/1 contact flag.

    Returns:
        The crossing time in seconds (float), or None when there is no crossing.
    """
    t, y = checked_series(t, y)
    c = float(threshold)
    if not math.isfinite(c):
        raise ValueError(f"threshold must be finite, got {threshold!r}")
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 (rising) or -1 (falling), got {direction!r}")
    s = (y - c) * direction                                # rising crossing of s through 0
    hits = np.flatnonzero((s[:-1] < 0.0) & (s[1:] >= 0.0))
    if hits.size == 0:
        return None
    i = int(hits[0])
    return float(t[i] + (t[i + 1] - t[i]) * (-s[i]) / (s[i + 1] - s[i]))


def is_boolean(y) -> bool:
    """Whether a record only takes the values 0 and 1 (a flag such as ``contact``)."""
    y = np.asarray(y, dtype=float)
    return y.size > 0 and bool(np.all((y == 0.0) | (y == 1.0)))


def step_events(t, y) -> dict:
    """Events of a 0/1 record, each value held until the next sample: ``rises`` (0 -> 1
    steps), ``falls`` (1 -> 0), ``duty`` = the fraction of ``[t[0], t[-1]]`` spent at 1
    (``y[0]`` for a single sample) and ``first_rise_s`` (the time of the first sample at 1
    after one at 0, or None).

    Raises:
        ValueError: invalid record, or a value other than 0 and 1.
    """
    t, y = checked_series(t, y, name="flag", min_samples=1)
    if not is_boolean(y):
        bad = y[(y != 0.0) & (y != 1.0)][0]
        raise ValueError(f"flag: got the value {bad:g}, expected only 0 and 1")
    up = np.flatnonzero((y[:-1] == 0.0) & (y[1:] == 1.0))
    falls = int(np.count_nonzero((y[:-1] == 1.0) & (y[1:] == 0.0)))
    span = float(t[-1] - t[0])
    duty = float(y[0]) if span == 0.0 else float(np.sum(y[:-1] * np.diff(t)) / span)
    return {"rises": int(up.size), "falls": falls, "duty": duty,
            "first_rise_s": float(t[up[0] + 1]) if up.size else None}


def bounce_height(t, gap, t_impact, window_s):
    """Largest gap after the first impact, within ``window_s`` seconds of it, or None.

    ``h = max(0, max{gap(t_j) : t_impact < t_j <= t_impact + window_s})`` — the height the
    tip rebounds off the constraint surface (seed 000, Sec. 5: ~5 mm in the experiment
    and the simulation). ``gap`` is the signed distance to the surface (positive = free,
    <= 0 = contact/penetration); ``t_impact`` is usually
    ``event_time(t, gap, 0.0, direction=-1)``. A tip that stays in contact gives 0.0.

    Returns:
        The bounce height (same unit as ``gap``), or None when ``t_impact`` is None (no
        impact).

    Raises:
        ValueError: invalid record, ``window_s`` not positive, or no sample in the window.
    """
    t, gap = checked_series(t, gap, name="gap")
    if t_impact is None:
        return None
    window = _positive(window_s, "window_s")
    t0 = float(t_impact)
    sel = (t > t0) & (t <= t0 + window)
    if not np.any(sel):
        raise ValueError(f"no gap samples in the window ({t0:g}, {t0 + window:g}] s after "
                         f"the impact (record ends at {t[-1]:g} s)")
    return max(0.0, float(np.max(gap[sel])))


def _ratio(num: float, den: float) -> float:
    """num / den with 0/0 -> 0 and x/0 -> inf (a zero reference cannot be matched)."""
    if den == 0.0:
        return 0.0 if num == 0.0 else math.copysign(math.inf, num)
    return num / den


def channel_errors(t_ref, y_ref, t_run, y_run) -> dict:
    """Pointwise errors of one channel of the run against the reference.

    The run is linearly interpolated onto the reference times inside the overlapping
    span ``[max(t_ref[0], t_run[0]), min(t_ref[-1], t_run[-1])]``; with ``e = run - ref``
    over those M samples:

    * ``rms_error = sqrt(mean(e^2))``
    * ``peak_error = max|e|``
    * ``relative_rms_error = rms_error / sqrt(mean(ref^2))`` (fraction; the reference
      RMS is taken about zero, not about its mean)
    * ``amplitude_error = (ptp(run) - ptp(ref)) / ptp(ref)``, signed (fraction; positive
      when the run swings more), ``ptp`` = peak-to-peak over the same M instants. This is
      Gannon's strain-amplitude criterion (amplitude difference normalized by the
      experimental value; Ch. IV Sec. C) with amplitude taken as peak-to-peak.

    A zero reference gives 0.0 for a zero error and ``inf`` otherwise for the two relative
    measures. Shift the run first (:func:`estimate_offset`) if the clocks differ.

    Returns:
        dict with keys ``rms_error``, ``peak_error``, ``relative_rms_error``,
        ``amplitude_error`` (floats).
    """
    t_ref, y_ref = checked_series(t_ref, y_ref, name="reference")
    t_run, y_run = checked_series(t_run, y_run, name="run")
    a, b = _overlap(t_ref, t_run)
    sel = (t_ref >= a) & (t_ref <= b)
    if np.count_nonzero(sel) < 2:
        raise ValueError(f"no overlapping time span with at least 2 reference samples "
                         f"in [{a:g}, {b:g}] s")
    tr, ref = t_ref[sel], y_ref[sel]
    run = resample(t_run, y_run, tr)
    e = run - ref
    rms = float(np.sqrt(np.mean(e * e)))
    ref_rms = float(np.sqrt(np.mean(ref * ref)))
    ptp_ref = float(np.ptp(ref))
    ptp_run = float(np.ptp(run))
    return {
        "rms_error": rms,
        "peak_error": float(np.max(np.abs(e))),
        "relative_rms_error": _ratio(rms, ref_rms),
        "amplitude_error": _ratio(ptp_run - ptp_ref, ptp_ref),
    }


def normalized_amplitude_error(ref, run, length, reduce="max") -> float:
    """Gannon's tip-position amplitude error, normalized by the arm length.

    Gannon 1986 (seed 002), Ch. IV "Results", Sec. B "Tip Position" (Table 4.2): "The
    tip position amplitude error is computed by taking the square root of the sum of the
    squares of the differences between the theoretical and experimental X and Y
    coordinate positions ... Tip position amplitude was normalized using arm length":

        error = sqrt((X_run - X_ref)^2 + (Y_run - Y_ref)^2) / L

    The thesis does not say at which instant(s) the positions were compared (one number
    per load case is reported). Here ``ref`` and ``run`` are tip positions at the same
    instants and the per-instant distances are reduced by ``reduce``: ``'max'`` (default,
    the worst instant — conservative) or ``'rms'``. Pass the positions at the oscillation
    extremes to compare amplitudes only, or a whole resampled trajectory.

    Args:
        ref, run: same shape; a scalar (one coordinate at one instant), a 1-D array of
            the coordinates of ONE point (e.g. ``[X, Y]``), or an ``(M, d)`` array of M
            points (rows) with d coordinates each.
        length: arm length L (> 0), same unit as the positions.
        reduce: ``'max'`` or ``'rms'`` over the M instants.

    Returns:
        The error as a fraction of the arm length (>= 0); Gannon's pass mark is 0.10.
    """
    ref = np.asarray(ref, dtype=float)
    run = np.asarray(run, dtype=float)
    L = _positive(length, "length")
    if ref.shape != run.shape:
        raise ValueError(f"ref and run must have the same shape, got {ref.shape} and "
                         f"{run.shape}")
    if ref.ndim > 2:
        raise ValueError(f"positions must be a scalar, a point (d,) or points (M, d); "
                         f"got shape {ref.shape}")
    if ref.size == 0:
        raise ValueError("ref and run are empty")
    if not (np.all(np.isfinite(ref)) and np.all(np.isfinite(run))):
        raise ValueError("ref or run contains non-finite values (NaN or inf)")
    d = run - ref
    dist = np.sqrt(np.sum(np.atleast_2d(d) ** 2, axis=-1)) if d.ndim else np.abs(d)[None]
    if reduce == "max":
        value = float(np.max(dist))
    elif reduce == "rms":
        value = float(np.sqrt(np.mean(dist * dist)))
    else:
        raise ValueError(f"reduce must be 'max' or 'rms', got {reduce!r}")
    return value / L


def relative_error(ref, run) -> float:
    """Signed relative error of a scalar quantity, ``(run - ref) / |ref|`` (fraction).

    Gannon 1986, Ch. IV Sec. C: strain amplitude and frequency errors are "the difference
    between the theoretical and experimental" values "normalized using the respective
    experimental values" (reference = experiment).

    Raises:
        ValueError: non-finite inputs or a zero reference.
    """
    r, x = float(ref), float(run)
    if not (math.isfinite(r) and math.isfinite(x)):
        raise ValueError(f"relative_error needs finite values, got ref={ref!r}, run={run!r}")
    if r == 0.0:
        raise ValueError("relative_error: the reference value is zero; a relative error "
                         "is undefined")
    return (x - r) / abs(r)


def frequency_error(f_ref, f_run) -> float:
    """Signed relative frequency error ``(f_run - f_ref) / f_ref`` (fraction).

    Gannon 1986, Ch. IV Sec. B (Table 4.3) and Sec. C (Table 4.5): "frequencies were
    normalized using experimental frequencies". Positive = the run is stiffer (higher
    frequency). Use :func:`passes` for the +-10 % test.

    Raises:
        ValueError: ``f_ref`` not a positive finite frequency or ``f_run`` not finite
            and >= 0.
    """
    fr = _positive(f_ref, "f_ref")
    fx = float(f_run)
    if not (math.isfinite(fx) and fx >= 0.0):
        raise ValueError(f"f_run must be a finite frequency >= 0, got {f_run!r}")
    return (fx - fr) / fr


def passes(error_fraction, threshold=GANNON_THRESHOLD) -> bool:
    """Whether ``|error_fraction| <= threshold``; NaN fails.

    Default threshold 0.10: the "relative percentage error of +-10 %" standard Gannon
    (1986, Ch. IV Sec. B) adopted from Petroka.
    """
    thr = _positive(threshold, "threshold")
    e = float(error_fraction)
    return bool(abs(e) <= thr)  # NaN compares False
