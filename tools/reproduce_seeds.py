"""Reproduce the numbers the three seed documents report, with the twin's seed scenes.

    python tools/reproduce_seeds.py            # ~1-2 min; writes docs/reproduction.md
                                               # and docs/reproduction/*.png, summary.csv

Runs every seed experiment scene at its full duration and default fidelity (as shipped in
config/), extracts the quantities the sources report (shape criteria, crossing times,
frequencies, amplitudes, backlash flats) and writes a twin-vs-source table. The metric
functions below are also used by test/test_seed_scenes.py (loaded with runpy), so the
tests pin exactly what this report measures.

Sources: seed 000 Hariharesan 1998 (two-link arm, Cases 1-3), seed 001 Esfandiar &
Daneshmand 2012 (single link: torque pulse, +-3 V motor test), seed 002 Gannon 1986
(hydraulic arm, 0 / 2.115 / 4.233 kg). See docs/physics.md §14 (the sources).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
OUT = DOCS / "reproduction"
COMMAND = "python tools/reproduce_seeds.py"

WALL_X = -0.025            # m, seed 000 wall line (n1 direction)
SQUARE_HZ = 0.667          # Hz, seed 000 Case 3 square wave
GEAR = {"K_m": 0.05, "R": 1.2, "L": 0.05, "N": 12.0, "J_e": 0.02 + 12.0 ** 2 * 8e-4}


# ------------------------------------------------------------------------ metrics
def smooth(y, dt, window):
    """Centred moving average over ``window`` seconds (odd number of samples, edges held)."""
    n = max(1, int(round(window / dt)))
    n += (n + 1) % 2
    pad = np.pad(np.asarray(y, float), n // 2, mode="edge")
    return np.convolve(pad, np.ones(n) / n, mode="valid")


def pulse_shape(t, rate, window=0.1, tol=0.02):
    """Seed 001 hub-speed shape criteria of the torque pulse (+ for 0-1 s, - for 1-2 s).

    The hub speed is smoothed over ``window`` (removes the beam vibration, 60-80 Hz with
    the joint free). Returns t_peak (time of the largest smoothed speed), w_peak,
    t_fall_end (end of the decrease: the first time after the peak at which the smoothed
    speed comes within ``tol`` x w_peak of its minimum after the peak), w_2 (speed at
    2 s), t_min (time of the smallest smoothed speed within 1.5 s after the peak: where
    a decrease that overshoots ends; meaningless for a flat tail), drift_after (max - min
    of the smoothed speed over [2.2 s, end] / w_peak) and final (mean smoothed speed over
    the last 0.5 s).
    """
    t = np.asarray(t, float)
    dt = t[1] - t[0]
    ws = smooth(rate, dt, window)
    ip = int(np.argmax(ws))
    low = float(ws[ip:].min())
    k_end = ip + int(np.argmax(ws[ip:] <= low + tol * ws[ip]))
    late = ws[t >= 2.2]
    win = np.nonzero((t >= t[ip]) & (t <= t[ip] + 1.5))[0]
    return {"t_peak": float(t[ip]), "w_peak": float(ws[ip]),
            "t_fall_end": float(t[k_end]), "t_min": float(t[win[np.argmin(ws[win])]]),
            "w_2": float(np.interp(2.0, t, ws)),
            "drift_after": float((late.max() - late.min()) / ws[ip]),
            "final": float(np.mean(ws[t >= t[-1] - 0.5]))}


def extremum_dwell(t, theta, frequency_hz=SQUARE_HZ, band=0.10):
    """Flat regions at the peaks/troughs of a joint angle driven by a square wave.

    Around every reversal k/(2f) (k >= 1, windows of half a half-period on either side) the
    extremum of the angle is found; the dwell is the length of the contiguous stretch
    around it during which the angle stays within ``band`` x the local swing (extremum
    minus the nearer window end) of the extremum. A rounded triangle wave (no backlash)
    gives a short dwell set by the drive's time constant; a flat region makes it longer.
    Returns the dwell of each reversal (s).
    """
    t = np.asarray(t, float)
    theta = np.asarray(theta, float)
    half = 0.5 / frequency_hz
    dt = t[1] - t[0]
    out = []
    for k in range(1, int(t[-1] / half + 1e-9)):
        m = np.nonzero((t >= k * half - 0.5 * half) & (t < k * half + 0.5 * half))[0]
        if len(m) < 3:
            continue
        seg = theta[m]
        up = seg.max() - max(seg[0], seg[-1])
        down = min(seg[0], seg[-1]) - seg.min()
        if up >= down:
            i0, inside = int(np.argmax(seg)), seg >= seg.max() - band * up
        else:
            i0, inside = int(np.argmin(seg)), seg <= seg.min() + band * down
        a = b = i0
        while a > 0 and inside[a - 1]:
            a -= 1
        while b < len(seg) - 1 and inside[b + 1]:
            b += 1
        out.append((b - a + 1) * dt)
    return np.array(out)


def disengaged_time(t, motor, joint, width, frequency_hz=SQUARE_HZ):
    """Per half-period of the square wave: time the gear teeth are apart (|δ| < width/2,
    δ = motor − link angle), i.e. the dead band the backlash adds (s)."""
    t = np.asarray(t, float)
    free = np.abs(np.asarray(motor) - np.asarray(joint)) < 0.5 * width * (1 - 1e-3)
    half = 0.5 / frequency_hz
    dt = t[1] - t[0]
    n = int(t[-1] / half + 1e-9)
    return np.array([np.sum(free[(t >= k * half) & (t < (k + 1) * half)]) * dt
                     for k in range(n)])


def sine_fit_frequency(t, y, f_lo, f_hi, df=0.002, trend=2):
    """Frequency of the dominant oscillation by least squares: y ≈ poly(trend) + a sin +
    b cos, scanned over [f_lo, f_hi] (resolves a few periods better than an FFT bin)."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    tc = (t - t.mean()) / max(float(np.ptp(t)), 1e-12)
    P = np.vander(tc, trend + 1)
    best = (math.inf, math.nan)
    for f in np.arange(f_lo, f_hi + df / 2, df):
        A = np.column_stack([P, np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
        res = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        r = float(res @ res)
        if r < best[0]:
            best = (r, float(f))
    return best[1]


def detrended_ptp(t, y, t0, t1, window):
    """Peak-to-peak of y − (its moving average over ``window``) on [t0, t1]: the
    oscillation about the slowly moving mean."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    osc = y - smooth(y, t[1] - t[0], window)
    m = (t >= t0) & (t <= t1)
    return float(osc[m].max() - osc[m].min())


def motor_closed_form(t, volts_of_t, J, K=GEAR["K_m"], R=GEAR["R"], L=GEAR["L"],
                      N=GEAR["N"], breaks=(2.0,)):
    """Seed 001 Eq. 39 for a rigid load J: x = [θ, ω, i], ẋ = A x + B V (piecewise
    constant V), exact by the matrix exponential. Returns ω(t), i(t)."""
    t = np.asarray(t, float)
    Ab = np.zeros((4, 4))                   # augmented [x; 1]: the constant V as a state
    Ab[:3, :3] = [[0.0, 1.0, 0.0], [0.0, 0.0, N * K / J], [0.0, -K * N / L, -R / L]]
    xa = np.array([0.0, 0.0, 0.0, 1.0])
    out = np.zeros((len(t), 3))
    edges = [0.0] + [b for b in breaks if b < t[-1]] + [t[-1] + 1.0]
    for a, b in zip(edges[:-1], edges[1:]):
        Ab[2, 3] = volts_of_t(0.5 * (a + b)) / L
        ks = np.nonzero((t >= a) & (t < b))[0]
        if len(ks):                       # uniform samples: one step matrix per segment
            x = scipy.linalg.expm(Ab * (t[ks[0]] - a)) @ xa
            step = scipy.linalg.expm(Ab * (t[1] - t[0])) if len(ks) > 1 else None
            for n, k in enumerate(ks):
                if n:
                    x = scipy.linalg.expm(Ab * (t[k] - t[ks[n - 1]])) @ x if not np.isclose(
                        t[k] - t[ks[n - 1]], t[1] - t[0], rtol=1e-9, atol=0.0) else step @ x
                out[k] = x[:3]
        xa = scipy.linalg.expm(Ab * (b - a)) @ xa
    return out[:, 1], out[:, 2]


# ------------------------------------------------------------------------ helpers
def _load(name):
    from flexarm_ros.scene import load_scene
    return load_scene(name)


def _run(scene, duration=None):
    from flexarm_ros.sim.simulate import simulate
    return simulate(scene, duration=duration)


def _no_sensors(scene):
    return dataclasses.replace(scene, sensors=())


def with_backlash_width(scene, width):
    """The scene with every joint's backlash width replaced (sensors dropped)."""
    links = []
    for lk in scene.links:
        bl = lk.joint.backlash
        if bl is not None:
            lk = dataclasses.replace(lk, joint=dataclasses.replace(
                lk.joint, backlash=dataclasses.replace(bl, width=width)))
        links.append(lk)
    return dataclasses.replace(scene, links=tuple(links), sensors=())


def motor_only(scene):
    """The link_motor scene with the link reduced to a light rigid stub: the seed's Fig. 8
    motor with its load shaft J alone (the light-beam rig of test/test_drives.py)."""
    from flexarm_ros.scene import Beam, RigidBody
    lk = scene.links[0]
    lk = dataclasses.replace(lk, beam=Beam(length=1.0, EI=1e-3, mass_per_length=1e-9),
                             hub=RigidBody())
    return dataclasses.replace(scene, links=(lk,), sensors=()).with_fidelity(rung="rigid")


def _fmt(x, nd=3):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    if isinstance(x, (int, np.integer)):
        return str(x)
    return f"{x:.{nd}f}"


class Report:
    """Markdown sections plus a long-format CSV (seed, table, row, column, value)."""

    def __init__(self):
        self.md: list[str] = []
        self.rows: list[tuple] = []
        self.title = ""

    def table(self, seed, header, rows):
        self.md.append("| " + " | ".join(header) + " |")
        self.md.append("|" + "---|" * len(header))
        for r in rows:
            self.md.append("| " + " | ".join(str(c) for c in r) + " |")
            for h, v in zip(header[1:], r[1:]):
                self.rows.append((seed, self.title, str(r[0]).strip("`"), h, str(v)))
        self.md.append("")

    def heading(self, line, image=None):
        self.title = line.lstrip("# ")
        self.md += [line, ""]
        if image:
            self.md += [f"![{self.title}](reproduction/{image})", ""]

    def text(self, *paragraphs):
        for p in paragraphs:
            self.md += [p, ""]


# ------------------------------------------------------------------------ seed 001
def seed001(rep: Report, plt):
    rep.heading("## Seed 001 — Esfandiar & Daneshmand (2012), single flexible link")
    rep.text("Scenes `link`, `link_tipmass`, `link_flexjoint_notip`, `link_flexjoint` (ideal "
             "±0.55 N·m torque pulse on the joint / motor side; fd rung, 10 segments) and "
             "`link_motor` (geared DC motor, ±3 V). Hub speed = link-side joint rate "
             "(`link1_joint_rate`; with joint flexibility the hub angle is θ + α, Eq. 32), "
             "smoothed over 0.1 s to remove the beam vibration.")
    cases = [("link", "rigid", 0.0), ("link_tipmass", "rigid", 0.5),
             ("link_flexjoint_notip", "flexible", 0.0), ("link_flexjoint", "flexible", 0.5)]
    fig, ax = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    rows = []
    for name, joint, mt in cases:
        res = _run(_load(name).with_fidelity(rung="fd", refine=10))   # the seed's own model
        c = res.columns
        s = pulse_shape(c["t"], c["link1_joint_rate"])
        if joint == "rigid":
            src = "rises to 1 s, falls to 2 s, constant after"
            ok = (abs(s["t_peak"] - 1.0) <= 0.02 and abs(s["t_fall_end"] - 2.0) <= 0.05
                  and s["drift_after"] <= 0.05)
        else:
            src = "peak after 1 s, decrease until ≈ 2.3 s"
            ok = s["t_peak"] > 1.02 and 2.15 <= s["t_min"] <= 2.45
        rows.append((f"`{name}`", joint, mt, _fmt(s["t_peak"]), _fmt(s["t_fall_end"]),
                     _fmt(s["t_min"]) if joint == "flexible" else "(flat tail)",
                     _fmt(s["w_peak"]), f"{s['w_2']:.3f} / {s['final']:.3f}",
                     _fmt(s["drift_after"]), src, "yes" if ok else "**no**"))
        a = ax[0] if joint == "rigid" else ax[1]
        a.plot(c["t"], c["link1_joint_rate"], lw=0.6, alpha=0.35)
        a.plot(c["t"], smooth(c["link1_joint_rate"], c["t"][1] - c["t"][0], 0.1),
               lw=1.6, label=f"{name} (tip {mt} kg)", color=a.lines[-1].get_color())
    for a, title in zip(ax, ("rigid joint", "flexible joint (k = 5 N·m/rad)")):
        for x in (1.0, 2.0):
            a.axvline(x, color="k", lw=0.5, ls=":")
        a.set_ylabel("hub speed (rad/s)")
        a.set_title(f"seed 001 torque pulse, {title}: raw (thin) and 0.1 s mean (thick)")
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    ax[1].axvline(2.3, color="r", lw=0.5, ls="--")
    ax[1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(OUT / "seed001_torque_pulse.png", dpi=110)
    plt.close(fig)
    rep.heading("### Torque pulse: hub-speed shape", "seed001_torque_pulse.png")
    rep.table("001", ["scene", "joint", "tip kg", "t_peak s", "t_fall_end s", "t_min s",
                      "w_peak rad/s", "w(2 s) / final rad/s", "drift after 2.2 s / w_peak",
                      "source (Sec. 5.1)",
                      "criterion met"], rows)
    rep.text("t_peak: time of the largest smoothed hub speed; t_fall_end: first time after "
             "the peak at which the smoothed speed is within 2 % of the peak of its minimum "
             "after the peak (the end of the decrease); t_min: time of the smallest smoothed "
             "speed within 1.5 s after the peak (where an overshooting decrease ends). "
             "Criteria: rigid joint |t_peak − 1| ≤ 0.02 s, |t_fall_end − 2| ≤ 0.05 s, drift "
             "≤ 5 % of the peak; flexible joint t_peak > 1.02 s and t_min in [2.15, 2.45] s. "
             "The joint stiffness 5 N·m/rad is an assumption calibrated on this behaviour "
             "(`link_flexjoint`); with the same joint and no tip mass the decrease ends "
             "later and the speed overshoots more.")

    # --- ±3 V motor test
    scene = _load("link_motor").with_fidelity(rung="fd", refine=10)   # the seed's own
    res = _run(scene)
    c = res.columns
    t = c["t"]
    volts = lambda tt: 3.0 if tt < 2.0 else -3.0            # noqa: E731
    J_link = float(Chain_inertia(scene))
    w_cf_link, i_cf_link = motor_closed_form(t, volts, GEAR["J_e"] + J_link)
    mo = _run(motor_only(scene))
    w_mo, i_mo = mo.columns["link1_joint_rate"], mo.columns["link1_current"]
    w_cf, i_cf = motor_closed_form(mo.columns["t"], volts, GEAR["J_e"] + 1e-9 / 3.0)
    err_mo = max(np.max(np.abs(w_mo - w_cf)) / np.max(np.abs(w_cf)),
                 np.max(np.abs(i_mo - i_cf)) / np.max(np.abs(i_cf)))
    err_link = np.max(np.abs(c["link1_joint_rate"] - w_cf_link)) / np.max(np.abs(w_cf_link))
    k2 = int(np.searchsorted(t, 2.0))
    zero = None
    from flexarm_ros.analysis.metrics import event_time
    zero = event_time(t[k2:], c["link1_joint_rate"][k2:], 0.0, direction=-1)
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax[0].plot(t, c["link1_joint_rate"], label="twin, motor + flexible link (link_motor)")
    ax[0].plot(t, w_cf_link, "--", label="Eq. 39 closed form, J_e + rigid link inertia")
    ax[0].plot(mo.columns["t"], w_mo, label="twin, motor alone (Fig. 8 rig)")
    ax[0].plot(mo.columns["t"], w_cf, ":", label="Eq. 39 closed form, J_e only")
    ax[0].set_ylabel("hub speed ω (rad/s)")
    ax[1].plot(t, c["link1_current"], label="twin, motor + link")
    ax[1].plot(mo.columns["t"], i_mo, label="twin, motor alone")
    ax[1].plot(mo.columns["t"], i_cf, ":", label="Eq. 39, motor alone")
    ax[1].set_ylabel("armature current i (A)")
    ax[1].set_xlabel("t (s)")
    for a in ax:
        a.axvline(2.0, color="k", lw=0.5, ls=":")
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[0].set_title("seed 001 DC motor test: +3 V for 0-2 s, -3 V for 2-4 s")
    fig.tight_layout()
    fig.savefig(OUT / "seed001_motor.png", dpi=110)
    plt.close(fig)

    def at(tt, col, cols=c):
        return float(np.interp(tt, cols["t"], cols[col]))
    rep.heading("### ±3 V motor test", "seed001_motor.png")
    rep.text("Source: Fig. 8 plots the response of Eq. 39 (motor with its load J, T_L = 0); "
             "no numbers are printed. The twin's motor-alone rig (link reduced to a light "
             "rigid stub) is compared with the exact solution of Eq. 39 (matrix "
             "exponential), and `link_motor` (the same motor driving the flexible link) "
             "with Eq. 39 for J_e plus the link's rigid inertia about the joint "
             f"({J_link:.4f} kg·m²).")
    mo_c = mo.columns
    rep.table("001", ["quantity", "twin", "Eq. 39 / expected", "note"], [
        ("motor alone: max relative deviation from Eq. 39 (ω and i)", f"{err_mo:.2e}", "0",
         "checks the drive model against the seed's equations"),
        ("motor alone: ω at 2 s (rad/s)", _fmt(at(2.0, "link1_joint_rate", mo_c)),
         _fmt(float(np.interp(2.0, mo_c["t"], w_cf))),
         "no-load speed V/(K_m N) = 5 rad/s, τ_m = J_e R/(N K_m)² = 0.45 s"),
        ("motor alone: peak current (A)", _fmt(float(np.max(i_mo))),
         _fmt(float(np.max(i_cf))), "below V/R = 2.5 A (back-EMF builds during L/R = 42 ms)"),
        ("motor alone: current just after the reversal (A, min)",
         _fmt(float(np.min(i_mo))), _fmt(float(np.min(i_cf))),
         "(−3 − K_m N ω)/R at most"),
        ("with link: ω at 2 s (rad/s)", _fmt(at(2.0, "link1_joint_rate")),
         _fmt(float(np.interp(2.0, t, w_cf_link))), "rigid-link closed form"),
        ("with link: ω at 4 s (rad/s)", _fmt(at(4.0, "link1_joint_rate")),
         _fmt(float(w_cf_link[-1])), ""),
        ("with link: current at 2 s− / min after 2 s (A)",
         f"{at(1.999, 'link1_current'):.3f} / {float(np.min(c['link1_current'][k2:])):.3f}",
         f"{float(np.interp(1.999, t, i_cf_link)):.3f} / "
         f"{float(np.min(i_cf_link[k2:])):.3f}", "current reverses with the voltage"),
        ("with link: speed zero crossing after 2 s (s)", _fmt(zero),
         _fmt(event_time(t[k2:], w_cf_link[k2:], 0.0, direction=-1)), ""),
        ("with link: max relative deviation of ω from the rigid closed form",
         f"{err_link:.2e}", "small", "link flexibility (EI = 2000 N·m²) barely matters"),
    ])


def Chain_inertia(scene):
    """Rigid inertia of the link about the joint (hub + beam + tip), kg·m²."""
    lk = scene.links[0]
    b = lk.beam
    r0, r1 = b.hub_radius, b.hub_radius + b.length
    beam = b.mass_per_length * (r1 ** 3 - r0 ** 3) / 3.0
    tip = lk.tip.mass * (r1 + lk.tip.cg[0]) ** 2 + lk.tip.inertia
    return lk.hub.inertia + beam + tip


# ------------------------------------------------------------------------ seed 002
def seed002(rep: Report, plt):
    from flexarm_ros.analysis.spectra import dominant_frequency
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.linear import natural_modes
    from flexarm_ros.model.statics import initial_state
    rep.heading("## Seed 002 — Gannon (1986), hydraulic flexible arm in a vertical plane")
    rep.text("Scenes `hydraulic_0kg`, `hydraulic_2kg`, `hydraulic_4kg`: servovalve + rotary "
             "actuator with the Appendix B program constants, 4.0 mA step at t = 0.1 s from "
             "the static deflection (modal rung, 2 tip-loaded modes). Gannon prints no "
             "absolute frequencies or amplitudes, only relative errors of his models against "
             "his experiment (Tables 4.2-4.5, pass mark ±10 %); the twin's absolute values "
             "are listed for the record, with the source's error figures beside them.")
    loads = [("hydraulic_0kg", 0.0), ("hydraulic_2kg", 2.115), ("hydraulic_4kg", 4.233)]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    rows, rows_s = [], []
    L = 0.9985
    for (name, m), cm in zip(loads, ("C0", "C1", "C2")):
        scene = _load(name)
        chain = Chain(scene)
        q0 = initial_state(chain)[0]
        modes = natural_modes(chain, q0, "locked").frequencies_hz
        f_lin = math.nan
        try:
            from flexarm_ros.model.statespace import linearize
            ev = np.linalg.eigvals(linearize(Chain(scene)).A)
            osc = np.sort(np.abs(ev.imag[ev.imag > 1e-6])) / (2 * np.pi)
            f_lin = float(osc[0]) if len(osc) else math.nan
        except Exception as exc:  # the state-space module is new; report, don't fail
            print(f"  linearize({name}) unavailable: {exc}", file=sys.stderr)
        res = _run(scene)
        c = res.columns
        t = c["t"]
        tab = next(iter(res.sensor_tables.values()))
        ts = tab["t"]
        pre = t < 0.1
        rest = float(np.max(np.abs(c["arm_joint"][pre] - c["arm_joint"][0])))
        post = t >= 0.3
        f_fit = sine_fit_frequency(t[post], c["arm_tip_deflection"][post], 0.5, 4.0)
        sp = ts >= 0.3
        pk = dominant_frequency(ts[sp], tab["acc_tip_true"][sp], f_min=0.4, f_max=6.0)
        tip_ptp = detrended_ptp(t, c["arm_tip_deflection"], 0.1, 2.5, 1.0 / f_fit)
        eps0 = float(tab["strain_mid_true"][0])
        lk = scene.links[0]
        g = 9.8066
        x = 0.5 * lk.beam.length
        M_mid = (lk.beam.mass_per_length * g * x ** 2 / 2
                 + lk.tip.mass * g * (x + lk.tip.cg[0]))
        eps_el = -0.5 * lk.beam.thickness * M_mid / lk.beam.EI
        strain_ptp = detrended_ptp(ts, tab["strain_mid_true"], 0.1, 2.5, 1.0 / f_fit)
        rows.append((f"`{name}`", m, _fmt(modes[0]), _fmt(modes[1], 2), _fmt(f_lin),
                     _fmt(f_fit), f"{pk.frequency_hz:.2f} ± {pk.bound_hz:.2f}",
                     "< 5 % (cubic and modal, Table 4.3)", f"{rest:.1e}"))
        rows_s.append((f"`{name}`", m, f"{eps0 * 1e6:.1f}", f"{eps_el * 1e6:.1f}",
                       f"{strain_ptp * 1e6:.0f}", f"{tip_ptp * 1e3:.1f}",
                       f"{tip_ptp / L * 100:.2f}",
                       f"({c['tip_x'][0]:.3f}, {c['tip_y'][0]:.3f}) → "
                       f"({np.interp(1.1, t, c['tip_x']):.3f}, "
                       f"{np.interp(1.1, t, c['tip_y']):.3f}) → "
                       f"({c['tip_x'][-1]:.3f}, {c['tip_y'][-1]:.3f})"))
        ax[0, 0].plot(c["tip_x"], c["tip_y"], color=cm, label=f"{m} kg")
        ax[0, 1].plot(t, c["arm_tip_deflection"] * 1e3, color=cm, label=f"{m} kg")
        ax[1, 0].plot(ts, tab["strain_mid_true"] * 1e6, color=cm, label=f"{m} kg")
        ax[1, 1].plot(ts, tab["acc_tip_true"], color=cm, label=f"{m} kg")
    for a, (xl, yl, ti) in zip(ax.flat, [
            ("tip x (m)", "tip y (m)", "tip path (x up to the vertical)"),
            ("t (s)", "tip deflection w(L) (mm)", "tip deflection (step at 0.1 s)"),
            ("t (s)", "mid-length strain (µε)", "strain gauge, 166.67 Hz"),
            ("t (s)", "tip accelerometer along the arm (m/s²)", "Endevco 7265A axis")]):
        a.set_xlabel(xl)
        a.set_ylabel(yl)
        a.set_title(ti, fontsize=10)
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    ax[0, 0].set_aspect("equal", adjustable="datalim")
    fig.suptitle("seed 002: 4.0 mA servovalve step from the static deflection")
    fig.tight_layout()
    fig.savefig(OUT / "seed002_hydraulic.png", dpi=110)
    plt.close(fig)
    rep.heading("### First-mode frequency", "seed002_hydraulic.png")
    rep.table("002", ["scene", "load kg", "f1 locked Hz", "f2 locked Hz",
                      "f1 with oil compliance Hz", "f1 fit of w(L) Hz",
                      "f1 FFT of tip accel Hz", "source", "drift before step rad"], rows)
    rep.text("f1/f2 locked: `natural_modes` (joint held) at the static deflection; with oil "
             "compliance: lowest oscillatory eigenvalue of `flexarm linearize` (drive and "
             "pressure states included, null bias); fit: least-squares sine + quadratic "
             "trend on the simulated tip deflection after the step (the frequency drifts as "
             "the arm rises: gravity's geometric stiffness changes); FFT: "
             "`analysis.spectra.dominant_frequency` of the tip accelerometer (166.67 Hz, "
             "2.2 s record: resolution 0.45 Hz, so only indicative).")
    rep.heading("### Strain and tip amplitude")
    rep.table("002", ["scene", "load kg", "mid strain at rest µε", "elementary beam µε",
                      "strain oscillation p-p µε", "tip oscillation p-p mm",
                      "p-p / L %", "tip (x, y) m: start → 1 s after step → 2.5 s"], rows_s)
    rep.text("Static strain: (T/2)·M(L/2)/EI with the distributed weight and the tip load "
             "(compression on the gauge's face: negative). The oscillation amplitudes are "
             "peak-to-peak about a moving mean over one first-mode period, from the step to "
             "2.5 s. Source: Gannon gives the model-vs-experiment errors only — tip "
             "amplitude (normalised by L) cubic 5.3 / 7.9 / 8.3 %, modal 4.9 / 6.3 / 6.3 %; "
             "strain amplitude cubic 38 / 38 / 41 %, modal 17.9 / 17.4 / 23.7 % (Tables "
             "4.2, 4.4) — so no twin-vs-experiment error can be formed without his data.")

    # the ladder against Gannon's model comparison (2.115 kg; strain runs from vertical)
    base = _load("hydraulic_2kg")
    variants = [("cubic (Petroka's model)", {"rung": "cubic"}),
                ("modal 2, clamped-free modes (Gannon's model)",
                 {"rung": "modal", "refine": 2, "modal_basis": "clamped_free"}),
                ("modal 2, tip-loaded modes (scene default)",
                 {"rung": "modal", "refine": 2, "modal_basis": "tip_loaded"}),
                ("fem 8 elements (reference)", {"rung": "fem", "refine": 8})]
    vertical = dataclasses.replace(base, links=(dataclasses.replace(
        base.links[0], joint=dataclasses.replace(base.links[0].joint,
                                                 initial_angle=math.pi / 2)),), sensors=())
    ref = None
    lad = []
    ch_ref = Chain(base.with_fidelity(**variants[-1][1]))
    f2_ref = natural_modes(ch_ref, initial_state(ch_ref)[0], "locked").frequencies_hz[1]
    for label, fid in variants:
        sc = base.with_fidelity(**fid)
        ch = Chain(sc)
        fr = natural_modes(ch, initial_state(ch)[0], "locked").frequencies_hz
        rv = _run(vertical.with_fidelity(**fid), duration=1.6)
        cv = rv.columns
        ch_v = rv.chain
        lm = ch_v.links[0]
        curv = 0.5 * lm.link.beam.thickness * lm.beam.curvature([0.5 * lm.link.beam.length])[0]
        eta = np.column_stack([cv[ch_v.names[i]] for i in np.arange(ch_v.n)[lm.eta]])
        eps = eta @ curv
        ptp = float(eps.max() - eps.min())
        dyn = detrended_ptp(cv["t"], eps, 0.1, 1.6, 1.0 / fr[0])
        hi = eps - smooth(eps, cv["t"][1] - cv["t"][0], 1.0 / f2_ref)
        hi_ptp = float(np.ptp(hi[cv["t"] >= 0.1]))
        f2s = sine_fit_frequency(cv["t"][cv["t"] >= 0.15], hi[cv["t"] >= 0.15], 6.0, 20.0,
                                 df=0.01, trend=0)
        lad.append((label, fr[0], fr[1], ptp, dyn, hi_ptp, f2s))
        if label.startswith("fem"):
            ref = lad[-1][1:]
    rows_l = []
    for label, f1, f2, ptp, dyn, hi_ptp, f2s in lad:
        rows_l.append((label, _fmt(f1), _fmt(f2, 2), f"{(f2 / ref[1] - 1) * 100:+.1f}",
                       f"{ptp * 1e6:.0f} ({(ptp / ref[2] - 1) * 100:+.1f} %)",
                       f"{dyn * 1e6:.0f} ({(dyn / ref[3] - 1) * 100:+.1f} %)",
                       f"{hi_ptp * 1e6:.1f} ({(hi_ptp / ref[4] - 1) * 100:+.0f} %)",
                       f"{f2s:.2f} ({(f2s / ref[5] - 1) * 100:+.1f} %)"))
    rep.heading("### The model ladder against Gannon's model comparison (2.115 kg)")
    rep.text("Gannon's modal model (two clamped-free modes) beat Petroka's cubic model "
             "mainly on the strain amplitude (errors 17.4 % vs 38 %) and the second-mode "
             "strain frequency (< 5 % vs 26 %). The twin's ladder shows the same ordering "
             "against its converged FEM reference: frequencies at the horizontal static "
             "deflection, drive locked; strain = peak-to-peak mid-length strain of a strain "
             "run (Sec. IV.C: starting from the vertical, 4.0 mA step, 1.5 s after it).")
    rep.table("002", ["model", "f1 Hz", "f2 Hz", "f2 vs fem %",
                      "strain p-p µε (vs fem)", "first-mode strain oscillation p-p µε",
                      "second-mode strain ripple p-p µε", "second-mode strain frequency Hz"],
              rows_l)
    rep.text("Strain p-p: whole record (quasi-static bending as the arm passes the vertical "
             "plus vibration); first-mode oscillation: p-p about a moving mean over one "
             "first-mode period; second-mode ripple: p-p of the strain minus its moving mean "
             "over one second-mode period of the reference (the content at and above the "
             "second mode), and its frequency by a sine fit.")
    rep.text("Source (Tables 4.4, 4.5, 2.115 kg): strain amplitude error cubic 38 %, modal "
             "17.4 %; second-mode strain frequency error cubic 26 %, modal < 5 % (against "
             "the experiment, not a reference model).")


# ------------------------------------------------------------------------ seed 000
def seed000(rep: Report, plt):
    from flexarm_ros.analysis.metrics import event_time
    rep.heading("## Seed 000 — Hariharesan (1998), two-link flexible arm")
    rep.text("Scenes `two_link_case1`, `two_link_case2`, `two_link_case3_backlash`: Maxon "
             "motors as quasi-static DC drives (Eq. 5.11, catalogue-like K_t, K_b, "
             "resistances calibrated on Case 1), gearbox J_eq/C_eq, cubic rung, the rigid "
             "bodies' geometry derived from the source (hub radii, CG, joint-2 and tool "
             "offsets: the scenes' assumptions). The tool strikes the wall (impulse–"
             "constraint contact); the post-impact quantities (bounce ≈ 5 mm, frequencies "
             "10.96 / 10.94 / 10.56 Hz at A/B/C in Case 1, 9.31-9.71 Hz in Case 2) are in "
             "docs/reproduction_contact.md.")
    rows = []
    fig, ax = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for name, note in (("two_link_case1", "≈ 2.1 s (experiment; the author's simulation "
                                          "differs by 0.07 s)"),
                       ("two_link_case2", "not reported (motion along the wall)")):
        scene = _load(name)
        res = _run(scene)
        c = res.columns
        t = c["t"]
        # the tool point (on RB4, beyond the beam tip) reaching the wall line: the first
        # impact event (located by root finding on the step)
        tc = res.contact.impacts[0].time if res.contact.impacts else None
        rr = _run(_no_sensors(scene).with_fidelity(rung="rigid"))
        tr = rr.contact.impacts[0].time if rr.contact.impacts else None
        q1 = math.degrees(np.interp(tc, t, c["link1_joint"])) if tc else math.nan
        q2 = math.degrees(np.interp(tc, t, c["link2_joint"])) if tc else math.nan
        # the approach speed: the last sample before the strike
        vx = float(c["tool_vx"][np.searchsorted(t, tc) - 1]) if tc else math.nan
        rows.append((f"`{name}`", _fmt(tc), _fmt(tr), note, _fmt(q1, 1), _fmt(q2, 1),
                     _fmt(vx)))
        if name == "two_link_case1":
            ax[0].plot(t, c["tool_x"], label="tool x, cubic")
            ax[0].plot(t, c["tip_x"], lw=0.8, label="beam-2 tip x (RB4's leading edge)")
            ax[0].axhline(WALL_X, color="k", ls="--", lw=0.8, label="wall line x = −25 mm")
            if tc:
                ax[0].axvline(tc, color="r", lw=0.6)
            ax[0].axvline(2.1, color="g", lw=0.6, ls=":", label="reported impact ≈ 2.1 s")
            ax[0].set_ylabel("x (m)")
            ax[0].legend(fontsize=8)
            ax[1].plot(t, np.degrees(c["link1_joint"]), label="q1")
            ax[1].plot(t, np.degrees(c["link2_joint"]), label="joint 2 angle")
            ax[1].set_ylabel("angle (deg)")
            ax[1].legend(fontsize=8)
            tab = res.sensor_tables[4000.0]
            for k in "ABCD":
                ax[2].plot(tab["t"], tab[f"acc_{k}_true"], lw=0.7, label=f"{k}")
            ax[2].set_ylabel("transverse accel. A-D (m/s²)")
            ax[2].set_xlabel("t (s)")
            ax[2].legend(fontsize=8, ncol=4)
            enc = res.sensor_tables[1000.0]
            enc_at = (int(np.interp(tc, enc["t"], enc["enc1"])),
                      int(np.interp(tc, enc["t"], enc["enc2"])))
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].set_title("seed 000 Case 1: 1.5 V on both motors, to the wall and after")
    fig.tight_layout()
    fig.savefig(OUT / "seed000_case1.png", dpi=110)
    plt.close(fig)
    rep.heading("### Time the tool reaches the wall line x = −0.025 m", "seed000_case1.png")
    rep.table("000", ["scene", "twin cubic s", "twin rigid rung s", "source",
                      "q1 at crossing deg", "joint 2 at crossing deg",
                      "tool ẋ at crossing m/s"], rows)
    rep.text(f"Case 1 is the calibration target (motor resistances scaled by one factor), "
             f"so its crossing time is matched by construction; encoder counts at the "
             f"crossing: base {enc_at[0]}, middle {enc_at[1]} (500 lines ×4 on the motor "
             f"shafts). The rigid rung (seed 000's low-fidelity model, K = 3EI/L) reaches "
             f"the line earlier — the source notes its rigid model reaches the wall at a "
             f"different time. Case 2 uses the Case 1 motors unchanged.")

    # Case 3: backlash
    scene = _load("two_link_case3_backlash")
    width = scene.links[0].joint.backlash.width
    r_bl = _run(_no_sensors(scene))
    r_0 = _run(with_backlash_width(scene, 0.0))
    cb, c0 = r_bl.columns, r_0.columns
    rows = []
    dw = {}
    for j, lab in ((1, "q1 (base joint)"), (2, "joint 2")):
        d_bl = extremum_dwell(cb["t"], cb[f"link{j}_joint"])
        d_0 = extremum_dwell(c0["t"], c0[f"link{j}_joint"])
        dw[j] = (d_0, d_bl)
        dm = extremum_dwell(cb["t"], cb[f"link{j}_motor"])
        dis = disengaged_time(cb["t"], cb[f"link{j}_motor"], cb[f"link{j}_joint"],
                              scene.links[j - 1].joint.backlash.width)
        amp = float(np.ptp(cb[f"link{j}_joint"][cb["t"] > 1.5]))
        rows.append((lab, f"{d_0.mean():.3f} / {d_0.max():.3f}",
                     f"{d_bl.mean():.3f} / {d_bl.max():.3f}",
                     " ".join(f"{v:.2f}" for v in d_bl), f"{dm.mean():.3f}",
                     f"{dis[1:].mean():.3f}", f"{math.degrees(amp):.2f}"))
    fig, ax = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for j, a in ((1, ax[0]), (2, ax[1])):
        a.plot(c0["t"], np.degrees(c0[f"link{j}_joint"]), color="0.6",
               label="no backlash (width 0)")
        a.plot(cb["t"], np.degrees(cb[f"link{j}_motor"]), "--", lw=0.8,
               label="gearbox output (motor side)")
        a.plot(cb["t"], np.degrees(cb[f"link{j}_joint"]), lw=1.4,
               label=f"link side, backlash {math.degrees(width):.2f}°")
        a.set_ylabel("q1 (deg)" if j == 1 else "joint 2 (deg)")
        a.legend(fontsize=8)
    for j in (1, 2):
        ax[2].plot(cb["t"], np.degrees(cb[f"link{j}_motor"] - cb[f"link{j}_joint"]),
                   label=f"δ{j} = motor − link")
    ax[2].axhline(math.degrees(width / 2), color="k", lw=0.5)
    ax[2].axhline(-math.degrees(width / 2), color="k", lw=0.5)
    ax[2].set_ylabel("δ (deg)")
    ax[2].set_xlabel("t (s)")
    ax[2].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
        for k in range(1, int(6.0 * 2 * SQUARE_HZ) + 1):
            a.axvline(k * 0.5 / SQUARE_HZ, color="k", lw=0.3, ls=":")
    ax[0].set_title("seed 000 Case 3: ±0.5 V square wave, 0.667 Hz, motors 180° apart")
    fig.tight_layout()
    fig.savefig(OUT / "seed000_case3_backlash.png", dpi=110)
    plt.close(fig)
    rep.heading("### Case 3: backlash flats", "seed000_case3_backlash.png")
    rep.text("Source: flat regions at the peaks and troughs of both joint angles (Fig. 5.23; "
             "durations not printed), a dead band at t = 0 in the experiment (not in the "
             "author's simulation), amplitudes and frequency of experiment and simulation "
             "\"very close\". Twin: declared width vs the same scene with width 0.")
    rep.table("000", ["angle", "dwell mean / longest, width 0 (s)",
                      f"dwell mean / longest, width {math.degrees(width):.2f}° (s)",
                      "dwell per reversal 1..7 (s)", "motor-side dwell mean (s)",
                      "teeth apart per half-period (s)", "swing p-p deg"], rows)
    d_start = {j: float(cb["t"][np.argmax(np.abs(cb[f"link{j}_joint"] - cb[f"link{j}_joint"][0])
                                           > 1e-4)]) for j in (1, 2)}
    rep.text("Dwell: time the angle stays within 10 % of its local swing of the extremum, "
             f"per reversal of the square wave (1..7). Without backlash every corner is "
             f"rounded alike ({dw[1][0].mean():.2f} s and {dw[2][0].mean():.2f} s, set by "
             f"the drive time constant). With the declared backlash, joint 2 shows flat "
             f"regions at most reversals (mean {dw[2][1].mean() / dw[2][0].mean() - 1:+.0%}, "
             f"{np.sum(dw[2][1] > 1.2 * dw[2][0].max())} of {len(dw[2][1])} reversals "
             f"more than 20 % longer than any backlash-free corner); q1 shows long flats at "
             f"{np.sum(dw[1][1] > 1.2 * dw[1][0].max())} of {len(dw[1][1])} reversals (up "
             f"to {dw[1][1].max():.2f} s, {dw[1][1].max() / dw[1][0].max():.1f}× the "
             f"backlash-free corner) but sharper corners at the others: the disengaged link side carries no gearbox "
             "loss (C_eq is on the motor side of the dead zone, see the scene's "
             "assumptions) and no air-bearing friction, so link 1 often coasts through the "
             "dead band instead of stopping, and the middle motor's reaction torque on RB2 "
             "keeps it pressed against the rear flank for long stretches (δ1 = −width/2). "
             "The source's simulation lumped J_eq/C_eq on the link angle, which makes the "
             "link stop in the dead band. The gearbox-output (motor-shaft encoder) angles "
             "stay sharp-cornered. Initial dead band (the links start to move at): q1 "
             f"{d_start[1]:.3f} s, joint 2 {d_start[2]:.3f} s (experiment: a dead band at "
             "t = 0; the author's simulation: none).")


# ------------------------------------------------------------------------ main
def main(argv=None):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    OUT.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rep = Report()
    parts = {"000": seed000, "001": seed001, "002": seed002}
    want = argv or ["001", "002", "000"]
    for k in want:
        t1 = time.perf_counter()
        parts[k](rep, plt)
        print(f"seed {k}: {time.perf_counter() - t1:.1f} s", flush=True)
    head = ["# Reproduction of the seed experiments", "",
            f"Regenerate: `{COMMAND}` (writes this file, `docs/reproduction/*.png` and "
            f"`docs/reproduction/summary.csv`; {time.perf_counter() - t0:.0f} s on the "
            f"machine that wrote it). Every scene runs at its full duration and shipped "
            f"fidelity. Checked cheaply by `test/test_seed_scenes.py`.", "",
            "Values not given by the sources are assumptions listed in each scene's "
            "`assumptions:`; the ones that drive these numbers are the calibrated motor "
            "resistances (seed 000 Case 1), the joint stiffness of the flexible-joint scenes "
            "(seed 001) and the backlash width (seed 000 Case 3).", ""]
    if not argv:
        (DOCS / "reproduction.md").write_text("\n".join(head + rep.md).rstrip() + "\n")
        with open(OUT / "summary.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["seed", "table", "row", "column", "value"])
            w.writerows(rep.rows)
    else:
        print("\n".join(rep.md))
    print(f"total {time.perf_counter() - t0:.1f} s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
