"""Time integration of a chain: fixed-step RK4, the implicit trapezoidal rule, and scipy's
``solve_ivp`` methods.

Every run returns an :class:`Integration` result (like scipy's ``OdeResult``: ``status``,
``message``, call counters); the state is checked after every step and a non-finite or
invalid state raises
:class:`~flexarm_ros.errors.SimulationDiverged` naming what diverged, when, and what
to change. Nothing non-finite is ever returned.

The explicit step limit: RK4 is stable for h·|λ| below ≈ 2.78 on the negative real axis and
2√2 ≈ 2.83 on the imaginary axis, λ the eigenvalues of the linearized system. A fixed step
above that limit is refused up front (:class:`StepTooLarge`); the automatic step is
1.5/|λ|max, which also keeps the phase error of the highest retained mode small.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import BDF, DOP853, LSODA, RK45, Radau


from flexarm_ros.model.compiled import chain as kchain
from flexarm_ros.model.compiled import loops as kloops
from flexarm_ros.errors import SceneError, SimulationDiverged, StepTooLarge
from flexarm_ros.model.linear import highest_rate
from flexarm_ros.model.programs import torque_breakpoints
from flexarm_ros.sim.budget import Pace, check_work

RK4_STABILITY = 2.78
RK4_AUTO = 1.5
SOLVE_IVP = {"rk45": RK45, "dop853": DOP853, "radau": Radau, "bdf": BDF, "lsoda": LSODA}


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


class _Counted:
    def __init__(self, chain):
        self.chain = chain
        self.calls = 0

    def __call__(self, t, x):
        self.calls += 1
        return self.chain.rhs(t, x)


def choose_step(chain, x0, integrator, dt, output_dt, t0=0.0):
    """The fixed step to use (RK4, trapezoid) or max step (adaptive, 0 = unbounded).

    RK4: checked against its stability limit, automatic = 1.5/|λ|max. Trapezoid: no
    stability limit; automatic = the output period (choose --dt for accuracy).
    """
    if integrator == "trapezoid":
        h = min(dt, output_dt) if dt > 0 else output_dt
        return output_dt / np.ceil(output_dt / h - 1e-9)
    if integrator != "rk4":
        return dt
    q, qd = chain.full_state(t0, x0)
    rate = highest_rate(chain, q, qd, x0[2 * len(chain.free):])
    limit = RK4_STABILITY / rate if rate > 0 else np.inf
    if dt > 0:
        if dt > limit:
            raise StepTooLarge(
                "fixed step", t0, dt,
                f"use --dt <= {limit:.3g} s (auto: --dt 0), an implicit integrator "
                f"(--integrator trapezoid, radau or bdf), or a coarser rung / fewer modes",
                detail=f"dt = {dt:.3g} s exceeds the RK4 stability limit {limit:.3g} s set "
                       f"by the highest model rate {rate / (2 * np.pi):.4g} Hz")
        h = dt
    else:
        h = RK4_AUTO / rate if rate > 0 else output_dt
    h = min(h, output_dt)
    return output_dt / np.ceil(output_dt / h - 1e-9)


def integrate(chain, x0, t_end, integrator="rk4", dt=0.0, rtol=1e-8, atol=1e-10,
              output_dt=1e-3, max_deflection_ratio=0.5, progress=None) -> Integration:
    """Integrate the chain from state x0 = [q_free, q̇_free, z] over [0, t_end]."""
    if integrator not in ("rk4", "trapezoid", *SOLVE_IVP):
        raise SceneError(f"fidelity.integrator: got {integrator!r}, expected one of rk4, "
                         f"trapezoid, {', '.join(SOLVE_IVP)}")
    if integrator == "trapezoid" and chain.nz:
        raise SceneError(
            f"fidelity.integrator: got 'trapezoid', but the model has actuator states "
            f"({', '.join(chain.state_names)}) that the Newmark trapezoidal rule does not "
            f"carry; expected rk4, radau or bdf (or fidelity.motor_current: quasi_static "
            f"for a DC motor)")
    n_out = int(np.floor(t_end / output_dt + 1e-9))
    t_out = np.arange(n_out + 1) * output_dt
    chain.check_mass_matrix(chain.full_state(0.0, x0)[0])
    h = choose_step(chain, x0, integrator, dt, output_dt)
    if integrator in ("rk4", "trapezoid"):
        check_work(chain, x0, h, t_end, integrator)         # before the work: no silent hang
    guard = _Guard(chain, max_deflection_ratio, integrator, h)
    f = _Counted(chain)
    xs = np.empty((len(t_out), len(x0)))
    xs[0] = x0
    guard.check(0.0, x0)
    if chain.backend == "numba":
        kloops.warm_up(integrator, chain.kernel_args, x0, xs)   # compile outside the timing
    wall0 = time.perf_counter()
    last_report = wall0
    if integrator == "rk4" and chain.backend == "numba":
        per = int(round(output_dt / h))
        ws = kchain.workspace(chain.kernel_args)
        x, steps = np.array(x0, float), 0
        for k0, k1 in _chunks(n_out):
            code, t_fail, st, x_last, x_bad = kloops.rk4_loop(
                x, h, per, k0, k1, output_dt, max_deflection_ratio, xs, chain.kernel_args, ws)
            steps += st
            if code != kchain.OK:
                guard.last = x_last
                guard.check(t_fail, x_bad)
            x = x_last
            last_report = _report(progress, last_report, k1 * output_dt / t_end)
        f.calls += 4 * steps
    elif integrator == "trapezoid":
        steps, calls = _run_trapezoid(chain, x0, h, n_out, output_dt, max_deflection_ratio,
                                      xs, guard, progress)
        f.calls += calls
    elif integrator == "rk4":
        per = int(round(output_dt / h))
        x = np.array(x0, float)
        steps = 0
        for k in range(n_out):
            t = t_out[k]
            for j in range(per):
                tj = t + j * h
                k1 = f(tj + kchain.STAGE_EPS * h, x)
                k2 = f(tj + 0.5 * h, x + 0.5 * h * k1)
                k3 = f(tj + 0.5 * h, x + 0.5 * h * k2)
                k4 = f(tj + (1.0 - kchain.STAGE_EPS) * h, x + h * k3)
                x = chain.clamp_states(x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4))
                steps += 1
                guard.check(tj + h, x)
            xs[k + 1] = x
            last_report = _report(progress, last_report, t_out[k + 1] / t_end)
    else:
        steps = 0
        bps = sorted({b for a in chain.actuators
                      for b in torque_breakpoints(a.program, t_end)} | {t_end})
        t_lo, x = 0.0, np.array(x0, float)
        k_out = 1
        pace = Pace(chain, t_end, integrator)
        for t_hi in bps:   # restart at input discontinuities
            solver = SOLVE_IVP[integrator](f, t_lo, x, t_hi, rtol=rtol, atol=atol,
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
    q = np.empty((len(t_out), chain.n))
    qd = np.empty((len(t_out), chain.n))
    for k, tk in enumerate(t_out):
        q[k], qd[k] = chain.full_state(tk, xs[k])
    step_used = h if integrator in ("rk4", "trapezoid") else 0.0
    return Integration(t_out, q, qd, xs[:, 2 * len(chain.free):].copy(), 0,
                       "integration reached the end time", f.calls, steps, wall, step_used)


class _Guard:
    """Checks a state: finite, and beams within the small-deflection model's validity."""

    def __init__(self, chain, max_ratio, integrator, h):
        self.chain = chain
        self.max_ratio = max_ratio
        self.integrator = integrator
        self.h = h
        self.last = None
        self.lengths = np.array([lm.beam.length for lm in chain.links])
        self.tip_rows = [(lm.beam.phi_tip, lm.eta) for lm in chain.links]

    def _ratios(self, q):
        return np.array([phi @ q[sl] for phi, sl in self.tip_rows]) / self.lengths

    def _fix(self):
        if self.integrator == "rk4":
            return (f"reduce the step (--dt, now {self.h:.3g} s), use --integrator radau, "
                    f"or a coarser rung / fewer modes")
        return "tighten --rtol/--atol or use --integrator radau or bdf"

    def check(self, t, x):
        nf = len(self.chain.free)
        if not np.all(np.isfinite(x)):
            bad = int(np.nonzero(~np.isfinite(x))[0][0])
            name = self.chain.state_labels()[bad]
            kind = "coordinate" if bad < nf else ("rate" if bad < 2 * nf else "actuator state")
            last = float(self.last[bad]) if self.last is not None else float("nan")
            raise SimulationDiverged(f"{kind} {name}", t, last, self._fix(),
                                     detail="state became non-finite")
        q, _ = self.chain.full_state(t, x)
        ratios = self._ratios(q)
        worst = int(np.argmax(np.abs(ratios)))
        if abs(ratios[worst]) > self.max_ratio:
            lm = self.chain.links[worst]
            raise SimulationDiverged(
                f"tip deflection of {lm.name}", t, float(ratios[worst] * self.lengths[worst]),
                "check the input magnitude and damping; keep foreshortening on "
                "(fidelity.foreshortening: true) for fast rotation; or raise "
                "fidelity.max_deflection_ratio if large deflection is intended",
                detail=f"|w(L)|/L = {abs(ratios[worst]):.3g} exceeds "
                       f"fidelity.max_deflection_ratio = {self.max_ratio} (the small-deflection "
                       f"beam model is no longer valid)")
        self.last = np.array(x, copy=True)


