"""The contact trade (``flexarm study`` on a scene with a wall): impulse–constraint vs
compliant contact of several stiffnesses, and the beam rungs, against a converged
reference.

Reference: the scene's rung with impulse contact, RK4 at a quarter of the automatic step.
Per row: ``rung``, ``refinement``, ``contact`` (impulse or compliant), ``stiffness``
(N/m, compliant), ``step_s``, ``wall_s_per_sim_s`` (integration only, best of up to 3
runs), and against the reference: ``impact_time_error_s`` (first impact; compliant: first
penetration), ``bounce_height_m`` and ``bounce_height_error_m`` (largest gap within
``BOUNCE_WINDOW`` after the first impact), ``penetration_m`` (largest −gap),
``normal_impulse_ns`` and ``normal_impulse_error`` (relative error of the total normal
impulse the wall gives over the second half of the window: ∫F_n dt integrated with the
RK4 stage forces, plus the impact impulses of the impulse rung — a compliant contact
spreads each impact over a contact time shorter than the output step, so neither the
sampled mean force nor a sum over samples compares like with like),
``tip_rms_error_m``,
``status``.
"""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.analysis.run_metrics import first_touch
from flexarm_ros.errors import InputError, SceneError, SimulationDiverged
from flexarm_ros.twin.batch import run_scene
from flexarm_ros.ensemble.runner import run_tasks

BOUNCE_WINDOW = 0.2          # s after the first impact
STIFFNESSES = (1e4, 1e5, 1e6, 1e7)


def _metrics(res) -> dict:
    t = res.columns["t"]
    gap = res.columns["gap"]
    fn = res.columns["contact_normal_force"]
    t0 = first_touch(res)
    win = (t > t0) & (t <= t0 + BOUNCE_WINDOW) if math.isfinite(t0) else np.zeros_like(t, bool)
    P = res.columns["contact_normal_impulse"]
    k_half = int(np.searchsorted(t, 0.5 * t[-1]))
    impulse = float(P[-1] - P[k_half])
    return {"impact_time_s": t0,
            "bounce_height_m": float(gap[win].max()) if win.any() else math.nan,
            "penetration_m": float(max(0.0, -gap.min())),
            "normal_impulse_ns": impulse}


class ContactRow:
    """One row of the contact trade as a task of the ensemble runner (picklable: the base
    scene, the window, the reference's tip columns and metrics): ``__call__(item) → row``
    for ``item`` = dict(rung, refine, contact[, stiffness]); a refused or diverging run is
    a row with its message as ``status``."""

    def __init__(self, base, T, ref_tip: dict, m_ref: dict, repeats: int):
        self.base, self.T, self.ref_tip, self.m_ref, self.repeats = (base, T, ref_tip,
                                                                     m_ref, repeats)

    def __call__(self, it: dict) -> dict:
        import dataclasses
        T, m_ref = self.T, self.m_ref
        sc = self.base.with_fidelity(rung=it["rung"], refine=it["refine"],
                                     contact=it["contact"], dt=0.0)
        if it["contact"] == "compliant":
            w = dataclasses.replace(sc.walls[0], stiffness=it["stiffness"])
            sc = dataclasses.replace(sc, walls=(w,))
        row = {"rung": it["rung"], "refinement": it["refine"], "contact": it["contact"],
               "stiffness": it.get("stiffness")}
        try:
            best = math.inf
            for _ in range(self.repeats):
                res = run_scene(sc, T)
                best = min(best, res.run.wall_time_s)
                if best * 3 > 60:
                    break
            m = _metrics(res)
            tip = np.hypot(res.columns["tip_x"] - self.ref_tip["tip_x"],
                           res.columns["tip_y"] - self.ref_tip["tip_y"])
            row.update(
                status="ok", step_s=res.run.dt, wall_s_per_sim_s=best / T,
                impact_time_s=m["impact_time_s"],
                impact_time_error_s=abs(m["impact_time_s"] - m_ref["impact_time_s"]),
                bounce_height_m=m["bounce_height_m"],
                bounce_height_error_m=abs(m["bounce_height_m"] - m_ref["bounce_height_m"]),
                penetration_m=m["penetration_m"],
                normal_impulse_ns=m["normal_impulse_ns"],
                normal_impulse_error=(abs(m["normal_impulse_ns"] - m_ref["normal_impulse_ns"])
                                      / max(abs(m_ref["normal_impulse_ns"]), 1e-12)),
                tip_rms_error_m=float(np.sqrt(np.mean(tip ** 2))))
        except (SimulationDiverged, InputError) as exc:
            row.update(status=str(exc))
        return row


