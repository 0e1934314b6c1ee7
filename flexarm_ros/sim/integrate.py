"""Time integration of a chain: fixed-step RK4 and RKN4 (RK4 with the positions stepped by
the Runge–Kutta–Nyström formulas, :func:`~flexarm_ros.sim.step.rk4_step`), the implicit
trapezoidal rule, and scipy's ``solve_ivp`` methods.

Every run returns an :class:`Integration` result (like scipy's ``OdeResult``: ``status``,
``message``, call counters); the state is checked after every step and a non-finite or
invalid state raises
:class:`~flexarm_ros.errors.SimulationDiverged` naming what diverged, when, and what
to change (:class:`~flexarm_ros.sim.guard.DivergenceGuard`). Nothing non-finite is ever
returned. The step size and its stability limit: :mod:`flexarm_ros.sim.step`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np


from flexarm_ros.errors import SceneError, SimulationDiverged
from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import loops as kloops
from flexarm_ros.model.compiled.layout import Workspace
from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.model.differentiate import jacobian
from flexarm_ros.model.linear import smooth_rhs
from flexarm_ros.model.programs import torque_breakpoints
from flexarm_ros.sim.guard import DivergenceGuard
from flexarm_ros.sim.step import choose_step, nystrom_positions, rk4_step
from flexarm_ros.sim.budget import FORECAST_STEPS, Forecast, Pace, check_work

#: scipy's solve_ivp methods by integrator name (the class by :func:`solve_ivp_method`)
SOLVE_IVP = {"rk45": "RK45", "dop853": "DOP853", "radau": "Radau", "bdf": "BDF",
             "lsoda": "LSODA"}

#: the explicit fixed-step integrators (one step function, :func:`rk4_step`) and with the
#: implicit trapezoidal rule, the fixed-step ones
EXPLICIT = ("rk4", "rkn4")
FIXED_STEP = EXPLICIT + ("trapezoid", "lawson4")

#: fewest RK4 steps per call of a compiled loop between progress reports
MIN_CALL_STEPS = 250


def solve_ivp_method(integrator: str):
    """scipy's OdeSolver class of ``integrator`` (rk45, dop853, radau, bdf, lsoda),
    imported on first use: rk4 and trapezoid runs never load scipy.integrate (start-up,
    docs/performance.md, "Start-up")."""
    import scipy.integrate
    return getattr(scipy.integrate, SOLVE_IVP[integrator])


@dataclass
class Integration:
    """Result of a run: samples and the counters of scipy's result object."""
    t: np.ndarray
    q: np.ndarray          # (N, n)
    qd: np.ndarray         # (N, n)
    z: np.ndarray          # (N, nz) actuator states (currents A, pressures Pa)
    status: int
    message: str
    rhs_evaluations: int
    steps: int
    wall_time_s: float
    dt: float              # fixed step used (0 for adaptive methods)

    @property
    def success(self) -> bool:
        return self.status == 0

    @classmethod
    def completed(cls, chain, t, xs, rhs_evaluations, steps, wall_time_s, dt) -> "Integration":
        """A run that reached its end time, from its first-order states xs (N, m) at the
        output times t: q and q̇ of every coordinate (prescribed ones from their motion)
        and the actuator states."""
        q = np.empty((len(t), chain.n))
        qd = np.empty((len(t), chain.n))
        nf = len(chain.free)
        q[:, chain.free] = xs[:, :nf]
        qd[:, chain.free] = xs[:, nf:2 * nf]
        if len(chain.presc_idx):
            p = chain.prescribed_series(t)
            q[:, chain.presc_idx] = p[:, 0]
            qd[:, chain.presc_idx] = p[:, 1]
        return cls(t, q, qd, xs[:, 2 * len(chain.free):].copy(), 0,
                   "integration reached the end time", rhs_evaluations, steps, wall_time_s, dt)


class _Counted:
    def __init__(self, chain):
        self.chain = chain
        self.calls = 0

    def __call__(self, t, x):
        self.calls += 1
        return self.chain.rhs(t, x)


