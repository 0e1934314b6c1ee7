"""Seed 000's air-bearing friction (issue 40 items 2 and 3): the friction identified
without Case 2, Case 3 reproduced, Case 2 predicted — the numbers
docs/calibration_seed000.md §5 quotes. ``tools/bearing_friction_seed000.py`` is its
command line.

Every batch of independent simulations is one call of the ensemble runner
(:func:`flexarm_ros.ensemble.runner.run_tasks`) on the ``executor`` a study is given
(default: in this process, one task after the other; or a Dask executor from
:func:`~flexarm_ros.ensemble.runner.open_executor`): each study's scenes, μ values and
variants are the items of one batch, and a root find (``brentq``, sequential in itself) is
one task. The tasks are module-level functions of picklable items (scenes, numbers,
metric names), so Dask workers import them from here; the scenes are built on the
client, the simulations run in the tasks, and the results come back in input order —
the same numbers on every executor.

* :func:`case1` — what the source's 0.07 s impact delay (seed 000 lines 3853-3860) asks of
  a uniform friction μ on both bearings (RB2, RB4), for the shipped (calibrated) arm and
  the geometry-only one: the μ that delays each arm's own impact by 0.065 / 0.07 / 0.075 s,
  and the reconciled pair — a resistance factor that puts the friction-free impact 0.07 s
  early (2.03 s) and the μ that brings it back to 2.10 s.
* :func:`case3`, :func:`case3_amplitudes` — the backlash run (two_link_case3_backlash)
  without friction, with the identified uniform μ and with a high spot under each bearing:
  per-cycle amplitude of q1, q2, their frequency (spectral peak) against the 0.667 Hz
  drive, the drift of the oscillation centre (a linear fit of the per-cycle means, with its
  standard error); and the amplitudes against μ.
* :func:`case2` — Case 2 (two_link_case2) predicted with the identified friction: f_A, f_C
  beside the experiment's 9.31-9.71 Hz, and with the binding term, which no record but
  Case 2 identifies (shown as what it would take, not a fit).
* :func:`case2_sensitivity`, :func:`what_it_would_take` — what moves Case 2's frequencies:
  v_s and a slower approach without friction; RB4's inertia and the beams' stiffness,
  which move Cases 1 and 2 together (friction off).

Each study returns its numbers; the matching ``*_table`` function writes them as the
Markdown the tool prints.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import brentq

from flexarm_ros.ensemble.metrics import evaluate, resolve_metrics
from flexarm_ros.ensemble.runner import run_tasks
from flexarm_ros.scene import Bearing, HighSpot, load_scene
from flexarm_ros.sim.simulate import simulate

DRIVE_HZ = 0.667                 # Case 3's square waves (seed 000 lines 3964-3968)
DELAYS = (0.065, 0.07, 0.075)    # s: "0.07 seconds" read to its last digit
IMPACT_EXPERIMENT = 2.10         # s: Case 1's impact "near 2.1 s"
CASE1_DURATION = 2.6             # s: past the impact
CASE2_DURATION = 3.5             # s: the calibration's window (tools/calibrate_seed000.py)
CASE3_DURATION = 15.0            # s: ten periods of the drive
SPOT = dict(offset=0.012, radius=0.01, friction=0.02)   # the illustrative high spot
#: Case 3's uniform μ values against which its amplitudes are shown
AMPLITUDE_MUS = (0.0, 0.002, 0.0045, 0.01, 0.02, 0.05)
CASE1_ARMS = ("two_link_case1", "two_link_case1_geometry")
CASE1_METRICS = ("impact_time", "bounce_height", "frequency:acc_A_true",
                 "frequency:acc_C_true")
CASE2_METRICS = ("impact_time", "frequency:acc_A_true", "frequency:acc_C_true")
BAND_HZ = (9.31, 9.71)           # Case 2's experiment (seed 000)


# ---------------------------------------------------------------------- the scenes
def with_bearings(scene, mu: float, binding: float = 0.0, spots=None):
    """``scene`` with a bearing of coefficient μ under RB2 (links[0].tip, ``binding`` on
    it: it houses the middle drive) and RB4 (links[1].tip); ``spots``: one high spot per
    bearing (a (2,) centre each) or None."""
    spots = spots or (None, None)
    mk = [(HighSpot(point=tuple(c), radius=SPOT["radius"], friction=SPOT["friction"]),)
          if c is not None else () for c in spots]
    return dataclasses.replace(scene, bearings=(
        Bearing(link=scene.links[0].name, friction=mu, binding=binding, high_spots=mk[0]),
        Bearing(link=scene.links[1].name, friction=mu, high_spots=mk[1])))


def scale_resistance(scene, factor: float):
    """Both motors' resistances × factor (the calibration's ``resistance_factor``)."""
    links = []
    for lk in scene.links:
        dr = dataclasses.replace(lk.joint.drive, resistance=lk.joint.drive.resistance * factor)
        links.append(dataclasses.replace(lk, joint=dataclasses.replace(lk.joint, drive=dr)))
    return dataclasses.replace(scene, links=tuple(links))


def spot_centres(scene, offset=None):
    """One spot per bearing, ``offset`` m from its start point along the direction its
    first stroke takes (the first half-period's motion, from a short friction-free run)."""
    from flexarm_ros.model import Chain
    offset = SPOT["offset"] if offset is None else offset
    ch = Chain(scene)
    res = simulate(scene, 0.5 / DRIVE_HZ)
    q_end = np.array([res.columns[nm][-1] for nm in ch.names])
    q0, _ = ch.initial_q()
    out = []
    for k in range(2):
        p0 = ch.point_kinematics(q0, 0 * q0, k, "tip", scene.links[k].tip.cg)[0]
        p1 = ch.point_kinematics(q_end, 0 * q0, k, "tip", scene.links[k].tip.cg)[0]
        d = (p1 - p0) / np.linalg.norm(p1 - p0)
        out.append(p0 + offset * d)
    return out


# -------------------------------------------------------------------- the features
def impact_time(scene) -> float:
    """Case 1's first impact (s) in a run of :data:`CASE1_DURATION`; a runner task."""
    res = simulate(scene, CASE1_DURATION)
    return evaluate(res, resolve_metrics(["impact_time"], scene))["impact_time_s"]


def cycle_stats(t, angle_deg):
    """Per drive period: mean and half range (deg); the centre's drift: slope (deg/s) of a
    linear fit of the means and its standard error; the spectral peak (Hz)."""
    per = 1.0 / DRIVE_HZ
    n = int(t[-1] / per + 1e-9)
    means, amps = [], []
    for k in range(n):
        m = (t >= k * per) & (t < (k + 1) * per)
        means.append(angle_deg[m].mean())
        amps.append(0.5 * (angle_deg[m].max() - angle_deg[m].min()))
    tc = (np.arange(n) + 0.5) * per
    A = np.vstack([tc, np.ones(n)]).T
    coef, res, *_ = np.linalg.lstsq(A, np.asarray(means), rcond=None)
    dof = max(n - 2, 1)
    s2 = float(res[0]) / dof if len(res) else 0.0
    se = math.sqrt(s2 / np.sum((tc - tc.mean()) ** 2))
    x = angle_deg - angle_deg.mean()
    dt = t[1] - t[0]
    nfft = 1 << (int(len(x) * 16).bit_length())
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x)), nfft))
    fr = np.fft.rfftfreq(nfft, dt)
    band = (fr > 0.2) & (fr < 3.0)
    peak = fr[band][np.argmax(spec[band])]
    return {"means": np.asarray(means), "amplitude": float(np.mean(amps[1:])),
            "drift": float(coef[0]), "drift_se": se, "frequency": float(peak),
            "shift": float(means[-1] - means[0])}


