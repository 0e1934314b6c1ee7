"""Seed 000: the air-bearing friction identified without Case 2, Case 3 reproduced, Case 2
predicted (issue 40 items 2 and 3).

    python tools/bearing_friction_seed000.py            # every study (about 2 min here)
    python tools/bearing_friction_seed000.py case3      # one of: case1 case3 case2 take

Prints the numbers docs/calibration_seed000.md §5 quotes, as Markdown.

* case1 — what the source's 0.07 s impact delay (seed 000 lines 3853-3860) asks of a uniform
  friction μ on both bearings (RB2, RB4), for the shipped (calibrated) arm and the
  geometry-only one: the μ that delays each arm's own impact by 0.065 / 0.07 / 0.075 s, and
  the reconciled pair — a resistance factor that puts the friction-free impact 0.07 s
  early (2.03 s) and the μ that brings it back to 2.10 s.
* case3 — the backlash run (two_link_case3_backlash) without friction, with the identified
  uniform μ and with a high spot under each bearing: per-cycle amplitude of q1, q2, their
  frequency (spectral peak) against the 0.667 Hz drive, the drift of the oscillation
  centre (a linear fit of the per-cycle means, with its standard error).
* case2 — Case 2 (two_link_case2) predicted with the identified friction: f_A, f_C beside
  the experiment's 9.31-9.71 Hz, and with the binding term, which no record but Case 2
  identifies (shown as what it would take, not a fit).
* take — what moves Case 2's frequencies: v_s and a slower approach without friction; RB4's
  inertia and the beams' stiffness, which move Cases 1 and 2 together (friction off).
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from flexarm_ros.ensemble.metrics import evaluate, resolve_metrics  # noqa: E402
from flexarm_ros.scene import Bearing, HighSpot, load_scene  # noqa: E402
from flexarm_ros.sim.simulate import simulate  # noqa: E402

DRIVE_HZ = 0.667                 # Case 3's square waves (seed 000 lines 3964-3968)
DELAYS = (0.065, 0.07, 0.075)    # s: "0.07 seconds" read to its last digit
IMPACT_EXPERIMENT = 2.10         # s: Case 1's impact "near 2.1 s"
CASE1_DURATION = 2.6             # s: past the impact
CASE2_DURATION = 3.5             # s: the calibration's window (tools/calibrate_seed000.py)
CASE3_DURATION = 15.0            # s: ten periods of the drive
SPOT = dict(offset=0.012, radius=0.01, friction=0.02)   # the illustrative high spot


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


def impact_time(scene) -> float:
    res = simulate(scene, CASE1_DURATION)
    return evaluate(res, resolve_metrics(["impact_time"], scene))["impact_time_s"]


def study_case1() -> dict:
    out = {}
    for name in ("two_link_case1", "two_link_case1_geometry"):
        base = load_scene(name)
        t0 = impact_time(base)
        mus = {d: brentq(lambda m: impact_time(with_bearings(base, m)) - t0 - d, 0.0, 0.02,
                         xtol=1e-6) for d in DELAYS}
        out[name] = {"t0": t0, "mu": mus}
        print(f"| `{name}` | {t0:.3f} s | " + " | ".join(
            f"{mus[d]:.5f}" for d in DELAYS) + " |", flush=True)
    base = load_scene("two_link_case1")
    early = IMPACT_EXPERIMENT - DELAYS[1]
    f = brentq(lambda k: impact_time(scale_resistance(base, k)) - early, 0.8, 1.0, xtol=1e-5)
    arm = scale_resistance(base, f)
    mu = brentq(lambda m: impact_time(with_bearings(arm, m)) - IMPACT_EXPERIMENT, 0.0,
                0.02, xtol=1e-6)
    out["reconciled"] = {"factor": f, "mu": mu}
    print(f"\nreconciled: resistance × {f:.4f} (friction-free impact {early:.2f} s), "
          f"μ = {mu:.5f} (impact {IMPACT_EXPERIMENT:.2f} s)\n", flush=True)
    mu1 = out["two_link_case1"]["mu"][DELAYS[1]]
    metrics = ["impact_time", "bounce_height", "frequency:acc_A_true",
               "frequency:acc_C_true"]
    print("| Case 1 arm | impact (s) | bounce within 0.2 s (mm) | f_A (Hz) | f_C (Hz) |\n"
          "|---|---|---|---|---|")
    for label, sc in (("shipped, friction off", base),
                      (f"shipped, μ = {mu1:.5f}", with_bearings(base, mu1)),
                      (f"reconciled, μ = {mu:.5f}", with_bearings(arm, mu))):
        m = evaluate(simulate(sc, CASE2_DURATION), resolve_metrics(metrics, sc))
        print(f"| {label} | {m['impact_time_s']:.3f} | {1e3 * m['bounce_height_m']:.1f} | "
              f"{m['frequency_acc_A_true_hz']:.2f} | {m['frequency_acc_C_true_hz']:.2f} |",
              flush=True)
    return out


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
    res = simulate(scene, duration)
    c = res.columns
    t = c["t"]
    return {nm: cycle_stats(t, np.degrees(c[f"{lk.name}_joint"]))
            for nm, lk in zip(("q1", "q2"), scene.links)}


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


def study_case3(mu: float) -> dict:
    base = load_scene("two_link_case3_backlash")
    runs = {"off": base, f"uniform μ = {mu:.4f}": with_bearings(base, mu),
            f"μ = {mu:.4f} + a high spot": with_bearings(base, mu,
                                                         spots=spot_centres(base))}
    out = {}
    print("| friction | angle | amplitude (deg) | frequency (Hz) | centre drift (deg/s ± 1σ)"
          " | centre moved, first to last cycle (deg) |\n|---|---|---|---|---|---|")
    for label, sc in runs.items():
        r = case3_run(sc)
        out[label] = r
        for q in ("q1", "q2"):
            s = r[q]
            print(f"| {label} | {q} | {s['amplitude']:.3f} | {s['frequency']:.3f} | "
                  f"{s['drift']:+.4f} ± {s['drift_se']:.4f} | {s['shift']:+.3f} |",
                  flush=True)
    return out


def study_case3_amplitudes(mus=(0.0, 0.002, 0.0045, 0.01, 0.02, 0.05)) -> dict:
    """Case 3's amplitudes under a uniform μ: the source's "very close" amplitudes (its
    friction-free simulation against the experiment) bound μ from above."""
    base = load_scene("two_link_case3_backlash")
    out = {}
    print("| uniform μ | q1 amplitude (deg) | q2 amplitude (deg) | q1 / friction-free | "
          "q2 / friction-free |\n|---|---|---|---|---|")
    for mu in mus:
        r = case3_run(with_bearings(base, mu) if mu else base)
        out[mu] = (r["q1"]["amplitude"], r["q2"]["amplitude"])
        a0 = out[mus[0]]
        print(f"| {mu:g} | {out[mu][0]:.3f} | {out[mu][1]:.3f} | {out[mu][0] / a0[0]:.3f} | "
              f"{out[mu][1] / a0[1]:.3f} |", flush=True)
    return out


def what_it_would_take() -> None:
    """Cases 1 and 2 ring at frequencies that move together with the arm's inertia and
    stiffness: RB4's inertia ×1.5 or both beams' EI ×0.8, friction off."""
    metrics = ["impact_time", "frequency:acc_A_true", "frequency:acc_C_true"]
    print("| change (friction off) | Case 1 f_A / f_C (Hz) | Case 2 f_A / f_C (Hz) |\n"
          "|---|---|---|")
    for label, edit in (("none", lambda l0, l1: (l0, l1)),
                        ("RB4 inertia × 1.5", lambda l0, l1: (l0, dataclasses.replace(
                            l1, tip=dataclasses.replace(l1.tip, inertia=1.5 * l1.tip.inertia)))),
                        ("beams' EI × 0.8", lambda l0, l1: tuple(dataclasses.replace(
                            lk, beam=dataclasses.replace(lk.beam, EI=0.8 * lk.beam.EI))
                            for lk in (l0, l1)))):
        row = []
        for name in ("two_link_case1", "two_link_case2"):
            sc = load_scene(name)
            sc = dataclasses.replace(sc, links=tuple(edit(*sc.links)))
            m = evaluate(simulate(sc, CASE2_DURATION), resolve_metrics(metrics, sc))
            row.append(f"{m['frequency_acc_A_true_hz']:.2f} / {m['frequency_acc_C_true_hz']:.2f}")
        print(f"| {label} | {row[0]} | {row[1]} |", flush=True)


def case2_sensitivity(mu: float) -> None:
    """What sets Case 2's ringing under friction: the regularization speed v_s (0.1-10
    mm/s), and a slower approach without friction (both resistances × 1.1, × 1.2)."""
    metrics = ["impact_time", "frequency:acc_A_true", "frequency:acc_C_true"]
    print("| Case 2 run | impact (s) | f_A (Hz) | f_C (Hz) |\n|---|---|---|---|")
    base = load_scene("two_link_case2")
    runs = []
    for vs in (1e-4, 1e-3, 1e-2):
        sc = with_bearings(base, mu)
        runs.append((f"μ = {mu:.4f}, v_s = {vs * 1e3:g} mm/s", dataclasses.replace(
            sc, bearings=tuple(dataclasses.replace(b, slip_velocity=vs)
                               for b in sc.bearings))))
    runs += [(f"friction off, resistances × {f:g}", scale_resistance(base, f))
             for f in (1.0, 1.1, 1.2)]
    for label, sc in runs:
        m = evaluate(simulate(sc, CASE2_DURATION), resolve_metrics(metrics, sc))
        print(f"| {label} | {m['impact_time_s']:.3f} | {m['frequency_acc_A_true_hz']:.2f} | "
              f"{m['frequency_acc_C_true_hz']:.2f} |", flush=True)


def study_case2(mu: float, factor: float = 1.0) -> dict:
    base = scale_resistance(load_scene("two_link_case2"), factor)
    metrics = ["impact_time", "frequency:acc_A_true", "frequency:acc_C_true"]
    out = {}
    print("| friction | binding b (1/m) | impact (s) | f_A (Hz) | f_C (Hz) | f_A vs 9.31–9.71 |"
          " f_C vs 9.31–9.71 |\n|---|---|---|---|---|---|---|")
    for label, sc in (("off", base), (f"μ = {mu:.4f}", with_bearings(base, mu)),
                      (f"μ = {mu:.4f}", with_bearings(base, mu, binding=1.0)),
                      (f"μ = {mu:.4f}", with_bearings(base, mu, binding=10.0))):
        m = evaluate(simulate(sc, CASE2_DURATION), resolve_metrics(metrics, sc))
        b = sc.bearings[0].binding if sc.bearings else 0.0
        fa, fc = m["frequency_acc_A_true_hz"], m["frequency_acc_C_true_hz"]
        out[(label, b)] = m
        print(f"| {label} | {b:g} | {m['impact_time_s']:.3f} | {fa:.2f} | {fc:.2f} | "
              f"{_versus(fa)} | {_versus(fc)} |", flush=True)
    return out


def _versus(f) -> str:
    lo, hi = 9.31, 9.71
    if not math.isfinite(f):
        return "no peak"
    off = 0.0 if lo <= f <= hi else (f - hi) / hi if f > hi else (f - lo) / lo
    return f"{off * 100:+.1f} % {'hit' if abs(off) <= 0.15 else 'miss'}"


def main(argv):
    which = argv[1:] or ["case1", "case3", "case2", "take"]
    mu, factor, mu_rec = 0.00446, 1.0, 0.0050
    if "case1" in which:
        print("| arm | impact without friction | μ for 0.065 s | 0.07 s | 0.075 s |\n"
              "|---|---|---|---|---|")
        c1 = study_case1()
        mu = c1["two_link_case1"]["mu"][0.07]
        factor = c1["reconciled"]["factor"]
        mu_rec = c1["reconciled"]["mu"]
    if "case3" in which:
        print()
        study_case3(mu)
        print()
        study_case3_amplitudes()
    if "case2" in which:
        print()
        study_case2(mu)
        if factor != 1.0:
            print(f"\nreconciled arm (resistance × {factor:.4f}):")
            study_case2(mu_rec, factor)
    if "take" in which:
        print()
        case2_sensitivity(mu)
        print()
        what_it_would_take()


if __name__ == "__main__":
    main(sys.argv)