def integrate(chain, x0, t_end, integrator="rk4", dt=0.0, rtol=1e-8, atol=1e-10,
              output_dt=1e-3, max_deflection_ratio=0.5, progress=None) -> Integration:
    """Integrate the chain from state x0 = [q_free, q̇_free, z] over [0, t_end]."""
    if integrator not in FIXED_STEP + tuple(SOLVE_IVP):
        raise SceneError(f"fidelity.integrator: got {integrator!r}, expected one of "
                         f"{', '.join(FIXED_STEP)}, {', '.join(SOLVE_IVP)}")
    if integrator == "trapezoid" and chain.nz:
        raise SceneError(
            f"fidelity.integrator: got 'trapezoid', but the model has actuator states "
            f"({', '.join(chain.state_names)}) that the Newmark trapezoidal rule does not "
            f"carry; expected rk4, radau or bdf (or fidelity.motor_current: quasi_static "
            f"for a DC motor)")
    n_out = int(np.floor(t_end / output_dt + 1e-9))
    t_out = np.arange(n_out + 1) * output_dt
    chain.check_mass_matrix(chain.full_state(0.0, x0)[0])
    h = choose_step(chain, x0, integrator, dt, output_dt,
                    dense=integrator in EXPLICIT and smooth(chain))
    if integrator in FIXED_STEP:
        check_work(chain, x0, h, t_end, integrator)         # before the work: no silent hang
    guard = DivergenceGuard(chain, max_deflection_ratio, integrator, h)
    f = _Counted(chain)
    xs = np.empty((len(t_out), len(x0)))
    xs[0] = x0
    guard.check(0.0, x0)
    dense = integrator in EXPLICIT and not _divides(h, output_dt)
    nq = nystrom_positions(chain, integrator)
    if chain.backend == "numba" and integrator == "lawson4":    # compile outside the timing
        from flexarm_ros.model.compiled import lawson as klawson
        klawson.warm_up(chain.kernel_args, x0, xs)
    elif chain.backend == "numba":
        kloops.warm_up(integrator, chain.kernel_args, x0, xs, dense=dense)
    # lawson4's matrices, before the timing as RK4's stable step (choose_step) is
    lawson = lawson_matrices(chain, x0, h) if integrator == "lawson4" else None
    wall0 = time.perf_counter()
    last_report = wall0
    forecast = Forecast(t_end / h if integrator in FIXED_STEP else math.inf, integrator, h,
                        t_end)
    if dense and chain.backend == "numba":
        ws = kchain.workspace(chain.kernel_args)
        x, t, k_next, steps = np.array(x0, float), 0.0, 1, 0
        # whole steps per compiled call: ~1 % of the run for progress, at least
        # MIN_CALL_STEPS (a call's dispatch costs tens of µs: 100 calls of one step each
        # were most of a 1 s two_link_free run)
        chunk = h * max(MIN_CALL_STEPS, int(np.ceil(t_end / 100 / h)))
        bps = input_breakpoints(chain, t_end)
        first = min(h * FORECAST_STEPS, chunk)   # a short first call times the pace
        while t < t_end - 1e-12 * max(1.0, t_end):
            t_stop = min(t + (first if steps == 0 else chunk),
                         next(b for b in bps if b > t + 1e-12 * max(1.0, t_end)))
            code, t_new, st, calls, k_next, x_last, x_bad = kloops.rk4_dense(
                x, t, h, t_stop, output_dt, k_next, max_deflection_ratio, xs,
                chain.kernel_args, ws, nq > 0)
            steps += st
            f.calls += calls
            if code != kchain.OK:
                guard.last = x_last
                guard.check(t_new, x_bad)
            x, t = x_last, t_new
            forecast.update(steps)
            last_report = _report(progress, last_report, t / t_end)
        xs[k_next:] = x                  # t_end exactly on the grid but below rounding
    elif dense:
        steps = _run_rk4_dense(f, chain, x0, h, t_end, t_out, xs, guard,
                               input_breakpoints(chain, t_end), nq)
    elif integrator in EXPLICIT and chain.backend == "numba":
        per = int(round(output_dt / h))
        ws = kchain.workspace(chain.kernel_args)
        steps = _compiled_grid(
            lambda x, k0, k1: kloops.rk4_loop(x, h, per, k0, k1, output_dt,
                                              max_deflection_ratio, xs, chain.kernel_args,
                                              ws, nq > 0),
            x0, n_out, per, guard, forecast, progress, output_dt / t_end)
        f.calls += 4 * steps
    elif integrator == "lawson4":
        steps = _run_lawson(chain, x0, h, lawson, n_out, output_dt, max_deflection_ratio,
                            xs, guard, f, progress, forecast)
    elif integrator == "trapezoid":
        steps, calls = _run_trapezoid(chain, x0, h, n_out, output_dt, max_deflection_ratio,
                                      xs, guard, progress, forecast)
        f.calls += calls
    elif integrator in EXPLICIT:
        per = int(round(output_dt / h))
        x = np.array(x0, float)
        steps = 0
        for k in range(n_out):
            t = t_out[k]
            for j in range(per):
                tj = t + j * h
                x = chain.clamp_states(rk4_step(f, tj, x, h, nq=nq))
                steps += 1
                guard.check(tj + h, x)
            xs[k + 1] = x
            last_report = _report(progress, last_report, t_out[k + 1] / t_end)
    else:
        steps = 0
        bps = input_breakpoints(chain, t_end)
        t_lo, x = 0.0, np.array(x0, float)
        k_out = 1
        pace = Pace(chain, t_end, integrator)
        for t_hi in bps:   # restart at input discontinuities
            solver = solve_ivp_method(integrator)(f, t_lo, x, t_hi, rtol=rtol, atol=atol,
                                                  **({"max_step": dt} if dt > 0 else {}))
            while solver.status == "running":
                try:
                    msg = solver.step()
                except (ValueError, np.linalg.LinAlgError) as exc:
                    raise SimulationDiverged(
                        "integrator", solver.t, float(np.abs(solver.y).max()),
                        "use --integrator rk4 or radau, or give the beams a realistic mass",
                        detail=f"{integrator} failed: {exc}") from None
                if solver.status == "failed":
                    raise SimulationDiverged(
                        "integrator", solver.t, float(np.abs(solver.y).max()),
                        "loosen --rtol/--atol, use --integrator radau or bdf, or a coarser "
                        "rung", detail=str(msg))
                steps += 1
                guard.check(solver.t, solver.y)
                pace.check(steps, solver.t, solver.y)
                if k_out <= n_out and t_out[k_out] <= solver.t + 1e-12:
                    dense = solver.dense_output()
                    while k_out <= n_out and t_out[k_out] <= solver.t + 1e-12:
                        xs[k_out] = dense(t_out[k_out])
                        k_out += 1
                last_report = _report(progress, last_report, solver.t / t_end)
            x = solver.y
            t_lo = t_hi
        xs[k_out:] = x  # t_end exactly on the grid but below rounding
    wall = time.perf_counter() - wall0
    step_used = h if integrator in FIXED_STEP else 0.0
    return Integration.completed(chain, t_out, xs, f.calls, steps, wall, step_used)