def case3_run(scene, duration=CASE3_DURATION) -> dict:
    """:func:`cycle_stats` of q1 and q2 in a run of ``duration``."""
    res = simulate(scene, duration)
    c = res.columns
    t = c["t"]
    return {nm: cycle_stats(t, np.degrees(c[f"{lk.name}_joint"]))
            for nm, lk in zip(("q1", "q2"), scene.links)}


# ------------------------------------------------------------------------- tasks
# Module-level functions of picklable items: what the runner ships to a Dask worker.
def scene_metrics(item) -> dict:
    """Task: (scene, metric names, duration) → ``{column: value}`` of one run."""
    scene, names, duration = item
    return evaluate(simulate(scene, duration), resolve_metrics(list(names), scene))


def case1_root(item):
    """Task: one root find of :func:`case1`, sequential in itself.

    ``("delay", arm, t0, d)`` → the uniform μ that delays ``arm``'s impact from ``t0`` by
    ``d``; ``("reconcile", arm)`` → (factor, μ): the resistance factor that puts the
    friction-free impact 0.07 s before :data:`IMPACT_EXPERIMENT`, then the μ that brings
    that arm's impact back to it (the second root needs the first)."""
    kind, base, *rest = item
    if kind == "delay":
        t0, d = rest
        return brentq(lambda m: impact_time(with_bearings(base, m)) - t0 - d, 0.0, 0.02,
                      xtol=1e-6)
    if kind != "reconcile":
        raise ValueError(f"case1_root: got {kind!r}, expected 'delay' or 'reconcile'")
    early = IMPACT_EXPERIMENT - DELAYS[1]
    f = brentq(lambda k: impact_time(scale_resistance(base, k)) - early, 0.8, 1.0, xtol=1e-5)
    arm = scale_resistance(base, f)
    mu = brentq(lambda m: impact_time(with_bearings(arm, m)) - IMPACT_EXPERIMENT, 0.0,
                0.02, xtol=1e-6)
    return f, mu


