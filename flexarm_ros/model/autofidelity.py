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

Where the code is (this module gathers their public names):
:mod:`~flexarm_ros.model.auto_search` the search (:func:`choose`, :func:`resolve`,
:func:`assess`, the candidates' estimates), :mod:`~flexarm_ros.model.linear_response` the
linear responses it compares (:class:`LinearResponse`, :func:`step_cost_us`),
:mod:`~flexarm_ros.model.auto_choice` the settings above and the record of a choice with
its report (:class:`AutoChoice`, :meth:`AutoChoice.explain`).
"""

from flexarm_ros.model.auto_choice import (CROSS_CHECK_ELEMENTS, DEFAULT_TOLERANCE_M,
                                           FINER_FACTOR, FINER_TRIES, LADDER,
                                           MAX_LINEAR_SAMPLES, MAX_RK4_STEPS,
                                           REFERENCE_MODES, RKN4_LIMIT_RATIO, SPATIAL_SHARE,
                                           WINDOW_FRACTION, WINDOW_MIN_S, AutoChoice,
                                           Candidate, tolerance_of)
from flexarm_ros.model.auto_search import assess, check_window, choose, resolve
from flexarm_ros.model.linear_response import (COST_US, LinearResponse, one_blas_thread,
                                               step_cost_us)

__all__ = ["AutoChoice", "COST_US", "CROSS_CHECK_ELEMENTS", "Candidate",
           "DEFAULT_TOLERANCE_M", "FINER_FACTOR", "FINER_TRIES", "LADDER", "LinearResponse",
           "MAX_LINEAR_SAMPLES", "MAX_RK4_STEPS", "REFERENCE_MODES", "RKN4_LIMIT_RATIO",
           "SPATIAL_SHARE", "WINDOW_FRACTION", "WINDOW_MIN_S", "assess", "check_window",
           "choose", "one_blas_thread", "resolve", "step_cost_us", "tolerance_of"]
