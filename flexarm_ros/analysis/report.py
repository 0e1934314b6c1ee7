"""The ``flexarm compare --report DIR`` output: ``report.md`` and PNG figures.

Figures (matplotlib's Agg canvas, no display, no pyplot state):

* ``overlay_<channel>.png`` — reference and run (on the reference clock, ``t - offset``)
  against time, and below them the difference run - reference at the reference instants;
  the reference a broad light line under the run's thin red one, a 0/1 flag drawn as
  steps, the time outside the analysed span shaded light grey; a channel that tracks a
  command also shows its target(s), dashed, held between samples;
* ``spectrum_<channel>.png`` — the amplitude spectra of both records over the analysed
  span on one axis (Hann window, linear detrend, 4x zero padding: what the peak estimator
  searches; seed 000 Fig. 5.8 compares the FFTs of measured and simulated accelerations
  this way), the two dominant peaks marked and labelled, the band below 3 bins (not
  searched) shaded;
* ``tip_path.png`` — the tip path in the plane, both records, with the wall line(s) of the
  scene and the impact points;
* ``contact.png`` — the wall normal force and the contact phase (1 = in contact) against
  time, impact times marked.

Legends name the inputs by file: ``<run file> (run)``, ``<reference file> (reference)``.
Every number in ``report.md`` is read from the comparison result (the ``--json``
document), so the two never disagree.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy import signal as _sig

from flexarm_ros.analysis.comparison import (FREQ_DETREND, FREQ_MIN_BINS, FREQ_WINDOW,
                                             FREQ_ZERO_PAD, Comparison)
from flexarm_ros.analysis.spectra import MIN_SAMPLES, checked_series, crop, uniform_record

__all__ = ["write_report"]

#: Line styles: the reference a broad light band under the run's thin line, so both stay
#: visible where they agree; labels name the files (:func:`_styles`).
RUN_STYLE = {"color": "C3", "lw": 0.9, "zorder": 3}
REF_STYLE = {"color": "0.2", "lw": 2.2, "alpha": 0.4, "zorder": 2}
#: Face colour of the parts of the time axis outside the analysed span.
OUTSIDE_SPAN = "0.93"
DPI = 100


def _styles(cmp: Comparison) -> tuple[dict, dict]:
    """(reference style, run style), labelled ``<file name> (reference)`` / ``(run)``."""
    return ({**REF_STYLE, "label": f"{Path(cmp.reference.path).name} (reference)"},
            {**RUN_STYLE, "label": f"{Path(cmp.run.path).name} (run)"})


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def _pct(x) -> str:
    return "—" if x is None else f"{100.0 * x:+.2f} %"


def _g(x, unit="", digits=5) -> str:
    if x is None:
        return "—"
    return f"{x:.{digits}g}" + (f" {unit}" if unit else "")


def _ok(x) -> str:
    return {True: "pass", False: "**FAIL**", None: "—"}[x]


# ----------------------------------------------------------------------------- figures

def _padded_spectrum(t, y):
    """The amplitude spectrum the peak estimator searches: linear detrend, periodic Hann
    window, ``FREQ_ZERO_PAD``-fold zero padding, scaled as
    :func:`flexarm_ros.analysis.spectra.spectrum` (``2 |Y| / sum(w)``)."""
    t, y = checked_series(t, y, min_samples=MIN_SAMPLES)
    n = y.size
    w = _sig.get_window(FREQ_WINDOW, n, fftbins=True)
    nfft = FREQ_ZERO_PAD * n
    amp = np.abs(np.fft.rfft(_sig.detrend(y, type=FREQ_DETREND) * w, nfft)) * 2.0 / w.sum()
    return np.fft.rfftfreq(nfft, (t[-1] - t[0]) / (n - 1)), amp


def _overlay(cmp: Comparison, name: str, out: Path) -> Path | None:
    blk = cmp.result["channels"][name]
    run, ref = cmp.run[name], cmp.reference[name]
    off = cmp.offset_s
    unit = blk["unit"]
    ref_style, run_style = _styles(cmp)
    step = {"drawstyle": "steps-post"} if blk["signal"] == "boolean" else {}
    fig = Figure(figsize=(8.0, 5.0))
    ax, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(ref.t, ref.y, **ref_style, **step)
    ax.plot(run.t - off, run.y, **run_style, **step)
    ctl = blk["control"]
    if ctl is not None:                  # the command(s), held between their samples
        drawn = set()
        for side, style in (("reference", REF_STYLE), ("run", RUN_STYLE)):
            src = ctl["target_from"][side]
            if src in drawn:
                continue
            drawn.add(src)
            cs, shift = (cmp.reference, 0.0) if src == "reference" else (cmp.run, off)
            tch = cs[ctl["target_channel"][side]]
            ax.plot(tch.t - shift, tch.y, drawstyle="steps-post", ls="--", lw=1.0,
                        color=style["color"], zorder=4,
                        label=f"target ({Path(cs.path).name})")
    ax.set_ylabel(f"{name} [{unit}]")
    if blk["judged_by"] == "control":
        c = blk["control"]

        def two(k, f):
            return " / ".join("—" if c[s][k] is None else f(c[s][k])
                              for s in ("run", "reference"))
        ax.set_title(f"{name} (run / reference): overshoot "
                     f"{two('overshoot', lambda v: f'{100 * v:.3g} %')}, rise "
                     f"{two('rise_time_s', lambda v: f'{v:.4g}')} s, settling "
                     f"{two('settling_time_s', lambda v: f'{v:.4g}')} s", fontsize=10)
    else:
        ax.set_title(f"{name}: amplitude error {_pct(blk['amplitude_error'])}, relative "
                     f"RMS error {_pct(blk['relative_rms_error'])}", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    if blk["span_s"] is not None:
        a, b = blk["span_s"]
        tr, yr = crop(ref.t, ref.y, a, b)
        tp, yp = crop(run.t - off, run.y, a, b, pad=True)
        if tr.size and tp.size >= 2:
            ax2.plot(tr, np.interp(tr, tp, yp) - yr, color="C0", lw=0.8)
        lo = min(ref.t[0], run.t[0] - off)
        hi = max(ref.t[-1], run.t[-1] - off)
        for axis in (ax, ax2):       # shade what lies outside the analysed span
            for x0, x1 in ((lo, a), (b, hi)):
                if x1 > x0:
                    axis.axvspan(x0, x1, color=OUTSIDE_SPAN, zorder=0, lw=0)
            axis.set_xlim(lo, hi)
    ax2.set_ylabel(f"run − ref [{unit}]", fontsize=9)
    ax2.set_xlabel(f"time, reference clock [s] (run shifted by −offset = "
                   f"{0.0 - off:+.6g} s)")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out / f"overlay_{_safe(name)}.png")


def _spectrum(cmp: Comparison, name: str, out: Path) -> Path | None:
    blk = cmp.result["channels"][name]
    if blk["span_s"] is None:
        return None
    a, b = blk["span_s"]
    off = cmp.offset_s
    curves = []
    ref_style, run_style = _styles(cmp)
    for side, ch, shift, style in (("reference", cmp.reference[name], 0.0, ref_style),
                                   ("run", cmp.run[name], off, run_style)):
        t, y = crop(ch.t - shift, ch.y, a, b)
        try:
            t, y = uniform_record(t, y)
            f, amp = _padded_spectrum(t, y)
        except ValueError:
            continue
        curves.append((side, f, amp, style, blk[f"frequency_{side}_hz"], t.size))
    if not curves:
        return None
    fig = Figure(figsize=(8.0, 4.2))
    ax = fig.subplots()
    peaks = [c[4] for c in curves if c[4] is not None]
    nyq = min(c[1][-1] for c in curves)
    fmax = min(nyq, max(30.0, 3.0 * max(peaks, default=10.0)))
    lo_band, top = 0.0, 0.0
    for side, f, amp, style, fpk, n in curves:
        sel = f <= fmax
        ax.plot(f[sel], amp[sel], **style)
        fs = (n - 1) / (b - a) if b > a else 0.0
        lo_band = max(lo_band, FREQ_MIN_BINS * fs / n if n else 0.0)
        if fpk is not None:
            apk = float(np.interp(fpk, f, amp))
            ax.plot([fpk], [apk], marker="v", ms=9, color=style["color"], ls="none")
            ax.annotate(f"{side}: {fpk:.5g} Hz", (fpk, apk), textcoords="offset points",
                        xytext=(9, -4 if side == "run" else -16), fontsize=8,
                        color=style["color"])
            top = max(top, float(np.max(amp[sel])))
    ax.axvspan(0.0, lo_band, color=OUTSIDE_SPAN, zorder=0, lw=0,
               label="below 3 bins (not searched)")
    ax.set_xlim(0.0, fmax)
    if top > 0:
        ax.set_ylim(0.0, 1.12 * top)
    ax.set_xlabel(f"frequency [Hz] (resolution {_g(blk['frequency_resolution_hz'])} Hz, "
                  f"bound ±{_g(blk['frequency_bound_hz'], digits=3)} Hz)")
    ax.set_ylabel(f"amplitude [{blk['unit']}]")
    ax.set_title(f"{name}: spectra over [{a:.4g}, {b:.4g}] s, frequency error "
                 f"{_pct(blk['frequency_error'])}", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out / f"spectrum_{_safe(name)}.png")


def _tip_path(cmp: Comparison, out: Path) -> Path | None:
    run, ref = cmp.run, cmp.reference
    if not all(n in cs for cs in (run, ref) for n in ("tip_x", "tip_y")):
        return None
    xs = [float(v) for cs in (run, ref) for v in (cs["tip_x"].y.min(), cs["tip_x"].y.max())]
    ys = [float(v) for cs in (run, ref) for v in (cs["tip_y"].y.min(), cs["tip_y"].y.max())]
    dx, dy = max(xs) - min(xs), max(ys) - min(ys)
    ratio = min(max((dy + 0.2 * max(dx, dy)) / max(dx + 0.2 * max(dx, dy), 1e-9), 0.35), 1.5)
    fig = Figure(figsize=(8.0, 1.4 + 6.6 * ratio))
    ax = fig.subplots()
    contact = cmp.result["contact"]
    ref_style, run_style = _styles(cmp)
    for cs, style, shift, t_imp in (
            (ref, ref_style, 0.0, contact["impact_time_reference_s"]),
            (run, run_style, cmp.offset_s, contact["impact_time_run_s"])):
        x, y = cs["tip_x"], cs["tip_y"]
        t = x.t
        yy = np.interp(t, y.t, y.y)
        ax.plot(x.y, yy, **style)
        ax.plot([x.y[0]], [yy[0]], marker="o", color=style["color"], ls="none")
        if t_imp is not None:
            ax.plot([np.interp(t_imp, t, x.y)], [np.interp(t_imp, t, yy)], marker="x",
                    ms=10, mew=2, color=style["color"], ls="none")
    scene = run.scene if run.scene is not None else ref.scene
    walls = list(getattr(scene, "walls", ()) or ())
    span = max(max(xs) - min(xs), max(ys) - min(ys), 1e-3)
    for k, w in enumerate(walls):
        n = np.asarray(w.normal, float) / np.linalg.norm(w.normal)
        d = np.array([-n[1], n[0]])
        p = np.asarray(w.point, float)
        s = np.array([-1.5, 1.5]) * span
        mid = np.array([np.mean(xs), np.mean(ys)])
        s0 = float(np.dot(mid - p, d))
        ax.plot(p[0] + (s0 + s) * d[0], p[1] + (s0 + s) * d[1], color="C0", lw=2.5,
                label="wall" if k == 0 else None)
    ax.set_xlim(min(xs) - 0.1 * span, max(xs) + 0.1 * span)
    ax.set_ylim(min(ys) - 0.1 * span, max(ys) + 0.1 * span)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("tip x [m]")
    ax.set_ylabel("tip y [m]")
    ax.set_title("tip path (o start, x impact)", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out / "tip_path.png")


def _contact(cmp: Comparison, out: Path) -> Path | None:
    run, ref = cmp.run, cmp.reference
    have_f = [cs for cs in (ref, run) if "normal_force" in cs]
    have_c = [cs for cs in (ref, run) if "contact" in cs]
    if not have_f and not have_c:
        return None
    fig = Figure(figsize=(8.0, 5.0))
    ax, ax2 = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    res = cmp.result["contact"]
    ref_style, run_style = _styles(cmp)
    for cs, style, shift, t_imp in (
            (ref, ref_style, 0.0, res["impact_time_reference_s"]),
            (run, run_style, cmp.offset_s, res["impact_time_run_s"])):
        if "normal_force" in cs:
            ch = cs["normal_force"]
            ax.plot(ch.t - shift, ch.y, **style)
        if "contact" in cs:
            ch = cs["contact"]
            ax2.step(ch.t - shift, ch.y, where="post", **style)
        if t_imp is not None:
            for axis in (ax, ax2):
                axis.axvline(t_imp - shift, color=style["color"], ls="--", lw=0.8)
    ax.set_ylabel("normal force [N]")
    ax.set_title(f"wall contact; dashed: impact ({res['impact_source'] or 'none'}) at "
                 f"{_g(res['impact_time_reference_s'], 's')} (reference), "
                 f"{_g(res['impact_time_run_s'], 's')} (run, own clock)", fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    ax2.set_ylabel("in contact")
    ax2.set_yticks([0, 1])
    ax2.set_yticklabels(["free", "contact"])
    ax2.set_ylim(-0.2, 1.2)
    ax2.set_xlabel("time, reference clock [s]")
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out / "contact.png")


# ----------------------------------------------------------------------------- markdown

def _control_section(cmp: Comparison) -> list[str]:
    """The control table: per channel with a target, the command and each metric for the
    run and the reference, their difference, the tolerance and the verdict."""
    r = cmp.result
    tracking = [n for n in cmp.names if r["channels"][n]["control"] is not None]
    if not tracking:
        return []
    m = r["control_method"]
    targets = sorted({r["channels"][n]["control"]["target_channel"]["reference"]
                      for n in tracking})
    lines = ["", "## Control (channels that track a command)", "",
             f"A channel whose reference command (its target: "
             f"{', '.join(f'`{t}`' for t in targets)}) is a step or a ramp is judged by "
             f"these criteria instead of the frequency and amplitude ones: {m['tolerances']}. Rise time {100 * m['rise'][0]:g}–"
             f"{100 * m['rise'][1]:g} % of the step, settling time into ±"
             f"{100 * m['settling_band']:g} % of the step around the final target, overshoot "
             f"beyond the final target in the direction of travel (% of the step), times from "
             f"the command's onset; the target is held between its samples. The final-error "
             f"difference is the distance between the two signed end errors.", "",
             "| channel | command (reference) | metric | run | reference | difference | "
             "tolerance | result |", "|---|---|---|---|---|---|---|---|"]
    names = {"final_error": ("final error", "unit"), "overshoot": ("overshoot", "pct"),
             "rise_time_s": ("rise time", "s"), "settling_time_s": ("settling time", "s"),
             "rms_tracking_error": ("RMS tracking error", "unit")}
    notes = []
    for n in tracking:
        b = r["channels"][n]
        c = b["control"]
        cmd = (c["reference"] or {}).get("command") or {}
        kind = cmd.get("kind") or "—"
        desc = kind if kind == "none" else (
            f"{kind} {_g(cmd.get('initial'), digits=4)} → {_g(cmd.get('final_target'), digits=4)}"
            f" {b['unit']} at {_g(cmd.get('onset_s'), 's', 4)}")
        first = True
        for k, (label, how) in names.items():
            def fmt(v, how=how):
                if v is None:
                    return "—"
                if how == "pct":
                    return f"{100 * v:.3g} %"
                return _g(v, b["unit"] if how == "unit" else "s", 4)
            if all(v is None for v in (c["run"][k], c["reference"][k], c["difference"][k])):
                continue                  # no step: only the final and RMS errors
            crit = k[:-2] if k.endswith("_s") else k
            verdict = _ok(b["criteria"].get(crit)) if b["judged_by"] == "control" else \
                "reported"
            lines.append(f"| {n if first else ''} | {desc if first else ''} | {label} | "
                         f"{fmt(c['run'][k])} | {fmt(c['reference'][k])} | "
                         f"{fmt(c['difference'][k])} | {fmt(c['tolerance'][k])} | {verdict} |")
            first = False
        if b["judged_by"] != "control":
            why = (c["null_reasons"].get("reference.overshoot")
                   or c["null_reasons"].get("tolerance.final_error") or "")
            notes.append(f"- {n}: no step metrics, judged by the oscillation criteria: {why}")
    if notes:
        lines += [""] + notes
    return lines


def _markdown(cmp: Comparison, figs: dict) -> str:
    r = cmp.result
    thr = r["threshold"]
    off = r["offset"]
    run, ref = r["run"], r["reference"]
    lines = [
        f"# flexarm compare: {Path(run['path']).name} vs {Path(ref['path']).name}",
        "",
        f"**Result: {'PASS' if r['pass'] else 'FAIL'}** — criterion |relative error| ≤ "
        f"{100 * thr:g} % (Gannon 1986, Ch. IV, after Petroka)"
        + ("; the channels that track a step or ramp command by the control criteria "
           "(section Control)" if any(r["channels"][n]["judged_by"] == "control"
                                      for n in cmp.names) else "")
        + (f"; failed: {', '.join(r['failed'])}" if r["failed"] else "") + ".",
        "",
        "| | run (twin) | reference |",
        "|---|---|---|",
        f"| file | `{run['path']}` | `{ref['path']}` |",
        f"| kind | {run['kind']} | {ref['kind']} |",
        f"| scene | {run['scene'] or '—'} | {ref['scene'] or '—'} |",
        f"| time span | {_g(run['start_s'])} … {_g(run['end_s'])} s | "
        f"{_g(ref['start_s'])} … {_g(ref['end_s'])} s |",
        f"| truncated | {run['truncated']} | {ref['truncated']} |",
        "",
        "## Time alignment",
        "",
        f"Offset **{off['offset_s']:+.9g} s** ({off['method']}): the run's times are "
        f"shifted by −offset onto the reference clock, `run(t + offset) ≈ reference(t)` "
        f"(a positive offset means the run lags).",
    ]
    if off["sample_period_s"] is not None:
        lines.append(f"Finest sample period among the compared channels: "
                     f"{off['sample_period_s']:.6g} s.")
    if r["window"] is not None:
        w0, w1 = r["window"]["start_s"], r["window"]["end_s"]    # null: an open end
        lines.append(f"Analysis window (reference clock): "
                     f"{'the start' if w0 is None else f'{w0:g} s'} … "
                     f"{'the end' if w1 is None else f'{w1:g} s'}.")
    lines += [
        "",
        "## Channels",
        "",
        "| channel | unit | f run [Hz] | f ref [Hz] | resolution / bound [Hz] | "
        "frequency error | amplitude error | relative RMS error | RMS error | peak error | "
        "criteria | result |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for name in cmp.names:
        b = r["channels"][name]
        crit = ", ".join(k.replace("_error", "") for k in b["criteria"]) or "—"
        lines.append(
            f"| {name} | {b['unit']} | {_g(b['frequency_run_hz'])} | "
            f"{_g(b['frequency_reference_hz'])} | {_g(b['frequency_resolution_hz'], digits=3)}"
            f" / {_g(b['frequency_bound_hz'], digits=3)} | {_pct(b['frequency_error'])} | "
            f"{_pct(b['amplitude_error'])} | {_pct(b['relative_rms_error'])} | "
            f"{_g(b['rms_error'], digits=4)} | {_g(b['peak_error'], digits=4)} | {crit} | "
            f"{_ok(b['pass'])} |")
        keys_by_reason: dict = {}
        for k, why in sorted(b["null_reasons"].items()):
            keys_by_reason.setdefault(why, []).append(k)
        for why, keys in keys_by_reason.items():
            notes.append(f"- {name}.{', '.join(keys)}: {why}")
    flags = [n for n in cmp.names if r["channels"][n]["events"] is not None]
    if flags:
        lines += ["", "Boolean channels (0/1: events instead of a frequency; rises, falls, "
                      "time fraction at 1 over the span, first rise on the reference clock):",
                  "", "| channel | rises run / ref | falls run / ref | duty run / ref | "
                      "first rise run / ref [s] |", "|---|---|---|---|---|"]
        for n in flags:
            ev = r["channels"][n]["events"]
            run_ev, ref_ev = ev["run"] or {}, ev["reference"] or {}

            def pair(key, fmt=lambda v: f"{v}"):
                return " / ".join("—" if e.get(key) is None else fmt(e[key])
                                  for e in (run_ev, ref_ev))
            lines.append(f"| {n} | {pair('rises')} | {pair('falls')} | "
                         f"{pair('duty', lambda v: f'{v:.4g}')} | "
                         f"{pair('first_rise_s', lambda v: f'{v:.6g}')} |")
    lines += [
        "",
        "Frequencies: dominant peak of the Hann-windowed, 4× zero-padded FFT of each record "
        "over the analysed span, refined by Gaussian interpolation, searched from 3 bins "
        "(3 fs/N) up to Nyquist. The resolution is the bin spacing fs/N of the span (≈ 1 / "
        "span length); each frequency is stated to within the bound, 0.1 fs/N for clean "
        "signals (one bin near DC or Nyquist), so a frequency error is resolved to about "
        "2 × bound / f_ref. Amplitude error = signed peak-to-peak ratio − 1; errors are "
        "run − reference, normalized by the reference (the experiment).",
    ]
    if notes:
        lines += ["", "Figures not computed (null in the JSON):", ""] + notes
    lines += _control_section(cmp)
    c = r["contact"]
    lines += ["", "## Contact (seed 000: impact time and bounce)", ""]
    if c["impact_source"] is None:
        lines.append(f"Not evaluated: {c['null_reasons'].get('impact_time_run_s', '')}.")
    else:
        lines += [
            f"Impact detected on `{c['impact_source']}`.",
            "",
            "| | run | reference | error |",
            "|---|---|---|---|",
            f"| impact time [s] | {_g(c['impact_time_run_s'], digits=6)} (run clock) | "
            f"{_g(c['impact_time_reference_s'], digits=6)} | "
            f"{_g(c['impact_time_error_s'], 's', 4)} (after alignment) |",
            f"| bounce height within {c['bounce_window_s']:g} s [m] | "
            f"{_g(c['bounce_height_run_m'], digits=4)} | "
            f"{_g(c['bounce_height_reference_m'], digits=4)} | "
            f"{_g(c['bounce_height_abs_error_m'], 'm', 4)} ({_pct(c['bounce_height_error'])}) |",
        ]
        for k, why in sorted(c["null_reasons"].items()):
            lines.append(f"- {k}: {why}")
    tp = r["tip"]
    lines += ["", "## Tip (seed 002: Gannon's normalized tip errors)", ""]
    lines += [
        f"- arm length L = {_g(tp['arm_length_m'], 'm')}",
        f"- normalized tip-amplitude error max|Δp| / L = "
        f"{_pct(tp['normalized_amplitude_error'])} (RMS over the instants "
        f"{_pct(tp['normalized_rms_amplitude_error'])})",
        f"- tip frequency error ({tp['frequency_channel'] or '—'}) = "
        f"{_pct(tp['frequency_error'])}",
        f"- result: {_ok(tp['pass'])}",
    ]
    for k, why in sorted(tp["null_reasons"].items()):
        lines.append(f"- {k}: {why}")
    if r["warnings"]:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in r["warnings"]]
    lines += ["", "## Figures", ""]
    for key, title in (("tip_path", "Tip path in the plane"),
                       ("contact", "Contact normal force and phase")):
        if figs.get(key):
            lines += [f"### {title}", "", f"![{title}]({figs[key].name})", ""]
    for name in cmp.names:
        ov, sp = figs.get(f"overlay:{name}"), figs.get(f"spectrum:{name}")
        if ov or sp:
            lines.append(f"### {name}")
            lines.append("")
            if ov:
                lines.append(f"![{name} time overlay]({ov.name})")
            if sp:
                lines.append(f"![{name} spectra]({sp.name})")
            lines.append("")
    lines += [
        "## Reading this report",
        "",
        "Start from the failed criteria above. A frequency error on the accelerometers or "
        "strain points at stiffness or mass (EI, tip bodies, the rung: `flexarm study`); an "
        "amplitude error with matching frequencies at damping, drive gains or sensor "
        "sensitivities; an impact-time error at the drive model (motor constants, "
        "resistance) or the wall position. Check the overlays for a bad alignment first "
        "(a wrong offset inflates every RMS error; set `--offset` by hand if needed) and the "
        "spectra for peaks near the resolution (a short span cannot separate close "
        "modes: use a longer record or `--window`). Edit the scene, rerun `flexarm run`, "
        "compare again.",
        "",
    ]
    return "\n".join(lines)


def write_report(cmp: Comparison, directory) -> Path:
    """Write ``report.md`` and the figures into ``directory`` (created); return the
    Markdown path."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    figs: dict = {}
    for name in cmp.names:
        figs[f"overlay:{name}"] = _overlay(cmp, name, out)
        if cmp.result["channels"][name]["frequency_run_hz"] is not None or \
                cmp.result["channels"][name]["frequency_reference_hz"] is not None:
            figs[f"spectrum:{name}"] = _spectrum(cmp, name, out)
    figs["tip_path"] = _tip_path(cmp, out)
    figs["contact"] = _contact(cmp, out)
    md = out / "report.md"
    md.write_text(_markdown(cmp, figs), encoding="utf-8")
    return md