def case3_variant(item) -> dict:
    """Task: (base, μ, spotted, duration) → :func:`case3_run` of ``base`` with a uniform μ
    on both bearings (μ = 0: the base, bearings floating), and with ``spotted`` a high
    spot under each (:func:`spot_centres`, from a short run of the base)."""
    base, mu, spotted, duration = item
    if not mu:
        return case3_run(base, duration)
    spots = spot_centres(base) if spotted else None
    return case3_run(with_bearings(base, mu, spots=spots), duration)


# ----------------------------------------------------------------------- studies
def case1(executor=None) -> dict:
    """Case 1's delay as a uniform μ, per arm, the reconciled pair, and Case 1's features
    with them. Three batches: the friction-free impacts; the root finds (three delays per
    arm and the reconciled pair, one task each); the three feature runs."""
    bases = {name: load_scene(name) for name in CASE1_ARMS}
    t0s = run_tasks(impact_time, list(bases.values()), executor)
    roots = [("delay", bases[name], t0, d) for name, t0 in zip(CASE1_ARMS, t0s)
             for d in DELAYS]
    found = run_tasks(case1_root, roots + [("reconcile", bases[CASE1_ARMS[0]])], executor)
    out = {}
    for k, (name, t0) in enumerate(zip(CASE1_ARMS, t0s)):
        out[name] = {"t0": t0, "mu": dict(zip(DELAYS, found[k * len(DELAYS):
                                                            (k + 1) * len(DELAYS)]))}
    f, mu = found[-1]
    out["reconciled"] = {"factor": f, "mu": mu}
    base = bases[CASE1_ARMS[0]]
    arm = scale_resistance(base, f)
    mu1 = out[CASE1_ARMS[0]]["mu"][DELAYS[1]]
    runs = [("shipped, friction off", base),
            (f"shipped, μ = {mu1:.5f}", with_bearings(base, mu1)),
            (f"reconciled, μ = {mu:.5f}", with_bearings(arm, mu))]
    ms = run_tasks(scene_metrics, [(sc, CASE1_METRICS, CASE2_DURATION) for _, sc in runs],
                   executor)
    out["features"] = [(label, m) for (label, _), m in zip(runs, ms)]
    return out


def case1_table(r: dict) -> str:
    early = IMPACT_EXPERIMENT - DELAYS[1]
    rec = r["reconciled"]
    lines = ["| arm | impact without friction | μ for 0.065 s | 0.07 s | 0.075 s |",
             "|---|---|---|---|---|"]
    lines += [f"| `{name}` | {r[name]['t0']:.3f} s | " + " | ".join(
        f"{r[name]['mu'][d]:.5f}" for d in DELAYS) + " |" for name in CASE1_ARMS]
    lines += ["", f"reconciled: resistance × {rec['factor']:.4f} (friction-free impact "
              f"{early:.2f} s), μ = {rec['mu']:.5f} (impact {IMPACT_EXPERIMENT:.2f} s)", "",
              "| Case 1 arm | impact (s) | bounce within 0.2 s (mm) | f_A (Hz) | f_C (Hz) |",
              "|---|---|---|---|---|"]
    lines += [f"| {label} | {m['impact_time_s']:.3f} | {1e3 * m['bounce_height_m']:.1f} | "
              f"{m['frequency_acc_A_true_hz']:.2f} | {m['frequency_acc_C_true_hz']:.2f} |"
              for label, m in r["features"]]
    return "\n".join(lines)


