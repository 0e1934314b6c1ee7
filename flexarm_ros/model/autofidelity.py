"""Automatic fidelity: ``fidelity.rung: auto`` / ``--rung auto``.

Given a tip-position tolerance TOL (``fidelity.tolerance``; :data:`DEFAULT_TOLERANCE_M`
= 1e-5 m when it is 0), choose the cheapest rung, refinement and RK4 step whose estimated
tip error over the run stays below TOL, and say why (:meth:`AutoChoice.explain`, printed by
``flexarm explain``). The check after the run is in :mod:`flexarm_ros.sim.accuracy`
(:func:`~flexarm_ros.sim.accuracy.posterior_check`).

A priori, on the linearized model
    Every candidate of the ladder (:data:`LADDER`: rigid, cubic, modal 1–10, fem 2/4/8,
    fd 10/20; the modal basis is the scene's ``modal_basis``) is linearized about the
    scene's initial state (:func:`~flexarm_ros.model.statespace.linearize`: M δq̈ + D_t δq̇
    + K_t δq = B u with the drive states; a prescribed motion enters as the inputs δq_p,
    q̇_p, q̈_p through −M_fp q̈_p − D_fp q̇_p − K_fp δq_p; a backlash mesh is taken
    engaged). Its tip position — where the model starts (a static deflection differs
    between rungs) plus the linear response to the scene's own input programs over the
    whole run — is computed exactly in time (state-transition matrix e^{AΔt}, the inputs
    held over each output interval, the input jumps on the grid) and compared with the
    same of a converged reference, :data:`REFERENCE_MODES` modes per beam, whose own error
    is taken as the change from two fewer modes and added to every estimate; FEM on
    :data:`CROSS_CHECK_ELEMENTS` elements is reported beside it as an independent
    cross-check. The spatial estimate of a candidate is E_s = max_t |tip_c(t) − tip_ref(t)|
    + e_ref: truncated modes and mesh error together, weighted by how much the scene's
    inputs excite each mode — the excitation bandwidth enters through the input's own
    spectrum, and a frequency error shows as the phase drift it causes over this run's
    length, with no extrapolation in time. (Model reduction judged by the error of its
    input–output response: Antoulas, *Approximation of Large-Scale Dynamical Systems*,
    SIAM 2005, ch. 7; the static and dynamic error of mode truncation: Craig & Kurdila,
    *Fundamentals of Structural Dynamics*, 2nd ed. 2006, ch. 14.)

    The temporal estimate E_t(h) is the same linear candidate stepped by RK4 exactly as the
    integrator steps it (steps of h ending on every input jump, inputs at the stage times,
    outputs inside a step from the cubic Hermite dense output) against its exact response:
    RK4's global error on the linearized system over the whole run (the step-halving
    machinery of ``--tolerance``, :func:`~flexarm_ros.sim.accuracy.step_for_tolerance`,
    extrapolates a pilot window's error linearly in time; measured 10× conservative on
    link_tipmass over 3 s, where it would halve the step for nothing).

    A candidate is admissible when E_s ≤ :data:`SPATIAL_SHARE`·TOL; its step is its
    automatic (stable) step RK4_AUTO/|λ|max when E_t there is ≤ TOL − E_s, else the
    largest step that meets it (E_t ∝ h⁴, checked). Where E_t at the stable step leaves
    room, a step above it up to ABOVE_STABLE_SHARE of RK4's stability limit is taken if E_t
    evaluated there meets half the budget (``_above_stable``; no h⁴ law assumed above the
    stable step, where the highest modes leave RK4's asymptotic range). The candidate
    chosen is the admissible one of least predicted integration work: steps × a per-step
    cost fitted on this machine (:data:`COST_US`: µs per RK4 step ≈ 9 + 0.11·n·P, n
    coordinates, P mass points; within 20 % for modal 1/3/4/6, fem 2/4/6, fd 10 and cubic
    on link_tipmass).
    Families are walked upward in refinement and left once their predicted work at the
    largest step exceeds the best found (more modes or elements only cost more), so most
    candidates are never built. In a smooth scene without a wall every candidate is also
    stepped by integrator rkn4 (the same four right-hand sides per step, less error on the
    arms; :func:`~flexarm_ros.sim.step.rk4_step`) on its linear model, its stable step
    being the share of its own stability limit: where it meets the same budget at a longer
    step, or meets it where RK4 does not, the candidate takes rkn4 at that step
    (``_with_rkn4``; link_tipmass at 1e-5 m: 0.937 ms against RK4's 0.789; two_link_free
    at 1e-6 m: 5.8 against 4.6 ms), and the work compared between candidates is the one at
    that step: rung, refinement and integrator are chosen together (since session 16;
    before, the rung was chosen with RK4 and rkn4 tried on it). Other integrators are not
    candidates: the trapezoidal rule's step stays within the output period (above it the
    nonlinear rule diverged, docs/accuracy.md), and the adaptive methods cost 2–40× more
    at equal error on these models (docs/ladder.md).

Measured (link_tipmass, 3 s; linear estimate / nonlinear error against FEM 8):
rigid 3.6e-5 / 3.4e-5 m, cubic 6.4e-5 / 6.1e-5, modal 2 2.5e-5 / 1.2e-5, modal 3
4.4e-6 / 3.9e-6, modal 4 1.7e-6 / 9.6e-7: within 15 % or above (docs/accuracy.md has the
seed scenes against FEM with DOP853).

Where the linearization is blind: large motions change it (configuration-dependent inertia
of a two-link arm: the linear estimate of cubic on two_link_free over 2 s is 6.4e-7 m, the
nonlinear error 9.9e-7 m; centrifugal stiffening of a fast spin), the hydraulic orifice's
square root near the supply pressure, backlash (linearized engaged), and contact (with a
wall the free flight is analysed; the contact stepper keeps its own step, which auto does
not choose). The check after the run covers what the linearization misses: the run's
first window is run again one level finer (a candidate whose spatial estimate is at most
1/:data:`FINER_FACTOR` of the chosen one's, at half the step or its own stable step, the
shorter) and the observed difference,
extrapolated by the linear model's growth of the error with a margin, is the run's
reported estimate.

Not analysable: a scene whose arm only its controller moves (``control.mode`` position or
sanding without input programs): the excitation is unknown before the run, so auto is
refused there. In the ROS twin (``flexarm run``) and wherever a model is built from a scene
with rung auto (:class:`~flexarm_ros.model.chain.Chain`), auto chooses over the scene's
``duration``; the twin's plant steps on its own tick grid.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model.beams import MAX_ELASTIC_COORDINATES, elastic_coordinates
from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.model.differentiate import jacobian
from flexarm_ros.model.linear import (ABOVE_STABLE_SHARE, RK4_AUTO, RK4_STABILITY,
                                      grid_step, highest_rate, search_above_stable,
                                      smooth_rhs)
from flexarm_ros.model.programs import eval_motion, eval_torque, torque_breakpoints

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
#: µs per RK4 step ≈ COST_US[0] + COST_US[1]·n·P (n coordinates, P mass points), fitted on
#: this 2-core machine from the integration times of link_tipmass's rungs
COST_US = (9.0, 0.11)


def step_cost_us(chain) -> float:
    """Predicted µs per RK4 (or RKN4) step of ``chain``: COST_US[0] + COST_US[1]·n·P."""
    points = sum(len(lm.beam.x) for lm in chain.links)
    return COST_US[0] + COST_US[1] * chain.n * points


#: the check after the run: the first share of the run, at least WINDOW_MIN_S
WINDOW_FRACTION = 0.1
WINDOW_MIN_S = 0.1
#: torque-program codes that are constant between their breakpoints
_PIECEWISE_CONSTANT = (0, 1, 2, 3, 5)


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


def one_blas_thread():
    """A context with BLAS on one thread: the linear analyses here multiply and
    exponentiate matrices of a few to ~100 rows, where a threaded BLAS only makes its
    threads wait on each other (two_link_free's assessment 0.25–0.32 s threaded, 0.16–0.19 s
    on one thread, alternating in one run on 2 cores). A no-op without threadpoolctl."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:                   # a declared dependency; never fatal
        import contextlib
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def tolerance_of(fidelity) -> float:
    return fidelity.tolerance if fidelity.tolerance > 0 else DEFAULT_TOLERANCE_M


