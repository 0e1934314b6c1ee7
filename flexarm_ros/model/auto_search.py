"""The search of rung auto: every candidate of the ladder judged on its linear response
(:mod:`flexarm_ros.model.linear_response`) against a converged reference, the cheapest
admissible one chosen (:func:`choose`, :func:`resolve`), or one named model assessed
(:func:`assess`); the method is described in :mod:`flexarm_ros.model.autofidelity`, the
record of a choice is :mod:`flexarm_ros.model.auto_choice`."""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import numpy as np

from flexarm_ros.errors import InputError, SceneError
from flexarm_ros.model.auto_choice import (CROSS_CHECK_ELEMENTS, FINER_FACTOR, FINER_TRIES,
                                           LADDER, MAX_LINEAR_SAMPLES, MAX_RK4_STEPS,
                                           REFERENCE_MODES, RKN4_LIMIT_RATIO, SPATIAL_SHARE,
                                           WINDOW_FRACTION, WINDOW_MIN_S, AutoChoice,
                                           Candidate, tolerance_of)
from flexarm_ros.model.beams import MAX_ELASTIC_COORDINATES, elastic_coordinates
from flexarm_ros.model.linear import (ABOVE_STABLE_SHARE, RK4_AUTO, grid_step,
                                      search_above_stable, smooth_rhs)
from flexarm_ros.model.linear_response import LinearResponse, one_blas_thread
from flexarm_ros.model.programs import eval_torque, torque_breakpoints
from flexarm_ros.model.rung_chain import RungChain

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
        return RungChain(self._scene(rung, refine))

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
        y = {n: LinearResponse(*self._memo_chain("modal", n)).exact(self.grid, self.bps)
             for n in (nm - 2, nm)}
        self.y_ref = y[nm]
        # its own error: the last refinement's change (the modal sequence converges fast:
        # measured 4e-9 … 3e-7 m between 10 and 12 modes on the seed scenes)
        self.e_ref = float(np.max(np.linalg.norm(y[nm] - y[nm - 2], axis=1)))
        self.reference = f"modal {nm} (linear)"
        # an independent cross-check (reported, not added): FEM on CROSS_CHECK_ELEMENTS
        self.cross_check = None
        if self._fits("fem", CROSS_CHECK_ELEMENTS):
            fem = LinearResponse(*self._memo_chain("fem", CROSS_CHECK_ELEMENTS))
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
        lin = LinearResponse(chain, self.input_memo)
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
        except InputError as exc:
            c.verdict = f"refused: {exc}"
            return c, None
        c.coordinates = chain.n
        try:
            lin = LinearResponse(chain, self.input_memo)
        except InputError as exc:
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
                    lin = LinearResponse(*self._memo_chain(rung, n))
                except InputError:
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