def case3(mu: float, executor=None, duration=CASE3_DURATION) -> dict:
    """Case 3 without friction, with a uniform μ and with μ + a high spot under each
    bearing: ``{label: {"q1": stats, "q2": stats}}`` (:func:`cycle_stats`), one batch."""
    base = load_scene("two_link_case3_backlash")
    variants = {"off": (0.0, False), f"uniform μ = {mu:.4f}": (mu, False),
                f"μ = {mu:.4f} + a high spot": (mu, True)}
    rs = run_tasks(case3_variant, [(base, m, spotted, duration)
                                   for m, spotted in variants.values()], executor)
    return dict(zip(variants, rs))


def case3_table(r: dict) -> str:
    lines = ["| friction | angle | amplitude (deg) | frequency (Hz) | centre drift (deg/s ± 1σ)"
             " | centre moved, first to last cycle (deg) |", "|---|---|---|---|---|---|"]
    for label, run in r.items():
        for q in ("q1", "q2"):
            s = run[q]
            lines.append(f"| {label} | {q} | {s['amplitude']:.3f} | {s['frequency']:.3f} | "
                         f"{s['drift']:+.4f} ± {s['drift_se']:.4f} | {s['shift']:+.3f} |")
    return "\n".join(lines)


def case3_amplitudes(mus=AMPLITUDE_MUS, executor=None, duration=CASE3_DURATION) -> dict:
    """Case 3's amplitudes under a uniform μ: ``{μ: (q1, q2)}`` (deg), one batch. The
    source's "very close" amplitudes (its friction-free simulation against the
    experiment) bound μ from above."""
    base = load_scene("two_link_case3_backlash")
    rs = run_tasks(case3_variant, [(base, mu, False, duration) for mu in mus], executor)
    return {mu: (r["q1"]["amplitude"], r["q2"]["amplitude"]) for mu, r in zip(mus, rs)}


def case3_amplitudes_table(r: dict) -> str:
    a0 = next(iter(r.values()))
    lines = ["| uniform μ | q1 amplitude (deg) | q2 amplitude (deg) | q1 / friction-free | "
             "q2 / friction-free |", "|---|---|---|---|---|"]
    lines += [f"| {mu:g} | {a[0]:.3f} | {a[1]:.3f} | {a[0] / a0[0]:.3f} | "
              f"{a[1] / a0[1]:.3f} |" for mu, a in r.items()]
    return "\n".join(lines)


def case2(mu: float, factor: float = 1.0, executor=None) -> list:
    """Case 2 (both resistances × ``factor``) without friction, with μ, and with μ and
    binding b = 1 and 10 on RB2: ``[(label, b, {column: value})]``, one batch."""
    base = scale_resistance(load_scene("two_link_case2"), factor)
    runs = [("off", base), (f"μ = {mu:.4f}", with_bearings(base, mu)),
            (f"μ = {mu:.4f}", with_bearings(base, mu, binding=1.0)),
            (f"μ = {mu:.4f}", with_bearings(base, mu, binding=10.0))]
    ms = run_tasks(scene_metrics, [(sc, CASE2_METRICS, CASE2_DURATION) for _, sc in runs],
                   executor)
    return [(label, sc.bearings[0].binding if sc.bearings else 0.0, m)
            for (label, sc), m in zip(runs, ms)]


def case2_table(rows: list) -> str:
    lines = [f"| friction | binding b (1/m) | impact (s) | f_A (Hz) | f_C (Hz) | f_A vs "
             f"{_band()} | f_C vs {_band()} |", "|---|---|---|---|---|---|---|"]
    for label, b, m in rows:
        fa, fc = m["frequency_acc_A_true_hz"], m["frequency_acc_C_true_hz"]
        lines.append(f"| {label} | {b:g} | {m['impact_time_s']:.3f} | {fa:.2f} | {fc:.2f} | "
                     f"{versus(fa)} | {versus(fc)} |")
    return "\n".join(lines)


