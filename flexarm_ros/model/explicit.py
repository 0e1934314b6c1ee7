"""The explicit fixed-step methods, in numpy: one RK4 or RKN4 step (:func:`rk4_step`; the
compiled loops of :mod:`flexarm_ros.model.compiled.loops` are its twins), their step maps on
a linear system (:func:`rkn4_map`) and their stability limits and automatic steps about a
state (:func:`stability`). In the model layer so that the a-priori analyses (rung auto,
``flexarm explain``) step a linearized candidate exactly as a run steps the model;
:mod:`flexarm_ros.sim.step` chooses a run's step from them."""

from __future__ import annotations

import numpy as np

from flexarm_ros.model.compiled.chain import STAGE_EPS
from flexarm_ros.model.linear import RK4_AUTO, RK4_STABILITY, jacobians


def rk4_step(f, t, x, h, quadrature: bool = False, k1=None, nq: int = 0):
    """One RK4 step of ẋ = f(t, x) from (t, x) over h (actuator-state bounds are the
    caller's):

        k₁ = f(t + εh, x),            k₂ = f(t + h/2, x + h/2·k₁),
        k₃ = f(t + h/2, x + h/2·k₂),  k₄ = f(t + (1 − ε)h, x + h·k₃),
        x₁ = x + h/6·(k₁ + 2k₂ + 2k₃ + k₄),

    ε = ``STAGE_EPS``: the first and last stages lie just inside the step, so an input that
    jumps on a step boundary is seen with its value on that step (as the compiled loops).

    ``nq`` > 0 (integrator rkn4): the first nq entries of x are positions whose rates are
    the next nq, stepped by the fourth-order Runge–Kutta–Nyström formulas (Nyström 1925;
    Hairer, Nørsett & Wanner I, Sec. II.14): with a_i the accelerations of stage i,
    Q₂ = Q₃ = q + h/2·q̇ + h²/8·a₁, Q₄ = q + h·q̇ + h²/2·a₃ and
    q₁ = q + h·q̇ + h²/6·(a₁ + a₂ + a₃); the rest of x by RK4's stages and weights (the
    compiled ``loops._rk4_step`` with ``nystrom``).

    With ``quadrature``, ``f`` returns (ẋ, g) and the step returns (x₁, ∫g dt), the integral
    by the same stages and weights, h/6·(g₁ + 2g₂ + 2g₃ + g₄) (e.g. the normal impulse from
    the stage contact forces). ``k1``: the first stage, already known (first same as last:
    the previous step's ẋ at its end, no input jump between; not with ``quadrature``)."""
    def stage(ts, xs):
        return f(ts, xs) if quadrature else (f(ts, xs), 0.0)

    k1, g1 = stage(t + STAGE_EPS * h, x) if k1 is None or quadrature else (k1, 0.0)
    v, a = x[nq:2 * nq], slice(nq, 2 * nq)
    x2 = x + 0.5 * h * k1
    x2[:nq] = x[:nq] + 0.5 * h * v + 0.125 * h * h * k1[a]
    k2, g2 = stage(t + 0.5 * h, x2)
    x3 = x + 0.5 * h * k2
    x3[:nq] = x2[:nq]
    k3, g3 = stage(t + 0.5 * h, x3)
    x4 = x + h * k3
    x4[:nq] = x[:nq] + h * v + 0.5 * h * h * k3[a]
    k4, g4 = stage(t + (1.0 - STAGE_EPS) * h, x4)
    x1 = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    x1[:nq] = x[:nq] + h * v + (h * h / 6.0) * (k1[a] + k2[a] + k3[a])
    return (x1, (h / 6.0) * (g1 + 2 * g2 + 2 * g3 + g4)) if quadrature else x1


def explicit_integrator(fidelity) -> str:
    """The explicit method that steps a scene's pilots and a-priori estimates: its rkn4,
    else RK4 (for rk4 itself and for the integrators that have no fixed step)."""
    return "rkn4" if fidelity.integrator == "rkn4" else "rk4"


def nystrom_positions(chain, integrator: str) -> int:
    """The ``nq`` of :func:`rk4_step` for ``integrator``: the free coordinates for rkn4, 0
    (RK4 throughout) for rk4."""
    return len(chain.free) if integrator == "rkn4" else 0