def choose(scene, duration=None, output_dt=None) -> AutoChoice:
    """The model and step for ``scene`` (rung auto) over ``duration`` (default: the scene's)
    with outputs every ``output_dt`` (default: a batch run's sample period, fidelity.output_dt
    or the sensors' common grid). Results are kept per process (the same scene, duration and
    grid: the same choice)."""
    from flexarm_ros.model.sensors import output_period
    T = scene.duration if duration is None else float(duration)
    out_dt = output_period(scene) if output_dt is None else float(output_dt)
    if not (T > 0 and math.isfinite(T)):
        raise SceneError(f"duration: got {T}, expected a finite number > 0 s (rung auto "
                         f"analyses the run's length)")
    try:
        hash(scene)
    except TypeError:                      # an unhashable scene (built by hand): no memo
        with one_blas_thread():
            return _Analysis(scene, T, out_dt).run()
    return _choose(scene, T, out_dt)


@functools.lru_cache(maxsize=16)
def _choose(scene, T, out_dt) -> AutoChoice:
    with one_blas_thread():
        return _Analysis(scene, T, out_dt).run()


def resolve(scene, duration=None, output_dt=None):
    """(scene with the chosen rung, refinement and step, AutoChoice) for rung auto; (scene,
    None) otherwise."""
    if scene.fidelity.rung != "auto":
        return scene, None
    choice = choose(scene, duration, output_dt)
    return scene.with_fidelity(**choice.fidelity_overrides()), choice


def assess(scene, duration=None, output_dt=None) -> AutoChoice:
    """``fidelity.estimate`` / ``flexarm simulate --estimate``: the error of the scene's
    own named rung and step over ``duration`` — the same a-priori analysis as rung auto
    (spatial against the converged linear reference, temporal of RK4 at the run's step)
    for that one model, and the plan of the same check after the run
    (:func:`~flexarm_ros.sim.accuracy.posterior_check`). The returned :class:`AutoChoice`
    holds that model (``tolerance_m`` is the scene's fidelity.tolerance, 0 when none)."""
    from flexarm_ros.model.sensors import output_period
    T = scene.duration if duration is None else float(duration)
    out_dt = output_period(scene) if output_dt is None else float(output_dt)
    with one_blas_thread():
        return _Analysis(scene, T, out_dt).assess()


def check_window(chain, T: float) -> float:
    """The window of the check after the run: the first WINDOW_FRACTION of the run (at
    least WINDOW_MIN_S); when nothing is driven before the first input jump (every program
    zero at the start, no prescribed motion), it reaches that far past the jump. With a
    wall, the whole run: an impact shifts the phase at once, which no growth of the free
    flight's error extrapolates (as the contact stepper's tolerance pilots, sim/accuracy)."""
    if chain.scene.walls:
        return T
    w = max(WINDOW_MIN_S, WINDOW_FRACTION * T)
    idle = not len(chain.presc_idx) and all(
        eval_torque(*a.enc, 1e-12) == 0.0 for a in chain.actuators)
    if idle:
        bps = sorted(b for a in chain.actuators for b in torque_breakpoints(a.program, T))
        if bps:
            w += bps[0]
    return min(T, w)


