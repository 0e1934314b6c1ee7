"""The ``flexarm compare`` command: runs :func:`flexarm_ros.analysis.compare.compare_files`
on the parsed options, prints the summary table or the JSON document and writes the
report (:func:`flexarm_ros.analysis.report.write_report`). Options are parsed in
:mod:`flexarm_ros.commands.compare`; docs/compare.md describes them.
"""

from __future__ import annotations

import sys
import warnings as _w

from flexarm_ros.analysis import metrics as M
from flexarm_ros.analysis.compare import (DEFAULT_MAX_SHIFT_S, compare_files, parse_window,
                                          to_json)
from flexarm_ros.analysis.comparison import Comparison
from flexarm_ros.analysis.report import write_report

__all__ = ["run_cli", "summary"]


def summary(cmp: Comparison) -> str:
    """The result as the table ``flexarm compare`` prints (one line per channel)."""
    r = cmp.result
    lines = [f"{r['run']['path']} vs {r['reference']['path']}: "
             f"{'PASS' if r['pass'] else 'FAIL'} (threshold ±{100 * r['threshold']:g} %, "
             f"offset {r['offset']['offset_s']:+.6g} s, {r['offset']['mode']})"]
    lines.append(f"  {'channel':22s} {'f run':>9s} {'f ref':>9s} {'f err':>8s} "
                 f"{'amp err':>8s} {'rel RMS':>8s}  result")

    def pct(x):
        return "-" if x is None else f"{100 * x:+.2f}%"

    def hz(x):
        return "-" if x is None else f"{x:.4g}"
    for n in cmp.names:
        b = r["channels"][n]
        res = {True: "pass", False: "FAIL", None: "-"}[b["pass"]]
        if b["events"] is not None:          # a 0/1 flag: events, no frequency
            run_ev, ref_ev = b["events"]["run"] or {}, b["events"]["reference"] or {}
            res += (f"  (flag: rises {run_ev.get('rises', '-')} / "
                    f"{ref_ev.get('rises', '-')})")
        if b["judged_by"] == "control":
            res += " (control criteria, below)"
        lines.append(f"  {n:22s} {hz(b['frequency_run_hz']):>9s} "
                     f"{hz(b['frequency_reference_hz']):>9s} {pct(b['frequency_error']):>8s} "
                     f"{pct(b['amplitude_error']):>8s} {pct(b['relative_rms_error']):>8s}  "
                     f"{res}")
    tracking = [n for n in cmp.names if r["channels"][n]["control"] is not None]
    if tracking:
        lines.append(f"  {'tracking (run / ref)':22s} {'final err':>19s} {'overshoot':>15s} "
                     f"{'rise [s]':>17s} {'settling [s]':>17s} {'RMS track err':>19s}")

        def pair(c, k, fmt):
            return "/".join("-" if c[s][k] is None else fmt(c[s][k])
                            for s in ("run", "reference"))
        for n in tracking:
            c = r["channels"][n]["control"]
            kind = (c["reference"]["command"] or {}).get("kind") if c["reference"] else None
            lines.append(
                f"  {n + ' (' + str(kind) + ')':22s} "
                f"{pair(c, 'final_error', lambda v: f'{v:.3g}'):>19s} "
                f"{pair(c, 'overshoot', lambda v: f'{100 * v:.2f}%'):>15s} "
                f"{pair(c, 'rise_time_s', lambda v: f'{v:.4g}'):>17s} "
                f"{pair(c, 'settling_time_s', lambda v: f'{v:.4g}'):>17s} "
                f"{pair(c, 'rms_tracking_error', lambda v: f'{v:.3g}'):>19s}")
    c = r["contact"]
    if c["impact_source"] is not None:
        lines.append(f"  impact ({c['impact_source']}): run {hz(c['impact_time_run_s'])} s, "
                     f"reference {hz(c['impact_time_reference_s'])} s, error "
                     f"{hz(c['impact_time_error_s'])} s")
    tp = r["tip"]
    if tp["normalized_amplitude_error"] is not None or tp["frequency_error"] is not None:
        lines.append(f"  tip (Gannon): amplitude error / L "
                     f"{pct(tp['normalized_amplitude_error'])}, frequency error "
                     f"{pct(tp['frequency_error'])} "
                     f"({tp['frequency_channel'] or 'no tip channel compared'})")
    if r["failed"]:
        lines.append("  failed: " + ", ".join(r["failed"]))
    return "\n".join(lines)


def run_cli(args) -> int:
    """``flexarm compare`` (options parsed in :mod:`flexarm_ros.commands.compare`): prints
    the summary or the JSON, writes the report; returns 0 = pass, 1 = fail. Bad input
    raises :class:`~flexarm_ros.io.experiment.CompareInputError` (exit status 2)."""
    if args.report:                      # checked before the comparison, not after it
        from flexarm_ros.io.paths import check_output_dir
        check_output_dir("--report", args.report)
    channels = None
    if args.channels:
        channels = [c for item in args.channels for c in item.split(",") if c.strip()]
    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        cmp = compare_files(
            args.run, args.reference, map_path=args.map, offset=args.offset,
            threshold=M.GANNON_THRESHOLD if args.threshold is None else args.threshold,
            channels=channels,
            max_shift_s=DEFAULT_MAX_SHIFT_S if args.max_shift is None else args.max_shift,
            window=parse_window(args.window))
    for w in caught:
        print(f"flexarm compare: warning: {w.message}", file=sys.stderr)
    for w in cmp.result["warnings"]:
        if not any(str(c.message) == w for c in caught):
            print(f"flexarm compare: warning: {w}", file=sys.stderr)
    if args.report:
        md = write_report(cmp, args.report)
        if not args.json:
            print(f"report: {md}")
    print(to_json(cmp.result) if args.json else summary(cmp))
    return 0 if cmp.passed else 1