def case2_sensitivity(mu: float, executor=None) -> list:
    """What sets Case 2's ringing under friction: the regularization speed v_s (0.1-10
    mm/s), and a slower approach without friction (both resistances × 1.1, × 1.2):
    ``[(label, {column: value})]``, one batch."""
    base = load_scene("two_link_case2")
    runs = []
    for vs in (1e-4, 1e-3, 1e-2):
        sc = with_bearings(base, mu)
        runs.append((f"μ = {mu:.4f}, v_s = {vs * 1e3:g} mm/s", dataclasses.replace(
            sc, bearings=tuple(dataclasses.replace(b, slip_velocity=vs)
                               for b in sc.bearings))))
    runs += [(f"friction off, resistances × {f:g}", scale_resistance(base, f))
             for f in (1.0, 1.1, 1.2)]
    ms = run_tasks(scene_metrics, [(sc, CASE2_METRICS, CASE2_DURATION) for _, sc in runs],
                   executor)
    return [(label, m) for (label, _), m in zip(runs, ms)]


def case2_sensitivity_table(rows: list) -> str:
    lines = ["| Case 2 run | impact (s) | f_A (Hz) | f_C (Hz) |", "|---|---|---|---|"]
    lines += [f"| {label} | {m['impact_time_s']:.3f} | {m['frequency_acc_A_true_hz']:.2f} | "
              f"{m['frequency_acc_C_true_hz']:.2f} |" for label, m in rows]
    return "\n".join(lines)


def _inertia(l0, l1, factor=1.5):
    """RB4's inertia × ``factor``."""
    tip = dataclasses.replace(l1.tip, inertia=factor * l1.tip.inertia)
    return l0, dataclasses.replace(l1, tip=tip)


def _stiffness(l0, l1, factor=0.8):
    """Both beams' EI × ``factor``."""
    return tuple(dataclasses.replace(lk, beam=dataclasses.replace(lk.beam, EI=factor * lk.beam.EI))
                 for lk in (l0, l1))


#: the changes :func:`what_it_would_take` makes, friction off
CHANGES = (("none", lambda l0, l1: (l0, l1)), ("RB4 inertia × 1.5", _inertia),
           ("beams' EI × 0.8", _stiffness))


def what_it_would_take(executor=None) -> list:
    """Cases 1 and 2 ring at frequencies that move together with the arm's inertia and
    stiffness: RB4's inertia ×1.5 or both beams' EI ×0.8, friction off. ``[(label, (case
    1 metrics, case 2 metrics))]``, one batch (the scenes changed here, run in the tasks)."""
    scenes = []
    for _, edit in CHANGES:
        for name in ("two_link_case1", "two_link_case2"):
            sc = load_scene(name)
            scenes.append(dataclasses.replace(sc, links=tuple(edit(*sc.links))))
    ms = run_tasks(scene_metrics, [(sc, CASE2_METRICS, CASE2_DURATION) for sc in scenes],
                   executor)
    return [(label, (ms[2 * k], ms[2 * k + 1])) for k, (label, _) in enumerate(CHANGES)]


def what_it_would_take_table(rows: list) -> str:
    lines = ["| change (friction off) | Case 1 f_A / f_C (Hz) | Case 2 f_A / f_C (Hz) |",
             "|---|---|---|"]
    for label, pair in rows:
        cells = [f"{m['frequency_acc_A_true_hz']:.2f} / {m['frequency_acc_C_true_hz']:.2f}"
                 for m in pair]
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines)


def _band() -> str:
    return f"{BAND_HZ[0]}–{BAND_HZ[1]}"


def versus(f) -> str:
    """``f`` against Case 2's band: the distance from its nearer edge, a hit within 15 %."""
    lo, hi = BAND_HZ
    if not math.isfinite(f):
        return "no peak"
    off = 0.0 if lo <= f <= hi else (f - hi) / hi if f > hi else (f - lo) / lo
    return f"{off * 100:+.1f} % {'hit' if abs(off) <= 0.15 else 'miss'}"
