"""Seed 000 Case 1: what sets the first bounce (issue 40 item 1, docs/calibration_seed000.md
§6), as tasks for the ensemble runner (``tools/bounce_candidates_seed000.py`` is the command).

Each candidate is the shipped ``two_link_case1`` with one element changed (``--set`` keys, as
``flexarm simulate two_link_case1 --set KEY=VALUE`` takes them), run for 3.5 s (the
window of the f_A feature, tools/reproduce_contact.py: at 3.0 s the same run reads f_A
12.8 Hz instead of 10.85). Read from the simulated series, independently of the contact
machinery's event log:

* impact — the first time the gap falls to 0 (linear interpolation of the 1 ms output);
* first bounce — the largest gap of the first stretch after the impact where the gap
  exceeds 1 µm (the first free flight), second bounce the next such stretch;
* first over 0.1 mm — the first flight higher than 0.1 mm (a lift-off of micrometres for a
  millisecond right after the impact counts as the first flight above);
* f_A — the dominant post-impact acceleration frequency at point A (acc_A_true, from
  20 ms after the impact), as tools/reproduce_contact.py reads it.

:func:`candidates` runs them on an executor of :mod:`flexarm_ros.ensemble.runner` (one
task per row, in one batch); :func:`table` formats the rows.
"""

from __future__ import annotations

import time

import numpy as np

from flexarm_ros.analysis.spectra import dominant_frequency
from flexarm_ros.errors import SimulationDiverged
from flexarm_ros.ensemble.runner import run_tasks
from flexarm_ros.scene import load_scene
from flexarm_ros.scene.overrides import apply_sets
from flexarm_ros.sim.simulate import simulate

DURATION = 3.5
BOUNCE_M = 1e-6
MAIN_M = 1e-4       # m: the first flight higher than this (past lift-offs of micrometres)
BL1 = {"width": 0.017453, "stiffness": 5000.0, "damping": 2.0}   # two_link_case3_backlash
BL2 = {"width": 0.017453, "stiffness": 3000.0, "damping": 1.0}


def bearings(mu: float) -> list:
    """``bearings:`` with a uniform μ under RB2 and RB4 (§5.1)."""
    return [{"link": "link1", "friction": mu}, {"link": "link2", "friction": mu}]


#: (group, label, sets)
CANDIDATES = [
    ("shipped", "two_link_case1 as shipped (impulse, e = 0, μ = 0.5)", {}),
    ("wall friction", "μ = 0", {"walls[0].friction": 0.0}),
    ("wall friction", "μ = 0.25", {"walls[0].friction": 0.25}),
    ("wall friction", "μ = 1.0", {"walls[0].friction": 1.0}),
    ("wall friction", "μ = 0.5, μ_s = 0.8", {"walls[0].static_friction": 0.8}),
    ("compliant wall", "k = 1e6 N/m, ζ = 3 (e ≈ 0.02)", {"fidelity.contact": "compliant"}),
    ("compliant wall", "k = 1e6 N/m, ζ = 1 (e ≈ 0.14)",
     {"fidelity.contact": "compliant", "walls[0].damping_ratio": 1.0}),
    ("compliant wall", "k = 1e6 N/m, ζ = 0 (e = 1)",
     {"fidelity.contact": "compliant", "walls[0].damping_ratio": 0.0}),
    ("compliant wall", "k = 1e5 N/m, ζ = 3",
     {"fidelity.contact": "compliant", "walls[0].stiffness": 1e5}),
    ("compliant wall", "k = 1e4 N/m, ζ = 3",
     {"fidelity.contact": "compliant", "walls[0].stiffness": 1e4}),
    ("motor", "inductance 0.12 / 0.25 mH (catalogue)",
     {"links[0].joint.drive.inductance": 1.2e-4, "links[1].joint.drive.inductance": 2.5e-4}),
    ("motor", "current limit 0.5 A", {"links[0].joint.drive.current_limit": 0.5,
                                      "links[1].joint.drive.current_limit": 0.5}),
    ("motor", "current limit 0.25 A", {"links[0].joint.drive.current_limit": 0.25,
                                       "links[1].joint.drive.current_limit": 0.25}),
    ("backlash", "1° both gearboxes (two_link_case3_backlash's)",
     {"links[0].joint.backlash": BL1, "links[1].joint.backlash": BL2,
      "fidelity.dt": 2.5e-4}),
    ("bearings", "μ = 0.0045 on RB2 and RB4 (§5.1)", {"bearings": bearings(0.0045)}),
    ("bearings", "μ = 0.0050, resistances × 0.8525 (§5.1 reconciled)",
     {"bearings": bearings(0.005),
      "links[0].joint.drive.resistance": 0.9879832 * 0.8525,
      "links[1].joint.drive.resistance": 4.042532 * 0.8525}),
    ("bearings", "μ = 0.01 (Case 3's bound)", {"bearings": bearings(0.01)}),
    ("gearbox", "C_eq × 2", {"links[0].joint.drive_damping": 2 * 5.1764,
                             "links[1].joint.drive_damping": 2 * 3.7014}),
    ("gearbox", "J_eq × 0.5", {"links[0].joint.drive_inertia": 0.5 * 0.4832332,
                               "links[1].joint.drive_inertia": 0.5 * 0.3827326}),
    ("tool lever", "tool 0.10 m on RB4 (window 0.245-0.327 m)", {"tool.position": [0.10, 0.0]}),
    ("tool lever", "tool 0.04 m on RB4", {"tool.position": [0.04, 0.0]}),
    ("beam damping", "c × 10 (20 N·s/m²)", {"links[0].beam.damping.viscous_per_length": 20.0,
                                           "links[1].beam.damping.viscous_per_length": 20.0}),
    *[("beam damping", f"β = {b * 1e3:g} ms (D = β·K)", {
        "links[0].beam.damping.stiffness_proportional": b,
        "links[1].beam.damping.stiffness_proportional": b})
      for b in (3e-3, 4e-3, 5e-3, 6e-3, 1e-2)],
    ("beam damping", "β = 61 ms (≈ 2.0 N·m·s on each tip rotation)", {
        "links[0].beam.damping.stiffness_proportional": 0.0608,
        "links[1].beam.damping.stiffness_proportional": 0.0615}),
]