def rkn4_map(J, nq: int, h) -> np.ndarray:
    """The step map x₁ = R·x₀ of :func:`rk4_step` with ``nq`` Nyström positions on the
    linear system ẋ = J x (nq = 0: RK4's R = Σ (hJ)^k/k!, k ≤ 4); for an array of steps
    ``h`` the maps stacked along a first axis."""
    m = J.shape[0]
    h = np.asarray(h, float)
    H = h[..., None, None]
    X = np.broadcast_to(np.eye(m), h.shape + (m, m))
    v = slice(nq, 2 * nq)
    k1 = np.broadcast_to(J, h.shape + (m, m))
    x2 = X + 0.5 * H * k1
    x2[..., :nq, :] = X[..., :nq, :] + 0.5 * H * X[..., v, :] + 0.125 * H * H * k1[..., v, :]
    k2 = J @ x2
    x3 = X + 0.5 * H * k2
    x3[..., :nq, :] = x2[..., :nq, :]
    k3 = J @ x3
    x4 = X + H * k3
    x4[..., :nq, :] = X[..., :nq, :] + H * X[..., v, :] + 0.5 * H * H * k3[..., v, :]
    k4 = J @ x4
    R = X + (H / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    R[..., :nq, :] = (X[..., :nq, :] + H * X[..., v, :]
                      + (H * H / 6.0) * (k1[..., v, :] + k2[..., v, :] + k3[..., v, :]))
    return R


#: spectral radius of the step map above which a step counts as unstable: a rigid mode's
#: Jordan block gives eigenvalues 1 ± O(√ε) in floating point
GROWTH_TOL = 1e-6


def rkn4_limit(J, nq: int, rate: float) -> float:
    """The largest step h for which the RKN4 step map of ẋ = J x (:func:`rkn4_map`) has
    spectral radius ≤ 1 (+ GROWTH_TOL) — besides the eigenvalues of modes that grow in
    the flow itself (Re λ > 0); ``rate`` = |λ|max of J. Unlike RK4's, RKN4's limit
    depends on how each mode is damped, not on |λ| alone — for q̈ + 2ζωq̇ + ω²q = 0:
    h·ω = 2.59 undamped, 3.2 at ζ = 0.1–0.3, 1.33 at ζ = 1 (its least over ζ; RK4:
    2.78–2.95), so it is found on the map itself: h·rate scanned at 0.25, 0.5, 0.75 and
    from 1 by 0.1 up to 4 for the first unstable step (the maps of a scan stacked in one
    eigenvalue call), then that interval refined by two scans of 8 points (to 1.6e-3/rate;
    two_link_free modal 3: 2 ms, a 0.05 scan took 7)."""
    if not rate > 0:
        return np.inf
    re = np.linalg.eigvals(J).real
    s = RKN4_SCAN
    i = _first_unstable(J, nq, rate, re, s)
    if i is None:
        return float(s[-1] / rate)
    lo, hi = (s[i - 1] if i > 0 else 0.0), s[i]
    for _ in range(2):
        s = np.linspace(lo, hi, 9)[1:]
        i = _first_unstable(J, nq, rate, re, s)
        lo, hi = (s[i - 1] if i > 0 else lo), s[i]
    return float(lo / rate)


#: the scan of h·|λ|max for RKN4's first unstable step (:func:`rkn4_limit`)
RKN4_SCAN = np.r_[0.25, 0.5, 0.75, np.arange(10, 41) * 0.1]


def rkn4_admits(J, nq: int, rate: float, h: float) -> bool:
    """Whether the fixed step ``h`` is within RKN4's stability limit on ẋ = J x: the
    scan of :func:`rkn4_limit` up to h·rate and h itself, all stable. What a run at a
    given step needs to know, at the cost of the scan's points below it (the limit's
    two refinements and the points above h are not computed)."""
    if not rate > 0:
        return True
    s = np.r_[RKN4_SCAN[RKN4_SCAN < h * rate], h * rate]
    return _first_unstable(J, nq, rate, np.linalg.eigvals(J).real, s) is None


def _first_unstable(J, nq, rate, re, s):
    """The index of the first step h = s/rate (s ascending) whose RKN4 map of ẋ = J x
    grows, or None; ``re``: Re λ of J. A linearization about a moving state can have
    modes that grow (Re λ > 0: the centrifugal terms of a turning arm); their map's
    eigenvalues grow as the flow does, e^{h·λ}, which is not the step's instability: at
    each step the n of them that grow beyond GROWTH_TOL are set aside and the step is
    unstable where the next one grows."""
    h = np.asarray(s, float) / rate
    mu = -np.sort(-np.abs(np.linalg.eigvals(rkn4_map(J, nq, h))), axis=1)
    n = (np.exp(np.outer(h, re)) > 1.0 + GROWTH_TOL).sum(axis=1)
    rho = mu[np.arange(len(h)), np.minimum(n, mu.shape[1] - 1)]
    bad = np.nonzero((rho > 1.0 + GROWTH_TOL) & (n < mu.shape[1]))[0]
    return int(bad[0]) if len(bad) else None


def _linearized(chain, q, qd, z):
    """The Jacobians of :func:`~flexarm_ros.model.linear.jacobians` about (q, q̇, z) and
    their largest |λ| (what :func:`admits` and :func:`stability` both start from)."""
    Js = jacobians(chain, q, qd, z)
    return Js, max(float(np.abs(np.linalg.eigvals(J)).max()) for J in Js)


def admits(chain, q, qd, z, integrator, h) -> bool:
    """Whether a fixed step ``h`` of the explicit ``integrator`` is stable about the state
    (q, q̇, z): RK4 h ≤ RK4_STABILITY/|λ|max, RKN4 by :func:`rkn4_admits` on every
    Jacobian of :func:`~flexarm_ros.model.linear.jacobians` — the answer of
    ``h <= stability(...)[1]`` without RKN4's limit itself (a scene's fixed step: a
    quarter of the scan's eigenvalue calls on two_link_free)."""
    Js, rate = _linearized(chain, q, qd, z)
    if integrator != "rkn4":
        return not rate > 0 or h <= RK4_STABILITY / rate
    return all(rkn4_admits(J, len(chain.free), rate, h) for J in Js)


def stability(chain, q, qd, z, integrator="rk4") -> tuple[float, float, float]:
    """(|λ|max, stability limit, automatic step) of an explicit fixed-step ``integrator``
    about the state (q, q̇, z). RK4: RK4_STABILITY/|λ|max and RK4_AUTO/|λ|max. RKN4: the
    limit from its step map on the linearization (:func:`rkn4_limit`, the least over the
    Jacobians of :func:`~flexarm_ros.model.linear.jacobians`) and the automatic step the
    same share of it as RK4's, RK4_AUTO/RK4_STABILITY, at most RK4_AUTO/|λ|max."""
    Js, rate = _linearized(chain, q, qd, z)
    if not rate > 0:
        return rate, np.inf, np.inf
    if integrator != "rkn4":
        return rate, RK4_STABILITY / rate, RK4_AUTO / rate
    limit = min(rkn4_limit(J, len(chain.free), rate) for J in Js)
    return rate, limit, min(RK4_AUTO / rate, RK4_AUTO / RK4_STABILITY * limit)
