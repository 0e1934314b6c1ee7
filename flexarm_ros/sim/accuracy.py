"""The step for a tip-position tolerance: ``fidelity.tolerance`` / ``--tolerance``.

The user states the error in the quantity users think in, metres of tip position; the
step is chosen so that the estimated global tip error of the run stays below it.

Method (Richardson's step-halving estimate of the global error, Hairer, Nørsett & Wanner,
*Solving ODEs I*, Sec. II.4): RK4's global error at time t behaves as e(t) ≈ C(t)·h⁴.
Two pilot runs over a window [0, T_w] at the steps h₁ and h₂ ≈ h₁/2 give the tip error
of the coarser one as E₁ ≈ max|tip(h₁) − tip(h₂)| / (1 − (h₂/h₁)⁴) (16/15 at h₁/2). For an oscillating arm the phase
error, which dominates, grows linearly with time, so the run of length T at step h is
estimated at E(h) = E₁·(h/h₁)⁴·T/T_w. The step is the largest with E(h) ≤ SAFETY·TOL
up to the stable automatic step RK4_AUTO/|λ|max. Where the tolerance allows more, a step
above it (up to ABOVE_STABLE_SHARE of the stability limit) is taken only as measured by
a pilot at that step (:func:`_above_stable`: outside the asymptotic range of the highest
modes the h⁴ law is not assumed). The outputs, sampled inside steps
by the cubic Hermite dense output (third order, like the step), are part of what the pilot
runs compare, so the estimate covers them too.

The window starts at 0 and, when an input jumps during the run (a step, a pulse), reaches
past the first jump by the same length: a window before any input would see nothing move
(measured: hydraulic_2kg, valve step at 0.5 s, estimated 0 m, actual 5.6e-7 m).

The same estimate serves the contact stepper, with its own order and ceiling:

* **the contact stepper** (a scene with a wall; RK4 through impacts, sliding and lift-off
  located inside steps). Its error is not smooth in time — an impact shifts the phase
  at once — so the pilot runs cover the **whole run** (window = T, no extrapolation in
  time) at the automatic contact step and its half, and the automatic contact step is
  the ceiling. Measured per halving of the step on two_link_case1/case2 (2.5 s, against
  62.5 µs): error ratios 10–19, order 3.4–4.3. A third pilot at a quarter of the
  automatic step shows the order over the run; the estimate uses it or **3**, whichever
  is lower (so the chosen step errs short), on the finer pair, with the triangle
  inequality for steps above it (:func:`_step_from_three`: extrapolating the finer pair
  up at order 3 gave half the measured error on two_link_case2, whose pair order was
  4.1). Cost: the pilots are 7 runs' worth at the automatic step, then the run at the
  chosen one.

Models without a wall whose right-hand side has kinks (the hydraulic orifice) take the
same three pilots over their window. Backlash is refused: its dead zone, stepped over,
makes the error irregular in the step (two_link_case3_backlash, 1 s, against 15.6 µs:
1.4e-6, 3.1e-7, 4.3e-7 m at 250, 125 and 83 µs), which no step-halving estimate follows.

The estimate is reported in the run summary (``estimated_tip_error_m``) and checked
against a converged reference in ``test/test_accuracy.py`` for seed scenes at
TOL = 1e-3, 1e-5 and 1e-7 m, with and without a wall.

Not for the trapezoidal rule (refused): on the ladder's stiff rungs its steps near the
output period are far outside the asymptotic range of the highest modes (ω·h of order
1), where the error does not fall as h²: seed 001 ``link`` (modal 3, 1 s) against DOP853
gave 3.7e-5, 3.5e-5, 1.3e-5, 7.7e-6, 2.8e-6 m at 1 ms and four halvings, and the
step-halving estimate from 1 ms and 0.5 ms undershot the measured error 3–6× at
TOL = 1e-7 (session 7).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.model.explicit import explicit_integrator
from flexarm_ros.model.linear import ABOVE_STABLE_SHARE, search_above_stable

SAFETY = 0.5            # the estimate aims at half the tolerance
WINDOW_FRACTION = 0.1   # the pilot window: this share of the run ...
WINDOW_MIN_S = 0.1      # ... but at least this long (or the whole run)
#: the pilots cover the whole run — its error measured, not grown linearly in time from a
#: window — where their predicted integration work (autofidelity.COST_US per step) is at
#: most this many seconds (session 16: on two_link_free the window's linear growth had
#: asked 3.9 ms for 1e-6 m where 7.5 ms meets it; the error there peaks at 0.15 s and
#: decays with the damping)
WHOLE_RUN_PILOT_S = 0.25
MIN_STEP_S = 1e-7       # below this the tolerance is refused as unreachable
#: below this the tolerance is refused: the pilots' tip histories differ by round-off at
#: this level (two_link_case1 at 62.5 and 31.25 µs: 2e-12 m apart), so an estimate under
#: it would be noise — a 1e-15 m tolerance ran 890 000 steps and claimed 5e-16 m
MIN_TOLERANCE_M = 1e-10


@dataclass(frozen=True)
class StepChoice:
    """The chosen step and what it rests on."""
    step_s: float
    estimated_tip_error_m: float
    tolerance_m: float
    pilot_step_s: float
    pilot_window_s: float
    pilot_error_m: float        # E₁: the pilot's tip error at its coarse step
    stable_step_s: float        # the ceiling: RK4_AUTO/|λ|max or the automatic contact step
    order: float = 4.0          # the order the estimate used
    #: "step halving", "pilot above the stable step" (RK4 above RK4_AUTO/|λ|max) or
    #: "linear" (the trapezoid rule's)
    method: str = "step halving"
    #: the ceiling above the stable step (ABOVE_STABLE_SHARE of RK4's stability limit)
    limit_s: float = math.nan
    #: "given" (fidelity.tolerance) or "default" (the trapezoid's automatic step: chosen
    #: for rung auto's default tip tolerance, simulate.simulate)
    source: str = "given"

    def above(self) -> str:
        """'above the stable step …' and, at the ceiling, why the step is not larger."""
        at_cap = self.step_s >= self.limit_s * (1 - 1e-9)
        return (f"above the stable step {self.stable_step_s:.4g} s"
                + (f"; the ceiling, {ABOVE_STABLE_SHARE:g} of RK4's stability limit"
                   if at_cap else ""))

    def explain(self) -> str:
        if self.method == "linear":
            return (f"step {self.step_s:.4g} s for a tip tolerance of {self.tolerance_m:.3g} m "
                    f"(estimated {self.estimated_tip_error_m:.3g} m: the linearized model "
                    f"stepped by the trapezoidal rule against its exact response over "
                    f"{self.pilot_window_s:.3g} s; {self.pilot_error_m:.3g} m at the output "
                    f"period {self.pilot_step_s:.4g} s)")
        if self.method == "pilot above the stable step":
            return (f"step {self.step_s:.4g} s for a tip tolerance of {self.tolerance_m:.3g} "
                    f"m, {self.above()} (estimated "
                    f"{self.estimated_tip_error_m:.3g} m: a pilot run at this step over "
                    f"{self.pilot_window_s:.3g} s against one at a quarter of the stable "
                    f"step, the difference grown linearly to the run's length)")
        return (f"step {self.step_s:.4g} s for a tip tolerance of {self.tolerance_m:.3g} m "
                f"(estimated {self.estimated_tip_error_m:.3g} m: pilot runs over "
                f"{self.pilot_window_s:.3g} s at {self.pilot_step_s:.4g} s and about half of it "
                f"give {self.pilot_error_m:.3g} m at the coarse step, order "
                f"{self.order:.2g}; ceiling "
                f"{self.stable_step_s:.4g} s)")


#: the order the estimate assumes per stepper (the contact stepper's: see the module text)
ORDER = {"rk4": 4, "rkn4": 4, "contact": 3}


def tip_history(chain, x0, t_end, h, output_dt, max_ratio,
                contact=None) -> tuple[np.ndarray, float]:
    """(N, 2) tip positions on the output grid of a run asked for step h (the contact
    stepper's with a wall ``contact``), and the step it took (shortened to divide the
    output period where the run cannot step past it)."""
    if contact is not None:
        from flexarm_ros.sim.contact_run import integrate_with_contact
        run, _ = integrate_with_contact(chain, contact, x0, t_end, output_dt, dt=h)
    else:
        from flexarm_ros.sim.integrate import integrate
        run = integrate(chain, x0, t_end, explicit_integrator(chain.fidelity), h,
                        output_dt=output_dt, max_deflection_ratio=max_ratio)
    return chain.energies(run.t, run.q, run.qd, run.z)[1], run.dt   # one compiled pass


def check_tolerance(tol, why_floor: str) -> None:
    """SceneError unless ``tol`` is a finite bound of at least MIN_TOLERANCE_M."""
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise SceneError(f"fidelity.tolerance: got {tol!r}, expected a tip-position error "
                         f"bound > 0 m")
    if tol < MIN_TOLERANCE_M:
        raise SceneError(f"fidelity.tolerance: got {tol:g} m, expected at least "
                         f"{MIN_TOLERANCE_M:g} m (below it {why_floor}; for a converged "
                         f"reference use --integrator dop853 --rtol 1e-12)")


def step_for_tolerance(chain, x0, t_end: float, tol: float, output_dt: float,
                       max_ratio: float = 0.5, contact=None) -> StepChoice:
    """The RK4 step meeting the tip tolerance ``tol`` (m) over a run of ``t_end`` s (the
    contact stepper's with a wall ``contact``)."""
    check_tolerance(tol, "the step-halving estimate is round-off")
    from flexarm_ros.sim.integrate import input_breakpoints, smooth
    if contact is not None:
        from flexarm_ros.sim.step import choose_step
        order = ORDER["contact"]
        h_top = choose_step(chain, x0, "rk4", 0.0, output_dt, contact=contact,
                            dense=smooth(chain))
        h1, window = h_top, t_end               # pilots over the whole run: every event
    else:
        from flexarm_ros.sim.step import stability
        method = explicit_integrator(chain.fidelity)
        order = ORDER[method]
        q, qd = chain.full_state(0.0, x0)
        rate, limit, auto = stability(chain, q, qd, x0[2 * len(chain.free):], method)
        h_top = auto if rate > 0 else output_dt
        h1 = h_top / 2
        window = max(WINDOW_MIN_S, WINDOW_FRACTION * t_end)
        jumps = input_breakpoints(chain, t_end)[:-1]
        if jumps:               # the response to the first input jump is in the window
            window += jumps[0]
        window = min(t_end, window)
        if _pilot_work(chain, t_end, h1) <= WHOLE_RUN_PILOT_S:
            window = t_end
    coarse, h1 = tip_history(chain, x0, window, h1, output_dt, max_ratio, contact)
    fine, h2 = tip_history(chain, x0, window, h1 / 2, output_dt, max_ratio, contact)
    d12 = float(np.max(np.linalg.norm(coarse - fine, axis=1)))
    growth = t_end / window
    if contact is None and smooth(chain):
        if window == t_end:
            # over the whole run a third pilot shows the order the pair is in: the highest
            # modes at the stable step may still be pre-asymptotic (seed 001 link: 6.7e-7,
            # 1.7e-7, 1.1e-8 m at 253, 126, 63 µs — order 2, then 4), and an h⁴
            # extrapolation from there undershot 4× (5e-8 m estimated, 2e-7 measured)
            finest, _ = tip_history(chain, x0, window, h2 / 2, output_dt, max_ratio)
            d24 = float(np.max(np.linalg.norm(fine - finest, axis=1)))
            if d12 > 0.0 and d24 > 0.0:
                order = min(order, max(1.0, math.log(d12 / d24) / math.log(h1 / h2)))
        # e(h1) − e(h2) = C·(h1^p − h2^p)  →  e(h1) = difference / (1 − (h2/h1)^p)
        e1 = d12 / (1 - (h2 / h1) ** order)
        # (1 − 1e-12): the estimate below then stays at or under SAFETY·tol despite the
        # round-off of the root and power (it came out 1 ulp above)
        h_want = (h1 * (SAFETY * tol / (e1 * growth)) ** (1 / order) * (1.0 - 1e-12)
                  if e1 > 0.0 else math.inf)
        h = min(h_top, h_want)
        est = e1 * (h / h1) ** order * growth
        base = (h1, e1)
        if h_want > h_top:          # the stable step binds, not the tolerance: try above it
            above = _above_stable(chain, x0, window, tol, output_dt, max_ratio, limit,
                                  h_top, h_want, fine, (h1, e1), h2, order, growth)
            if above is not None:
                return above
    else:
        # events or a right-hand side with kinks (the hydraulic orifice; backlash is
        # refused before this): a third pilot shows the order, and the estimate rests on
        # the finer pair
        finest, h4 = tip_history(chain, x0, window, h2 / 2, output_dt, max_ratio, contact)
        d24 = float(np.max(np.linalg.norm(fine - finest, axis=1)))
        if d12 > 0.0 and d24 > 0.0:
            order = min(order, max(1.0, math.log(d12 / d24) / math.log(h1 / h2)))
        h, est, base = _step_from_three(h_top, h1, h2, h4, d12, d24, order, growth, tol)
    if h < MIN_STEP_S:
        raise SceneError(f"fidelity.tolerance: got {tol:g} m, expected a tolerance the "
                         f"{'contact stepper' if contact is not None else 'RK4 step'} "
                         f"can reach with a step above {MIN_STEP_S:g} s (it would need "
                         f"{h:.3g} s); loosen it or use --integrator dop853 with --rtol")
    return StepChoice(h, est, tol, base[0], window, base[1], h_top, order)


def _pilot_work(chain, t_end, h1) -> float:
    """Predicted integration time (s) of the three pilots over ``t_end`` at h1, h1/2 and
    h1/4 (autofidelity.COST_US per step)."""
    from flexarm_ros.model.linear_response import rk4_work_s
    return 7 * rk4_work_s(chain, t_end, h1)


def _above_stable(chain, x0, window, tol, output_dt, max_ratio, limit, h_top, h_want,
                  fine, base, h2, order, growth) -> StepChoice | None:
    """A step above the stable step h_top, up to ABOVE_STABLE_SHARE of the stability
    limit, *measured* at that step, or None (keep h_top).

    Above h_top the highest modes are outside RK4's asymptotic range (ω·h > 1.5), where
    the error need not fall as h⁴, so the step is not extrapolated there: a third pilot
    over the same window at the candidate step h_c gives E_c = max|tip(h_c) − tip(h₂)| +
    E₂ (the fine pilot's own error, E₁·(h₂/h₁)⁴; the triangle inequality, no order
    assumed above h₁) and h_c is taken when E_c·T/T_w ≤ SAFETY·TOL. Otherwise one more
    candidate, where the line through (h₁, E₁) and (h_c, E_c) on log-log axes meets the
    target, is measured the same way; failing both, the stable step stays."""
    h1, e1 = base
    e2 = e1 * (h2 / h1) ** order
    target = SAFETY * tol / growth
    h_cap = ABOVE_STABLE_SHARE * limit
    if not math.isfinite(h_cap) or h_cap <= h_top * (1 + 1e-9):
        return None

    def pilot(h):
        trial, h = tip_history(chain, x0, window, h, output_dt, max_ratio)
        return h, float(np.max(np.linalg.norm(trial - fine, axis=1))) + e2
    got = search_above_stable(h_top, min(h_want, h_cap), (h1, e1), target,
                              target * (1.0 - 1e-12), pilot, first_floor=1.0)
    if got is None:
        return None
    return StepChoice(got[0], got[1] * growth, tol, h1, window, e1, h_top, order,
                      "pilot above the stable step", h_cap)


#: most steps per output interval the trapezoid's step is searched over (the rule needs a
#: Newton solve per step: far more is a stiff model the tolerance cannot afford this way)
TRAPEZOID_MAX_PER = 4096


def trapezoid_step_for_tolerance(chain, t_end: float, tol: float,
                                 output_dt: float) -> StepChoice:
    """The step of the implicit trapezoidal rule meeting the tip tolerance ``tol`` over
    ``t_end``: the largest divisor output_dt/k of the output period whose error on the
    linearized model — the model stepped by the trapezoidal rule exactly as the compiled
    loop steps it, against its exact response (e^{AΔt}), max over the output grid — is at
    most SAFETY·tol (:meth:`~flexarm_ros.model.linear_response.LinearResponse.trapezoid`).

    Why not step halving as for RK4: on the ladder's stiff rungs the trapezoid's steps near
    the output period lie far outside the asymptotic range of the highest modes (ω·h ~ 1),
    where its error does not fall as h² (seed 001 ``link``: 3.7e-5 m at 1 ms, 3.5e-5 m at
    0.5 ms), and a step-halving estimate undershot 3–6×. The linear map has no asymptotic
    assumption: measured against the nonlinear runs (DOP853 at rtol 1e-12 of the same
    model), its error equals the trapezoid's to 1 % on the seed 001 links (modal, fd, fem)
    and within 0.98–1.29× on two_link_free (docs/accuracy.md)."""
    from flexarm_ros.model.linear_response import LinearResponse, one_blas_thread
    check_tolerance(tol, "the linear estimate is round-off")
    with one_blas_thread():
        return _trapezoid_step(LinearResponse(chain), chain, t_end, tol, output_dt)


def _trapezoid_step(lin, chain, t_end, tol, output_dt) -> StepChoice:
    from flexarm_ros.sim.integrate import input_breakpoints
    n_out = int(math.floor(t_end / output_dt + 1e-9))
    T = n_out * output_dt
    # the exact response on the output grid (and every input jump; inputs held at the
    # middle of each interval: exact for piecewise-constant programs, 8 sub-intervals per
    # output interval otherwise, where holding would err like the rule itself)
    sub = 1 if lin.constant_inside else 8
    fine = np.arange(n_out * sub + 1) * (output_dt / sub)
    bps = [b for b in input_breakpoints(chain, T) if b < T]
    grid = np.unique(np.concatenate([fine, bps]))
    exact = lin.exact(grid, bps)
    at_out = np.searchsorted(grid, np.arange(n_out + 1) * output_dt - 1e-12 * output_dt)
    exact = exact[at_out]
    target = SAFETY * tol
    per, tried = 1, {}
    while True:
        h = output_dt / per
        if h < MIN_STEP_S or per > TRAPEZOID_MAX_PER:
            best = min(tried, key=tried.get)
            raise SceneError(
                f"fidelity.tolerance: got {tol:g} m with integrator 'trapezoid', expected a "
                f"tolerance it meets with at most {TRAPEZOID_MAX_PER} steps per output "
                f"interval (at {output_dt / best:.3g} s its estimated tip error is "
                f"{tried[best]:.3g} m); loosen it or use --integrator rk4")
        y = lin.trapezoid(h, T)[::per]
        err = float(np.max(np.linalg.norm(y - exact, axis=1)))
        tried[per] = err
        if err <= target:
            return StepChoice(h, err, tol, output_dt, T, tried[1], output_dt, 2.0, "linear")
        # E ∝ h² in the asymptotic range; never less than one more step per interval
        per = max(per + 1, int(math.ceil(per * math.sqrt(err / target))))


def _step_from_three(h_top, h1, h2, h4, d12, d24, p, growth, tol):
    """(step, its estimate, (base step, base error)) from pilots at h1 > h2 > h4 with the
    tip differences d12 = |x(h1) − x(h2)|, d24 = |x(h2) − x(h4)| and the order p (the
    assumed one or the observed one, whichever is lower).

    E₂ = d24 / (1 − (h4/h2)ᵖ) (Richardson on the finer pair, conservative at the lower
    order) and E₁ = d12 + E₂ (the triangle inequality: no order assumed). Between h2 and
    h1 the estimate interpolates the two on log-log axes; below h2 it falls as hᵖ. (On
    two_link_case2 the pair order was 4.1 but p = 3: extrapolating E₂ up to h1 at order
    3 gave half the measured error, E₁ does not.)"""
    e2 = d24 / (1 - (h4 / h2) ** p) if d24 > 0.0 else 0.0
    e1 = d12 + e2
    target = SAFETY * tol / growth
    if e1 <= target:
        h = h_top if e1 == 0.0 else h1
        return h, e1 * growth, (h1, e1)
    if e2 <= target:
        q = math.log(e1 / e2) / math.log(h1 / h2) if e2 > 0.0 else p
        h = h2 * (target / e2) ** (1 / q) * (1.0 - 1e-12) if e2 > 0.0 else h2
        return h, (e2 * (h / h2) ** q if e2 > 0.0 else 0.0) * growth, (h2, e2)
    h = h2 * (target / e2) ** (1 / p) * (1.0 - 1e-12)
    return h, e2 * (h / h2) ** p * growth, (h2, e2)


# ----------------------------------------------------------------- rung auto: the check
#: the check's extrapolation from its window to the whole run uses the linear model's growth
#: of the error; a large motion makes the error grow faster than the linearization says
#: (measured: two_link_free, cubic, 2 s: 1.6× the linear growth), hence this factor
POSTERIOR_SAFETY = 2.0


@dataclass(frozen=True)
class PosteriorCheck:
    """The check after a rung-auto run (:mod:`flexarm_ros.model.autofidelity`): its first
    ``window_s`` run again one level finer — the ``finer`` model, whose a-priori spatial
    estimate is at most a quarter of the run's, at half the run's step (never above its own
    stable step) — and the largest tip distance between the two (``observed_m``: spatial
    and temporal error of the window together), scaled by ``growth`` to the whole run
    (:attr:`AutoChoice.growth`) with the margin :data:`POSTERIOR_SAFETY`, plus the finer
    model's own a-priori spatial estimate (``estimate_m``, by the triangle inequality)."""
    finer: str
    window_s: float
    step_s: float
    observed_m: float
    growth: float
    estimate_m: float
    wall_s: float
    status: str = "ok"          # or why the check could not run (the a-priori estimate stands)


def posterior_check(scene, auto, columns, run_step, T) -> PosteriorCheck:
    """The check of an auto run of ``scene`` (the chosen model) over ``T`` s: ``columns``
    are its output columns (tip_x, tip_y every fidelity.output_dt), ``run_step`` its step."""
    import time
    from flexarm_ros.errors import SimulationDiverged
    from flexarm_ros.model.chain import Chain
    from flexarm_ros.model.contact import build_contact
    from flexarm_ros.model.statics import initial_x
    from flexarm_ros.sim.integrate import integrate
    t0 = time.perf_counter()
    if auto.finer is None:
        return PosteriorCheck("", 0.0, 0.0, math.nan, auto.growth, math.nan, 0.0,
                              "no finer model on the ladder")
    rung, refine, stable, finer_error = auto.finer
    label = rung if rung in ("rigid", "cubic") else f"{rung} {refine}"
    window = min(auto.window_s, T)
    fid = scene.fidelity
    h = min(0.5 * run_step, stable)
    try:
        sc = scene.with_fidelity(rung=rung, refine=refine, dt=h, tolerance=0.0)
        chain = Chain(sc)
        x0 = initial_x(chain)
        contact = build_contact(chain)
        if contact is None:
            run = integrate(chain, x0, window, "rk4", h, output_dt=fid.output_dt,
                            max_deflection_ratio=fid.max_deflection_ratio)
        else:
            from flexarm_ros.sim.contact_run import integrate_with_contact
            run, _ = integrate_with_contact(chain, contact, x0, window, fid.output_dt)
        tip = chain.energies(run.t, run.q, run.qd, run.z)[1]
    except (InputError, SimulationDiverged) as exc:
        return PosteriorCheck(label, window, h, math.nan, auto.growth, math.nan,
                              time.perf_counter() - t0,
                              "not run: " + " ".join(str(exc).split()))
    k = min(len(tip), len(columns["tip_x"]))
    mine = np.c_[columns["tip_x"][:k], columns["tip_y"][:k]]
    observed = float(np.max(np.linalg.norm(mine - tip[:k], axis=1)))
    # |run − truth| ≤ |run − finer| + |finer − truth|: the finer model's own a-priori
    # spatial estimate is added
    return PosteriorCheck(label, float(run.t[k - 1]), float(run.dt), observed, auto.growth,
                          POSTERIOR_SAFETY * observed * auto.growth + finer_error,
                          time.perf_counter() - t0)


def auto_summary(auto, check, key="auto") -> dict:
    """The run summary's keys of a rung-auto run (``key`` "auto": the choice) or of a named
    rung assessed (``key`` "assessment", fidelity.estimate): the estimate and its basis;
    without a tolerance (an assessment of a scene with none) only the estimate."""
    ok = check is not None and check.status == "ok"
    est = check.estimate_m if ok else auto.estimated_m
    if ok:
        basis = (f"a posteriori, spatial + temporal: the first {check.window_s:.3g} s again "
                 f"with {check.finer} at {check.step_s:.3g} s; their difference "
                 f"{check.observed_m:.2g} m times {check.growth:.3g} (the linear model's "
                 f"growth of the error to the end) times {POSTERIOR_SAFETY:g} (margin for "
                 f"large motions) plus {check.finer}'s own a-priori spatial estimate")
    else:
        basis = "a priori (linearized model): spatial" + (
            "" if auto.wall else " + temporal") + (
            f"; the check did not run: {check.status}" if check is not None else "")
    if auto.wall:
        basis += ("; with a wall the check covers the whole run, impacts included (the "
                  "a-priori part the free flight only)" if ok else
                  "; with a wall: free flight only, the impacts are not covered")
    tol = auto.tolerance_m if auto.tolerance_m > 0 else None
    detail = auto.as_dict()
    if key == "assessment":              # a named rung: no tolerance chose anything
        detail["tolerance_m"] = tol
        detail["tolerance_source"] = ("none" if tol is None else
                                      "fidelity.tolerance (it chose the step only)")
    if check is not None:
        detail["check"] = {"finer": check.finer, "window_s": check.window_s,
                           "step_s": check.step_s, "observed_m": _num(check.observed_m),
                           "growth": check.growth, "estimate_m": _num(check.estimate_m),
                           "wall_s": check.wall_s, "status": check.status}
    met = None if tol is None else bool(est <= tol)
    out = {"tolerance_m": tol, "estimated_tip_error_m": est,
           "a_priori_tip_error_m": auto.estimated_m, "estimate": basis,
           "tolerance_met": met, key: detail}
    if met is not False:
        return out
    if key == "assessment":
        # the tolerance chose the step; the rung's own (spatial) error it cannot reduce
        out["warning"] = (f"the estimated tip error {est:.2g} m exceeds the tolerance "
                          f"{auto.tolerance_m:.2g} m ({basis.split(':')[0]}; the rung's "
                          f"own error is about {auto.spatial_m:.2g} m, which a shorter "
                          f"step does not reduce); name a finer rung (--rung/--refine) or "
                          f"let --rung auto choose one")
    elif auto.wall:
        out["warning"] = (f"the estimated tip error {est:.2g} m exceeds the tolerance "
                          f"{auto.tolerance_m:.2g} m ({basis.split(':')[0]}, the impacts "
                          f"included; rung auto chose {auto.label} from the free flight "
                          f"alone, and a strike multiplies a coarse model's error); name a "
                          f"finer rung and check it with --estimate (docs/accuracy.md, "
                          f"'Through the impacts')")
    else:
        out["warning"] = (f"the estimated tip error {est:.2g} m exceeds the tolerance "
                          f"{auto.tolerance_m:.2g} m ({basis.split(':')[0]}); tighten "
                          f"--tolerance or name a finer rung")
    return out


def _num(v):
    return None if isinstance(v, float) and math.isnan(v) else v


def truth_summary(res, out: dict) -> dict:
    """The run summary's keys of a run checked against the top rung
    (:mod:`flexarm_ros.sim.truth`): the error in both measures over the whole run, whether
    the tolerance is met in the measures ``fidelity.tolerance_metric`` bounds, and why not.
    ``out``: the summary so far (its a-priori estimate moves to ``a_priori_tip_error_m``)."""
    chk = res.truth
    fid = res.chain.fidelity
    metric = fid.tolerance_metric
    tol = out.get("tolerance_m") or None
    new = {"check": chk.as_dict(), "tolerance_metric": metric}
    if out.get("estimated_tip_error_m") is not None:
        new["a_priori_tip_error_m"] = out["estimated_tip_error_m"]
    if out.get("estimate"):
        new["a_priori_estimate"] = out["estimate"]
    if not chk.ok:
        if res.contact is not None and res.check is not None:
            return new          # a wall: the class check's verdict stands (auto_summary)
        new["tolerance_met"] = None         # never claimed without the check
        why = f"the check against the top rung did not run ({chk.status})"
        base = out.get("estimate")
        if tol is not None:
            new["estimate"] = f"{base or 'a priori'}; {why}: the tolerance is not certified"
        else:
            new["estimate"] = f"{base}; {why}" if base else f"none: {why}"
        return new
    est = chk.estimate
    new["estimated_tip_error_m"] = est.position_m
    new["estimated_deflection_error_m"] = est.deflection_max_m
    new["estimated_deflection_share"] = max(est.deflection_share, default=0.0)
    new["estimate"] = (f"against the top rung over the whole run: the run's largest distance "
                       f"to {chk.reference} ({chk.observed.position_m:.2g} m tip position, "
                       f"{chk.observed.deflection_max_m:.2g} m tip deflection) plus "
                       f"{chk.reference}'s own bound ({chk.reference_error.position_m:.2g} m, "
                       f"{chk.reference_error.deflection_max_m:.2g} m: its distance to the rod "
                       f"with fewer terms)")
    if res.escalated:
        new["escalated"] = [{"model": m, "estimated_tip_error_m": e.position_m,
                             "estimated_deflection_error_m": e.deflection_max_m}
                            for m, e in res.escalated]
    if tol is None:
        return new
    met = chk.met(tol, metric)
    new["tolerance_met"] = all(met.values())
    new["tolerance_met_by"] = met
    ratios = {"position": est.position_m / tol, "deflection": est.deflection_max_m / tol}
    new["bound_by"] = max((m for m in met), key=lambda m: ratios[m])
    if new["tolerance_met"]:
        return new
    short = ", ".join(f"{m} {(est.position_m if m == 'position' else est.deflection_max_m):.2g} m"
                      for m, ok in met.items() if not ok)
    own = max(chk.reference_error.position_m, chk.reference_error.deflection_max_m)
    if own > tol:
        fix = (f"the tolerance is below what the check can certify here ({chk.reference}'s "
               f"own bound {own:.2g} m); loosen --tolerance")
    elif res.chain.fidelity.rung != "rod":
        fix = ("the floating-frame rungs keep the beam's shortening to second order only; "
               "run the geometrically exact rung (--rung rod)"
               + ("" if getattr(res, "closed_loop", False) else " or --rung auto"))
    else:
        fix = "add curvature terms (--refine) or shorten the step (--dt)"
    new["warning"] = (f"the tolerance {tol:.2g} m is not met: {short} against the top rung "
                      f"over the whole run; {fix}")
    return new