TRAPEZOID_TOL = 1e-10       # Newton: |Δa| <= tol·(|a| + |S⁻¹|·|f|)
TRAPEZOID_MAX_ITER = 8      # iterations per step before the iteration matrix is refreshed


def iteration_matrix(chain, t, x, h) -> np.ndarray:
    """(M + h/2·C + h²/4·K)⁻¹ on the free coordinates at state x, with K = −∂f/∂q and
    C = −∂f/∂q̇ of the generalized forces f (central differences of the compiled forces)."""
    model = chain.kernel_args
    ws = kchain.workspace(model)
    free = chain.free
    nf = len(free)
    q, qd = chain.full_state(t, x)

    def force(qq, vv):
        kchain.forces(float(t), qq.copy(), vv.copy(), x[:0], model, ws)
        return ws[kchain.W_F][free].copy()

    K = np.zeros((nf, nf))
    C = np.zeros((nf, nf))
    for j, idx in enumerate(free):
        for arr, out in ((q, K), (qd, C)):
            d = 1e-7 * max(1.0, abs(arr[idx]))
            ap, am = arr.copy(), arr.copy()
            ap[idx] += d
            am[idx] -= d
            fp = force(ap, qd) if arr is q else force(q, ap)
            fm = force(am, qd) if arr is q else force(q, am)
            out[:, j] = -(fp - fm) / (2 * d)
    kchain.forces(float(t), q.copy(), qd.copy(), x[:0], model, ws)
    M = ws[kchain.W_M][np.ix_(free, free)]
    return np.linalg.inv(M + 0.5 * h * C + 0.25 * h * h * K)


def _run_trapezoid(chain, x0, h, n_out, output_dt, max_ratio, xs, guard, progress=None):
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


def _chunks(n_out, parts=100):
    """Split output intervals into ~``parts`` compiled calls (progress between them)."""
    step = max(1, n_out // parts)
    return [(k, min(n_out, k + step)) for k in range(0, n_out, step)]


def _report(progress, last, fraction):
    """Call ``progress(fraction)`` at most once per wall second; returns the last report time."""
    now = time.perf_counter()
    if progress is not None and now - last > 1.0:
        progress(fraction)
        return now
    return last