def lawson_matrices(chain, x0, h):
    """(A, exp(A h/2), exp(A h)) of integrator lawson4: A = ∂f/∂x at the start state
    (central differences, :func:`~flexarm_ros.model.differentiate.jacobian`; the inputs at
    t = 0 do not enter it), the part of the model its steps take exactly
    (:mod:`flexarm_ros.model.compiled.lawson`)."""
    import scipy.linalg       # lazily: rk4 runs never load it
    A = np.ascontiguousarray(jacobian(lambda x: chain.rhs(0.0, x), np.asarray(x0, float)))
    E = scipy.linalg.expm(0.5 * h * A)
    return A, np.ascontiguousarray(E), np.ascontiguousarray(E @ E)


def lawson_step(f, t, x, h, A, E, E2):
    """One step of integrator lawson4 (numpy twin of the compiled
    :func:`~flexarm_ros.model.compiled.lawson._lawson_step`), ``f`` the right-hand side."""
    def rest(tt, xx):
        return f(tt, xx) - A @ xx
    k1 = rest(t + STAGE_EPS * h, x)
    k2 = rest(t + 0.5 * h, E @ (x + 0.5 * h * k1))
    ex = E @ x
    k3 = rest(t + 0.5 * h, ex + 0.5 * h * k2)
    k4 = rest(t + (1.0 - STAGE_EPS) * h, E @ (ex + h * k3))
    return E2 @ (x + h / 6.0 * k1) + E @ (h / 3.0 * (k2 + k3)) + h / 6.0 * k4