# ---------------------------------------------------------------------------- analysis
class _Linear:
    """The linearized chain: ẋ = A x + B u, tip = C_t q_free; u = the actuator programs and,
    for prescribed coordinates, (q_p − q_p(0), q̇_p, q̈_p)."""

    def __init__(self, chain, input_memo=None):
        from flexarm_ros.model.statespace import linearize
        self.chain = chain
        self.input_memo = input_memo     # shared by the candidates of one analysis
        ss = linearize(chain, outputs=False)
        free = chain.free
        nf = len(free)
        self.nf, self.ns = nf, ss.A.shape[0]
        self.A = ss.A
        x0 = ss.x0
        q0 = chain.full_state(0.0, x0)[0]
        # ∂tip/∂q_free: the last beam's tip frame at q0 (a prescribed coordinate moves every
        # candidate's tip alike, so its column cancels in the comparisons)
        J = chain.point_kinematics(q0, np.zeros(chain.n), len(chain.links) - 1, "tip",
                                   (0.0, 0.0))[1]
        self.Ct = J[:, free]                                    # (2, nf)
        # the tip where the model starts (a static deflection differs between rungs)
        self.tip0 = chain.tip_position(q0)
        B = ss.B
        presc = chain.presc_idx
        zero = np.zeros(chain.n)
        M = chain.kinematics(q0, zero).M
        Minv = np.linalg.inv(M[np.ix_(free, free)])
        for im, ij, b, k, c in chain.backlash:   # the mesh engaged (teeth apart at the start
            if abs(q0[im] - q0[ij]) > b:         # would decouple the drive from the link)
                continue
            dK = np.zeros((chain.n, chain.n))
            dK[np.ix_([im, ij], [im, ij])] = np.array([[1.0, -1.0], [-1.0, 1.0]])
            self.A[nf:2 * nf, :nf] -= Minv @ (k * dK)[np.ix_(free, free)]
            self.A[nf:2 * nf, nf:2 * nf] -= Minv @ (c * dK)[np.ix_(free, free)]
        if len(presc):
            if chain.has_gravity:
                def force(q):
                    kin = chain.kinematics(q, zero)
                    return kin.Qg - kin.h - chain.K @ q
                Kfp = -jacobian(force, q0, columns=presc)[free]
            else:
                Kfp = chain.K[np.ix_(free, presc)]
            Bp = np.zeros((self.ns, 3 * len(presc)))
            Bp[nf:2 * nf] = -Minv @ np.hstack([Kfp, chain.D[np.ix_(free, presc)],
                                               M[np.ix_(free, presc)]])
            B = np.hstack([B, Bp])
            self.q_p0 = q0[presc]
        self.B = B
        self.m = B.shape[1]
        self.acts = [a.enc for a in chain.actuators]
        self.motions = list(chain._motion_enc)
        self.constant_inside = (not self.motions
                                and all(e[0] in _PIECEWISE_CONSTANT for e in self.acts))
        rate = highest_rate(chain, q0, chain.full_state(0.0, x0)[1], x0[2 * nf:])
        self.rate = rate
        self.x0 = x0
        self.method = "rk4"
        self.nq = 0             # Nyström positions of the step (rkn4: the free coordinates)
        self.stable_step = RK4_AUTO / rate if rate > 0 else math.inf
        self.limit = RK4_STABILITY / rate if rate > 0 else math.inf
        self.cost_us = step_cost_us(chain)
        self._maps: dict = {}

    def use(self, method: str) -> None:
        """Step the candidate with ``method`` (rk4 or rkn4) from now on: its stable step
        and stability limit as the run's :func:`~flexarm_ros.sim.step.stability` gives
        them, and :meth:`rk4`'s maps with Nyström's positions for rkn4."""
        if method == self.method:
            return
        from flexarm_ros.model.explicit import stability
        q, qd = self.chain.full_state(0.0, self.x0)
        rate, self.limit, auto = stability(self.chain, q, qd, self.x0[2 * self.nf:], method)
        self.stable_step = auto if rate > 0 else math.inf
        self.method = method
        self.nq = self.nf if method == "rkn4" else 0

    def inputs(self, times, bps=()) -> np.ndarray:
        """u at ``times`` (N, m). A program constant between the breakpoints ``bps`` (a
        piecewise-constant one, given its breakpoints) is evaluated once per piece."""
        times = np.asarray(times, float)
        key = (len(times), float(times[0]) if len(times) else 0.0,
               float(times[-1]) if len(times) else 0.0, hash(times.tobytes()), tuple(bps))
        if self.input_memo is not None and key in self.input_memo:
            return self.input_memo[key]      # every candidate has the scene's programs
        U = np.empty((len(times), self.m))
        na = len(self.acts)
        edges = np.unique(np.concatenate([[0.0], np.asarray(bps, float)]))
        last = max(edges[-1], float(times.max())) if len(times) else edges[-1]
        mids = np.append(0.5 * (edges[:-1] + edges[1:]), last)   # no jump past the last
        piece = np.searchsorted(edges, times, side="right") - 1
        for j, (code, p, ts, vs) in enumerate(self.acts):
            if code in _PIECEWISE_CONSTANT and len(bps):
                U[:, j] = np.array([eval_torque(code, p, ts, vs, t) for t in mids])[piece]
            elif code == 0:
                U[:, j] = p[0]
            else:
                U[:, j] = [eval_torque(code, p, ts, vs, t) for t in times]
        for j, (code, p, _, _) in enumerate(self.motions):
            mv = np.array([eval_motion(code, p, t) for t in times])
            k = len(self.motions)
            U[:, na + j] = mv[:, 0] - self.q_p0[j]
            U[:, na + k + j] = mv[:, 1]
            U[:, na + 2 * k + j] = mv[:, 2]
        if self.input_memo is not None:
            self.input_memo[key] = U
        return U

    def tip(self, X) -> np.ndarray:
        return self.tip0 + X[:, :self.nf] @ self.Ct.T

    def exact(self, grid, bps=()) -> np.ndarray:
        """Tip deviation (len(grid), 2) with the inputs held at their value in the middle
        of each interval (exact for piecewise-constant programs jumping on the grid)."""
        from scipy.linalg import expm
        d = np.diff(grid)
        U = self.inputs(grid[:-1] + 0.5 * d, bps)
        keys = np.round(d, 15)
        maps, G = {}, np.empty((len(d), self.ns))
        for key in np.unique(keys):
            E = np.zeros((self.ns + self.m, self.ns + self.m))
            E[:self.ns, :self.ns] = self.A * key
            E[:self.ns, self.ns:] = self.B * key
            E = expm(E)
            maps[key] = E[:self.ns, :self.ns]
            sel = keys == key
            G[sel] = U[sel] @ E[:self.ns, self.ns:].T
        return self.tip(_recur(maps, keys, G, self.ns))

    def rk4(self, h, grid, bps) -> np.ndarray:
        """Tip deviation on ``grid`` of RK4 (RKN4 after :meth:`use`) at step h as the
        integrator steps: steps end on every breakpoint in ``bps`` (and the end), inputs at
        the stage times (the first and last ε inside the step), outputs inside a step by
        the cubic Hermite dense output."""
        T = grid[-1]
        eps_t = 1e-12 * max(1.0, T)
        starts, lens = [], []
        t = 0.0
        for b in sorted(set(bps) | {T}):
            if b <= t + eps_t:
                continue
            n = int(math.floor((b - t) / h + 1e-9))
            if n:
                starts.append(t + h * np.arange(n))
                lens.append(np.full(n, h))
            t_full = t + n * h
            if b - t_full > eps_t:
                starts.append(np.array([t_full]))
                lens.append(np.array([b - t_full]))
            t = b
        ts, hs = np.concatenate(starts), np.concatenate(lens)
        keys = np.round(hs, 15)
        uniq = np.unique(keys)
        maps = {k: self._rk4_maps(k) for k in uniq}
        if self.constant_inside:
            U = self.inputs(ts + 0.5 * hs, bps)
            G = {k: maps[k][1] + maps[k][2] + maps[k][3] for k in uniq}
            GU = np.empty((len(ts), self.ns))
            for k in uniq:
                sel = keys == k
                GU[sel] = U[sel] @ G[k].T
        else:
            U1 = self.inputs(ts + STAGE_EPS * hs)
            U2 = self.inputs(ts + 0.5 * hs)
            U4 = self.inputs(ts + (1.0 - STAGE_EPS) * hs)
            GU = np.empty((len(ts), self.ns))
            for k in uniq:
                sel = keys == k
                _, G1, G2, G4 = maps[k]
                GU[sel] = U1[sel] @ G1.T + U2[sel] @ G2.T + U4[sel] @ G4.T
        X = _recur({k: maps[k][0] for k in uniq}, keys, GU, self.ns)
        Y = self.tip(X)
        Yd = X[:, self.nf:2 * self.nf] @ self.Ct.T
        ends = np.append(ts, T)
        j = np.clip(np.searchsorted(ends, grid, side="right") - 1, 0, len(ts) - 1)
        hj = hs[j]
        th = np.clip((grid - ts[j]) / hj, 0.0, 1.0)[:, None]
        t2, t3 = th * th, th ** 3
        return ((2 * t3 - 3 * t2 + 1) * Y[j] + (t3 - 2 * t2 + th) * hj[:, None] * Yd[j]
                + (3 * t2 - 2 * t3) * Y[j + 1] + (t3 - t2) * hj[:, None] * Yd[j + 1])

    def trapezoid(self, h, T) -> np.ndarray:
        """Tip deviation at the ends of the steps of the implicit trapezoidal rule at step h
        over [0, T] (T a multiple of h), as the compiled loop steps it (Newmark average
        acceleration = the trapezoidal rule on ẋ = Ax + Bu): x₁ = (I − hA/2)⁻¹[(I + hA/2)x₀
        + h/2·B(u_a + u_b)], the input at the first stage just inside the step (its right
        limit at a jump on the step grid) and at the last one just before its end."""
        n = int(round(T / h))
        ts = np.arange(n) * h
        L = np.eye(self.ns) - 0.5 * h * self.A
        P = np.linalg.solve(L, np.eye(self.ns) + 0.5 * h * self.A)
        Q = np.linalg.solve(L, 0.5 * h * self.B)
        U = self.inputs(ts + STAGE_EPS * h) + self.inputs(ts + (1.0 - STAGE_EPS) * h)
        return self.tip(_recur({h: P}, np.full(n, h), U @ Q.T, self.ns))

    def _rk4_maps(self, h):
        """The step's maps x₁ = P x₀ + G₁u₁ + G₂u₂ + G₄u₄ (inputs at the stage times), by
        the step of :func:`~flexarm_ros.sim.step.rk4_step` itself (its ``nq`` Nyström
        positions with rkn4) on ẋ = A x + B u."""
        from flexarm_ros.model.explicit import rk4_step
        A, B, ns, m, nq = self.A, self.B, self.ns, self.m, self.nq

        def step(x, u1, u2, u4):      # the stages at εh, h/2, h/2, (1 − ε)h
            return rk4_step(lambda t, y: A @ y + B @ (u1 if t < 0.25 * h else
                                                      u2 if t < 0.75 * h else u4),
                            0.0, x, h, nq=nq)
        I, Zx, Zu, Im = np.eye(ns), np.zeros((ns, m)), np.zeros((m, m)), np.eye(m)
        Zs = np.zeros((m, ns))
        return (step(I, Zs, Zs, Zs), step(Zx, Im, Zu, Zu), step(Zx, Zu, Im, Zu),
                step(Zx, Zu, Zu, Im))