def features(res) -> dict:
    """impact (s), bounces (m), f_A (Hz) from the series of ``res``."""
    t = np.asarray(res.columns["t"], float)
    gap = np.asarray(res.columns["gap"], float)
    k = int(np.flatnonzero(gap <= 0.0)[0])
    t_imp = float(t[k - 1] + (t[k] - t[k - 1]) * gap[k - 1] / (gap[k - 1] - gap[k]))
    free = (t > t_imp) & (gap > BOUNCE_M)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], free.astype(int), [0]])))
    flights = [float(gap[a:b].max()) for a, b in zip(edges[::2], edges[1::2])]
    tab = res.sensor_tables[4000.0]
    ts = np.asarray(tab["t"], float)
    sel = ts > t_imp + 0.02
    f_a = dominant_frequency(ts[sel], np.asarray(tab["acc_A_true"], float)[sel],
                             f_min=2.0, f_max=60.0).frequency_hz
    main = next((h for h in flights if h > MAIN_M), 0.0)
    return {"impact_s": t_imp, "bounces_m": flights[:2], "main_m": main, "f_A": float(f_a),
            "deepest_m": float(gap.min())}


def run(item) -> dict:
    group, label, sets = item
    sc = apply_sets(load_scene("two_link_case1"), dict(sets))
    t0 = time.perf_counter()
    row = {"group": group, "label": label}
    try:
        res = simulate(sc, DURATION)
    except SimulationDiverged as e:          # a diverged run is a row too
        row.update(wall_s=time.perf_counter() - t0, error=str(e).split(";")[0])
        return row
    row["wall_s"] = time.perf_counter() - t0
    row.update(features(res))
    return row


def table(rows) -> list[str]:
    ok = lambda c: "✓" if c else "✗"                    # noqa: E731
    out = ["| element | value | first bounce mm | second mm | first over 0.1 mm | impact s "
           "| f_A Hz | in target |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['group']} | {r['label']} | {r['error']} | | | | | |")
            continue
        b = r["bounces_m"] + [None, None]
        first = 1e3 * b[0] if b[0] is not None else 0.0
        sec = f"{1e3 * b[1]:.1f}" if b[1] is not None else "—"
        hit = (0.5 <= first <= 20.0, abs(r["impact_s"] - 2.1) <= 0.02,
               abs(r["f_A"] - 10.96) <= 0.05 * 10.96)
        out.append(f"| {r['group']} | {r['label']} | {first:.1f} | {sec} | "
                   f"{1e3 * r['main_m']:.1f} | "
                   f"{r['impact_s']:.3f} | {r['f_A']:.2f} | "
                   f"{ok(hit[0])} {ok(hit[1])} {ok(hit[2])} |")
    return out


def candidates(executor=None, only: str | None = None, on_result=None) -> list[dict]:
    """The rows of :data:`CANDIDATES` (those whose group contains ``only``), one task each
    on ``executor`` (default: in this process)."""
    items = [c for c in CANDIDATES if not only or only in c[0]]
    return run_tasks(run, items, executor, on_result=on_result)
