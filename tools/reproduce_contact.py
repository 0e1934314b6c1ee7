"""Seed 000 Cases 1 and 2 with the wall: the twin against the source (Hariharesan 1998,
Sec. 5.6), for the flexible rungs and the rigid-spring rung.

    python tools/reproduce_contact.py            # writes docs/reproduction_contact.md
    python tools/reproduce_contact.py --workers 2     # the six runs on a local Dask cluster
    python tools/reproduce_contact.py --scheduler tcp://127.0.0.1:8786

The six runs (case x rung) are tasks of the ensemble runner
(:func:`flexarm_ros.ensemble.runner.run_tasks`): in this process one after the other by
default (the ``wall s`` column then times each run alone), or on Dask workers.

Per case and rung: impact time, number of impacts, bounce height (largest gap within
0.3 s after the first impact), the heights of the first two bounces (the largest gap of
each free flight after the first impact that leaves the wall by more than 1 µm), the
deepest gap of the run (the tool's penetration; the impulse rung holds it near
fidelity.contact_tolerance), the dominant post-impact acceleration frequency at points
A–D (Hann-windowed, zero-padded FFT with peak interpolation, from 20 ms after the impact to
the end of a 3.5 s run; resolution fs/N and the estimator's bound stated) against the
source's experiment and its own simulation, with the ±10 % bar of seed 002, and the peak
post-impact acceleration; and the natural frequencies of the arm linearized at the impact
pose (joint angles at the first impact, joints locked, no wall: what ``flexarm modes``
gives for a scene starting there).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.analysis.spectra import dominant_frequency  # noqa: E402
from flexarm_ros.model.linear import natural_modes  # noqa: E402
from flexarm_ros.model.statics import initial_state  # noqa: E402
from flexarm_ros.scene import load_scene  # noqa: E402
from flexarm_ros.sim.simulate import simulate  # noqa: E402

DURATION = 3.5
CALIBRATION_BEGIN = "<!-- calibration: tools/calibrate_seed000.py -->"
SOURCE = {  # experiment, author's simulation (Hz); seed 000 Sec. 5.6 / docs/physics.md §14.1
    "two_link_case1": {"A": (10.96, 11.53), "B": (10.94, 11.52), "C": (10.56, 11.53),
                       "D": (None, None)},
    "two_link_case2": {"A": ((9.31, 9.71), (10.05, 10.14)), "B": ((9.31, 9.71), (10.05, 10.14)),
                       "C": ((9.31, 9.71), (10.05, 10.14)), "D": ((9.31, 9.71), (10.05, 10.14))},
}
RUNGS = (("cubic", 0), ("fem", 4), ("rigid", 0))
#: A gap below this (m) means the tool went through the wall: the impulse rung holds it
#: within fidelity.contact_tolerance (1 nm) in contact, so deeper is a stepper failure.
THROUGH_M = 1e-6
#: A free flight counts as a bounce when the gap exceeds this (m): lift-offs of a
#: micrometre between sliding stretches are not bounces.
BOUNCE_M = 1e-6
#: The scenes ship the Case 1 calibration (issue 40); the same table on the
#: geometry-only arm (two_link_case1_geometry's values), kept for comparison.
GEOMETRY_ONLY = (
    "Geometry only (the values derived from the source's geometry, before the Case 1 "
    "calibration was shipped: two_link_case1_geometry; commit 34cdd74): case1 cubic impact "
    "2.100 s, 3 impacts, bounce 37.553 mm (bounces 37.55 / 133.19 mm), f_A/B/C/D 11.88 / "
    "11.88 / 11.90 / 11.90 Hz; fem 4 2.100 s, 37.367 mm, 11.65 / 11.66 / 11.67 / 11.67 Hz; "
    "rigid 1.984 s, 3.09 / 3.09 / 3.03 / 8.50 Hz; case2 cubic 1.240 s, 5.755 mm, 12.07 / "
    "3.20 / 11.98 / 3.75 Hz; fem 4 1.240 s, 5.786 mm; rigid 1.106 s. Linearized at the "
    "impact pose (cubic): 0.25 / 1.55 / 12.21 / 24.00 Hz (case1). This page's earlier "
    "warning, case2 fem 4 through the wall from t = 2.276 s (gap −336 mm), dated from "
    "commit d386c3d, before the stepper checked a free step that starts a hair inside the "
    "wall after a lift-off for re-contact (2378bfc); the page was not regenerated after "
    "that fix. At 34cdd74 the same run keeps the gap above −1.3e-13 m.")
#: The same table before the rigid-body geometry was derived from the source (every CG,
#: hub radius, joint-2 and tool offset at zero; motor factor 1.776), kept for comparison.
BEFORE_GEOMETRY = (
    "Before the geometry (every rigid-body offset zero, the tool at the beam-2 tip, motor "
    "resistances 1.085 / 4.44 Ω; commit 2809361): case1 cubic impact 2.100 s, 3 impacts, "
    "bounce 0.003 mm, f_A/B/C/D 13.19 / 13.20 / 13.20 / 13.24 Hz; fem 4 2.100 s, 0.354 mm, "
    "12.78 / 12.79 / 12.78 / 3.62 Hz; rigid 2.038 s, 0.047 mm, 7.93 / 7.93 / 7.94 / 6.23 Hz; "
    "case2 cubic 1.361 s, 0.000 mm, 13.26 Hz at A–D; fem 4 1.361 s, 37.22 Hz; rigid 1.248 s, "
    "8.73 / 8.73 / 3.47 / 3.16 Hz (case2 fem 4 then too went through the wall: gap −247 mm "
    "at 3.5 s). Linearized at the impact pose (joints locked, cubic): "
    "0.28 / 1.64 / 13.18 / 24.13 Hz (case1), 0.28 / 1.66 / 13.19 / 24.14 Hz (case2).")


def analyse(name, rung, refine):
    sc = load_scene(name).with_fidelity(rung=rung, refine=refine)
    t0 = time.perf_counter()
    res = simulate(sc, DURATION)
    wall = time.perf_counter() - t0
    imp = res.contact.impacts
    t = res.columns["t"]
    gap = res.columns["gap"]
    row = {"case": name, "rung": f"{rung} {refine}" if refine else rung, "wall_s": wall,
           "impact_s": imp[0].time if imp else None, "impacts": len(imp)}
    if imp:
        win = (t > imp[0].time) & (t < imp[0].time + 0.3)
        row["bounce_mm"] = 1e3 * max(0.0, gap[win].max())
        row["bounces_mm"] = [1e3 * h for h in bounces(t, gap, imp[0].time)[:2]]
    row["min_gap"] = float(gap.min())
    inside = np.flatnonzero(gap < -THROUGH_M)
    if inside.size:             # the tool went through the wall (see THROUGH_M)
        row["through"] = (float(t[inside[0]]), float(gap.min()))
    if imp:
        row["modes_hz"] = impact_modes(sc, res, imp[0].time)
    tab = res.sensor_tables[4000.0]
    ts = tab["t"]
    start = (imp[0].time + 0.02) if imp else 0.5
    sel = ts > start
    for ch in "ABCD":
        y = tab[f"acc_{ch}_true"][sel]
        pk = dominant_frequency(ts[sel], y, f_min=2.0, f_max=60.0)
        row[f"f_{ch}"] = pk.frequency_hz
        row[f"peak_{ch}"] = float(np.abs(y).max())
        row["res_hz"], row["bound_hz"] = pk.resolution_hz, pk.bound_hz
    return row


def bounces(t, gap, t_impact):
    """Heights (m) of the free flights after ``t_impact``: the largest gap of each stretch
    where the gap exceeds BOUNCE_M, in order."""
    free = (t > t_impact) & (gap > BOUNCE_M)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], free.astype(int), [0]])))
    return [float(gap[a:b].max()) for a, b in zip(edges[::2], edges[1::2])]


def impact_modes(scene, res, t_impact, count=4):
    """First ``count`` natural frequencies (Hz) of the chain linearized at the joint angles
    of ``res`` at ``t_impact`` (elastic coordinates at rest, joints locked)."""
    from flexarm_ros.model.chain import Chain
    chain = Chain(scene)
    q0 = initial_state(chain)[0].copy()
    t = res.columns["t"]
    for lm in chain.links:
        q0[lm.i_joint] = np.interp(t_impact, t, res.columns[chain.names[lm.i_joint]])
    return [float(f) for f in natural_modes(chain, q0, "locked").frequencies_hz[:count]]


def _targets(rows) -> list[str]:
    """The shipped Case 1 (cubic) against the targets of issue 40: first bounce 0.5–20 mm
    (experiment about 5 mm), f_A within 5 % of 10.96 Hz, impact within 0.02 s of 2.1 s."""
    r = next((r for r in rows if r["case"] == "two_link_case1" and r["rung"] == "cubic"), None)
    if r is None or r["impact_s"] is None:
        return []
    b = r.get("bounces_mm", [])
    first = b[0] if b else 0.0
    fa = r["f_A"]
    ok = lambda c: "✓" if c else "✗"                        # noqa: E731
    second = f", the second {b[1]:.1f} mm" if len(b) > 1 else ""
    return ["The shipped Case 1 (two_link_case1, calibrated on Case 1; cubic) against its "
            f"targets: first bounce {first:.1f} mm{second} (target 0.5–20 mm, experiment "
            f"≈ 5 mm) {ok(0.5 <= first <= 20.0)}; f_A {fa:.2f} Hz, "
            f"{100 * (fa - 10.96) / 10.96:+.1f} % of 10.96 Hz (target ±5 %) "
            f"{ok(abs(fa - 10.96) <= 0.05 * 10.96)}; impact {r['impact_s']:.3f} s (target "
            f"2.1 ± 0.02 s) {ok(abs(r['impact_s'] - 2.1) <= 0.02)}.", ""]


def _err(f, ref):
    if ref is None:
        return "—"
    if isinstance(ref, tuple):
        lo, hi = ref
        e = 0.0 if lo <= f <= hi else (f - hi) / hi if f > hi else (f - lo) / lo
    else:
        e = (f - ref) / ref
    ok = "✓" if abs(e) <= 0.10 else "✗"
    return f"{100 * e:+.1f} % {ok}"


def _ref(ref):
    if ref is None:
        return "—"
    return f"{ref[0]}–{ref[1]}" if isinstance(ref, tuple) else f"{ref}"


def _analyse(item):
    return analyse(*item)


def main(argv=None):
    import argparse
    from flexarm_ros.ensemble.runner import open_executor, run_tasks
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=0,
                    help="local Dask worker processes (default 0: in this process)")
    ap.add_argument("--scheduler", help="an existing Dask scheduler address")
    args = ap.parse_args(argv)
    items = [(name, rung, refine) for name in SOURCE for rung, refine in RUNGS]
    with open_executor(args.workers, args.scheduler) as ex:
        rows = run_tasks(_analyse, items, ex,
                         on_result=lambda k, r: print(f"{r['case']} {r['rung']}: "
                                                      f"{r['wall_s']:.1f} s", flush=True))
    lines = ["# Seed 000 with the wall: the twin against the source", "",
             "Regenerate: `python tools/reproduce_contact.py` (impulse–constraint contact, "
             f"{DURATION} s runs, about a minute).", "",
             "Source (Hariharesan 1998, Sec. 5.6): Case 1 impact near 2.1 s, the tip "
             "bounces about 5 mm and is driven back; dominant post-impact acceleration "
             "frequency, experiment vs the author's simulation: A 10.96/11.53, B 10.94/11.52, "
             "C 10.56/11.53 Hz, D differs by 0.97 Hz; Case 2 9.31–9.71 Hz (experiment), "
             "10.05–10.14 Hz (simulation). The rigid model changes abruptly at impact, misses "
             "the higher frequencies and over-predicts the impact acceleration.", "",
             "| case | rung | impact s | impacts | bounce mm | bounces 1/2 mm | deepest gap m "
             "| f_A Hz | f_B Hz | f_C Hz | "
             "f_D Hz | peak acc A/B/C/D m/s² | modes at the impact pose Hz | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        imp = f"{r['impact_s']:.3f}" if r["impact_s"] is not None else "none"
        lines.append(
            f"| {r['case'][-5:]} | {r['rung']} | {imp} | {r['impacts']}"
            f"{' ⚠' if 'through' in r else ''} | "
            f"{r.get('bounce_mm', float('nan')):.3f} | "
            + (" / ".join(f"{b:.2f}" for b in r.get("bounces_mm", [])) or "—")
            + f" | {r['min_gap']:.2g} | "
            + " | ".join(f"{r['f_' + c]:.2f}" for c in "ABCD")
            + " | " + " / ".join(f"{r['peak_' + c]:.2g}" for c in "ABCD")
            + " | " + " / ".join(f"{f:.2f}" for f in r.get("modes_hz", []))
            + f" | {r['wall_s']:.1f} |")
    lines += ["", f"Frequency resolution fs/N ≈ {rows[0]['res_hz']:.2f} Hz; estimator bound "
              f"≈ {rows[0]['bound_hz']:.2f} Hz (`flexarm_ros/analysis/spectra.py`). Modes at "
              "the impact pose: the first natural frequencies of the arm linearized at the "
              "joint angles of the first impact, joints locked, no wall (`flexarm modes` on "
              "a scene starting there). Bounce mm: the largest gap within 0.3 s of the first "
              "impact; bounces 1/2: the highest gap of the first two free flights after it "
              f"(lift-offs below {BOUNCE_M * 1e6:.0f} µm not counted); deepest gap: the "
              "lowest gap of the run (negative: inside the wall; the impulse rung keeps a "
              "step's end within fidelity.contact_tolerance, 1 nm, and the samples inside "
              "a step are its interpolant).", ""]
    bad = [r for r in rows if "through" in r]
    if bad:
        lines += ["⚠ The tool went through the wall in " + "; ".join(
            f"{r['case'][-5:]} {r['rung']} (from t = {r['through'][0]:.3f} s, gap "
            f"{1e3 * r['through'][1]:.0f} mm at the deepest)" for r in bad)
            + ": a failure of the contact stepper, which holds the tool on the wall within "
            "fidelity.contact_tolerance (test/test_contact_gap.py holds every rung to "
            "that). Those rows' frequencies are not the arm against the wall.", ""]
    lines += _targets(rows)
    lines += [GEOMETRY_ONLY, "", BEFORE_GEOMETRY, "",
              "## Against the ±10 % bar (relative error of the dominant frequency)", "",
              "| case | rung | point | twin Hz | experiment Hz | vs experiment | source's "
              "simulation Hz | vs source's simulation |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for c in "ABCD":
            exp, sim = SOURCE[r["case"]][c]
            f = r["f_" + c]
            lines.append(f"| {r['case'][-5:]} | {r['rung']} | {c} | {f:.2f} | {_ref(exp)} | "
                         f"{_err(f, exp)} | {_ref(sim)} | {_err(f, sim)} |")
    out = ROOT / "docs" / "reproduction_contact.md"
    kept = ""                 # the calibration's section (tools/calibrate_seed000.py) stays
    if out.exists():
        old = out.read_text()
        if CALIBRATION_BEGIN in old:
            kept = "\n" + old[old.index(CALIBRATION_BEGIN):]
    out.write_text("\n".join(lines) + "\n" + kept)
    print("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