def _run_lawson(chain, x0, h, matrices, n_out, output_dt, max_ratio, xs, guard, f, progress,
                forecast) -> int:
    """Integrator lawson4 on the output grid (h divides the output period: outputs on
    step ends, input jumps on the grid as RK4's grid loop); compiled where numba is.
    ``matrices``: :func:`lawson_matrices`."""
    from flexarm_ros.model.compiled import lawson as klawson
    A, E, E2 = matrices
    per = int(round(output_dt / h))
    if chain.backend == "numba":
        ws = kchain.workspace(chain.kernel_args)
        steps = _compiled_grid(
            lambda x, k0, k1: klawson.lawson_loop(x, h, per, k0, k1, output_dt, max_ratio,
                                                  xs, A, E, E2, chain.kernel_args, ws),
            x0, n_out, per, guard, forecast, progress, 1.0 / n_out)
        f.calls += 4 * steps
        return steps
    x, steps = np.array(x0, float), 0
    last_report = time.perf_counter()
    for k in range(n_out):
        for j in range(per):
            tj = k * output_dt + j * h
            x = chain.clamp_states(lawson_step(f, tj, x, h, A, E, E2))
            steps += 1
            guard.check(tj + h, x)
        xs[k + 1] = x
        last_report = _report(progress, last_report, (k + 1) / n_out)
    return steps


def smooth(chain) -> bool:
    """:func:`flexarm_ros.model.linear.smooth_rhs`: RK4 may step past the output period."""
    return smooth_rhs(chain)


def input_breakpoints(chain, t_end: float) -> list[float]:
    """The instants in (0, t_end] where an input program jumps, and t_end: the integrators
    end a step on each (RK4's dense path, the solve_ivp methods restart there), so no step
    straddles a jump — its error would be O(h), not O(h⁵)."""
    return sorted({b for a in chain.actuators
                   for b in torque_breakpoints(a.program, t_end)} | {t_end})


def _divides(h: float, output_dt: float) -> bool:
    """True when the step h is a whole fraction of the output period (outputs on step
    ends); else the outputs come from the dense output inside steps."""
    n = output_dt / h
    return n >= 1 - 1e-9 and abs(n - round(n)) <= 1e-9 * max(1.0, n)


def hermite(theta, h, x0, f0, x1, f1):
    """The cubic Hermite interpolant of a step [t, t + h] at t + θh (numpy twin of the
    compiled :func:`~flexarm_ros.model.compiled.loops.hermite`)."""
    t2, t3 = theta * theta, theta ** 3
    return ((2 * t3 - 3 * t2 + 1) * x0 + (t3 - 2 * t2 + theta) * h * f0
            + (3 * t2 - 2 * t3) * x1 + (t3 - t2) * h * f1)


def _run_rk4_dense(f, chain, x0, h, t_end, t_out, xs, guard, bps, nq=0) -> int:
    """RK4 with steps of h independent of the output grid (numpy backend): outputs inside
    a step from :func:`hermite`, ẋ from the right-hand side at both ends; a step ends on
    every input breakpoint in ``bps``. As the compiled :func:`kloops.rk4_dense`, the ẋ at
    a step's end is the next step's first stage unless an input breakpoint lies between."""
    x, t, k, steps = np.array(x0, float), 0.0, 1, 0
    eps = 1e-12 * max(1.0, t_end)
    n_out = len(t_out) - 1
    f1 = None
    while t < t_end - eps:
        bp = next(b for b in bps if b > t + eps)
        hh = min(h, bp - t)
        f0 = f1 if f1 is not None else f(t + STAGE_EPS * hh, x)
        x1 = chain.clamp_states(rk4_step(f, t, x, hh, k1=f0, nq=nq))
        f1 = None
        steps += 1
        guard.check(t + hh, x1)
        t1 = t + hh
        if k <= n_out and t_out[k] < t1 - eps:
            # ẋ just inside the step (as RK4's first and last stages): the limits on this
            # side of an input jump on either end
            f1 = f(t + (1.0 - STAGE_EPS) * hh, x1)
            while k <= n_out and t_out[k] < t1 - eps:
                xs[k] = hermite((t_out[k] - t) / hh, hh, x, f0, x1, f1)
                k += 1
        if k <= n_out and abs(t_out[k] - t1) <= eps:
            xs[k] = x1
            k += 1
        if abs(t1 - bp) <= eps:
            f1 = None           # an input jump: the next step's first stage is its own
        x, t = x1, t1
    xs[k:] = x
    return steps


TRAPEZOID_TOL = 1e-10       # Newton: |Δa| <= tol·(|a| + |S⁻¹|·|f|)
TRAPEZOID_MAX_ITER = 8      # iterations per step before the iteration matrix is refreshed
ITERATION_REL_STEP = 1e-7   # relative difference step of the iteration matrix's K and C


