"""The speed–accuracy study of the fidelity ladder (``flexarm study SCENE``).

Every row is one model (rung × refinement) integrated by one integrator over the same
window of the scene, measured in the same process, and compared with a converged
reference run of the same scene.

Reference
    Rung ``fem`` on a mesh twice as fine as the finest ``fem`` row of the ladder (16
    elements per beam; quick: 8), integrated by fixed-step RK4 at the automatic step
    (``dt = 0``), shortened if needed so that ``ω₁·h ≤ 0.05`` for its first natural
    frequency. Why not DOP853 at a tight tolerance: on a fine mesh every explicit method
    is held to a step near the stability limit ``~1.5/|λ|max`` of the highest beam mode,
    which is orders of magnitude below the period of the modes that move the tip, so
    RK4's time error of the tip path, O((ω h)⁴), is negligible next to the mesh error,
    while DOP853 at a tight tolerance costs many times more (the comparison is in
    docs/decisions/0024-the-ladder-studys-reference-is-rk4.md). The reference can be replaced
    (``reference=`` spec) and the test suite checks an RK4
    reference against a DOP853 rtol 1e-10 one.

Columns of a row
    ``rung``, ``refinement`` (modes / elements / FD segments), ``integrator``, ``rtol``,
    ``atol`` (adaptive only, else null), ``step_s`` (RK4 step used, else null),
    ``n_coordinates`` (generalized coordinates of the chain), ``duration_s`` (simulated),
    ``wall_s_per_sim_s`` (integration wall time / simulated time, from
    ``SimResult.summary()``; model build and output post-processing excluded; a run
    shorter than 0.2 s is integrated again, up to 10 runs in all, and the fastest run
    counts, as with ``timeit``: ``timing_runs`` says how many),
    ``real_time_factor`` (its inverse), ``rhs_evaluations``, ``steps``,
    ``tip_rms_error_m`` and ``tip_max_error_m`` (RMS and max over the common output
    grid of |tip(t) − tip_ref(t)|, the Euclidean distance of the last beam's tip from
    the reference's), ``first_frequency_hz`` (first natural frequency above 1e-6 Hz of
    the chain linearized at its initial state, joints ``locked`` when the scene has
    inputs, else ``free``; rigid-body 0-Hz modes skipped), ``first_frequency_error``
    (|f − f_ref| / f_ref, a fraction; the sign follows from ``first_frequency_hz`` vs
    ``reference_first_frequency_hz``), ``energy_drift``, ``status`` (``"ok"`` or the
    error of a row that failed: a failure is data, not a crash), ``pareto`` (on the
    non-dominated front of (``wall_s_per_sim_s``, ``tip_rms_error_m``) among the ``ok``
    rows; tip errors closer than 1 % or than the reference's estimated error count as
    equal, so a costlier row is not on the front for an error difference the study
    cannot resolve), ``reference`` (which run the errors are measured against) and
    ``reference_first_frequency_hz``.

Energy drift
    ``max_t |E(t) − E(0)| / max_t T(t)``: the largest change of the total energy
    (kinetic + elastic + gravity) as a fraction of the largest kinetic energy reached
    during the run. The kinetic scale is used rather than |E(0)| because the gravity
    datum makes E(0) arbitrary (an arm hanging far below its joint would hide any drift).
    Only defined for a conservative scene: no inputs (torques or prescribed motions)
    and no damping of any kind (beam, joint, drive); otherwise energy is not conserved by
    the physics and the column is null. A run in which nothing moves has drift 0.

Reference accuracy
    ``StudyRows.meta['reference_error_estimate_m']`` estimates the reference's own RMS tip
    error (Richardson: the error of the ``fem`` row on half its mesh / 15); errors near it
    are at the resolution of the study, not differences between the models.

Duration
    ``duration=None`` takes the scene's duration, capped at 1 s (quick: 0.1 s) after the
    latest start of its input programs, so the window sees the inputs act. The window is
    shortened so that the whole study fits in ``budget_s`` (default 240 s, quick 60 s):
    every RK4 run is forecast (its steps at its step times the predicted cost per step,
    with the reference at its phase-limited step), the other integrators are timed on a
    short pilot window (20 output samples), and the window is scaled to the budget,
    never below the input's start plus 5 pilot windows. Where even that window does not
    fit, the costliest rows are left out (status ``skipped: forecast ...``); a reference
    that does not fit alone is refused before anything runs, with its forecast and the
    budget it needs. An explicit ``duration`` is used as given, rows beyond the budget
    left out the same way. A window in which the reference's tip does not move is
    reported (``meta['warning']``): its table ranks nothing.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Iterable, Optional

import numpy as np

from flexarm_ros.analysis.run_metrics import energy_drift
from flexarm_ros.model.beams import DEFAULT_REFINE
from flexarm_ros.model.chain import Chain
from flexarm_ros.errors import SceneError, SimulationDiverged
from flexarm_ros.sim.integrate import integrate
from flexarm_ros.sim.step import choose_step
from flexarm_ros.model.linear import natural_modes
from flexarm_ros.model.statics import initial_state, initial_x
from flexarm_ros.twin.batch import closed_loop, open_loop_scene, run_scene
from flexarm_ros.ensemble.runner import run_tasks

#: duration cap of the study window when none is given, s
DEFAULT_DURATION_S = 1.0
QUICK_DURATION_S = 0.1
#: wall-time budget of a full default study, s (forecasts and pilot runs choose the window
#: to fit); of a quick one
DEFAULT_BUDGET_S = 240.0
QUICK_BUDGET_S = 60.0
#: each row shorter than MIN_TIMING_S is integrated again: its forecast's fixed part, s
ROW_OVERHEAD_S = 0.3
PILOT_SAMPLES = 20
#: runs shorter than this are timed again (fastest of up to MAX_TIMING_RUNS runs)
MIN_TIMING_S = 0.2
MAX_TIMING_RUNS = 10
#: the RK4 reference step keeps ω₁·h below this
REFERENCE_PHASE_STEP = 0.05
#: adaptive integrator of the ladder and its tolerances
ADAPTIVE = ("dop853", 1e-6, 1e-9)
TRAPEZOID_DT = 2.5e-4   # s, the implicit rule's step in the full ladder
#: frequencies below this are rigid-body modes (Hz)
RIGID_MODE_HZ = 1e-6
#: tip errors within this fraction (or within the reference's estimated error) are ties
PARETO_REL_TIE = 0.01
#: failures that make a row's status instead of ending the study
ROW_ERRORS = (SimulationDiverged, SceneError, np.linalg.LinAlgError)

ROW_KEYS = ("rung", "refinement", "integrator", "rtol", "atol", "step_s", "n_coordinates",
            "duration_s", "wall_s_per_sim_s", "real_time_factor", "rhs_evaluations", "steps",
            "tip_rms_error_m", "tip_max_error_m", "first_frequency_hz",
            "first_frequency_error", "energy_drift", "status", "pareto", "timing_runs",
            "reference", "reference_first_frequency_hz")


class StudyRows(list):
    """The rows of a study (a plain list for JSON) with ``meta``: the reference run."""

    def __init__(self, rows=(), meta=None):
        super().__init__(rows)
        self.meta = dict(meta or {})


# ------------------------------------------------------------------------------- ladder
def spec(rung, refine=0, integrator="rk4", rtol=None, atol=None, dt=0.0) -> dict:
    """One row of the ladder: fidelity overrides (``dt = 0``: automatic RK4 step /
    unbounded adaptive step)."""
    return {"rung": rung, "refine": int(refine or DEFAULT_REFINE[rung]),
            "integrator": integrator, "rtol": rtol, "atol": atol, "dt": float(dt)}


def default_ladder(quick: bool = False) -> list[dict]:
    """The rows of the study: rigid(1), cubic(1), modal(2,4,8), fem(2,4,8), fd(8,16,32)
    each by RK4 (automatic step) and DOP853 (rtol 1e-6, atol 1e-9), and the trapezoidal
    rule (2.5e-4 s) on modal 8, fem 4/8, fd 16/32; quick: rigid, cubic,
    modal 2, fem 2 and 4, fd 8 by RK4 only."""
    if quick:
        models = [("rigid", 1), ("cubic", 1), ("modal", 2), ("fem", 2), ("fem", 4), ("fd", 8)]
        integrators = [("rk4", None, None)]
    else:
        models = [("rigid", 1), ("cubic", 1), ("modal", 2), ("modal", 4), ("modal", 8),
                  ("fem", 2), ("fem", 4), ("fem", 8), ("fd", 8), ("fd", 16), ("fd", 32)]
        integrators = [("rk4", None, None), ADAPTIVE]
    rows = [spec(r, n, i, rt, at) for r, n in models for i, rt, at in integrators]
    if not quick:   # the implicit rule where the explicit step is expensive
        rows += [spec(r, n, "trapezoid", dt=TRAPEZOID_DT) for r, n in
                 (("modal", 8), ("fem", 4), ("fem", 8), ("fd", 16), ("fd", 32))]
    return rows


def reference_spec(ladder: Iterable[dict]) -> dict:
    """FEM on twice the finest ``fem`` mesh of the ladder (at least 8 elements), RK4."""
    finest = max([s["refine"] for s in ladder if s["rung"] == "fem"], default=4)
    return spec("fem", max(8, 2 * finest), "rk4")


def _label(s: dict) -> str:
    text = f"{s['rung']} {s['refine']} {s['integrator']}"
    if s["integrator"] != "rk4" and s.get("rtol") is not None:
        text += f" rtol {s['rtol']:g}"
    if s.get("dt"):
        text += f" dt {s['dt']:g}"
    return text


def _apply(scene, s: dict):
    over = {k: s.get(k) for k in ("rung", "refine", "integrator", "rtol", "atol", "dt")}
    return scene.with_fidelity(**over)


# ------------------------------------------------------------------------------ metrics
def _tip(res) -> tuple[np.ndarray, np.ndarray]:
    cols = res.columns if hasattr(res, "columns") else res
    return np.asarray(cols["t"], float), np.column_stack([cols["tip_x"], cols["tip_y"]])


def _errors(res, ref) -> dict:
    """Tip-path error of ``res`` against ``ref`` (SimResults or column dicts): RMS and max
    over the common output grid of the distance |tip(t) − tip_ref(t)| (m). Grids that
    differ are compared on the reference's samples inside both runs (linear
    interpolation of ``res``)."""
    t, tip = _tip(res)
    tr, tip_r = _tip(ref)
    if len(t) == len(tr) and np.allclose(t, tr, rtol=0.0, atol=1e-9):
        d = np.linalg.norm(tip - tip_r, axis=1)
    else:
        keep = (tr >= t[0] - 1e-12) & (tr <= t[-1] + 1e-12)
        if not np.any(keep):
            raise ValueError("no common output samples between the run and the reference")
        ti = tr[keep]
        at = np.column_stack([np.interp(ti, t, tip[:, 0]), np.interp(ti, t, tip[:, 1])])
        d = np.linalg.norm(at - tip_r[keep], axis=1)
    return {"tip_rms_error_m": float(np.sqrt(np.mean(d ** 2))),
            "tip_max_error_m": float(np.max(d))}


def first_frequency(chain: Chain) -> Optional[float]:
    """First natural frequency (Hz) above 1e-6 Hz of the chain linearized at its initial
    state (:func:`~flexarm_ros.model.linear.natural_modes`, whose rigid-body modes are at
    exactly 0 Hz); joints locked when the scene has inputs, else free. None if there is
    none."""
    joints = "locked" if chain.scene.inputs else "free"
    f = natural_modes(chain, initial_state(chain)[0], joints).frequencies_hz
    f = np.sort(f[f > RIGID_MODE_HZ])
    return float(f[0]) if len(f) else None


def pareto_front(points, rel_tie: float = 0.0, abs_tie: float = 0.0) -> list[bool]:
    """Flags of the non-dominated points (minimize both cost and error); None entries are
    never on the front. Point o dominates p when o costs no more, o's error is no larger
    and one of the two is strictly smaller. Errors closer than ``abs_tie + rel_tie·error``
    count as equal (a difference below the reference's own accuracy is no difference)."""
    pts = [None if p is None or any(v is None or not math.isfinite(v) for v in p)
           else (float(p[0]), float(p[1])) for p in points]

    def dominates(o, p):
        slack = abs_tie + rel_tie * max(o[1], p[1])
        no_worse = o[0] <= p[0] and o[1] <= p[1] + slack
        better = o[0] < p[0] or o[1] < p[1] - slack
        return no_worse and better

    flags = []
    for i, p in enumerate(pts):
        if p is None:
            flags.append(False)
            continue
        flags.append(not any(o is not None and dominates(o, p)
                             for j, o in enumerate(pts) if j != i))
    return flags


# --------------------------------------------------------------------------------- runs
def _warm_up(scene):
    """Compile / load the compiled kernels so no row's wall time includes it."""
    for s in (spec("cubic", 1, "rk4"), spec("cubic", 1, *ADAPTIVE)):
        try:
            sc = _apply(scene, s)
            run_scene(sc, 2 * max(sc.fidelity.output_dt,
                                  1.0 / sc.twin_control.rate_hz))
        except ROW_ERRORS:
            pass


def _rk4_step(sc, chain, s: dict, reference: bool = False):
    """(h, f1, limited): the RK4 step of row ``s`` (its dt, else the automatic step) and,
    for the ``reference``, the chain's first frequency (None otherwise) and whether the
    bound ω₁·h ≤ REFERENCE_PHASE_STEP shortened the automatic step."""
    h = s.get("dt") or choose_step(chain, initial_x(chain), "rk4", 0.0,
                                   sc.fidelity.output_dt)
    f1 = first_frequency(chain) if reference else None
    limited = bool(not s.get("dt") and f1 and 2 * math.pi * f1 * h > REFERENCE_PHASE_STEP)
    if limited:
        h = REFERENCE_PHASE_STEP / (2 * math.pi * f1)
    return h, f1, limited


def _reference_run(scene, ref: dict, T: float):
    """Run the reference (errors propagate: without it there is no study)."""
    sc = _apply(scene, ref)
    chain = Chain(sc)
    if ref["integrator"] != "rk4":
        return run_scene(sc, T, chain=chain), first_frequency(chain)
    h, f1, limited = _rk4_step(sc, chain, ref, reference=True)
    if limited:
        sc = sc.with_fidelity(dt=h)
        chain = Chain(sc)
    return run_scene(sc, T, chain=chain), f1


def _row(scene, s: dict, T: float, ref_res, f_ref, ref_label) -> dict:
    row = {k: None for k in ROW_KEYS}
    adaptive = s["integrator"] != "rk4"
    row.update(rung=s["rung"], refinement=s["refine"], integrator=s["integrator"],
               rtol=s.get("rtol") if adaptive else None,
               atol=s.get("atol") if adaptive else None,
               duration_s=float(T), status="ok", pareto=False, reference=ref_label,
               reference_first_frequency_hz=f_ref)
    if s.get("skip"):
        row["status"] = s["skip"]
        return row
    try:
        sc = _apply(scene, s)
        if adaptive:
            row["rtol"], row["atol"] = sc.fidelity.rtol, sc.fidelity.atol
        chain = Chain(sc)
        row["n_coordinates"] = chain.n
        f1 = first_frequency(chain)
        row["first_frequency_hz"] = f1
        if f1 is not None and f_ref:
            row["first_frequency_error"] = abs(f1 - f_ref) / f_ref
        res = run_scene(sc, T, chain=chain)
        summ = res.summary()
        sim, wall = summ["sim_time_s"], summ["wall_time_s"]
        wall, row["timing_runs"] = _repeat_timing(chain, sc, T, wall)
        row["duration_s"] = sim
        row["wall_s_per_sim_s"] = wall / sim if sim > 0 else None
        row["real_time_factor"] = sim / wall if wall > 0 else None
        row["rhs_evaluations"] = int(summ["rhs_evaluations"])
        row["steps"] = int(summ["steps"])
        row["step_s"] = float(summ["dt"]) if not adaptive else None
        row.update(_errors(res, ref_res))
        row["energy_drift"] = energy_drift(res)
    except ROW_ERRORS as exc:
        row["status"] = f"{type(exc).__name__}: {exc}"
    return row


class LadderRow:
    """One ladder row as a task (picklable: the scene, the window and the reference's
    ``t``/``tip_x``/``tip_y`` columns): ``__call__(spec) → row`` (:func:`_row`)."""

    def __init__(self, scene, T, ref_columns: dict, f_ref, ref_label):
        self.scene, self.T, self.ref = scene, T, ref_columns
        self.f_ref, self.ref_label = f_ref, ref_label

    def warm_up(self):
        _warm_up(self.scene)

    def __call__(self, s: dict) -> dict:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return _row(self.scene, s, self.T, self.ref, self.f_ref, self.ref_label)


def _repeat_timing(chain, sc, T, wall):
    """Short runs are timed again (same model, integration only) until MIN_TIMING_S of
    wall time has been spent or MAX_TIMING_RUNS runs made; the fastest run counts (as
    ``timeit`` does: slower runs measure other load on the machine, not the model)."""
    runs, spent, best = 1, wall, wall
    if wall >= MIN_TIMING_S:
        return best, runs
    fid = sc.fidelity
    x0 = initial_x(chain)
    while spent < MIN_TIMING_S and runs < MAX_TIMING_RUNS:
        if closed_loop(sc):        # the loop again (the controller and driver count)
            w = run_scene(sc, T).run.wall_time_s
        else:
            w = integrate(chain, x0, T, fid.integrator, fid.dt, fid.rtol, fid.atol,
                          fid.output_dt, fid.max_deflection_ratio).wall_time_s
        best, spent, runs = min(best, w), spent + w, runs + 1
    return best, runs


def input_start(scene) -> float:
    """The latest time at which one of the scene's input programs first moves, s (0: its
    inputs act from the start, or a controller drives it)."""
    latest = 0.0
    for inp in scene.inputs:
        p = inp.program
        start = (p.times[0] if p.type.startswith("piecewise") and p.times else
                 p.start if "start" in type(p).KEYS.get(p.type, ()) else 0.0)
        latest = max(latest, float(start))
    return latest


def forecast_rate(scene, s: dict, reference: bool = False):
    """Forecast wall seconds per simulated second of row ``s`` (RK4 rows: its steps per
    second at its step — the automatic one, or the reference's phase-limited one — times
    the predicted cost per step, :func:`~flexarm_ros.model.linear_response.rk4_work_s`),
    and the step; (None, None) for the other integrators (timed by a pilot run)."""
    from flexarm_ros.model.linear_response import rk4_work_s
    if s.get("integrator", "rk4") != "rk4":
        return None, None
    try:
        sc = _apply(scene, s)
        chain = Chain(sc)
        h = _rk4_step(sc, chain, s, reference)[0]
        return rk4_work_s(chain, 1.0, h), h
    except ROW_ERRORS:
        return 0.0, None              # the row fails at once when it runs


def _choose_duration(scene, ladder, ref, quick, budget_s, progress, duration=None):
    """(window T, {row index: why skipped}): the study's window and the rows left out so
    that the forecast study fits ``budget_s`` (module doc, *Duration*)."""
    dt_out = scene.fidelity.output_dt
    T_p = PILOT_SAMPLES * dt_out
    t_in = input_start(scene)
    after = QUICK_DURATION_S if quick else DEFAULT_DURATION_S
    cap = min(scene.duration, max(after, t_in + after))     # the window sees the input act
    T_min = min(cap, max(5 * T_p, t_in + 5 * T_p))
    if duration is not None:
        cap = T_min = float(duration)
    if not budget_s or budget_s <= 0:
        return cap, {}
    ref_rate, ref_h = forecast_rate(scene, ref, reference=True)
    rates = [forecast_rate(scene, s)[0] for s in ladder]
    unknown = [k for k, r in enumerate(rates) if r is None]
    if unknown and 5 * T_p < cap:
        if progress:
            progress(f"pilot runs of {T_p:.3g} s for the rows without a forecast ...")
        for k in unknown:
            t0 = time.perf_counter()
            try:
                sc = _apply(scene, ladder[k])
                run_scene(sc, T_p, chain=Chain(sc))
            except ROW_ERRORS:
                pass
            rates[k] = (time.perf_counter() - t0) / T_p
    rates = [r or 0.0 for r in rates]
    ref_rate = ref_rate or 0.0
    fixed = ROW_OVERHEAD_S * (len(ladder) + 1)

    def total(T, keep):
        return fixed + T * (ref_rate + sum(rates[k] for k in keep))
    keep = list(range(len(ladder)))
    rate_all = ref_rate + sum(rates)
    T = cap if rate_all <= 0 else min(cap, max(0.0, budget_s - fixed) / rate_all)
    T = max(T, T_min)
    T = max(dt_out, math.floor(T / dt_out + 1e-9) * dt_out)
    if ref_rate * T + fixed > budget_s:
        from flexarm_ros.errors import InputError
        from flexarm_ros.sim.truth import why_slow
        why = why_slow(scene)
        raise InputError(
            f"--budget: got {budget_s:g} s, expected at least the reference's forecast: "
            f"{_label(ref)} needs about {ref_rate * T + fixed:.3g} s for the shortest "
            f"window that sees the input act ({T:.3g} s at its RK4 step {ref_h:.3g} s"
            f"{why}); give --budget {math.ceil(1.5 * (ref_rate * T + fixed))}"
            + (f" or a --duration below {T:.3g} s" if duration is None else
               " or a shorter --duration")
            + (", or damp the beams by viscous_per_length instead" if why else ""))
    skipped = {}
    while total(T, keep) > budget_s and keep:
        worst = max(keep, key=lambda k: rates[k])
        keep.remove(worst)
        skipped[worst] = (f"skipped: forecast {rates[worst] * T:.3g} s for the "
                          f"{T:.3g} s window, beyond the study's budget {budget_s:g} s "
                          f"(--budget)")
    if progress:
        progress(f"window {T:.4g} s (inputs act from {t_in:g} s), forecast "
                 f"{total(T, keep):.3g} s within the budget {budget_s:g} s"
                 + (f"; {len(skipped)} row(s) left out" if skipped else ""))
    return T, skipped


def run_study(scene, duration: Optional[float] = None, quick: bool = False,
              progress: Optional[Callable[[str], None]] = None, *,
              ladder: Optional[list] = None, reference: Optional[dict] = None,
              budget_s: Optional[float] = None, executor=None,
              open_loop: bool = False) -> StudyRows:
    """Run the speed–accuracy study of ``scene``; returns the rows (see module doc). A
    scene with a wall gets the contact trade instead (:mod:`contact_study`).

    ``ladder``: row specs (:func:`spec`), default :func:`default_ladder`;
    ``reference``: the reference spec, default :func:`reference_spec` of the ladder;
    ``duration``: simulated seconds (default: see module doc); ``progress``: called with
    one line of text per row. Fidelity fields the specs do not set (foreshortening,
    modal basis, output sampling, deflection limit) stay the scene's.

    The ladder rows are tasks of the ensemble runner (:class:`LadderRow`,
    :func:`flexarm_ros.ensemble.runner.run_tasks`); ``executor`` (default: in this
    process, one row after the other) may be a Dask executor
    (:func:`flexarm_ros.ensemble.runner.open_executor`): the rows are then built and run
    in the workers, with the same errors, frequencies and step counts, but rows that run
    side by side share the machine, so their ``wall_s_per_sim_s`` (and the Pareto flags
    drawn from it) measure a loaded machine; the default keeps one run at a time.
    A scene with rung auto is studied about the model auto chooses for it.

    A scene with a controller is studied as every command runs it, closed loop
    (:func:`flexarm_ros.twin.batch.run_scene`; ``open_loop``: its input programs alone):
    its plant steps RK4, so only the ladder's RK4 rows are run.
    """
    if open_loop:
        scene = open_loop_scene(scene)
    if scene.fidelity.rung == "auto":
        from flexarm_ros.model.autofidelity import resolve
        scene = resolve(scene)[0].with_fidelity(dt=0.0)
    if scene.walls:
        from flexarm_ros.studies.contact import run_contact_study
        rows = run_contact_study(scene, duration, quick, progress, executor=executor)
        ok = [r for r in rows if r.get("status") == "ok"]
        front = pareto_front([(r["wall_s_per_sim_s"], r["tip_rms_error_m"]) for r in ok])
        for r in rows:
            r.setdefault("integrator", "rk4")
            r["pareto"] = False
            r["label"] = (f"{r['rung']} impulse" if r["contact"] == "impulse" else
                          f"{r['rung']} k={r['stiffness']:.0e}")
        for r, p in zip(ok, front):
            r["pareto"] = p
        return StudyRows(rows, {"kind": "contact"})
    ladder = [dict(s) for s in (ladder if ladder is not None else default_ladder(quick))]
    if closed_loop(scene):     # the plant of the loop steps RK4 (twin.batch)
        ladder = [s for s in ladder if s.get("integrator", "rk4") == "rk4"]
    for s in ladder:
        s.setdefault("refine", 0)
        s["refine"] = int(s["refine"] or DEFAULT_REFINE[s["rung"]])
        s.setdefault("integrator", "rk4")
        s.setdefault("dt", 0.0)
    ref = dict(reference) if reference is not None else reference_spec(ladder)
    ref["refine"] = int(ref.get("refine") or DEFAULT_REFINE[ref["rung"]])
    ref.setdefault("dt", 0.0)
    ref.setdefault("integrator", "rk4")
    if duration is not None and not float(duration) > 0:
        raise SceneError(f"duration: got {duration}, expected > 0 s")
    if budget_s is None:            # 0: no budget
        budget_s = QUICK_BUDGET_S if quick else DEFAULT_BUDGET_S
    T, skipped = _choose_duration(scene, ladder, ref, quick, budget_s, progress, duration)
    for k, why in skipped.items():
        ladder[k]["skip"] = why
    _warm_up(scene)
    ref_label = _label(ref)
    if progress:
        progress(f"reference {ref_label}, {T:.4g} s simulated ...")
    ref_res, f_ref = _reference_run(scene, ref, T)
    ref_summ = ref_res.summary()
    meta = {"scene": scene.name, "duration_s": ref_summ["sim_time_s"], "reference": ref_label,
            "reference_step_s": ref_summ["dt"] or None,
            "reference_first_frequency_hz": f_ref,
            "reference_wall_s_per_sim_s": (ref_summ["wall_time_s"] / ref_summ["sim_time_s"]
                                           if ref_summ["sim_time_s"] > 0 else None),
            "reference_energy_drift": energy_drift(ref_res),
            "joints": "locked" if scene.inputs else "free"}
    if progress:
        progress(f"reference done: {meta['reference_wall_s_per_sim_s']:.3g} wall s per "
                 f"simulated s, first frequency "
                 + (f"{f_ref:.6g} Hz" if f_ref else "none"))
    task = LadderRow(scene, T, {k: np.asarray(ref_res.columns[k]) for k in
                                ("t", "tip_x", "tip_y")}, f_ref, ref_label)

    def done(k, row):
        if progress:
            progress(f"[{k + 1}/{len(ladder)}] {_label(ladder[k])}: " + _row_line(row))
    rows = run_tasks(task, ladder, executor, on_result=done)
    meta["reference_error_estimate_m"] = _reference_error_estimate(rows, ref)
    flags = pareto_front([(r["wall_s_per_sim_s"], r["tip_rms_error_m"])
                          if r["status"] == "ok" else None for r in rows],
                         rel_tie=PARETO_REL_TIE,
                         abs_tie=meta["reference_error_estimate_m"] or 0.0)
    for r, f in zip(rows, flags):
        r["pareto"] = bool(f)
    tip = np.hypot(ref_res.columns["tip_x"] - ref_res.columns["tip_x"][0],
                   ref_res.columns["tip_y"] - ref_res.columns["tip_y"][0])
    if not np.max(tip, initial=0.0) > 1e-9:
        meta["warning"] = (f"the reference's tip does not move in the {T:.4g} s window "
                           f"(its largest displacement {np.max(tip, initial=0.0):.2g} m): "
                           f"every row's error is about zero and the table ranks nothing; "
                           f"give a longer --duration or inputs that act in it")
    if skipped:
        meta["skipped"] = len(skipped)
    return StudyRows(rows, meta)


def _reference_error_estimate(rows, ref) -> Optional[float]:
    """Estimated RMS tip error of the reference itself: the error of the ladder's FEM row on
    half the reference mesh divided by 2⁴ − 1 (Richardson, Hermite cubics converge at
    fourth order: fem 2 → 4 → 8 errors fall by 9× and 12× on link_tipmass). None when the
    ladder has no such row."""
    if ref["rung"] != "fem" or ref["refine"] % 2:
        return None
    errs = [r["tip_rms_error_m"] for r in rows if r["status"] == "ok" and r["rung"] == "fem"
            and r["refinement"] == ref["refine"] // 2]
    return min(errs) / 15.0 if errs else None


def _row_line(row) -> str:
    if row["status"] != "ok":
        return row["status"]
    return (f"{row['wall_s_per_sim_s']:.3g} wall s/s, tip RMS {row['tip_rms_error_m']:.3g} m, "
            f"f1 error " + ("-" if row["first_frequency_error"] is None
                            else f"{row['first_frequency_error']:.3g}"))


# ------------------------------------------------------------------------------- output
def _fmt(v, spec_):
    if v is None:
        return "-"
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return format(v, spec_)


def format_table(rows) -> str:
    """A fixed-width text table of the rows (failed rows show their status at the end)."""
    if rows and "contact" in rows[0]:
        from flexarm_ros.studies.contact import format_contact_table
        return format_contact_table(rows)
    cols = [("rung", 6, "s"), ("ref", 4, "d"), ("integrator", 10, "s"), ("n", 4, "d"),
            ("wall s/s", 9, ".3g"), ("RTF", 9, ".3g"), ("RHS evals", 10, "d"),
            ("tip RMS m", 10, ".3e"), ("tip max m", 10, ".3e"), ("f1 Hz", 11, ".6g"),
            ("f1 err", 9, ".2e"), ("E drift", 9, ".2e"), ("P", 1, "s")]
    keys = ["rung", "refinement", "integrator", "n_coordinates", "wall_s_per_sim_s",
            "real_time_factor", "rhs_evaluations", "tip_rms_error_m", "tip_max_error_m",
            "first_frequency_hz", "first_frequency_error", "energy_drift", "pareto"]
    head = "  ".join(f"{name:>{w}}" if i > 2 else f"{name:<{w}}"
                     for i, (name, w, _) in enumerate(cols))
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = []
        for i, ((_, w, sp), key) in enumerate(zip(cols, keys)):
            v = r.get(key)
            if key == "pareto":
                text = "*" if v else ""
            elif key == "first_frequency_hz" and v is not None:
                text = _fmt(float(v), sp)
            else:
                text = _fmt(v, sp)
            cells.append(f"{text:<{w}}" if i <= 2 else f"{text:>{w}}")
        line = "  ".join(cells)
        if r.get("status", "ok") != "ok":
            line += "  " + r["status"]
        lines.append(line.rstrip())
    meta = getattr(rows, "meta", None)
    if meta:
        lines.append("")
        lines.append(f"reference: {meta['reference']}, {meta['duration_s']:.4g} s simulated, "
                     f"{_fmt(meta['reference_wall_s_per_sim_s'], '.3g')} wall s/s, f1 "
                     f"{_fmt(meta['reference_first_frequency_hz'], '.6g')} Hz "
                     f"(joints {meta['joints']}); estimated reference tip error "
                     f"{_fmt(meta.get('reference_error_estimate_m'), '.2g')} m")
        lines.append("P = on the Pareto front of (wall s/s, tip RMS); wall s/s = integration "
                     "wall seconds per simulated second; RTF = its inverse")
    return "\n".join(lines)


_MARKERS = {"rigid": "o", "cubic": "s", "modal": "^", "fem": "D", "fd": "v"}
_COLOURS = {"rk4": "tab:blue", "dop853": "tab:orange", "rk45": "tab:green",
            "radau": "tab:red", "bdf": "tab:purple", "lsoda": "tab:brown", "trapezoid": "tab:cyan"}


def plot_pareto(rows, png_path, title: str = "") -> None:
    """Log–log plot of RMS tip error against wall seconds per simulated second (PNG):
    one marker per rung, one colour per integrator, the Pareto front joined, points
    labelled rung + refinement; failed rows listed below the axes. Zero errors (a row
    identical to the reference) are drawn at the bottom edge."""
    # the Agg canvas directly (no pyplot, no display, the global backend untouched)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(9.0, 6.2), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ok = [r for r in rows if r.get("status") == "ok" and r.get("wall_s_per_sim_s")
          and r.get("tip_rms_error_m") is not None]
    failed = [r for r in rows if r.get("status") != "ok"]
    pos = [r["tip_rms_error_m"] for r in ok if r["tip_rms_error_m"] > 0]
    floor = (min(pos) / 10.0) if pos else 1e-12

    def y_of(r):
        return r["tip_rms_error_m"] if r["tip_rms_error_m"] > 0 else floor

    for r in ok:
        ax.scatter(r["wall_s_per_sim_s"], y_of(r), marker=_MARKERS.get(r["rung"], "x"),
                   s=60 if r["pareto"] else 42, color=_COLOURS.get(r["integrator"], "k"),
                   edgecolors="k" if r["pareto"] else "none", linewidths=1.0, zorder=3)
        ax.annotate(r.get("label", f"{r['rung']} {r['refinement']}"),
                    (r["wall_s_per_sim_s"], y_of(r)),
                    xytext=(5, 4), textcoords="offset points", fontsize=7.5, color="0.2")
    front = sorted((r for r in ok if r["pareto"]), key=lambda r: r["wall_s_per_sim_s"])
    if len(front) > 1:
        ax.plot([r["wall_s_per_sim_s"] for r in front], [y_of(r) for r in front],
                color="0.35", lw=1.2, ls="--", zorder=2, label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    if ok:
        xs = [r["wall_s_per_sim_s"] for r in ok]
        ax.set_xlim(min(xs) / 1.6, max(xs) * 2.5)      # room for the labels
    meta = getattr(rows, "meta", None) or {}
    if ok:
        xs = [r["wall_s_per_sim_s"] for r in ok]
        lo, hi = min(xs), max(xs)
        marks = [(1.0, "real time")]
        if meta.get("reference_wall_s_per_sim_s"):
            marks.append((meta["reference_wall_s_per_sim_s"], "reference run"))
        for x, text in marks:
            if lo / 3 <= x <= hi * 3:
                ax.axvline(x, color="0.55", lw=0.8, ls=":", zorder=1)
                ax.text(x, 0.02, f" {text}", transform=ax.get_xaxis_transform(), rotation=90,
                        fontsize=7.5, color="0.4", va="bottom", ha="right")
    est = meta.get("reference_error_estimate_m")
    if ok and est:
        ax.axhline(est, color="0.55", lw=0.8, ls=":", zorder=1)
        ax.text(0.5, est, "estimated error of the reference itself", fontsize=7.5,
                color="0.4", va="bottom", ha="center", transform=ax.get_yaxis_transform())
    ax.set_xlabel("wall seconds per simulated second (integration only)")
    ax.set_ylabel("RMS tip-path error against the reference (m)")
    ax.grid(True, which="major", color="0.85", lw=0.6)
    ax.grid(True, which="minor", color="0.93", lw=0.4)
    sub = ""
    if meta.get("reference"):
        sub = (f"reference {meta['reference']}, {meta['duration_s']:.3g} s simulated")
    elif meta.get("kind") == "contact" and rows:
        ref = rows[0].get("reference", {})
        sub = f"reference {ref.get('rung')} impulse, dt {ref.get('dt', 0):.3g} s"
    elif rows:
        sub = f"reference {rows[0].get('reference')}, {rows[0].get('duration_s', 0):.3g} s"
    ax.set_title((title + "\n" if title else "") + f"speed–accuracy of the fidelity ladder"
                 + (f" ({sub})" if sub else ""), fontsize=10)
    rung_handles = [Line2D([], [], marker=m, ls="none", color="0.3", label=k)
                    for k, m in _MARKERS.items() if any(r["rung"] == k for r in ok)]
    integ_handles = [Line2D([], [], marker="o", ls="none", color=c, label=k)
                     for k, c in _COLOURS.items() if any(r["integrator"] == k for r in ok)]
    extra = [Line2D([], [], marker="o", ls="--", color="0.35", mfc="white", mec="k",
                    label="Pareto front")] if front else []
    leg1 = ax.legend(handles=rung_handles, title="rung", loc="upper right", fontsize=8,
                     title_fontsize=8)
    ax.add_artist(leg1)
    ax.legend(handles=integ_handles + extra, title="integrator", loc="lower left",
              fontsize=8, title_fontsize=8)
    if failed:
        txt = "failed: " + "; ".join(f"{r['rung']} {r['refinement']} {r['integrator']}"
                                     for r in failed)
        fig.text(0.01, 0.01, txt, fontsize=7, color="tab:red")
    fig.tight_layout(rect=(0, 0.03 if failed else 0, 1, 1))
    fig.savefig(str(png_path))