class _Analysis:
    def __init__(self, scene, T, out_dt):
        self.scene = scene
        self.fid = scene.fidelity
        self.input_memo: dict = {}
        self.T = T
        self.out_dt = out_dt
        self.tol = tolerance_of(self.fid)
        self.wall = bool(scene.walls)
        self.n_beams = len(scene.links)
        dt = max(out_dt, T / MAX_LINEAR_SAMPLES)
        n = int(math.floor(T / dt + 1e-9))
        grid = np.arange(n + 1) * dt
        self.bps = sorted({b for inp in scene.inputs if inp.motion is None
                           for b in torque_breakpoints(inp.program, T)})
        self.grid = np.unique(np.concatenate([grid, self.bps, [T]]))
        self.grid = self.grid[np.concatenate([[True], np.diff(self.grid) > 1e-12 * T])]

    def _scene(self, rung, refine):
        fid = dataclasses.replace(self.fid, rung=rung, refine=refine, tolerance=0.0)
        return dataclasses.replace(self.scene, fidelity=fid)

    def _chain(self, rung, refine):
        from flexarm_ros.model.chain import Chain
        return Chain(self._scene(rung, refine))

    def _memo_chain(self, rung, refine):
        return self._chain(rung, refine), self.input_memo

    def _fits(self, rung, refine) -> bool:
        return elastic_coordinates(rung, refine) * self.n_beams <= MAX_ELASTIC_COORDINATES

    def _reference(self, key="fidelity.rung", got="'auto'"):
        """The converged linear reference (y_ref, its own error e_ref, the FEM cross-check);
        SceneError for a scene only its controller moves (``key``/``got`` name the setting
        that asked for the analysis)."""
        nm = REFERENCE_MODES
        while not self._fits("modal", nm) and nm > 4:
            nm -= 2
        y = {n: _Linear(*self._memo_chain("modal", n)).exact(self.grid, self.bps)
             for n in (nm - 2, nm)}
        self.y_ref = y[nm]
        # its own error: the last refinement's change (the modal sequence converges fast:
        # measured 4e-9 … 3e-7 m between 10 and 12 modes on the seed scenes)
        self.e_ref = float(np.max(np.linalg.norm(y[nm] - y[nm - 2], axis=1)))
        self.reference = f"modal {nm} (linear)"
        # an independent cross-check (reported, not added): FEM on CROSS_CHECK_ELEMENTS
        self.cross_check = None
        if self._fits("fem", CROSS_CHECK_ELEMENTS):
            fem = _Linear(*self._memo_chain("fem", CROSS_CHECK_ELEMENTS))
            yf = fem.exact(self.grid, self.bps)
            self.cross_check = float(np.max(np.linalg.norm(yf - self.y_ref, axis=1)))
        mode = self.scene.twin_control.mode
        if mode != "open_loop" and not np.any(self.y_ref != self.y_ref[0]):
            raise SceneError(
                f"{key}: got {got} for a scene whose arm only its controller moves "
                f"(control.mode {mode!r}, no input program moves it), expected "
                + ("a named rung: auto weighs the candidates" if key == "fidelity.rung"
                   else "it off: the estimate weighs the model's error")
                + " by the response to the scene's input programs, "
                f"and the controller's commands are known only during the run")

    def run(self) -> AutoChoice:
        t0 = time.perf_counter()
        self._reference()
        budget_s = SPATIAL_SHARE * self.tol
        best = None
        cands: list[Candidate] = []
        analysed: dict = {}
        for rung, refines in LADDER:
            for n in refines:
                if not self._fits(rung, n):
                    break
                c, lin = self._candidate(rung, n, best)
                cands.append(c)
                if lin is None:
                    break                     # pruned or refused: the rest cost more
                analysed[(rung, n)] = (c, lin)
                if c.spatial_m <= budget_s:
                    if c.verdict.startswith("admissible") and (best is None
                                                      or c.work_s < best[0].work_s):
                        best = (c, lin)
                    break
        if best is None:
            finest = min((c for c in cands if not math.isnan(c.spatial_m)),
                         key=lambda c: c.spatial_m, default=None)
            got = (f"; the best estimated: {finest.label}, {finest.spatial_m:.2g} m"
                   if finest else "")
            if 2 * self.e_ref > budget_s:
                got += (f"; the linear reference's own error {self.e_ref:.2g} m limits what "
                        f"can be certified here")
            raise SceneError(f"fidelity.tolerance: got {self.tol:g} m with fidelity.rung "
                             f"'auto', expected a tolerance some rung of the ladder is "
                             f"estimated to meet (spatial error <= {SPATIAL_SHARE:g} TOL"
                             f"{got}); loosen it or name a rung")
        chosen, lin = best
        for c in cands:
            if c is chosen:
                c.verdict = "chosen: the least work meeting the tolerance" + c.rkn4_note
            elif c.verdict.startswith("admissible"):
                c.verdict = f"admissible, more work than {chosen.label}" + c.rkn4_note
        integrator = chosen.integrator
        finer = self._finer(chosen, analysed, cands)
        window = check_window(lin.chain, self.T)
        growth = self._growth(lin, chosen, window)
        dt_request = 0.0 if chosen.step_s == self._auto_step(lin) else chosen.step_s
        return AutoChoice(
            tolerance_m=self.tol, tolerance_given=self.fid.tolerance > 0, duration_s=self.T,
            rung=chosen.rung, refine=chosen.refine, step_s=chosen.step_s,
            dt_request=dt_request, spatial_m=chosen.spatial_m,
            temporal_m=math.nan if self.wall else chosen.temporal_m, candidates=cands,
            reference=self.reference, reference_error_m=self.e_ref,
            cross_check_m=self.cross_check,
            finer=None if finer is None else (finer[0].rung, finer[0].refine,
                                              finer[1].stable_step, finer[0].spatial_m),
            window_s=window, growth=growth, wall=self.wall,
            analysis_s=time.perf_counter() - t0, integrator=integrator)

    def _with_rkn4(self, c, lin, budget_t) -> tuple[float, float] | None:
        """(step, E_t) of integrator rkn4 on candidate ``c`` where it meets the temporal
        budget TOL − E_s at a longer step than RK4 (``c.step_s``), or meets it where RK4
        does not; else None (``lin`` left on RK4). RKN4 costs what RK4 costs per step (the
        same four right-hand sides) and errs less on the arms (docs/accuracy.md,
        *Integrator rkn4*), so the larger step is the cheaper run. Its stable step (the
        share of its own stability limit, at most RK4's) must meet the budget, else it is
        shortened as RK4's is (E_t ∝ h⁴, checked); above it, as for RK4, half the budget
        evaluated there."""
        rk4_met = c.temporal_m <= budget_t
        kept = (getattr(lin, "y_rk4", None), getattr(lin, "h_rk4", None))
        lin.use("rkn4")
        h = grid_step(lin.stable_step, self.out_dt, True)
        e = self._temporal(lin, h)
        if e <= budget_t:
            h, e = self._above_stable(lin, h, e, 0.5 * budget_t)
        elif not rk4_met:
            h, e = self._shortened(lin, h, e, budget_t, True)
        if e <= budget_t and (not rk4_met or h > c.step_s * (1 + 1e-9)):
            return h, e
        lin.use("rk4")
        lin.y_rk4, lin.h_rk4 = kept         # RK4's response at its step: the check's growth
        return None

    def assess(self) -> AutoChoice:
        """The scene's own (named) rung judged as auto judges a candidate, at the step the
        run takes: spatial and temporal estimates, the finer model and window of the check
        after the run, the growth (:func:`assess`)."""
        t0 = time.perf_counter()
        fid = self.fid
        if fid.integrator not in ("rk4", "rkn4"):
            raise SceneError(
                f"fidelity.estimate: got true with integrator {fid.integrator!r}, expected "
                f"rk4 or rkn4 (the temporal estimate follows their steps; the adaptive "
                f"integrators "
                f"hold their own error to --rtol/--atol, and the trapezoid's step gets its "
                f"estimate from --tolerance, docs/accuracy.md)")
        self._reference("fidelity.estimate", "true")
        rung = fid.rung
        chain = self._chain(rung, fid.refine)
        lin = _Linear(chain, self.input_memo)
        if not self.wall:                   # the contact stepper steps RK4
            lin.use(fid.integrator)
        n = chain.links[0].beam.refine      # as the run summary names it (cubic: 1)
        c = Candidate(rung, n, coordinates=chain.n, stable_step_s=lin.stable_step)
        dense = not self.wall and smooth_rhs(chain)
        h = grid_step(fid.dt, self.out_dt, dense) if fid.dt > 0 else self._auto_step(lin)
        c.take_step(h, self.T, lin.cost_us)
        lin.y_exact = lin.exact(self.grid, self.bps)
        c.spatial_m = float(np.max(np.linalg.norm(lin.y_exact - self.y_ref, axis=1))) + \
            self.e_ref
        if not self.wall:
            c.temporal_m = self._temporal(lin, h)
        c.verdict = "the scene's model, assessed"
        cands = [c]
        finer = self._finer(c, {(rung, n): (c, lin)}, cands)
        window = check_window(chain, self.T)
        return AutoChoice(
            tolerance_m=fid.tolerance, tolerance_given=fid.tolerance > 0, duration_s=self.T,
            rung=rung, refine=n, step_s=h, dt_request=fid.dt, spatial_m=c.spatial_m,
            temporal_m=math.nan if self.wall else c.temporal_m, candidates=cands,
            reference=self.reference, reference_error_m=self.e_ref,
            cross_check_m=self.cross_check,
            finer=None if finer is None else (finer[0].rung, finer[0].refine,
                                              finer[1].stable_step, finer[0].spatial_m),
            window_s=window, growth=self._growth(lin, c, window), wall=self.wall,
            analysis_s=time.perf_counter() - t0)

    def _auto_step(self, lin) -> float:
        """The step the integrator takes at dt = 0 (dense output without a wall for a
        smooth model, else a divisor of the output period)."""
        from flexarm_ros.model.contact import build_contact, constrained_rate
        h = lin.stable_step if math.isfinite(lin.stable_step) else self.out_dt
        dense = not self.wall and smooth_rhs(lin.chain)
        h = grid_step(h, self.out_dt, dense)
        if self.wall:
            contact = build_contact(lin.chain)
            if contact.method == "impulse":
                from flexarm_ros.model.statics import initial_x
                x0 = initial_x(lin.chain)
                h = grid_step(min(h, RK4_AUTO / constrained_rate(contact, x0)),
                               self.out_dt, False)
        return h

    def _candidate(self, rung, n, best):
        c = Candidate(rung, n)
        try:
            chain = self._chain(rung, n)
        except SceneError as exc:
            c.verdict = f"refused: {exc}"
            return c, None
        c.coordinates = chain.n
        try:
            lin = _Linear(chain, self.input_memo)
        except SceneError as exc:
            c.verdict = f"refused: {exc}"
            return c, None
        c.stable_step_s = lin.stable_step
        dense = not self.wall and smooth_rhs(chain)
        if self.fid.dt > 0:
            if self.fid.dt > lin.limit:
                c.verdict = (f"refused: fidelity.dt {self.fid.dt:g} s above its RK4 stability "
                             f"limit {lin.limit:.3g} s")
                return c, None
            h = grid_step(self.fid.dt, self.out_dt, dense)
        else:
            h = self._auto_step(lin)
        c.take_step(h, self.T, lin.cost_us)
        least = c.work_s         # the least work it could take: at its largest step
        if self.fid.dt == 0 and dense:
            if math.isfinite(lin.limit):
                # rkn4's limit is up to RKN4_LIMIT_RATIO × RK4's (the damping of a mode)
                longest = ABOVE_STABLE_SHARE * lin.limit * (
                    RKN4_LIMIT_RATIO if self._rkn4_allowed(dense) else 1.0)
                least = min(least, math.ceil(self.T / longest - 1e-9) * lin.cost_us * 1e-6)
        if best is not None and least >= best[0].work_s:
            c.verdict = f"pruned: more work at its largest step than {best[0].label}"
            return c, None
        y = lin.exact(self.grid, self.bps)
        lin.y_exact = y
        c.spatial_m = float(np.max(np.linalg.norm(y - self.y_ref, axis=1))) + self.e_ref
        if c.spatial_m > SPATIAL_SHARE * self.tol:
            c.verdict = f"spatial estimate above {SPATIAL_SHARE:g} TOL"
            return c, lin
        if self.wall:
            c.verdict = "admissible"
            return c, lin
        budget_t = self.tol - c.spatial_m
        c.temporal_m = self._temporal(lin, h)
        if c.temporal_m > budget_t and self.fid.dt == 0:
            h, c.temporal_m = self._shortened(lin, h, c.temporal_m, budget_t, dense)
            c.take_step(h, self.T, lin.cost_us)
        elif self.fid.dt == 0 and dense and c.temporal_m <= budget_t:
            # above the stable step at half the budget (as --tolerance aims at half TOL):
            # the check after the run doubles its observed difference
            # (POSTERIOR_SAFETY), and at the full budget it flagged runs that met TOL
            h, c.temporal_m = self._above_stable(lin, h, c.temporal_m, 0.5 * budget_t)
            c.take_step(h, self.T, lin.cost_us)
        got = self._with_rkn4(c, lin, budget_t) if self._rkn4_allowed(dense) else None
        if got is not None:
            rk4 = (f"rk4's step {c.step_s:.3g} s" if c.temporal_m <= budget_t
                   else "rk4 misses it")
            c.take_step(got[0], self.T, lin.cost_us)
            c.temporal_m = got[1]
            c.stable_step_s = lin.stable_step
            c.integrator = "rkn4"
            c.rkn4_note = (f"; rkn4 at {got[0]:.3g} s ({rk4}: the same tolerance"
                           + (", fewer steps)" if rk4.startswith("rk4's") else ")"))
            c.verdict = "admissible" + c.rkn4_note
            return c, lin
        if c.temporal_m > budget_t:
            c.verdict = f"temporal estimate above TOL - spatial at {h:.3g} s"
            c.work_s = math.inf
            return c, lin
        c.verdict = "admissible"
        return c, lin

    def _shortened(self, lin, h, e_h, budget, dense) -> tuple[float, float]:
        """(step, E_t) below h, whose E_t e_h misses ``budget``: E_t ∝ h⁴ gives the next
        step (with a 0.9 margin), checked on the linear candidate, at most four times."""
        for _ in range(4):
            h = grid_step(h * 0.9 * (budget / e_h) ** 0.25, self.out_dt, dense)
            e_h = self._temporal(lin, h)
            if e_h <= budget:
                break
        return h, e_h

    def _rkn4_allowed(self, dense) -> bool:
        """Auto may step a candidate by rkn4: a scene that leaves it the integrator
        (fidelity.integrator rk4, the default, and no fidelity.dt), without a wall (the
        contact stepper is RK4's), with a smooth model (dense output)."""
        return (dense and not self.wall and self.fid.dt == 0
                and self.fid.integrator == "rk4")

    def _above_stable(self, lin, h, e_h, budget) -> tuple[float, float]:
        """(step, E_t) above the stable step h where the temporal budget allows it, up to
        ABOVE_STABLE_SHARE of the stability limit; else (h, e_h). E_t is RK4 on the linear
        candidate itself, no asymptotic law assumed: a candidate step is taken only as
        evaluated there (the first from E_t ∝ h⁴ with a 0.9 margin, a second where the
        log-log line through the two evaluated steps meets the budget)."""
        cap = ABOVE_STABLE_SHARE * lin.limit
        if not math.isfinite(cap) or cap <= 1.05 * h:
            return h, e_h
        kept = (lin.y_rk4, lin.h_rk4)      # RK4's response at h: the check's growth uses it
        first = cap if e_h <= 0.0 else min(cap, h * (0.9 * budget / e_h) ** 0.25)
        got = search_above_stable(h, first, (h, e_h), budget, 0.9 * budget,
                                  lambda h_c: (h_c, self._temporal(lin, h_c)))
        if got is not None:
            return got
        lin.y_rk4, lin.h_rk4 = kept
        return h, e_h

    def _temporal(self, lin, h) -> float:
        """RK4's error at step h on the linear candidate; past MAX_RK4_STEPS steps over the
        first MAX_RK4_STEPS·h of the run, scaled linearly in time to the whole run."""
        n = self.grid[-1] / h
        if n <= MAX_RK4_STEPS:
            y = lin.rk4(h, self.grid, self.bps)
            lin.y_rk4, lin.h_rk4 = y, h
            return float(np.max(np.linalg.norm(y - lin.y_exact, axis=1)))
        T_used = MAX_RK4_STEPS * h
        k = int(np.searchsorted(self.grid, T_used, side="right"))
        grid = self.grid[:k]
        y = lin.rk4(h, grid, [b for b in self.bps if b < grid[-1]])
        e = float(np.max(np.linalg.norm(y - lin.y_exact[:k], axis=1)))
        return e * self.grid[-1] / grid[-1]

    def _finer(self, chosen, analysed, cands):
        """The cheapest analysed candidate whose spatial estimate is at most
        1/FINER_FACTOR of the chosen's, analysing up to FINER_TRIES more up the chosen's
        family, then the modal family, when none is; failing that the most accurate one
        analysed (None when none is more accurate than the chosen)."""
        target = max(chosen.spatial_m / FINER_FACTOR, 2 * self.e_ref)

        def work(cl):
            c, lin = cl
            return c.work_s if math.isfinite(c.work_s) else \
                lin.cost_us * self.T / lin.stable_step

        def pick():
            ok = [cl for cl in analysed.values()
                  if cl[0] is not chosen and cl[0].spatial_m <= target]
            return min(ok, key=work, default=None)
        got = pick()
        families = [f for f in LADDER if f[0] == chosen.rung] + [f for f in LADDER
                                                                 if f[0] == "modal"]
        tries = 0
        for rung, refines in families:
            for n in refines:
                if got is not None or tries >= FINER_TRIES:
                    break
                if (rung, n) in analysed or (rung == chosen.rung and n <= chosen.refine):
                    continue
                if not self._fits(rung, n):
                    break
                tries += 1
                try:
                    lin = _Linear(*self._memo_chain(rung, n))
                except SceneError:
                    break
                y = lin.exact(self.grid, self.bps)
                lin.y_exact = y
                c = Candidate(rung, n, coordinates=lin.chain.n, stable_step_s=lin.stable_step)
                c.spatial_m = float(np.max(np.linalg.norm(y - self.y_ref, axis=1))) + \
                    self.e_ref
                c.verdict = "analysed for the check after the run"
                cands.append(c)
                analysed[(rung, n)] = (c, lin)
                got = pick()
        if got is None:         # the most accurate analysed, if better than the chosen
            better = [cl for cl in analysed.values() if cl[0] is not chosen
                      and cl[0].spatial_m < chosen.spatial_m]
            got = min(better, key=lambda cl: cl[0].spatial_m, default=None)
        if got is not None:
            got[0].verdict = (got[0].verdict + "; " if got[0].verdict else "") + \
                "the check's finer model"
        return got

    def _growth(self, lin, chosen, window) -> float:
        """max over the run / max over the window of the linear model's tip error (RK4 at
        the chosen step against the reference; spatial alone with a wall); 1 when the
        window is the run."""
        if window >= self.T * (1 - 1e-12):
            return 1.0
        y = lin.y_exact if self.wall or not hasattr(lin, "y_rk4") else lin.y_rk4
        e = np.linalg.norm(y - self.y_ref, axis=1)
        inside = self.grid <= window + 1e-12
        e_w = float(np.max(e[inside]))
        e_all = float(np.max(e))
        if e_w <= 1e-3 * e_all or e_w == 0.0:
            return self.T / window
        return max(1.0, e_all / e_w)



