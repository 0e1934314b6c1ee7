"""Closed-form and transcendental-equation results of Euler-Bernoulli beam theory.

These are the *independent truth* against which the numerical flexible-multibody model
is checked, so they are derived here from the beam equation and boundary conditions
alone, never from the model's own discretisation. Pure numpy / scipy, SI units.

Common notation (uniform beam, length ``L``, bending stiffness ``EI`` [N m^2], mass per
unit length ``rho_A`` [kg/m], transverse deflection ``w(x, t)``, ``x`` from the root):

* Equation of motion: ``EI w'''' + rho_A w_tt = 0``. For harmonic motion
  ``w = W(x) cos(omega t)``: ``W'''' = (beta/L)^4 W`` with the frequency parameter

      beta^4 = rho_A omega^2 L^4 / EI,   so   f = omega / (2 pi)
             = beta^2 / (2 pi L^2) * sqrt(EI / rho_A).

  ``beta`` is dimensionless throughout (the literature's ``lambda`` or ``beta_n L``).
* General solution, ``xi = x / L``:
  ``W = a cos(beta xi) + b sin(beta xi) + c cosh(beta xi) + d sinh(beta xi)``.
* Sign convention: bending moment ``EI w''`` and shear ``EI w'''`` as they appear in the
  boundary terms of Hamilton's principle,
  ``delta int EI w''^2 / 2 dx = [EI w'' dw']_0^L - [EI w''' dw]_0^L + int EI w'''' dw dx``.
  Every inertia boundary condition below follows from adding the lumped body's kinetic
  energy to that variation (so signs are derived, not remembered); they were also
  checked numerically against an independent Hermite-cubic finite-element eigen-solve
  (see ``test/test_beam_theory.py``).
* Dimensionless end loads: ``mu = M / (rho_A L)`` (tip mass ratio),
  ``j = J / (rho_A L^3)`` (tip rotary inertia ratio), ``eps = e / L`` (tip-CG offset),
  ``h = I_h / (rho_A L^3)`` (hub inertia ratio).

All characteristic functions are written with terms at most linear in ``cosh``/``sinh``
(the quadratic terms cancel exactly through ``cosh^2 - sinh^2 = 1``,
``cos^2 + sin^2 = 1``; done symbolically, not numerically), then divided by
``cosh(beta)`` and by a strictly positive polynomial in ``beta``. The result is bounded,
free of overflow and catastrophic cancellation for large ``beta``, and has no poles, so
its sign changes are exactly the roots.

References
----------
* R. D. Blevins, *Formulas for Natural Frequency and Mode Shape*, Van Nostrand
  Reinhold, 1979 (Krieger reprint 2001), ch. 8 (Table 8-1 single-span beams; beams
  carrying end masses).
* L. Meirovitch, *Fundamentals of Vibrations*, McGraw-Hill, 2001, sec. 8 (boundary
  conditions from the extended Hamilton principle, cantilever with tip mass).
* P. A. A. Laura, J. L. Pombo, E. A. Susemihl, "A note on the vibrations of a
  clamped-free beam with a mass at the free end", J. Sound Vib. 37(2), 1974, 161-168.
* F. Bellezza, L. Lanari, G. Ulivi, "Exact modeling of the flexible slewing link",
  Proc. IEEE ICRA 1990, 734-739 (hub-beam "unconstrained" modes).
* W. C. Young, R. G. Budynas, *Roark's Formulas for Stress and Strain*, 7th ed.,
  Table 8.1 cases 1a and 2a (cantilever statics).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

__all__ = [
    "clamped_free_betas",
    "clamped_free_frequencies_hz",
    "tip_loaded_betas",
    "tip_loaded_frequencies_hz",
    "hub_beam_betas",
    "hub_beam_frequencies_hz",
    "beta_to_hz",
    "cantilever_static_tip_deflection",
    "cantilever_static_tip_slope",
    "cantilever_curvature",
]

_XTOL = 1e-15
_RTOL = 4.0 * np.finfo(float).eps
# Root scan: geometric grid near zero, then a uniform grid much finer than the ~pi root
# spacing. Roots with beta < _BETA_MIN (omega < 1e-6 of sqrt(EI/rho_A)/L^2) are not
# searched; that needs end inertias ~1e12 times the beam's.
_BETA_MIN = 1e-3
_BETA_SPLIT = 0.5
_DBETA = 0.01
# |f| at an accepted root, relative to the function's O(1) scale (spurious-root guard).
_RESIDUAL_TOL = 1e-8


# --------------------------------------------------------------------------- helpers
def _sech(x):
    """sech(x) = 1/cosh(x) without overflow for large x (x >= 0)."""
    e = np.exp(-np.asarray(x, dtype=float))
    return 2.0 * e / (1.0 + e * e)


def _check_positive(name, value):
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


def _check_nonnegative(name, value, allow_inf=False):
    v = float(value)
    if math.isnan(v) or v < 0.0 or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


def _check_finite(name, value):
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def _check_n(n):
    if isinstance(n, bool) or int(n) != n or int(n) < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    return int(n)


def beta_to_hz(betas, EI, mass_per_length, length):
    """Convert dimensionless frequency parameters ``beta = beta_n L`` to hertz.

    ``f_n = beta_n^2 / (2 pi L^2) * sqrt(EI / rho_A)``, from
    ``beta^4 = rho_A omega^2 L^4 / EI`` (Blevins 1979, Table 8-1 header).
    """
    EI = _check_positive("EI", EI)
    rho_a = _check_positive("mass_per_length", mass_per_length)
    L = _check_positive("length", length)
    b = np.asarray(betas, dtype=float)
    return b * b / (2.0 * np.pi * L * L) * np.sqrt(EI / rho_a)


def _scan_roots(func, n, beta_max):
    """First ``n`` positive roots of ``func`` (bounded, pole-free) by sign-change scan.

    The scan range is extended until ``n`` roots are found; each bracket is refined with
    ``brentq`` and a root is accepted only if ``|func|`` there is tiny (guards against a
    sign change that is not a root).
    """
    roots = []
    lo_grid = np.geomspace(_BETA_MIN, _BETA_SPLIT, 200)
    grid = np.concatenate([lo_grid, np.arange(_BETA_SPLIT + _DBETA, beta_max, _DBETA)])
    start = 0
    while True:
        vals = func(grid)
        if not np.all(np.isfinite(vals)):
            raise FloatingPointError("characteristic function is not finite on the scan grid")
        for i in range(start, len(grid) - 1):
            f0, f1 = vals[i], vals[i + 1]
            if f0 == 0.0:
                r = grid[i]
            elif f0 * f1 < 0.0:
                r = brentq(func, grid[i], grid[i + 1], xtol=_XTOL, rtol=_RTOL, maxiter=200)
            else:
                continue
            if abs(float(func(r))) <= _RESIDUAL_TOL:
                roots.append(float(r))
                if len(roots) == n:
                    return np.array(roots)
        # Not enough roots yet: extend the grid by another ~n pi.
        start = len(grid) - 1
        ext = np.arange(grid[-1] + _DBETA, grid[-1] + (n + 2) * np.pi, _DBETA)
        grid = np.concatenate([grid, ext])
        if grid[-1] > 1e5:  # pragma: no cover - would mean a broken characteristic function
            raise RuntimeError(f"found only {len(roots)} of {n} roots below beta = 1e5")


# --------------------------------------------------------------------- clamped-free
def clamped_free_betas(n):
    """First ``n`` roots ``beta_k = (beta L)_k`` of the clamped-free (cantilever) beam.

    Boundary conditions: ``w(0) = w'(0) = 0`` (clamped), ``w''(L) = w'''(L) = 0`` (free).
    Characteristic equation (Blevins 1979, Table 8-1; Meirovitch 2001)::

        1 + cos(beta) cosh(beta) = 0.

    Solved in the equivalent, bounded form ``cos(beta) + sech(beta) = 0`` (divide by
    ``cosh``), which has no overflow and no cancellation: for large ``beta`` the root
    tends to ``(2k-1) pi / 2`` with correction ``(-1)^(k+1) 2 exp(-beta)`` that is
    resolved to full double precision. Root ``k`` is bracketed in ``[(k-1) pi, k pi]``,
    where the function changes sign exactly once.

    Returns 1.875104069, 4.694091133, 7.854757438, 10.99554073, 14.13716839, ...
    """
    n = _check_n(n)

    def f(b):
        return np.cos(b) + _sech(b)

    out = np.empty(n)
    for k in range(1, n + 1):
        out[k - 1] = brentq(f, (k - 1) * np.pi, k * np.pi, xtol=_XTOL, rtol=_RTOL,
                            maxiter=200)
    return out


def clamped_free_frequencies_hz(EI, mass_per_length, length, n):
    """First ``n`` natural frequencies [Hz] of a uniform clamped-free beam.

    ``f_k = beta_k^2 / (2 pi L^2) sqrt(EI / rho_A)`` with ``beta_k`` the roots of
    ``1 + cos(beta) cosh(beta) = 0`` (:func:`clamped_free_betas`; Blevins 1979,
    Table 8-1).
    """
    return beta_to_hz(clamped_free_betas(n), EI, mass_per_length, length)


# ------------------------------------------------------------------ tip-loaded cantilever
def _clamped_tip_D(b, mu, jt, kappa, delta):
    """Clamped-root / tip-body characteristic determinant, divided by cosh(beta).

    D = 1 + c C + mu b (S c - C s) - jt b^3 (C s + S c) - 2 kappa b^2 S s
          + delta b^4 (1 - c C)
    with c = cos b, s = sin b, C = cosh b, S = sinh b; returned as D / C.
    """
    b = np.asarray(b, dtype=float)
    c, s = np.cos(b), np.sin(b)
    sech, th = _sech(b), np.tanh(b)
    return (sech + c + mu * b * (th * c - s) - jt * b**3 * (s + th * c)
            - 2.0 * kappa * b**2 * th * s + delta * b**4 * (sech - c))


def _tip_scale(b, mu, jt, kappa, delta):
    """Strictly positive polynomial bounding the size of the tip terms."""
    return 1.0 + mu * b + abs(kappa) * b**2 + jt * b**3 + delta * b**4


def tip_loaded_betas(mu, j, n, eps=0.0):
    """First ``n`` roots ``beta = beta L`` of a clamped beam carrying a rigid tip body.

    Dimensionless form of :func:`tip_loaded_frequencies_hz`: ``mu = M/(rho_A L)``,
    ``j = J_cg/(rho_A L^3)``, ``eps = e/L``. See that function for the equation.
    """
    n = _check_n(n)
    mu = _check_nonnegative("mu", mu)
    j = _check_nonnegative("j", j)
    eps = _check_finite("eps", eps)
    jt, kappa, delta = j + mu * eps * eps, mu * eps, mu * j

    def f(b):
        return (_clamped_tip_D(b, mu, jt, kappa, delta)
                / _tip_scale(b, mu, jt, kappa, delta))

    return _scan_roots(f, n, (n + 1) * np.pi + 2.0)


def tip_loaded_frequencies_hz(EI, mass_per_length, length, tip_mass, tip_inertia, n,
                              tip_cg_offset=0.0):
    """First ``n`` natural frequencies [Hz] of a cantilever carrying a rigid tip body.

    Root clamped: ``w(0) = w'(0) = 0``. At ``x = L`` a rigid body of mass ``M``
    (``tip_mass`` [kg]) and rotary inertia ``J`` (``tip_inertia`` [kg m^2], about the
    body's own centre of mass, axis normal to the plane of bending) is rigidly attached,
    its CG at distance ``e`` (``tip_cg_offset`` [m], along the undeformed beam axis,
    positive outward) beyond the tip. With ``e = 0`` (default) the CG is at the tip and
    ``J`` is the inertia about the tip point.

    Boundary conditions (natural BCs of Hamilton's principle with tip kinetic energy
    ``T = 1/2 M (w_t + e w'_t)^2 + 1/2 J w'_t^2`` at ``x = L``)::

        EI w'''(L) = -omega^2 [ M w(L) + M e w'(L) ]              (shear)
        EI w''(L)  = +omega^2 [ M e w(L) + (J + M e^2) w'(L) ]     (moment)

    i.e. for ``e = 0``: ``EI w''' = -M omega^2 w`` and ``EI w'' = +J omega^2 w'``.
    Substituting ``W = a(cos - cosh) + b(sin - sinh)`` (clamped root eliminated from the
    4x4 determinant) gives, with ``c, s, C, S = cos, sin, cosh, sinh (beta)``,
    ``kappa = mu eps``, ``jt = j + mu eps^2``::

        1 + c C + mu beta (c S - s C) - jt beta^3 (s C + c S)
          - 2 kappa beta^2 s S + mu j beta^4 (1 - c C) = 0.

    For ``eps = 0`` this is the classical equation (Blevins 1979, ch. 8; Laura et al.
    1974; Meirovitch 2001); note the ``+ mu j beta^4 (1 - c C)`` sign, checked by the
    limit ``M, J -> inf`` -> clamped-clamped ``1 - c C = 0`` and by FEM. It is solved
    divided by ``cosh(beta) (1 + mu beta + |kappa| beta^2 + jt beta^3 + mu j beta^4)``
    (positive, no poles) by a fine sign-change scan plus ``brentq``.

    ``M = J = 0`` reduces to :func:`clamped_free_frequencies_hz`. Returns ``f`` with
    ``beta^4 = rho_A (2 pi f)^2 L^4 / EI``.
    """
    _check_positive("EI", EI)
    rho_a = _check_positive("mass_per_length", mass_per_length)
    L = _check_positive("length", length)
    M = _check_nonnegative("tip_mass", tip_mass)
    J = _check_nonnegative("tip_inertia", tip_inertia)
    e = _check_finite("tip_cg_offset", tip_cg_offset)
    betas = tip_loaded_betas(M / (rho_a * L), J / (rho_a * L**3), n, e / L)
    return beta_to_hz(betas, EI, rho_a, L)


# -------------------------------------------------------------------------- hub + beam
def hub_beam_betas(h, n, mu=0.0, j=0.0, eps=0.0):
    """First ``n`` non-zero roots ``beta = beta L`` of the free hub + beam system.

    Dimensionless form of :func:`hub_beam_frequencies_hz`: ``h = I_h/(rho_A L^3)``
    (``h = inf`` allowed: clamped root), ``mu, j, eps`` as in :func:`tip_loaded_betas`.
    """
    n = _check_n(n)
    h = _check_nonnegative("h", h, allow_inf=True)
    mu = _check_nonnegative("mu", mu)
    j = _check_nonnegative("j", j)
    eps = _check_finite("eps", eps)
    if math.isinf(h):
        return tip_loaded_betas(mu, j, n, eps)
    jt, kappa, delta = j + mu * eps * eps, mu * eps, mu * j

    def f(b):
        b = np.asarray(b, dtype=float)
        c, s = np.cos(b), np.sin(b)
        th = np.tanh(b)
        b3 = b**3
        # D0 / cosh: pinned-root (h = 0) characteristic function.
        d0 = (s - th * c + 2.0 * jt * b3 * c + 2.0 * kappa * b**2 * (s + th * c)
              + 2.0 * mu * b * th * s - delta * b**4 * (s - th * c))
        d = d0 + h * b3 * _clamped_tip_D(b, mu, jt, kappa, delta)
        # D ~ 2 b^3 (h + I_total/(rho_A L^3)) as b -> 0 (the rigid mode): divide by
        # b^3/(1 + b^3) so the 0 Hz root is removed and f(0+) > 0.
        scale = _tip_scale(b, mu, jt, kappa, delta) * (1.0 + h * b3)
        return d * (1.0 + b3) / (b3 * scale)

    return _scan_roots(f, n, (n + 1) * np.pi + 2.0)


def hub_beam_frequencies_hz(EI, mass_per_length, length, hub_inertia, n, tip_mass=0.0,
                            tip_inertia=0.0, tip_cg_offset=0.0):
    """First ``n`` NON-ZERO natural frequencies [Hz] of a beam on a free rotating hub.

    The beam root is rigidly clamped to a rigid hub of rotary inertia ``I_h``
    (``hub_inertia`` [kg m^2]) that turns freely (no spring, no motor torque) about a
    fixed axis through the beam root (hub radius 0). ``w`` is measured in the inertial
    frame, so the hub angle is the root slope ``theta = w'(0)``. Root BCs::

        w(0) = 0,      I_h theta_tt = EI w''(0)   ->   EI w''(0) = -I_h omega^2 w'(0)

    (hub moment balance; natural BC of Hamilton's principle with ``T_hub = 1/2 I_h
    w'_t(0)^2``). Tip: free, or a rigid tip body with ``tip_mass``, ``tip_inertia``
    (about its CG) and ``tip_cg_offset`` exactly as in :func:`tip_loaded_frequencies_hz`.

    With ``h = I_h/(rho_A L^3)`` and ``D_c`` the clamped/tip-body function of
    :func:`tip_loaded_frequencies_hz`, the characteristic equation is::

        D_0 + h beta^3 D_c = 0,
        D_0 = (s C - c S) + 2 jt beta^3 c C + 2 kappa beta^2 (s C + c S)
              + 2 mu beta s S - mu j beta^4 (s C - c S),

    where ``D_0 = 0`` is the pinned-root (``I_h = 0``) equation. For a free tip this is
    ``tan(beta) - tanh(beta) + h beta^3 (1 + cos(beta) cosh(beta)) / (cos(beta)
    cosh(beta)) = 0`` (cf. Bellezza, Lanari & Ulivi 1990, "unconstrained" modes).

    The rigid-body rotation (``omega = 0``; ``D ~ 2 beta^3 (h + I_total/(rho_A L^3))``
    as ``beta -> 0``) is EXCLUDED: the function is solved divided by ``beta^3`` so only
    the flexible modes are returned. Limits: ``I_h -> inf`` gives the clamped-free /
    tip-loaded values (``hub_inertia = numpy.inf`` is accepted and delegates to
    :func:`tip_loaded_frequencies_hz`); ``I_h -> 0`` gives the pinned-free values
    ``beta = 3.926602, 7.068583, ...`` (roots of ``tan beta = tanh beta``, Blevins 1979
    Table 8-1).
    """
    _check_positive("EI", EI)
    rho_a = _check_positive("mass_per_length", mass_per_length)
    L = _check_positive("length", length)
    Ih = _check_nonnegative("hub_inertia", hub_inertia, allow_inf=True)
    M = _check_nonnegative("tip_mass", tip_mass)
    J = _check_nonnegative("tip_inertia", tip_inertia)
    e = _check_finite("tip_cg_offset", tip_cg_offset)
    betas = hub_beam_betas(Ih / (rho_a * L**3), n, M / (rho_a * L), J / (rho_a * L**3),
                           e / L)
    return beta_to_hz(betas, EI, rho_a, L)


# ------------------------------------------------------------------------------ statics
def _static_loads(EI, mass_per_length, length, gravity, tip_mass):
    EI = _check_positive("EI", EI)
    rho_a = _check_nonnegative("mass_per_length", mass_per_length)
    L = _check_positive("length", length)
    g = abs(_check_finite("gravity", gravity))
    M = _check_nonnegative("tip_mass", tip_mass)
    return EI, L, rho_a * g, M * g


def cantilever_static_tip_deflection(EI, mass_per_length, length, gravity, tip_mass):
    """Static tip deflection [m] of a horizontal cantilever under its own weight + tip mass.

    Clamped at ``x = 0``, free at ``x = L``, uniform load ``q = rho_A g`` [N/m] plus tip
    point load ``P = M g`` [N], both transverse (gravity normal to the beam). Small
    deflection, linear Euler-Bernoulli; superposition of Roark Table 8.1 cases 2a and 1a
    (Blevins 1979 ch. 7 / any strength-of-materials text)::

        delta = q L^4 / (8 EI) + P L^3 / (3 EI).

    ``gravity`` is a magnitude (its sign is ignored); the result is the positive
    magnitude of the deflection, which points in the direction of gravity. Tip body
    treated as a point mass at the tip (its rotary inertia has no static effect).
    """
    EI, L, q, P = _static_loads(EI, mass_per_length, length, gravity, tip_mass)
    return q * L**4 / (8.0 * EI) + P * L**3 / (3.0 * EI)


def cantilever_static_tip_slope(EI, mass_per_length, length, gravity, tip_mass):
    """Static tip slope [rad] (magnitude) of a cantilever under its own weight + tip mass.

    Same loading and conventions as :func:`cantilever_static_tip_deflection`
    (Roark Table 8.1 cases 2a, 1a)::

        theta_L = q L^3 / (6 EI) + P L^2 / (2 EI),  q = rho_A g,  P = M g.

    The tip rotates so the beam droops toward gravity.
    """
    EI, L, q, P = _static_loads(EI, mass_per_length, length, gravity, tip_mass)
    return q * L**3 / (6.0 * EI) + P * L**2 / (2.0 * EI)


def cantilever_curvature(EI, mass_per_length, length, gravity, tip_mass, x):
    """Static curvature ``w''(x) = M_b(x) / EI`` [1/m] (magnitude) of a loaded cantilever.

    Bending moment at section ``x`` from the load outboard of it (uniform ``q = rho_A g``
    plus tip point load ``P = M g``)::

        M_b(x) = q (L - x)^2 / 2 + P (L - x),     kappa(x) = M_b(x) / EI,

    maximal at the root ``(q L^2 / 2 + P L) / EI``, zero at the free end. Returned as a
    non-negative magnitude (hogging, concave toward gravity). Integrating twice with
    ``w(0) = w'(0) = 0`` gives :func:`cantilever_static_tip_slope` and
    :func:`cantilever_static_tip_deflection`. ``x`` [m] may be a scalar or array in
    ``[0, L]``; returns a float for scalar ``x``.
    """
    EI, L, q, P = _static_loads(EI, mass_per_length, length, gravity, tip_mass)
    xa = np.asarray(x, dtype=float)
    if np.any(~np.isfinite(xa)) or np.any(xa < 0.0) or np.any(xa > L):
        raise ValueError(f"x must lie in [0, length={L}], got {x!r}")
    r = L - xa
    k = (q * r * r / 2.0 + P * r) / EI
    return float(k) if k.ndim == 0 else k


# ------------------------------------------------------------------ the large deflection
def elastica_tip(alpha):
    """The tip of a cantilever under a tip load P that keeps its direction (perpendicular
    to the unloaded beam), inextensible, at any deflection (the elastica; Bisshopp &
    Drucker, Q. Appl. Math. 3, 1945, 272-275), ``alpha = P L² / EI``: returns
    ``(u/L, v/L, theta0)`` — the tip's shortening along the unloaded axis, its deflection
    along the load and its slope (rad).

    With the tip slope θ₀, ``k = sqrt((1 + sin θ₀)/2)`` and ``sin φ₁ = 1 / (k √2)``:

        √α = K(k) − F(φ₁, k),
        v/L = 1 − 2 [E(k) − E(φ₁, k)] / √α,
        x_tip/L = sqrt(2 sin θ₀ / α),   u/L = 1 − x_tip/L,

    K, F, E, E(φ, k) the complete and incomplete elliptic integrals (modulus k; scipy's
    parameter m = k²). θ₀ is found by Brent's method on the first equation, which rises
    monotonically from 0 (θ₀ = 0) to ∞ (θ₀ → π/2)."""
    from scipy.special import ellipe, ellipeinc, ellipk, ellipkinc
    _check_positive("alpha", alpha)

    def parts(theta0):
        k2 = 0.5 * (1.0 + math.sin(theta0))
        phi1 = math.asin(min(1.0, 1.0 / math.sqrt(2.0 * k2)))
        return k2, phi1

    def residual(theta0):
        k2, phi1 = parts(theta0)
        return ellipk(k2) - ellipkinc(phi1, k2) - math.sqrt(alpha)

    theta0 = brentq(residual, 1e-15, 0.5 * math.pi - 1e-12, xtol=1e-15, rtol=_RTOL)
    k2, phi1 = parts(theta0)
    v = 1.0 - 2.0 * (ellipe(k2) - ellipeinc(phi1, k2)) / math.sqrt(alpha)
    u = 1.0 - math.sqrt(2.0 * math.sin(theta0) / alpha)
    return u, v, theta0