def iteration_matrix(chain, t, x, h) -> np.ndarray:
    """(M + h/2·C + h²/4·K)⁻¹ on the free coordinates at state x, with K = −∂f/∂q and
    C = −∂f/∂q̇ of the generalized forces f (central differences of the compiled forces)."""
    model = chain.kernel_args
    ws = kchain.workspace(model)
    named = Workspace._make(ws)
    free = chain.free
    q, qd = chain.full_state(t, x)

    def force(qq, vv):
        kchain.forces(float(t), qq.copy(), vv.copy(), x[:0], model, ws)
        return named.f[free].copy()

    K = -jacobian(lambda qq: force(qq, qd), q, ITERATION_REL_STEP, columns=free)
    C = -jacobian(lambda vv: force(q, vv), qd, ITERATION_REL_STEP, columns=free)
    kchain.forces(float(t), q.copy(), qd.copy(), x[:0], model, ws)
    M = named.M[np.ix_(free, free)]
    return np.linalg.inv(M + 0.5 * h * C + 0.25 * h * h * K)


def _run_trapezoid(chain, x0, h, n_out, output_dt, max_ratio, xs, guard, progress=None,
                   forecast=None):
    """Drive the compiled trapezoidal loop, refreshing the iteration matrix when Newton
    stalls (fast rotation, large deflection change the tangent)."""
    model = chain.kernel_args
    ws = kchain.workspace(model)
    nf = len(chain.free)
    per = int(round(output_dt / h))
    x = np.array(x0, float)
    acc = kchain.rhs(kchain.STAGE_EPS * h, x, model, ws)[nf:]
    k, steps, calls, refreshes, k_failed = 0, 0, 0, 0, -1
    Sinv = iteration_matrix(chain, 0.0, x, h)
    last_report = time.perf_counter()
    while True:
        k_end = min(n_out, k + max(1, n_out // 100))
        code, k, st, it, x, acc = kloops.trapezoid_loop(
            x, acc, h, per, k, k_end, output_dt, max_ratio, xs, model, ws, Sinv,
            TRAPEZOID_TOL, TRAPEZOID_MAX_ITER)
        steps += st
        calls += it
        if forecast is not None:
            forecast.update(steps)
        if code == kchain.OK:
            last_report = _report(progress, last_report, k * output_dt / (n_out * output_dt))
            if k >= n_out:
                return steps, calls
            continue
        if code == kchain.DEFLECTION:
            guard.check((k + 1) * output_dt, x)
        # Newton stalled: refresh the iteration matrix where it stalled, once per place
        if k == k_failed or not np.all(np.isfinite(x)):
            raise SimulationDiverged(
                "Newton iteration of the trapezoidal rule", k * output_dt,
                float(np.abs(x).max()),
                f"reduce the step (--dt, now {h:.3g} s) or use --integrator rk4 / radau",
                detail="no convergence with a fresh iteration matrix")
        k_failed = k
        refreshes += 1
        Sinv = iteration_matrix(chain, k * output_dt, x, h)


def _compiled_grid(call, x0, n_out, per, guard, forecast, progress, scale) -> int:
    """A compiled fixed-step loop on the output grid (RK4's, lawson4's) in ~100 calls,
    progress between them: ``call(x, k0, k1)`` steps output intervals k0..k1 and returns
    (code, t_fail, steps, x_last, x_bad); a diverged state stops the run through
    ``guard``; ``progress`` gets k1·``scale``. Returns the steps taken."""
    x, steps = np.array(x0, float), 0
    last_report = time.perf_counter()
    for k0, k1 in _chunks(n_out, per=per):
        code, t_fail, st, x_last, x_bad = call(x, k0, k1)
        steps += st
        if code != kchain.OK:
            guard.last = x_last
            guard.check(t_fail, x_bad)
        x = x_last
        forecast.update(steps)
        last_report = _report(progress, last_report, k1 * scale)
    return steps


def _chunks(n_out, parts=100, per=1):
    """Split output intervals into ~``parts`` compiled calls (progress between them), each
    of at least MIN_CALL_STEPS steps when an interval takes ``per``."""
    step = max(1, n_out // parts, -(-MIN_CALL_STEPS // per))
    return [(k, min(n_out, k + step)) for k in range(0, n_out, step)]


def _report(progress, last, fraction):
    """Call ``progress(fraction)`` at most once per wall second; returns the last report time."""
    now = time.perf_counter()
    if progress is not None and now - last > 1.0:
        progress(fraction)
        return now
    return last
