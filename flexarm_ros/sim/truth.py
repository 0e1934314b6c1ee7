"""The check of a run against the physics: the same scene on the top rung of the ladder,
over the whole run, in the two quantities users read (issue 36).

Every error the twin reports for a run — ``--tolerance``, ``--rung auto``, ``--estimate``
— rests on this check, not on the run's own model class. The reference is the
geometrically exact rod (:mod:`flexarm_ros.model.rod`) at its automatic step, with the
curvature terms of the first pair of :data:`REFERENCES` whose own error bound — its
distance to the rod with two terms fewer — is at most a quarter of the tolerance (the rod
converges spectrally: on the spin-up 8 and 10 terms agree to 3e-9 m, so the bound is
conservative; through a wall's impacts 8 and 6 terms part by 5e-4 m on two_link_case1,
and a tolerance below that is reported as not certified). The two measures, each the largest
over the run:

``position``   |tip(t) − tip_ref(t)|, the last beam tip in the world frame (m);
``deflection`` |w_k(t) − w_k,ref(t)| per link, the elastic tip deflection in the link's
               hub frame (m) — what a strain gauge, an accelerometer and seed 001's plots
               see — and as a share of its peak |w_k,ref| over the run.

The estimate of a run's error is what the check observed plus the reference's own bound
(the triangle inequality), per measure. Why the whole run: the error of an oscillating arm
grows with time and a strike or a large motion can multiply it; a window scaled up missed
it by 10× on the spin-up (the first 2 s of 20 extrapolated linearly through the
large-deflection phase).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError, SceneError, SimulationDiverged

#: (curvature terms of the reference rod, of the rod that bounds its error), tried in turn
#: until the bound is at most BOUND_SHARE of the tolerance (the last pair otherwise)
REFERENCES = ((8, 6), (10, 8), (12, 10))
BOUND_SHARE = 0.25
REFERENCE_TERMS = REFERENCES[0][0]
METRICS = ("position", "deflection", "both")
#: why a scene with a wall is not checked: through impacts the rods converge slowly in
#: their terms (two_link_case1, 2.5 s: rod 8 and rod 6 part by 4.8e-4 m, case 2 by
#: 4.3e-5 m), so the check could certify nothing below that, at four rod runs per scene
WALL_NOTE = ("not run: a wall (through impacts the rod's terms converge slowly: rod 8 and "
             "rod 6 part by 4.8e-4 m on two_link_case1; the estimate is the model's own, "
             "docs/accuracy.md)")


@dataclass(frozen=True)
class Measures:
    """A run's distance to another, each measure its largest over the run."""
    position_m: float
    deflection_m: tuple            # per link (m)
    deflection_peak_m: tuple       # the other run's peak |w_k| per link (m)

    @property
    def deflection_max_m(self) -> float:
        return max(self.deflection_m) if self.deflection_m else 0.0

    @property
    def deflection_share(self) -> tuple:
        return tuple(d / p if p > 0 else math.inf for d, p in
                     zip(self.deflection_m, self.deflection_peak_m))

    def __add__(self, other: "Measures") -> "Measures":
        return Measures(self.position_m + other.position_m,
                        tuple(a + b for a, b in zip(self.deflection_m, other.deflection_m)),
                        self.deflection_peak_m)

    def as_dict(self) -> dict:
        return {"position_m": self.position_m, "deflection_m": list(self.deflection_m),
                "deflection_share": list(self.deflection_share),
                "deflection_peak_m": list(self.deflection_peak_m)}


def measures(columns, reference, links) -> Measures:
    """:class:`Measures` of the output columns of a run against a reference's, on their
    common samples (the shorter run's length; both on the scene's output grid)."""
    k = min(len(columns["t"]), len(reference["t"]))
    pos = float(np.max(np.hypot(np.asarray(columns["tip_x"][:k]) - reference["tip_x"][:k],
                                np.asarray(columns["tip_y"][:k]) - reference["tip_y"][:k])))
    defl, peak = [], []
    for name in links:
        a = np.asarray(columns[f"{name}_tip_deflection"][:k], float)
        b = np.asarray(reference[f"{name}_tip_deflection"][:k], float)
        defl.append(float(np.max(np.abs(a - b))))
        peak.append(float(np.max(np.abs(b))))
    return Measures(pos, tuple(defl), tuple(peak))


