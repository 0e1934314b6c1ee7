"""The linear response of one model of the ladder (:class:`LinearResponse`): the chain
linearized about its initial state, ẋ = A x + B u, its tip driven by the scene's own input
programs — exactly in time (:meth:`LinearResponse.exact`, the state-transition matrix), as
RK4/RKN4 steps it (:meth:`LinearResponse.rk4`) and as the trapezoidal rule steps it
(:meth:`LinearResponse.trapezoid`). Rung auto (:mod:`flexarm_ros.model.autofidelity`)
compares the candidates with it; :mod:`flexarm_ros.sim.accuracy` chooses the trapezoid's
step with it. Also the predicted cost of a step (:func:`step_cost_us`) and the BLAS
setting of these analyses (:func:`one_blas_thread`)."""

from __future__ import annotations

import math

import numpy as np

from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.model.differentiate import jacobian
from flexarm_ros.model.linear import RK4_AUTO, RK4_STABILITY, highest_rate
from flexarm_ros.model.programs import eval_motion, eval_torque

#: µs per RK4 step ≈ COST_US[0] + COST_US[1]·n·P (n coordinates, P mass points), fitted on
#: this 2-core machine from the integration times of link_tipmass's rungs
COST_US = (9.0, 0.11)


def step_cost_us(chain) -> float:
    """Predicted µs per RK4 (or RKN4) step of ``chain``: COST_US[0] + COST_US[1]·n·P."""
    points = sum(len(lm.beam.x) for lm in chain.links)
    return COST_US[0] + COST_US[1] * chain.n * points


def rk4_work_s(chain, duration: float, h: float) -> float:
    """Predicted integration time (s) of ``duration`` s of ``chain`` at the RK4 step ``h``:
    its steps times :func:`step_cost_us`."""
    return duration / h * step_cost_us(chain) * 1e-6


#: torque-program codes that are constant between their breakpoints
PIECEWISE_CONSTANT = (0, 1, 2, 3, 5)


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


class LinearResponse:
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
                                and all(e[0] in PIECEWISE_CONSTANT for e in self.acts))
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
            if code in PIECEWISE_CONSTANT and len(bps):
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
        from flexarm_ros.model.statespace import zoh
        d = np.diff(grid)
        U = self.inputs(grid[:-1] + 0.5 * d, bps)
        keys = np.round(d, 15)
        maps, G = {}, np.empty((len(d), self.ns))
        for key in np.unique(keys):
            maps[key], gamma = zoh(self.A, self.B, key)
            sel = keys == key
            G[sel] = U[sel] @ gamma.T
        return self.tip(recur(maps, keys, G, self.ns))

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
        X = recur({k: maps[k][0] for k in uniq}, keys, GU, self.ns)
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
        return self.tip(recur({h: P}, np.full(n, h), U @ Q.T, self.ns))

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


#: steps per block of :func:`recur`
BLOCK = 32


def recur(maps, keys, G, ns) -> np.ndarray:
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
            Pj = np.empty((BLOCK, ns, ns))     # P^1 … P^B
            Sj = np.empty((BLOCK, ns, ns))     # I + P + … + P^{j−1}, j = 1 … B
            Pj[0], Sj[0] = P, np.eye(ns)
            for j in range(1, BLOCK):
                Pj[j] = P @ Pj[j - 1]
                Sj[j] = Sj[j - 1] + Pj[j - 1]
            powers[keys[s0]] = (Pj, Sj)
        Pj, Sj = powers[keys[s0]]
        k = s0
        while k < e0:
            L = min(BLOCK, e0 - k)
            X[k + 1:k + 1 + L] = Pj[:L] @ X[k] + Sj[:L] @ g
            k += L
    return X
