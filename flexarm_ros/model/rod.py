"""The geometrically exact rung: a planar Kirchhoff rod parameterized by its strains.

Every other rung describes a beam by its transverse deflection w(x) = φ(x)ᵀη and keeps the
shortening of the neutral fibre to second order, −½ηᵀS(x)η: exact to second order in the
deflection, and 0.4 % (2e-3 m) off a geometrically exact solution on the spin-up at any
refinement (docs/accuracy.md). The rod describes the rotation θ(x) of every cross-section
exactly and the positions follow from it (Boyer et al. 2021, strain parameterization; Renda
et al. 2018):

    κ(x) = θ′(x) = Σ_k a_k P_k(2x/L − 1)     (curvature: Legendre polynomials P_0..P_{n−1})
    ε(x) = e · (1 − (x/L)²)                  (axial strain, when the beam declares EA)
    s(x) = (r_h, 0) + ∫₀ˣ (1 + ε) (cos θ, sin θ) dσ      (in the hub frame)

so θ(x) = Σ_k a_k Θ_k(x) with Θ_k = ∫₀ˣ P_k, linear in the coordinates, and so is the tip
frame's turn θ(L). The strain energy is quadratic: ½EI∫κ² + ½EA∫ε², K constant (Legendre
polynomials are orthogonal: EI·L/(2k+1) on the diagonal).

Why this formulation (measured on the spin-up: docs/physics.md §6.1 and
docs/decisions/0002-the-top-rung-and-the-check.md): few
coordinates, smooth (global polynomial) curvature, exact kinematics. The one axial
coordinate takes the shape of the static centrifugal stretch, ε ∝ 1 − (x/L)² (the exact
axial strain of a spinning uniform bar, N(x) ∝ L² − x²): the stretch matters below 1e-4 m
on the spin-up (5.1e-4 m at its tip), while a full axial polynomial expansion raises the
highest frequency — and so lowers the explicit step — about threefold per degree.
Piecewise-constant curvature converges only as h²; bending-mode bases for the curvature
converge non-monotonically.

Numerics. P Gauss–Legendre points carry the beam's mass (ρA·weight); the positions at the
points and at the tip come from the integration matrix W (W_ji = ∫₀^{x_j} ℓ_i, ℓ_i the
Lagrange polynomials through the Gauss points), exact for an integrand of degree < P and
spectrally accurate for the smooth (cos θ, sin θ). With f_i = (1 + ε_i)(cos θ_i, sin θ_i):

    s_j = (r_h, 0) + Σ_i W_ji f_i,
    ∂s_j/∂η_a = Σ_i W_ji [C_ia (cos θ_i, sin θ_i) + (1 + ε_i) T_ia (−sin θ_i, cos θ_i)],
    s̈_j = (∂s_j/∂η) η̈ + Σ_i W_ji [2 ε̇_i θ̇_i (−sin θ_i, cos θ_i) − (1 + ε_i) θ̇_i² (cos θ_i, sin θ_i)],

with T = ∂θ/∂η and C = ∂ε/∂η at the points. The chain turns these local kinematics into
the world as for every rung (r = o + A(ψ)s, ṙ, r̈ of :mod:`flexarm_ros.model.chain`).

The coordinates are the small-deflection modes of the rod carrying its tip body (linear
combinations of the Legendre coefficients and the stretch), scaled to unit peak deflection
(or unit tip stretch): the raw Legendre coefficients give a mass matrix of condition ~1e6.
``fidelity.rod_modes`` keeps only the lowest of them (and the stretch): the curvature
shapes of a longer rod on fewer coordinates, without its high rates — better than as many
Legendre terms where the beams bend little (two_link_free), worse where they bend far
(the spin-up); docs/decisions/0033-rod-modes.md.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import legendre as _leg

from flexarm_ros.errors import SceneError

#: curvature terms (Legendre polynomials P_0..P_{n−1}) by default
DEFAULT_TERMS = 5
#: most curvature terms (the mass matrix of the raw basis and the step degrade beyond)
MAX_TERMS = 16


def gauss_points(n_terms: int) -> int:
    """Gauss points along a rod of ``n_terms`` curvature terms: θ is a polynomial of
    degree n and the integrand (cos θ, sin θ) smooth. Measured on the spin-up (n = 5,
    20 s, whole-history tip error against n = 10): 6 points 1.41e-6 m, 7 to 10 points
    1.30e-6 m (the basis' own error); n + 3 keeps one point of margin, and the static
    elastica at P L²/EI = 3 (a 60° tip rotation) holds it (test_rod.py)."""
    return max(6, n_terms + 3)


@dataclass(frozen=True)
class RodBasis:
    """The rod's arrays, rows 0..P−1 the Gauss points and row P the tip:
    ``T`` (P+1, ne) = ∂θ/∂η, ``C`` (P+1, ne) = ∂ε/∂η, ``W`` (P+1, P) the integration
    matrix, ``hub_radius``; :meth:`local` evaluates the kinematics of every row."""
    T: np.ndarray
    C: np.ndarray
    W: np.ndarray
    hub_radius: float
    length: float
    terms: int
    axial: bool
    basis_x: np.ndarray          # the Gauss points (P,)
    transform: np.ndarray        # raw (Legendre, stretch) coordinates = transform @ η

    def local(self, eta, etad):
        """(s (P+1, 2), ∂s/∂η (P+1, 2, ne), a (P+1, 2)): positions in the hub frame, their
        Jacobian and the velocity-product acceleration (s̈ = (∂s/∂η)η̈ + a)."""
        return _local(self.T, self.C, self.W, self.hub_radius, eta, etad)

    def point_rows(self, x: float):
        """(W row (P,), T row (ne,), C row (ne,)) at abscissa 0 <= x <= L: a sensor's
        kinematics from the same quadrature."""
        x = min(max(float(x), 0.0), self.length)
        w = _integration_rows(self.basis_x, np.array([x]), self.length)[0]
        t_raw, c_raw = _raw_rows(np.array([x]), self.length, self.terms, self.axial)
        return w, t_raw[0] @ self.transform, c_raw[0] @ self.transform

    def rows_at(self, xs):
        """(W rows (N, P), T rows (N, ne), C rows (N, ne)) at the abscissae ``xs``: the
        rows of :meth:`point_rows` for many points at once."""
        xs = np.clip(np.asarray(xs, float), 0.0, self.length)
        w = _integration_rows(self.basis_x, xs, self.length)
        t_raw, c_raw = _raw_rows(xs, self.length, self.terms, self.axial)
        return w, t_raw @ self.transform, c_raw @ self.transform

    def positions_at(self, rows, eta):
        """Positions s (N, 2) in the hub frame at the abscissae of ``rows``
        (:meth:`rows_at`): :meth:`local_at`'s s for every point at once."""
        w, t_rows, c_rows = rows
        P = len(self.basis_x)
        s = _local(np.vstack([self.T[:P], t_rows]), np.vstack([self.C[:P], c_rows]),
                   np.vstack([np.zeros((P, P)), w]), self.hub_radius, eta,
                   np.zeros_like(eta))[0]
        return s[P:]

    def local_at(self, x: float, eta, etad):
        """(s (2,), ∂s/∂η (2, ne), a (2,), θ) at abscissa x."""
        w, t_row, c_row = self.point_rows(x)
        P = len(self.basis_x)
        T = np.vstack([self.T[:P], t_row[None]])
        C = np.vstack([self.C[:P], c_row[None]])
        W = np.vstack([np.zeros((P, P)), w[None]])
        s, ds, a = _local(T, C, W, self.hub_radius, eta, etad)
        return s[-1], ds[-1], a[-1], float(t_row @ eta)

    def tip_deflection(self, etas) -> np.ndarray:
        """The tip's transverse position in the hub frame (m) for rows of coordinates
        ``etas`` (N, ne): w(L) of the exact kinematics (zero etad needs no rates)."""
        etas = np.atleast_2d(np.asarray(etas, float))
        P = len(self.basis_x)
        th = etas @ self.T[:P].T                        # (N, P)
        eps = etas @ self.C[:P].T
        return ((1.0 + eps) * np.sin(th)) @ self.W[P]


def _local(T, C, W, hub_radius, eta, etad):
    P = W.shape[1]
    th = T[:P] @ eta
    thd = T[:P] @ etad
    eps = C[:P] @ eta
    epsd = C[:P] @ etad
    ct, st = np.cos(th), np.sin(th)
    fac = 1.0 + eps
    f = np.stack([fac * ct, fac * st], axis=1)                       # (P, 2)
    g = (C[:P, None, :] * np.stack([ct, st], axis=1)[:, :, None]
         + (fac[:, None] * np.stack([-st, ct], axis=1))[:, :, None] * T[:P, None, :])
    acc = (2.0 * epsd * thd)[:, None] * np.stack([-st, ct], axis=1) \
        - (fac * thd * thd)[:, None] * np.stack([ct, st], axis=1)
    s = W @ f
    s[:, 0] += hub_radius
    ds = np.einsum("ji,imk->jmk", W, g)
    a = W @ acc
    return s, ds, a


def _integration_rows(nodes, xs, length):
    """W (len(xs), P): W_ji = ∫₀^{x_j} ℓ_i over the Lagrange basis through ``nodes``."""
    P = len(nodes)
    xi_n = 2.0 * np.asarray(nodes) / length - 1.0
    V = _leg.legvander(xi_n, P - 1)                 # P × P: P_m at the nodes
    Vinv = np.linalg.inv(V)
    xi = 2.0 * np.asarray(xs, float) / length - 1.0
    ints = np.empty((len(xs), P))
    for m in range(P):
        c = np.zeros(m + 1)
        c[m] = 1.0
        ints[:, m] = _leg.legval(xi, _leg.legint(c, lbnd=-1)) * (0.5 * length)
    return ints @ Vinv


def _raw_rows(xs, length, terms, axial):
    """(∂θ/∂raw, ∂ε/∂raw) at abscissae ``xs``, raw = (a_0..a_{n−1}[, e])."""
    xi = 2.0 * np.asarray(xs, float) / length - 1.0
    ne = terms + (1 if axial else 0)
    T = np.zeros((len(xi), ne))
    C = np.zeros((len(xi), ne))
    for k in range(terms):
        c = np.zeros(k + 1)
        c[k] = 1.0
        T[:, k] = _leg.legval(xi, _leg.legint(c, lbnd=-1)) * (0.5 * length)
    if axial:
        C[:, terms] = 1.0 - ((xi + 1.0) * 0.5) ** 2
    return T, C


def curvature_rows(xs, length, terms, axial, transform) -> np.ndarray:
    """∂κ/∂η at abscissae ``xs`` (len, ne): strain at depth t/2 is (t/2)·κ."""
    xi = 2.0 * np.asarray(xs, float) / length - 1.0
    ne = terms + (1 if axial else 0)
    K = np.zeros((len(xi), ne))
    for k in range(terms):
        c = np.zeros(k + 1)
        c[k] = 1.0
        K[:, k] = _leg.legval(xi, c)
    return K @ transform


def kept_modes(modes: int, terms: int) -> int:
    """The bending coordinates per beam of a rod with ``terms`` curvature terms and
    ``fidelity.rod_modes`` = ``modes`` (0, or as many as the terms: all of them)."""
    return modes if 0 < modes < terms else terms


def build(beam, tip, terms: int, fidelity_refine_name: str = "fidelity.refine",
          points: int = 0, modes: int = 0):
    """(RodBasis, x, mass, K, D, M0, linear shape rows function, curvature rows function)
    of one beam: ``terms`` curvature terms, the stretch when the beam declares EA, the
    coordinates the small-deflection modes carrying ``tip`` (module doc) — all of them, or
    (``modes`` > 0) the lowest ``modes`` bending modes and the stretch (:func:`_build`);
    ``points`` Gauss points (0: :func:`gauss_points` of ``terms``, which carries the
    modes' own polynomial degree: link_tipmass on rod 12's lowest 3 modes has beam
    theory's frequencies to 1e-6 on its 15 points, its third 8e-4 off on 6; else at least
    one more than the bending coordinates, so that their mass matrix stays regular — fewer
    are cheaper where the check against the top rung allows: on two_link_free rod 8's
    lowest 3 / 4 modes read the same on 6 / 7 points as on 11)."""
    if not 1 <= terms <= MAX_TERMS:
        raise SceneError(f"{fidelity_refine_name}: got {terms} curvature terms for the rod "
                         f"rung, expected 1..{MAX_TERMS}")
    if not 0 <= modes <= terms:
        raise SceneError(f"fidelity.rod_modes: got {modes} for {terms} curvature terms, "
                         f"expected 0 (all {terms}) or 1..{terms} (the lowest bending modes "
                         f"of the {terms}-term rod kept as coordinates)")
    kept = kept_modes(modes, terms)
    if points and points < kept + 1:
        what = (f"{kept} curvature terms" if kept == terms else
                f"{kept} rod modes of {terms} curvature terms")
        raise SceneError(f"fidelity.rod_points: got {points} Gauss points for {what}, "
                         f"expected 0 (the default, {gauss_points(terms)}) or at least "
                         f"{kept + 1}")
    return _build(beam, tip, terms, points or gauss_points(terms), kept)


def _on_points(beam, terms, P):
    """The raw (Legendre, stretch) rod on P Gauss points: (x, mass, W, T_raw, C_raw,
    K_raw, ds0) — abscissae, point masses, the integration matrix, ∂θ/∂raw and ∂ε/∂raw
    at the points and the tip, the stiffness, and ∂s/∂raw at η = 0."""
    L = beam.length
    axial = getattr(beam, "EA", None) is not None
    gx, gw = _leg.leggauss(P)
    x = 0.5 * L * (gx + 1.0)
    w = 0.5 * L * gw
    xs = np.append(x, L)
    W = _integration_rows(x, xs, L)
    T_raw, C_raw = _raw_rows(xs, L, terms, axial)
    K_raw = _stiffness(beam, terms, axial, C_raw[:P], w)
    zero = np.zeros(T_raw.shape[1])
    _, ds0, _ = _local(T_raw, C_raw, W, beam.hub_radius, zero, zero)
    return x, beam.mass_per_length * w, W, T_raw, C_raw, K_raw, ds0


def _modes(tip, raw):
    """(vectors, scale, sign, bending) of the small-deflection modes carrying ``tip`` of
    the raw rod ``raw`` (:func:`_on_points`: its terms, its mass on its Gauss points;
    K_raw v = ω² M_raw v, ω rising): each vector's scale (its peak transverse deflection,
    or its tip stretch for the axial one), sign (the tip's) and whether it bends."""
    import scipy.linalg
    _, mass, _, T_raw, _, K_raw, ds0 = raw
    P = len(mass)
    M_raw = np.einsum("p,pik,pil->kl", mass, ds0[:P], ds0[:P])
    if tip is not None and (tip.mass > 0 or tip.inertia > 0):
        gy = ds0[P, 1] + tip.cg[0] * T_raw[P]            # CG of the tip body, transverse
        gx_ = ds0[P, 0] - tip.cg[1] * T_raw[P]           # ... axial
        M_raw = M_raw + tip.mass * (np.outer(gy, gy) + np.outer(gx_, gx_)) \
            + tip.inertia * np.outer(T_raw[P], T_raw[P])
    _, vecs = scipy.linalg.eigh(K_raw, M_raw)
    # scale: unit peak transverse deflection (bending) or unit tip stretch (axial)
    trans = ds0[:, 1, :] @ vecs                           # (P+1, ne) at the points and tip
    axl = ds0[P, 0, :] @ vecs
    bending = np.abs(trans).max(axis=0) >= np.abs(axl)
    scale = np.where(bending, np.abs(trans).max(axis=0), np.abs(axl))
    sign = np.sign(np.where(np.abs(trans[P]) > 0, trans[P], axl))
    sign[sign == 0] = 1.0
    return vecs, scale, sign, bending


def _stiffness(beam, terms, axial, C_pts, w):
    """K_raw of the (Legendre, stretch) coordinates: EI·L/(2k+1) on the diagonal (the
    Legendre polynomials are orthogonal), EA ∫ε² for the stretch."""
    ne = terms + (1 if axial else 0)
    K_raw = np.zeros((ne, ne))
    for k in range(terms):
        K_raw[k, k] = beam.EI * beam.length / (2 * k + 1)
    if axial:
        K_raw[terms, terms] = beam.EA * float(w @ C_pts[:, terms] ** 2)
    return K_raw


@functools.lru_cache(maxsize=32)
def _build(beam, tip, terms, P, kept):
    """The rod of :func:`build` on P Gauss points. All ``terms`` bending modes (kept =
    terms): the modes of the rod on those points, as sessions 20-25 shipped them. Fewer
    (kept < terms): the lowest ``kept`` bending modes of the ``terms``-term rod on its
    default quadrature — the curvature shapes a higher-order rod converges to, rather than
    the best ``kept``-term polynomials — and the stretch, then carried on P points. The
    lowest modes of a Galerkin basis are its accurate ones: on two_link_free three modes
    of the 8-term rod cut the link-2 tip deflection error of three Legendre terms to 0.4
    at 1 ms on 6 points (1.3e-6 against 3.3e-6 m of rod 12) at the same highest rate, 52 Hz,
    where four Legendre terms go to 107 Hz (docs/decisions/0033-rod-modes.md)."""
    L = beam.length
    axial = getattr(beam, "EA", None) is not None
    raw = _on_points(beam, terms, P)
    x, mass, W, T_raw, C_raw, K_raw, ds0 = raw
    if kept == terms:
        vecs, scale, sign, _ = _modes(tip, raw)
    else:
        vecs, scale, sign, bending = _modes(tip, _on_points(beam, terms, gauss_points(terms)))
        keep = np.flatnonzero(~bending | (np.cumsum(bending) <= kept))
        vecs, scale, sign = vecs[:, keep], scale[keep], sign[keep]
    V = vecs * (sign / scale)[None, :]
    basis = RodBasis(T_raw @ V, C_raw @ V, W, beam.hub_radius, L, terms, axial, x, V)
    K = V.T @ K_raw @ V
    M0 = V.T @ np.einsum("p,pik,pil->kl", mass, ds0[:P], ds0[:P]) @ V
    d = beam.damping
    D = d.viscous_per_length / beam.mass_per_length * _transverse_mass(mass, ds0, P, V) \
        + d.stiffness_proportional * K
    for a in (basis.T, basis.C, basis.W, K, D, M0):
        a.setflags(write=False)

    def shape(xq):                       # the transverse shape at η = 0 (small deflection)
        xq = np.atleast_1d(np.asarray(xq, float))
        Wq = _integration_rows(x, xq, L)
        return Wq @ (T_raw[:P] @ V)

    def curvature(xq):
        return curvature_rows(xq, L, terms, axial, V)

    return basis, x, mass, K, D, M0, shape, curvature


def _transverse_mass(mass, ds0, P, V):
    """Σ m φφᵀ of the transverse small-deflection shapes (the viscous damping's weight)."""
    phi = ds0[:P, 1, :] @ V
    return (phi * mass[:, None]).T @ phi


def suffixes(n: int) -> list[str]:
    """Coordinate names after the link name: ``rod1``..``rodN``, the small-deflection modes
    by rising frequency (the stretch among them when the beam declares EA)."""
    return [f"rod{i}" for i in range(1, n + 1)]