@dataclass(frozen=True)
class TopCheck:
    """A run against the top rung over the whole run (module doc)."""
    reference: str                 # "rod 8"
    observed: Measures | None      # the run against the reference
    reference_error: Measures | None   # the reference against the bound rod
    wall_s: float
    status: str = "ok"             # or why the check could not run

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def estimate(self) -> Measures | None:
        """The run's error bound: observed + the reference's own (per measure)."""
        if not self.ok:
            return None
        return self.observed + self.reference_error

    def met(self, tolerance_m: float, metric: str) -> dict:
        """{measure: bool} of the measures ``metric`` bounds (position, deflection or
        both) against the tolerance."""
        est = self.estimate
        out = {}
        if metric in ("position", "both"):
            out["position"] = bool(est.position_m <= tolerance_m)
        if metric in ("deflection", "both"):
            out["deflection"] = bool(est.deflection_max_m <= tolerance_m)
        return out

    def as_dict(self) -> dict:
        out = {"reference": self.reference, "wall_s": self.wall_s, "status": self.status}
        if self.ok:
            out.update(observed=self.observed.as_dict(),
                       reference_error=self.reference_error.as_dict(),
                       estimate=self.estimate.as_dict())
        return out


def check_metric(metric: str) -> str:
    if metric not in METRICS:
        raise SceneError(f"fidelity.tolerance_metric: got {metric!r}, expected one of "
                         f"{', '.join(METRICS)}")
    return metric


def reference_scene(scene, terms, closed_loop=False):
    """The scene on the rod with ``terms`` terms at its automatic RK4 step, no tolerance,
    no estimate; the input programs alone, or (``closed_loop``) with the scene's controller
    and driver in the loop at the control rate, as the checked run had them."""
    import dataclasses
    sc = scene if closed_loop else dataclasses.replace(scene, control=None)
    defaults = type(sc.fidelity)()
    return sc.with_fidelity(rung="rod", refine=terms, dt=0.0, tolerance=0.0,
                            estimate=False, integrator="rk4",
                            modal_basis=defaults.modal_basis,
                            rod_points=defaults.rod_points,
                            rod_modes=defaults.rod_modes,
                            foreshortening=defaults.foreshortening, rtol=defaults.rtol,
                            atol=defaults.atol,
                            tolerance_metric=defaults.tolerance_metric)


def _rod_columns(scene, T, terms, simulate, closed_loop=False):
    """The output columns the check compares (t, tip, tip deflections) of the scene on the
    rod with ``terms`` terms over T s, and the link names (kept per process, keyed by the
    reference scene — the fidelity keys the rod does not read set to their defaults — so
    every rung and tolerance of one scene, and the pairs of references, share the runs).
    ``simulate``: the batch run without a check
    (:func:`flexarm_ros.sim.simulate._simulate`, passed in: this module sits below it)."""
    return _rod_run(reference_scene(scene, terms, closed_loop), T, simulate)


#: (scene, T, closed_loop) whose references this process has run (no forecast again)
_DONE: set = set()


@functools.lru_cache(maxsize=16)
def _rod_run(ref_scene, T, simulate):
    run = simulate(ref_scene, T)
    cols = {k: np.asarray(v) for k, v in run.columns.items()
            if k in ("t", "tip_x", "tip_y") or k.endswith("_tip_deflection")}
    return cols, [lm.name for lm in run.chain.links]


def reference(scene, T: float, tolerance_m: float, simulate, closed_loop=False,
              first_forecast_s: float = 0.0):
    """(label, columns, links, own error Measures) of the top rung for ``scene`` over
    ``T`` s: the first pair of :data:`REFERENCES` whose own bound is at most
    :data:`BOUND_SHARE` of ``tolerance_m`` (0: the first pair) — or the last pair that
    fits :data:`CHECK_BUDGET_S` (each further pair is forecast, scaled by how the first
    pair's forecast ``first_forecast_s`` compared with its wall time, before it runs; a
    larger own bound only makes the estimate more conservative)."""
    spent, scale, best = 0.0, 1.0, None
    for i, pair in enumerate(REFERENCES):
        if i > 0 and first_forecast_s > 0:
            need = scale * _pairs_forecast(scene, T, pair, closed_loop)
            if spent + need > CHECK_BUDGET_S:
                return best
        t0 = time.perf_counter()
        ref_terms, bound_terms = pair
        cols, links = _rod_columns(scene, T, ref_terms, simulate, closed_loop)
        bound, _ = _rod_columns(scene, T, bound_terms, simulate, closed_loop)
        wall = time.perf_counter() - t0
        spent += wall
        if i == 0 and first_forecast_s > 0 and wall > 0.5:
            scale = max(1.0, wall / first_forecast_s)
        own = measures(bound, cols, links)
        best = (f"rod {ref_terms}", cols, links, own)
        good = max(own.position_m, own.deflection_max_m) <= BOUND_SHARE * tolerance_m
        if tolerance_m <= 0 or good or i == len(REFERENCES) - 1:
            return best