def run_contact_study(scene, duration=None, quick=False, progress=None,
                      executor=None) -> list[dict]:
    """Rows of the contact trade for ``scene`` (which must have a wall). The rows are
    tasks of the ensemble runner (:class:`ContactRow`,
    :func:`flexarm_ros.ensemble.runner.run_tasks`): by default one after the other in this
    process (each row times itself alone); ``executor`` may be a Dask executor, as for the
    ladder (:func:`flexarm_ros.studies.ladder.run_study`)."""
    if not scene.walls:
        raise SceneError("study: the contact trade needs a scene with a wall")
    T = duration or scene.duration
    base = scene.with_fidelity(integrator="rk4", contact="impulse")
    probe = run_scene(base, min(T, 0.01) if base.control is None else
                      max(min(T, 0.01), 2.0 / base.twin_control.rate_hz))
    h_auto = probe.run.dt
    ref_scene = base.with_fidelity(dt=h_auto / 4)
    if progress:
        progress(f"reference: {scene.fidelity.rung}, impulse, dt {h_auto / 4:.3g} s")
    ref = run_scene(ref_scene, T)
    m_ref = _metrics(ref)
    specs = [dict(contact="impulse")]
    specs += [dict(contact="compliant", stiffness=k)
              for k in (STIFFNESSES[1:3] if quick else STIFFNESSES)]
    rungs = [(scene.fidelity.rung, scene.fidelity.refine)]
    if not quick:
        rungs += [r for r in (("rigid", 0), ("modal", 2)) if r[0] != scene.fidelity.rung]
    items = [dict(rung=rung, refine=refine, **sp) for rung, refine in rungs for sp in specs]
    task = ContactRow(base, T, {k: np.asarray(ref.columns[k]) for k in ("tip_x", "tip_y")},
                      m_ref, 1 if quick else 3)

    def done(k, row):
        if progress:
            progress(_line(row))
    rows = run_tasks(task, items, executor, on_result=done)
    for r in rows:
        r["reference"] = {"rung": scene.fidelity.rung, "contact": "impulse",
                          "dt": h_auto / 4, **m_ref}
    return rows


def _line(r) -> str:
    k = f"k={r['stiffness']:.0e}" if r.get("stiffness") else "impulse"
    if r.get("status") != "ok":
        return f"{r['rung']:6s} {k:9s} {r.get('status')}"
    return (f"{r['rung']:6s} {k:9s} {r['wall_s_per_sim_s']:8.3f} s/s  "
            f"impact {r['impact_time_error_s']:.2e} s  bounce {r['bounce_height_m'] * 1e3:6.2f} mm "
            f"(err {r['bounce_height_error_m'] * 1e3:6.2f})  pen {r['penetration_m'] * 1e3:7.3f} mm  "
            f"impulse {r['normal_impulse_ns']:7.4f} N·s ({100 * r['normal_impulse_error']:5.1f} %)  "
            f"tip {r['tip_rms_error_m']:.2e} m")


def format_contact_table(rows) -> str:
    ref = rows[0]["reference"] if rows else {}
    head = (f"reference: {ref.get('rung')} impulse, dt {ref.get('dt', 0):.3g} s — impact "
            f"{ref.get('impact_time_s', math.nan):.4f} s, bounce "
            f"{1e3 * ref.get('bounce_height_m', math.nan):.2f} mm, normal impulse (2nd half) "
            f"{ref.get('normal_impulse_ns', math.nan):.4f} N·s")
    return "\n".join([head] + [_line(r) for r in rows])
