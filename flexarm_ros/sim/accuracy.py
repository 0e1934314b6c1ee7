"""The RK4 step for a tip-position tolerance: ``fidelity.tolerance`` / ``--tolerance``.

The user states the error in the quantity users think in, metres of tip position; the
step is chosen so that the estimated global tip error of the run stays below it.

Method (Richardson's step-halving estimate of the global error, Hairer, Nørsett & Wanner,
*Solving ODEs I*, Sec. II.4): RK4's global error at time t behaves as e(t) ≈ C(t)·h⁴.
Two pilot runs over a window [0, T_w] at the steps h₁ and h₂ ≈ h₁/2 give the tip error
of the coarser one as E₁ ≈ max|tip(h₁) − tip(h₂)| / (1 − (h₂/h₁)⁴) (16/15 at h₁/2). For an oscillating arm the phase
error, which dominates, grows linearly with time, so the run of length T at step h is
estimated at E(h) = E₁·(h/h₁)⁴·T/T_w. The step is the largest with E(h) ≤ SAFETY·TOL,
never above the stable automatic step RK4_AUTO/|λ|max. The outputs, sampled inside steps
by the cubic Hermite dense output (third order, like the step), are part of what the pilot
runs compare, so the estimate covers them too.

The window starts at 0 and, when an input jumps during the run (a step, a pulse), reaches
past the first jump by the same length: a window before any input would see nothing move
(measured: hydraulic_2kg, valve step at 0.5 s, estimated 0 m, actual 5.6e-7 m).

Scope: RK4 without a wall (the contact stepper's events are not covered by the estimate;
a scene with a wall keeps its step). The estimate is reported in the run summary
(``estimated_tip_error_m``) and checked against a converged reference in
``test/test_accuracy.py`` for two seed scenes at TOL = 1e-3, 1e-5 and 1e-7 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.model.linear import highest_rate
from flexarm_ros.sim.step import RK4_AUTO

SAFETY = 0.5            # the estimate aims at half the tolerance
WINDOW_FRACTION = 0.1   # the pilot window: this share of the run ...
WINDOW_MIN_S = 0.1      # ... but at least this long (or the whole run)
MIN_STEP_S = 1e-7       # below this the tolerance is refused as unreachable


@dataclass(frozen=True)
class StepChoice:
    """The chosen step and what it rests on."""
    step_s: float
    estimated_tip_error_m: float
    tolerance_m: float
    pilot_step_s: float
    pilot_window_s: float
    pilot_error_m: float        # E₁: the pilot's tip error at its coarse step
    stable_step_s: float        # RK4_AUTO / |λ|max: the ceiling

    def explain(self) -> str:
        return (f"step {self.step_s:.4g} s for a tip tolerance of {self.tolerance_m:.3g} m "
                f"(estimated {self.estimated_tip_error_m:.3g} m: pilot runs over "
                f"{self.pilot_window_s:.3g} s at {self.pilot_step_s:.4g} s and about half of it "
                f"give {self.pilot_error_m:.3g} m at the coarse step; stable ceiling "
                f"{self.stable_step_s:.4g} s)")


def tip_history(chain, x0, t_end, h, output_dt, max_ratio) -> tuple[np.ndarray, float]:
    """(N, 2) tip positions on the output grid of an RK4 run asked for step h, and the
    step it took (shortened to divide the output period when below it)."""
    from flexarm_ros.sim.integrate import integrate
    run = integrate(chain, x0, t_end, "rk4", h, output_dt=output_dt,
                    max_deflection_ratio=max_ratio)
    return np.array([chain.tip_position(q) for q in run.q]), run.dt


def step_for_tolerance(chain, x0, t_end: float, tol: float, output_dt: float,
                       max_ratio: float = 0.5) -> StepChoice:
    """The RK4 step meeting the tip tolerance ``tol`` (m) over a run of ``t_end`` s."""
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise SceneError(f"fidelity.tolerance: got {tol!r}, expected a tip-position error "
                         f"bound > 0 m")
    q, qd = chain.full_state(0.0, x0)
    rate = highest_rate(chain, q, qd, x0[2 * len(chain.free):])
    h_stable = RK4_AUTO / rate if rate > 0 else output_dt
    window = max(WINDOW_MIN_S, WINDOW_FRACTION * t_end)
    from flexarm_ros.sim.integrate import input_breakpoints
    jumps = input_breakpoints(chain, t_end)[:-1]
    if jumps:                   # the response to the first input jump is in the window
        window += jumps[0]
    window = min(t_end, window)
    h1 = h_stable / 2
    coarse, h1 = tip_history(chain, x0, window, h1, output_dt, max_ratio)
    fine, h2 = tip_history(chain, x0, window, h1 / 2, output_dt, max_ratio)
    # e(h1) − e(h2) = C·(h1⁴ − h2⁴)  →  e(h1) = difference / (1 − (h2/h1)⁴)  (16/15 at h/2)
    e1 = float(np.max(np.linalg.norm(coarse - fine, axis=1))) / (1 - (h2 / h1) ** 4)
    growth = t_end / window
    if e1 <= 0.0:
        h = h_stable
    else:
        # (1 − 1e-12): the estimate below then stays at or under SAFETY·tol despite the
        # round-off of the fourth root and power (it came out 1 ulp above)
        h = min(h_stable, h1 * (SAFETY * tol / (e1 * growth)) ** 0.25 * (1.0 - 1e-12))
    if h < MIN_STEP_S:
        raise SceneError(f"fidelity.tolerance: got {tol:g} m, expected a tolerance the RK4 "
                         f"step can reach above {MIN_STEP_S:g} s (it would need "
                         f"{h:.3g} s); loosen it or use --integrator dop853 with --rtol")
    est = e1 * (h / h1) ** 4 * growth
    return StepChoice(h, est, tol, h1, window, e1, h_stable)