#: the longest check a run takes on itself, s: a check forecast above it (its reference
#: rods' steps × the predicted cost per step) is not run and says so, naming the forecast
#: and what sets the rods' step (``flexarm explain --check-budget`` sets it for explain)
CHECK_BUDGET_S = 120.0
#: where the check announces itself and its forecast (None: silent; the CLI sets stderr)
ANNOUNCE_STREAM = None


def forecast_s(scene, T: float, closed_loop: bool = False):
    """(seconds, step_s, terms) forecast for the first pair of :data:`REFERENCES` over
    ``T`` s: each rod's RK4 steps at its automatic step (the stability limit of its
    linearization at the start, :func:`flexarm_ros.model.explicit.stability`) times the
    predicted cost per step (:func:`flexarm_ros.model.linear_response.rk4_work_s`); the
    reference rod's step is returned."""
    return _pairs_forecast(scene, T, REFERENCES[0], closed_loop, want_step=True)


def _pairs_forecast(scene, T, pair, closed_loop, want_step=False):
    """:func:`forecast_s` of the rods of ``pair``."""
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.explicit import stability
    from flexarm_ros.model.linear_response import rk4_work_s
    from flexarm_ros.model.statics import initial_state
    total, step = 0.0, math.inf
    for terms in pair:
        chain = Chain(reference_scene(scene, terms, closed_loop))
        rate, limit, auto = stability(chain, *initial_state(chain), "rk4")
        h = auto if auto > 0 else chain.fidelity.output_dt
        h = min(h, chain.fidelity.output_dt)
        if terms == pair[0]:
            step = h
        total += rk4_work_s(chain, T, h)
    return (total, step, pair[0]) if want_step else total


def why_slow(scene) -> str:
    """What a slow reference comes from, where the scene says it."""
    beta = [f"links[{k}].beam.damping.stiffness_proportional = "
            f"{lk.beam.damping.stiffness_proportional:g} s"
            for k, lk in enumerate(scene.links) if lk.beam.damping.stiffness_proportional > 0]
    if beta:
        return (f"; the fine model's highest modes under {', '.join(beta)} (D = β·K damps "
                f"mode ω at β·ω², which sets an explicit step of about 2.8/(β·ω²))")
    return ""


def top_check(scene, columns, T: float, tolerance_m: float, simulate,
              closed_loop: bool = False) -> TopCheck:
    """The run of ``scene`` (its output ``columns`` over ``T`` s) against the top rung
    (the reference good enough for ``tolerance_m``, :func:`reference`; ``simulate`` runs
    it; ``closed_loop``: the reference runs with the scene's controller and driver, and
    ``simulate`` is the closed-loop batch run)."""
    t0 = time.perf_counter()
    if scene.walls:
        return TopCheck("rod", None, None, 0.0, WALL_NOTE)
    try:
        hash(scene)
    except TypeError:                        # an unhashable scene: no memo
        return TopCheck("rod", None, None, 0.0, "not run: the scene is not hashable")
    try:
        key = (scene, float(T), closed_loop)
        need = 0.0
        if key not in _DONE:
            need, step, terms = forecast_s(scene, float(T), closed_loop)
            if need > CHECK_BUDGET_S:
                return TopCheck(
                    f"rod {terms}", None, None, time.perf_counter() - t0,
                    f"not run: the reference rods would take about {need:.3g} s (rod "
                    f"{terms} at its stable RK4 step {step:.3g} s over {T:g} s){why_slow(scene)}"
                    f", above the check's budget {CHECK_BUDGET_S:g} s")
            if ANNOUNCE_STREAM is not None and need > 1.0:
                print(f"flexarm: checking against the geometrically exact rod {terms}: about "
                      f"{need:.2g} s (its stable RK4 step {step:.3g} s) ...",
                      file=ANNOUNCE_STREAM, flush=True)
        label, cols, links, own = reference(scene, float(T), tolerance_m, simulate,
                                            closed_loop, need)
        _DONE.add(key)
    except (InputError, SimulationDiverged) as exc:
        return TopCheck(f"rod {REFERENCES[0][0]}", None, None, time.perf_counter() - t0,
                        "not run: " + " ".join(str(exc).split()))
    return TopCheck(label, measures(columns, cols, links), own, time.perf_counter() - t0)
