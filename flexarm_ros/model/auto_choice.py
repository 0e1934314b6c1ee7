"""What rung auto chose and why: the settings of the choice (the tolerance, the ladder of
candidates, the shares of the budget, the check after the run), one judged candidate
(:class:`Candidate`) and the choice with its report (:class:`AutoChoice`,
:meth:`AutoChoice.explain`, printed by ``flexarm explain``). How the choice is made:
:mod:`flexarm_ros.model.autofidelity`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

#: RKN4's stability limit over RK4's at most (h·ω = 3.51 against 2.78, a mode damped at
#: ζ ≈ 0.2; model/explicit.rkn4_limit): bounds a candidate's largest step when pruning
RKN4_LIMIT_RATIO = 1.27

#: the tip tolerance of rung auto when fidelity.tolerance is 0, m: 10 µm, the issue's
#: accuracy target for the seed 001 link and below what the seeds' instruments resolve
#: at the tip (seed 000's accelerometers and encoders, seed 002's strain gauge)
DEFAULT_TOLERANCE_M = 1e-5
#: share of TOL for the spatial estimate; the RK4 step gets the rest
SPATIAL_SHARE = 0.5
#: the a-posteriori check's finer model: spatial estimate ≤ 1/FINER_FACTOR of the chosen's
FINER_FACTOR = 4
#: ... looked for among at most this many more candidates
FINER_TRIES = 5
#: the candidates, by family, each family in increasing refinement (and cost)
LADDER = (("rigid", (0,)), ("cubic", (0,)), ("modal", tuple(range(1, 11))),
          ("fem", (2, 4, 8)), ("fd", (10, 20)))
#: modes per beam of the linear reference (its own error: the change from 2 fewer); the
#: modal sequence converges much faster than FEM's on these arms (measured, linear, max tip
#: distance over the run: modal 10 vs 12 4e-9 m on link_tipmass, 3e-7 m on hydraulic_0kg,
#: where FEM 8 and 12 are still 2e-4 and 8e-5 m away), and FEM 12 and finer lose accuracy
#: to round-off in the state-transition matrix of their stiff element modes (|λ| ≥ 5e4 1/s:
#: 7e-8 … 2e-7 m on two_link_free, where FEM 4, 6, 8 and modal 12 agree to 1e-9 m)
REFERENCE_MODES = 12
#: elements per beam of the independent cross-check of the reference (reported)
CROSS_CHECK_ELEMENTS = 8
#: the temporal estimate steps the linear model at most this many RK4 steps (a longer run
#: is estimated over its start and scaled linearly in time, as a phase error grows)
MAX_RK4_STEPS = 200_000
#: the linear responses are sampled on at most this many output intervals
MAX_LINEAR_SAMPLES = 5000
#: the check after the run: the first share of the run, at least WINDOW_MIN_S
WINDOW_FRACTION = 0.1
WINDOW_MIN_S = 0.1


def tolerance_of(fidelity) -> float:
    return fidelity.tolerance if fidelity.tolerance > 0 else DEFAULT_TOLERANCE_M


@dataclass
class Candidate:
    """One rung × refinement as auto judged it."""
    rung: str
    refine: int
    coordinates: int = 0
    stable_step_s: float = math.nan     # RK4_AUTO/|λ|max
    step_s: float = math.nan            # the step the run would take
    steps: int = 0
    work_s: float = math.nan            # predicted integration time (COST_US)
    spatial_m: float = math.nan         # E_s (reference error included)
    temporal_m: float = math.nan        # E_t at step_s
    integrator: str = "rk4"             # rkn4 where it steps this model further
    verdict: str = ""
    rkn4_note: str = ""                 # "; rkn4 at … (rk4's step …)" when it took rkn4

    @property
    def label(self) -> str:
        return self.rung if self.rung in ("rigid", "cubic") else f"{self.rung} {self.refine}"

    def take_step(self, h: float, duration: float, cost_us: float) -> None:
        """Step h over ``duration`` s: the steps and their predicted work."""
        self.step_s = h
        self.steps = int(math.ceil(duration / h - 1e-9))
        self.work_s = self.steps * cost_us * 1e-6

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and math.isnan(v) else v)
                for k, v in dataclasses.asdict(self).items()}


@dataclass
class AutoChoice:
    """What auto chose for a scene, a tolerance and a duration, and on what grounds."""
    tolerance_m: float
    tolerance_given: bool
    duration_s: float
    rung: str
    refine: int
    step_s: float                 # the RK4 step of the run (the contact stepper's: wall)
    dt_request: float             # fidelity.dt to run with (0: the automatic step)
    spatial_m: float
    temporal_m: float             # nan with a wall (the contact stepper's step)
    candidates: list = field(default_factory=list)
    reference: str = ""
    reference_error_m: float = 0.0
    cross_check_m: float | None = None   # the reference against FEM (independent family)
    finer: tuple | None = None     # (rung, refine, stable step s, spatial estimate m): the
    #                                check after the run runs it
    window_s: float = 0.0          # the check's window
    growth: float = 1.0            # linear error at the end / in the window
    wall: bool = False
    analysis_s: float = 0.0
    integrator: str = "rk4"        # rkn4 where it takes the chosen model further (_with_rkn4)

    @property
    def label(self) -> str:
        return self.rung if self.rung in ("rigid", "cubic") else f"{self.rung} {self.refine}"

    @property
    def estimated_m(self) -> float:
        """The a-priori estimate: spatial + temporal (spatial only with a wall)."""
        return self.spatial_m + (0.0 if math.isnan(self.temporal_m) else self.temporal_m)

    def fidelity_overrides(self) -> dict:
        """``Scene.with_fidelity`` keywords of the chosen model (tolerance consumed)."""
        return {"rung": self.rung, "refine": self.refine, "dt": self.dt_request,
                "tolerance": 0.0, "integrator": self.integrator}

    def as_dict(self) -> dict:
        return {"tolerance_m": self.tolerance_m,
                "tolerance_source": "fidelity.tolerance" if self.tolerance_given else
                "default", "duration_s": self.duration_s, "rung": self.rung,
                "refine": self.refine, "integrator": self.integrator, "step_s": self.step_s,
                "a_priori_spatial_m": self.spatial_m,
                "a_priori_temporal_m": None if math.isnan(self.temporal_m) else
                self.temporal_m,
                "reference": self.reference, "reference_error_m": self.reference_error_m,
                "cross_check_m": self.cross_check_m,
                "finer": None if self.finer is None else
                {"rung": self.finer[0], "refine": self.finer[1]},
                "check_window_s": self.window_s, "growth": self.growth,
                "analysis_s": self.analysis_s,
                "candidates": [c.as_dict() for c in self.candidates]}

    def explain(self) -> str:
        """What was chosen and why: the candidates tried and their estimates."""
        src = "fidelity.tolerance" if self.tolerance_given else "the default"
        chosen = next((c for c in self.candidates if c.verdict.startswith("chosen")), None)
        stable = chosen.stable_step_s if chosen is not None else math.nan
        how = ("the contact stepper's step" if self.wall else
               "the automatic step" if self.dt_request == 0 else
               "a step chosen for the tolerance")
        step = f"{how} {self.step_s:.4g} s"
        if not self.wall and self.dt_request != 0 and self.step_s > stable:
            step = (f"{self.step_s:.4g} s, above its stable step {stable:.4g} s "
                    f"({self.integrator.upper()}'s error on the linearized model evaluated "
                    f"there)")
        lines = [f"rung auto: chose {self.label}, {self.integrator} at {step}, for a "
                 f"tip tolerance of {self.tolerance_m:.3g} m ({src}) over "
                 f"{self.duration_s:.4g} s",
                 f"  why: the least predicted work among the candidates whose estimated spatial "
                 f"error is <= {SPATIAL_SHARE:g} TOL and whose RK4 error at their step is "
                 f"within the rest"
                 + ("" if self.wall else " (or rkn4's, the same cost per step, where it "
                    "steps a candidate further)"),
                 f"  estimates (linearized model, the scene's inputs, the whole run): "
                 f"spatial {self.spatial_m:.2g} m against {self.reference} (its own error "
                 f"{self.reference_error_m:.2g} m, included)"
                 + ("" if math.isnan(self.temporal_m) else
                    f", temporal {self.temporal_m:.2g} m"),
                 *([f"  cross-check: FEM {CROSS_CHECK_ELEMENTS} (linear) lies "
                    f"{self.cross_check_m:.2g} m from the reference (FEM's own error, "
                    f"h⁴)"] if self.cross_check_m is not None else []),
                 f"  {'candidate':10s} {'coords':>6s} {'step s':>9s} {'steps':>8s} "
                 f"{'work s':>8s} {'spatial m':>9s} {'temporal m':>10s}  verdict"]

        def num(v, fmt):
            return f"{v:{fmt}}" if isinstance(v, (int, float)) and not (
                isinstance(v, float) and math.isnan(v)) else "-"
        for c in self.candidates:
            lines.append(f"  {c.label:10s} {num(c.coordinates, '6d'):>6s} "
                         f"{num(c.step_s, '9.3g'):>9s} "
                         f"{num(c.steps, '8d') if c.steps else '-':>8s} "
                         f"{num(c.work_s, '8.2g'):>8s} {num(c.spatial_m, '9.2g'):>9s} "
                         f"{num(c.temporal_m, '10.2g'):>10s}  {c.verdict}")
        if self.finer is not None:
            fl = self.finer[0] if self.finer[0] in ("rigid", "cubic") else \
                f"{self.finer[0]} {self.finer[1]}"
            h_check = min(0.5 * self.step_s, self.finer[2])     # as posterior_check
            lines.append(f"  after a run: the first {self.window_s:.3g} s again with {fl} at "
                         f"{h_check:.3g} s (half the step or {fl}'s stable step, the "
                         f"shorter); the difference × {self.growth:.3g} (the linear "
                         f"error's growth to the end) × 2 (margin) + {fl}'s own spatial "
                         f"estimate {self.finer[3]:.2g} m is the run's estimate")
        if self.wall:
            lines.append("  with a wall: the estimates cover the free flight; the impacts "
                         "and the contact stepper's step are not error-controlled")
        lines.append(f"  analysis {self.analysis_s:.2f} s; a named rung overrides auto "
                     f"(--rung …; the scene file names the seed's own model)")
        return "\n".join(lines)