#: steps per block of :func:`_recur`
_BLOCK = 32


def _recur(maps, keys, G, ns) -> np.ndarray:
    """States x_0 = 0, x_{k+1} = P[keys[k]] x_k + G[k] (N + 1, ns). A run of steps with the
    same map and the same forcing (a constant input) is advanced in blocks: x_{s+j} =
    P^j x_s + (I + P + … + P^{j−1}) g, with the powers precomputed per map."""
    N = len(keys)
    X = np.empty((N + 1, ns))
    X[0] = 0.0
    if N == 0:
        return X
    change = np.ones(N, bool)
    change[1:] = (keys[1:] != keys[:-1]) | np.any(G[1:] != G[:-1], axis=1)
    starts = np.flatnonzero(change)
    ends = np.append(starts[1:], N)
    powers: dict = {}
    for s0, e0 in zip(starts, ends):
        P = maps[keys[s0]]
        g = G[s0]
        if e0 - s0 < 4:                     # short runs (steps cut at a jump, smooth inputs)
            x = X[s0]
            for k in range(s0, e0):
                x = P @ x + G[k]
                X[k + 1] = x
            continue
        if keys[s0] not in powers:
            Pj = np.empty((_BLOCK, ns, ns))     # P^1 … P^B
            Sj = np.empty((_BLOCK, ns, ns))     # I + P + … + P^{j−1}, j = 1 … B
            Pj[0], Sj[0] = P, np.eye(ns)
            for j in range(1, _BLOCK):
                Pj[j] = P @ Pj[j - 1]
                Sj[j] = Sj[j - 1] + Pj[j - 1]
            powers[keys[s0]] = (Pj, Sj)
        Pj, Sj = powers[keys[s0]]
        k = s0
        while k < e0:
            L = min(_BLOCK, e0 - k)
            X[k + 1:k + 1 + L] = Pj[:L] @ X[k] + Sj[:L] @ g
            k += L
    return X
