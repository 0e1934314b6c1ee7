"""Beam discretizations: the rungs of the fidelity ladder behind one interface.

Every rung describes the transverse deflection of a beam clamped to its hub as
``w(x) = φ(x)ᵀ η`` and the foreshortening of its neutral fibre as
``u_f(x) = −½ ηᵀ S(x) η`` with ``S(x) = ∫₀ˣ φ′ φ′ᵀ ds`` (docs/physics.md §3.1).
A rung hands the chain a :class:`BeamDiscretization`: mass points (abscissa, mass, φ, S),
the tip quantities (φ(L), φ′(L), S(L)), the stiffness K and damping D matrices and the
curvature basis φ″ for strain. The chain never needs to know which rung it got.

| rung   | coordinates                     | source                                    |
|--------|---------------------------------|-------------------------------------------|
| rigid  | 1 spring angle, K = 3EI/L       | seed 000 low-fidelity model               |
| cubic  | tip displacement, tip rotation  | seed 000 / seed 002 cubic shape functions |
| modal  | N mode amplitudes               | seed 002 modal model (modes from FEM)     |
| fem    | (w, θ) per node, Hermite cubic  | convergence reference                     |
| fd     | nodal deflections y1..yn        | seed 001 finite differences               |
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np

from flexarm_ros.errors import SceneError
from flexarm_ros.scene.sections import Beam

#: default refinement per rung (modes / elements / FD segments)
DEFAULT_REFINE = {"rigid": 1, "cubic": 1, "modal": 4, "fem": 8, "fd": 20, "rod": 5}

_GAUSS_POINTS = 4  # per element: integrates degree-7 polynomials exactly


@dataclass(frozen=True)
class BeamDiscretization:
    """What a rung gives the chain for one beam (all arrays read-only).

    Shapes: P mass points, ne elastic coordinates.
    ``x`` (P,), ``mass`` (P,) in kg, ``phi`` (P, ne), ``S`` (P, ne, ne),
    ``phi_tip``/``slope_tip`` (ne,), ``S_tip`` (ne, ne), ``K``/``D``/``M_e`` (ne, ne).
    """
    rung: str
    refine: int
    coord_suffixes: tuple[str, ...]
    length: float
    hub_radius: float
    x: np.ndarray
    mass: np.ndarray
    phi: np.ndarray
    S: np.ndarray
    phi_tip: np.ndarray
    slope_tip: np.ndarray
    S_tip: np.ndarray
    K: np.ndarray
    D: np.ndarray
    M_e: np.ndarray
    curvature_fn: Callable[[np.ndarray], np.ndarray]
    shape_fn: Callable[[np.ndarray], np.ndarray]
    point_fn: Callable[[float], tuple] = None
    #: the rod rung's exact kinematics (:class:`flexarm_ros.model.rod.RodBasis`); None on
    #: every other rung. φ, φ(L) and S of a rod are its small-deflection shapes (S zero):
    #: what linear analyses read; the chain's kinematics use the rod's own
    rod: object = None

    @property
    def n(self) -> int:
        return len(self.coord_suffixes)

    @property
    def coord_units(self) -> tuple[str, ...]:
        """SI unit of each coordinate: the rigid rung's spring angle and the nodal slopes
        rad; nodal deflections and modal amplitudes (modes scaled to unit peak deflection)
        m."""
        if self.rung == "rigid":
            return ("rad",) * self.n
        if self.rung == "rod":      # modes scaled to unit peak deflection (or stretch)
            return ("m",) * self.n
        if self.rung in ("cubic", "fem"):
            return ("m", "rad") * (self.n // 2)
        return ("m",) * self.n

    def curvature(self, x) -> np.ndarray:
        """φ″(x), shape (len(x), ne): strain at depth t/2 is (t/2)·φ″(x)ᵀη."""
        return self.curvature_fn(np.atleast_1d(np.asarray(x, float)))

    def tip_deflections(self, etas) -> np.ndarray:
        """w(L), the tip's transverse position in the hub frame, for rows of elastic
        coordinates (N, ne): φ(L)ᵀη, or the rod's exact kinematics."""
        etas = np.atleast_2d(np.asarray(etas, float))
        if self.rod is not None:
            return self.rod.tip_deflection(etas)
        return etas @ self.phi_tip

    def deflection(self, x, eta) -> np.ndarray:
        """w(x) for elastic coordinates ``eta`` (rigid rung: x·β, small angle)."""
        return self.shape(x) @ np.asarray(eta)

    def shape(self, x) -> np.ndarray:
        """φ(x), shape (len(x), ne)."""
        return self.shape_fn(np.atleast_1d(np.asarray(x, float)))

    def point(self, x: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(φ(x), φ′(x), S(x)) at one abscissa 0 <= x <= L, consistent with the mass points
        (same basis, S(x) = ∫₀ˣ φ′φ′ᵀ by the same quadrature): a sensor's kinematics."""
        return self.point_fn(float(x))


# --------------------------------------------------------------------------------------
# Hermite cubic elements (also the cubic rung, n = 1, and the modal rung's parent)
# --------------------------------------------------------------------------------------

def _hermite_eval(x, length, n_el):
    """Hermite cubic shape functions of a clamped beam with ``n_el`` equal elements.

    Returns φ, φ′, φ″ with shape (len(x), 2·n_el), coordinates ordered
    [w1, θ1, w2, θ2, …, w_n, θ_n] (node 0, the clamped root, removed).
    """
    x = np.clip(np.asarray(x, float), 0.0, length)
    h = length / n_el
    e = np.minimum((x / h).astype(int), n_el - 1)
    xi = (x - e * h) / h
    N = np.stack([1 - 3 * xi**2 + 2 * xi**3, h * (xi - 2 * xi**2 + xi**3),
                  3 * xi**2 - 2 * xi**3, h * (-xi**2 + xi**3)], axis=1)
    dN = np.stack([(-6 * xi + 6 * xi**2) / h, 1 - 4 * xi + 3 * xi**2,
                   (6 * xi - 6 * xi**2) / h, -2 * xi + 3 * xi**2], axis=1)
    ddN = np.stack([(-6 + 12 * xi) / h**2, (-4 + 6 * xi) / h,
                    (6 - 12 * xi) / h**2, (-2 + 6 * xi) / h], axis=1)
    ndof = 2 * (n_el + 1)
    out = []
    rows = np.arange(len(x))
    for arr in (N, dN, ddN):
        full = np.zeros((len(x), ndof))
        for k in range(4):       # one entry per row and k: plain indexing adds as add.at
            full[rows, 2 * e + k] += arr[:, k]
        out.append(full[:, 2:])
    return out


def _gauss_build(rung, refine, suffixes, length, hub_radius, rho_a, EI, damping,
                 breaks, evaluate, K=None, gauss_points=_GAUSS_POINTS, with_S=True):
    """Mass points, S(x) and matrices of a basis that is polynomial between ``breaks``.

    S(x) = ∫₀ˣ φ′φ′ᵀ ds is integrated element by element with Gauss–Legendre quadrature
    (exact for the piecewise-cubic bases used here); the mass points are the Gauss points
    with mass ρA·weight. K = EI ∫ φ″φ″ᵀ dx unless given (rigid rung). ``with_S=False``:
    matrices only (S, S_tip and the point function are None): the fine eigen-solve mesh of
    the modal rung, whose S tensor (points × coordinates²) would take gigabytes.
    """
    gx, gw = np.polynomial.legendre.leggauss(gauss_points)
    a, b = breaks[:-1], breaks[1:]
    half = 0.5 * (b - a)
    xs = (a[:, None] + half[:, None] * (gx[None, :] + 1)).ravel()
    ws = (half[:, None] * gw[None, :]).ravel()
    phi, dphi, ddphi = evaluate(xs)
    ne = phi.shape[1]
    if not with_S:
        mass = rho_a * ws
        M_e, K = _mass_stiffness(mass, ws, phi, ddphi, EI, K)
        phiL, dphiL, _ = evaluate(np.array([length]))
        D = damping.viscous_per_length / rho_a * M_e + damping.stiffness_proportional * K
        return BeamDiscretization(rung, refine, tuple(suffixes), length, hub_radius, xs, mass,
                                  phi, None, phiL[0], dphiL[0], None, _sym(K), _sym(D),
                                  _sym(M_e), lambda x: evaluate(x)[2],
                                  lambda x: evaluate(x)[0], None)
    # element integrals of φ′φ′ᵀ, cumulative at element starts
    elem = np.einsum("p,pi,pj->pij", ws, dphi, dphi).reshape(len(a), gauss_points, ne, ne)
    elem_tot = elem.sum(axis=1)
    start = np.concatenate([np.zeros((1, ne, ne)), np.cumsum(elem_tot, axis=0)[:-1]])
    # partial integral from element start to each Gauss point
    S = np.empty((len(xs), ne, ne))
    for k, xk in enumerate(xs):
        el = k // gauss_points
        lo = a[el]
        hk = 0.5 * (xk - lo)
        px = lo + hk * (gx + 1)
        _, dp, _ = evaluate(px)
        S[k] = start[el] + np.einsum("p,pi,pj->ij", hk * gw, dp, dp)
    S_tip = start[-1] + elem_tot[-1]
    mass = rho_a * ws
    M_e, K = _mass_stiffness(mass, ws, phi, ddphi, EI, K)
    phiL, dphiL, _ = evaluate(np.array([length]))
    D = damping.viscous_per_length / rho_a * M_e + damping.stiffness_proportional * K

    def point(x):
        x = min(max(x, 0.0), length)
        el = min(int(np.searchsorted(breaks, x, side="right")) - 1, len(a) - 1)
        hk = 0.5 * (x - a[el])
        _, dp, _ = evaluate(a[el] + hk * (gx + 1))
        Sx = start[el] + np.einsum("p,pi,pj->ij", hk * gw, dp, dp)
        ph, dph, _ = evaluate(np.array([x]))
        return ph[0], dph[0], Sx

    return BeamDiscretization(rung, refine, tuple(suffixes), length, hub_radius, xs, mass,
                              phi, S, phiL[0], dphiL[0], S_tip, _sym(K), _sym(D), _sym(M_e),
                              lambda x: evaluate(x)[2], lambda x: evaluate(x)[0], point)


def _mass_stiffness(mass, ws, phi, ddphi, EI, K=None):
    """M = Σ_p m_p φ_p φ_pᵀ and (unless given) K = EI Σ_p w_p φ″_p φ″_pᵀ over the quadrature
    points, as matrix products (BLAS: einsum's loop took 0.1 s on a modal rung's 144-element
    eigen-solve mesh); the same in the full and the matrices-only build."""
    M_e = (phi * mass[:, None]).T @ phi
    if K is None:
        K = EI * ((ddphi * ws[:, None]).T @ ddphi)
    return M_e, K


def _sym(a):
    a = 0.5 * (a + a.T)
    a.setflags(write=False)
    return a


def hermite_fem(beam, n_el, rung="fem", suffixes=None, refine=None, with_S=True):
    """Hermite cubic finite elements, ``n_el`` per beam (2 coordinates per node)."""
    L = beam.length
    if suffixes is None:
        suffixes = [f"{k}{i}" for i in range(1, n_el + 1) for k in ("w", "th")]
    return _gauss_build(rung, n_el if refine is None else refine, suffixes, L, beam.hub_radius,
                        beam.mass_per_length, beam.EI, beam.damping,
                        np.linspace(0.0, L, n_el + 1), lambda x: _hermite_eval(x, L, n_el),
                        with_S=with_S)


def cubic(beam):
    """Single cubic: tip displacement and tip rotation (seed 000 Eq. 3.25 shape functions
    φ_d = 3x²/L² − 2x³/L³, φ_r = x³/L² − x²/L); identical to one Hermite element."""
    return hermite_fem(beam, 1, rung="cubic", suffixes=["tip_disp", "tip_rot"], refine=1)


def rigid_spring(beam):
    """Rigid link on a torsional spring at the hub: w = x·β, K = 3EI/L (tip-load equivalent
    stiffness, seed 000 low-fidelity model); foreshortening −½xβ² is the second-order
    expansion of x(cos β − 1)."""
    L = beam.length

    def evaluate(x):
        x = np.asarray(x, float)
        return x[:, None], np.ones((len(x), 1)), np.zeros((len(x), 1))

    K = np.array([[3.0 * beam.EI / L]])
    return _gauss_build("rigid", 1, ["spring"], L, beam.hub_radius, beam.mass_per_length,
                        beam.EI, beam.damping, np.array([0.0, L]), evaluate, K=K)


def natural_modes(beam, tip, n_modes, with_tip=True, mesh=None, n_segments=None,
                  hub_inertia=None):
    """The first ``n_modes`` clamped modes of the beam, from a Hermite FEM eigen-solve.

    With ``with_tip`` the tip body's mass, inertia and CG offset are included in the
    eigenproblem (modes that can carry the tip shear, docs/physics.md §5.2); otherwise plain
    clamped-free modes. With ``hub_inertia`` (kg·m² about the joint axis) the root is not
    held: the beam sits on its hub, which turns freely about the joint with that inertia
    (``fidelity.modal_basis: free_hub``, :func:`hub_load`), and the shapes are the elastic
    modes of that system seen from the hub (the deflection relative to the hub's turn:
    still zero deflection and slope at the root, an admissible clamped-frame basis). Each
    mode is scaled to unit peak deflection, positive at the tip. The FEM eigen-solve avoids
    the textbook closed form, which cancels catastrophically above ~8 modes.
    """
    L = beam.length
    n_fe = mesh or max(48, 12 * n_modes)   # eigen-solve error < 1e-6 up to 12 modes
    hub = None if hub_inertia is None else (float(hub_inertia), float(beam.hub_radius))
    K, V = _mode_shapes(beam.length, beam.mass_per_length, tip if with_tip else None, n_fe,
                        max(n_modes, n_fe // 12), hub)
    K = beam.EI * K
    V = V[:, :n_modes]

    def evaluate(x):
        return [a @ V for a in _hermite_eval(x, L, n_fe)]

    suffixes = [f"mode{i}" for i in range(1, n_modes + 1)]
    # quadrature on N segments of 6 Gauss points, coarser than the eigen-solve mesh:
    # measured frequency error <= 2.3e-6 against the closed forms for N = 2…8 with 6N points
    # (4 points on N segments: 1.2e-4; on 2N segments: 1e-6 with 8N points, 33 % dearer)
    n_q = n_segments or max(2, n_modes)
    return _gauss_build("modal", n_modes, suffixes, L, beam.hub_radius, beam.mass_per_length,
                        beam.EI, beam.damping, np.linspace(0.0, L, n_q + 1), evaluate,
                        K=V.T @ K @ V, gauss_points=6)


@functools.lru_cache(maxsize=32)
def _mode_shapes(length, mass_per_length, tip, n_fe, n_modes, hub=None):
    """(K, V) of :func:`natural_modes`: the FEM stiffness of ``n_fe`` Hermite elements per
    unit EI and its first ``n_modes`` clamped modes (with the tip body's mass when ``tip``
    is given; on a hub free to turn when ``hub`` = (inertia about the joint, hub radius) is
    given: :func:`_free_hub_modes`), scaled to unit peak deflection, positive at the tip.
    The shapes of
    K v = ω² M v do not depend on EI (K is EI times a matrix of the geometry), so the key
    holds only what they depend on: a calibration or sweep of EI reuses one eigen-solve
    (it was 36 % of a link_motor fit). Kept per process (read-only): the ladder's modal
    rungs on one mesh share one eigen-solve (rung auto builds several)."""
    L = length
    beam = Beam(length=length, EI=1.0, mass_per_length=mass_per_length)
    fe = hermite_fem(beam, n_fe, with_S=False)       # K and M only: no S tensor
    K, M = np.array(fe.K), np.array(fe.M_e)
    import scipy.linalg       # lazily: start-up time of runs that never need it
    if hub is not None:
        vecs = _free_hub_modes(fe, K, M, tip, hub, n_modes)
    else:
        if tip is not None and (tip.mass > 0 or tip.inertia > 0):
            M = M + _tip_body_mass(fe.phi_tip, fe.slope_tip, tip)
        vals, vecs = scipy.linalg.eigh(K, M, subset_by_index=[0, n_modes - 1])
    xs = np.linspace(0, L, 8 * n_fe + 1)
    peak = np.abs(_hermite_eval(xs, L, n_fe)[0] @ vecs).max(axis=0)
    sign = np.sign(fe.phi_tip @ vecs)
    sign[sign == 0] = 1.0
    V = vecs * (sign / peak)[None, :]
    K.setflags(write=False)
    V.setflags(write=False)
    return K, V


def _free_hub_modes(fe, K, M, tip, hub, n_modes):
    """The clamped-frame shapes (deflection relative to the hub) of the first ``n_modes``
    elastic modes of the beam on a hub that turns freely about the joint axis: the
    eigen-solve of (hub angle ψ, beam coordinates) with the kinetic energy
    ½ I_h ψ̇² + ½ ∫ ρA ((r + x) ψ̇ + ẇ)² dx + the tip body's (its CG at (r + L + c_x, c_y)
    in the hub frame, turning with ψ + w′(L)) and the strain energy of w only; the rigid
    turn (ω = 0) is left out. ``hub`` = (I_h about the joint, hub radius r). On a one-link
    arm these are the arm's own modes: the hub angle and n such shapes span its first
    n + 1 linear modes exactly (Rayleigh–Ritz), where clamped modes only approach them."""
    import scipy.linalg
    inertia, r = hub
    L = float(fe.length)
    ne = K.shape[0]
    arm = r + fe.x
    Ma = np.zeros((ne + 1, ne + 1))
    Ma[0, 0] = inertia + float(fe.mass @ arm ** 2)
    Ma[0, 1:] = Ma[1:, 0] = (fe.phi * fe.mass[:, None]).T @ arm
    Ma[1:, 1:] = M
    if tip is not None and (tip.mass > 0 or tip.inertia > 0):
        cx, cy = tip.cg
        across = np.r_[r + L + cx, fe.phi_tip + cx * fe.slope_tip]   # CG's velocity across
        along = np.r_[-cy, -cy * fe.slope_tip]                        # ... and along
        turn = np.r_[1.0, fe.slope_tip]
        Ma += tip.mass * (np.outer(across, across) + np.outer(along, along)) \
            + tip.inertia * np.outer(turn, turn)
    Ka = np.zeros_like(Ma)
    Ka[1:, 1:] = K
    _, vecs = scipy.linalg.eigh(Ka, Ma, subset_by_index=[1, n_modes])
    return np.ascontiguousarray(vecs[1:, :])


def hub_load(links, k, basis):
    """The hub inertia (kg·m² about the joint axis) that the modal rung's modes of link
    ``k`` turn with under ``fidelity.modal_basis: free_hub`` (None for the other bases:
    a root held still). The hub body about the joint, plus the drive inertia where the
    joint is rigid (no flexibility, no backlash: the drive turns with the hub); behind a
    flexible joint or backlash the motor side is left out (measured on link_flexjoint:
    the spring at 1 Hz leaves the hub all but free at the beam's frequencies). The inboard
    links are held still."""
    if basis != "free_hub":
        return None
    lk = links[k]
    hub = lk.hub
    inertia = hub.inertia + hub.mass * (hub.cg[0] ** 2 + hub.cg[1] ** 2)
    if lk.joint.flexibility is None and lk.joint.backlash is None:
        inertia += lk.joint.total_drive_inertia
    return float(inertia)


def _tip_body_mass(phi_tip, slope_tip, tip):
    """Linearised mass of a tip body on a clamped beam, in the beam's coordinates:
    translation of its CG = w(L) + c_x·w′(L) (small rotation), rotation w′(L)."""
    cx = tip.cg[0]
    g = phi_tip + cx * slope_tip
    return tip.mass * np.outer(g, g) + (tip.inertia + tip.mass * tip.cg[1] ** 2) * np.outer(
        slope_tip, slope_tip)


def finite_differences(beam, n_seg):
    """Nodal finite differences (seed 001, Sec. 3): y1..yn at h = L/n, lumped masses.

    The stiffness is the energy-consistent form of the seed's scheme: strain energy
    ½EI Σ_i w_i h κ_i² (trapezoidal weights) with the central-difference curvature
    κ_i = (y_{i−1} − 2y_i + y_{i+1})/h², the clamped root through the ghost node y_{−1} = y_1
    and, at the tip, the one-sided κ_n = (y_n − 2y_{n−1} + y_{n−2})/h² (keeps second-order
    convergence with a tip inertia; docs/decisions/0004-finite-differences-in-energy-form.md).
    Its interior rows are the seed's
    stencil EI(1, −4, 6, −4, 1)/h⁴ per unit length; being symmetric it conserves energy,
    which the seed's unsymmetric ghost-node rows do not (a documented improvement). Tip slope
    by the second-order one-sided difference (the seed's backward difference is first
    order and made chained tip paths converge at O(h)).
    """
    if n_seg < 4:
        raise SceneError(f"fidelity.refine: got {n_seg}, expected >= 4 segments for the fd "
                         f"rung (seed 001 needs at least 4)")
    L, n = beam.length, n_seg
    h = L / n
    rho_a = beam.mass_per_length
    E = np.vstack([np.zeros(n), np.eye(n)])  # row i: node i in terms of y1..yn (y0 = 0)
    x = np.arange(n + 1) * h
    w_mass = np.full(n + 1, h)
    w_mass[[0, -1]] = 0.5 * h
    mass = rho_a * w_mass
    d = (E[1:] - E[:-1]) / h  # backward slopes of segments 1..n
    S = np.zeros((n + 1, n, n))
    S[1:] = np.cumsum(h * np.einsum("ki,kj->kij", d, d), axis=0)
    K = np.zeros((n, n))
    kappa0 = 2.0 * E[1] / h**2
    K += 0.5 * h * np.outer(kappa0, kappa0)
    for i in range(1, n):
        kap = (E[i - 1] - 2 * E[i] + E[i + 1]) / h**2
        K += h * np.outer(kap, kap)
    kappa_n = (E[n] - 2 * E[n - 1] + E[n - 2]) / h**2
    K += 0.5 * h * np.outer(kappa_n, kappa_n)
    K *= beam.EI
    M_e = np.einsum("p,pi,pj->ij", mass, E, E)
    D = beam.damping.viscous_per_length * np.diag(w_mass[1:]) + \
        beam.damping.stiffness_proportional * K

    def curvature(xq):
        # central-difference curvature at the nodes, linearly interpolated
        kap = np.zeros((n + 1, n))
        kap[0] = kappa0
        for i in range(1, n):
            kap[i] = (E[i - 1] - 2 * E[i] + E[i + 1]) / h**2
        kap[n] = kappa_n
        idx = np.clip(xq / h, 0, n)
        lo = np.minimum(idx.astype(int), n - 1)
        fr = (idx - lo)[:, None]
        return (1 - fr) * kap[lo] + fr * kap[lo + 1]

    def shape(xq):
        idx = np.clip(np.asarray(xq, float) / h, 0, n)
        lo = np.minimum(idx.astype(int), n - 1)
        fr = (idx - lo)[:, None]
        return (1 - fr) * E[lo] + fr * E[lo + 1]

    # tip slope by the second-order one-sided difference (3y_n − 4y_{n−1} + y_{n−2})/2h: the
    # seed's first-order backward difference made the next link's frame, and so the tip
    # path of a chain, converge only at O(h)
    slope = (3 * E[n] - 4 * E[n - 1] + E[n - 2]) / (2 * h)

    def point(xq):
        # the FD fibre is piecewise straight between nodes: slope of the segment, S linear
        xq = min(max(xq, 0.0), L)
        seg = min(int(xq / h), n - 1)
        fr = xq / h - seg
        return ((1 - fr) * E[seg] + fr * E[seg + 1], d[seg].copy(),
                (1 - fr) * S[seg] + fr * S[seg + 1])

    return BeamDiscretization("fd", n, tuple(f"y{i}" for i in range(1, n + 1)), L,
                              beam.hub_radius, x, mass, E.copy(), S, E[-1].copy(), slope,
                              S[-1].copy(), _sym(K), _sym(D), _sym(M_e), curvature, shape,
                              point)


#: elastic coordinates of all beams of a chain together: a finer model takes minutes to
#: build and to linearize (measured on 2 cores: fem 100 elements = 200 coordinates builds in
#: 3 s and its RK4 step choice takes 30 s; fem 200 builds in 27 s), and its highest element
#: mode forces explicit steps of ~1e-8 s
MAX_ELASTIC_COORDINATES = 200


def elastic_coordinates(rung: str, refine: int) -> int:
    """Elastic coordinates one beam gets on ``rung`` refined ``refine`` (0: the default)."""
    n = refine or DEFAULT_REFINE[rung]
    return {"rigid": 1, "cubic": 2, "modal": n, "fem": 2 * n, "fd": n, "rod": n + 1}[rung]


def check_model_size(n_beams: int, fidelity) -> None:
    """SceneError, before anything is built, when the beams would get more than
    :data:`MAX_ELASTIC_COORDINATES` elastic coordinates together."""
    per = elastic_coordinates(fidelity.rung, fidelity.refine)
    if per * n_beams <= MAX_ELASTIC_COORDINATES:
        return
    what = {"modal": "modes", "fem": "elements", "fd": "segments"}.get(fidelity.rung, "")
    n = fidelity.refine or DEFAULT_REFINE[fidelity.rung]
    most = MAX_ELASTIC_COORDINATES // n_beams // (2 if fidelity.rung == "fem" else 1)
    raise SceneError(
        f"fidelity.refine: got {n} {what} on the {fidelity.rung} rung, {per} elastic "
        f"coordinates per beam × {n_beams} beam(s) = {per * n_beams}, expected at most "
        f"{MAX_ELASTIC_COORDINATES} in the chain (here refine <= {most}): a finer model takes "
        f"minutes to build and linearize and forces explicit steps of ~1e-8 s; the modal "
        f"rung keeps the low modes exactly with few coordinates")


def modal_load(links, k, basis):
    """The body whose mass and inertia the modal rung's modes of link ``k`` carry at the tip.

    ``basis`` (``fidelity.modal_basis``): ``tip_loaded`` — link k's own tip body;
    ``chain_loaded`` — that body together with everything outboard of it (the next links'
    hubs, beams and tip bodies) as one rigid body, the outboard joints locked at their
    initial angles and the outboard beams straight: the clamped-mass assumed modes of
    De Luca & Siciliano (IEEE T-SMC 21(4), 1991, Sec. III), whose boundary conditions
    carry the mass and inertia of the distal links at a nominal configuration. On the last
    link both are the same body. Any admissible shapes are a valid Ritz basis — the chain's
    mass matrix is still computed exactly for the configuration — so the choice changes
    only how fast the modal rung converges: on two_link_free (1 s, against FEM 8) 2 / 3 / 4
    modes miss the tip by 6.1e-4 / 3.3e-5 / 3.5e-6 m with ``tip_loaded`` and 3.1e-6 /
    3.9e-7 / 5.2e-8 m with ``chain_loaded`` (docs/accuracy.md, *The modal basis of a
    chain*). ``free_hub`` — as ``chain_loaded`` at the tip, the root on a hub free to turn
    (:func:`hub_load`). ``clamped_free`` — no tip body (returned as it is; unused by the
    rung).
    """
    tip = links[k].tip
    if basis not in ("chain_loaded", "free_hub") or k == len(links) - 1:
        return tip
    parts = [(tip.mass, np.asarray(tip.cg, float), tip.inertia)]
    origin = np.asarray(tip.joint_offset, float)     # next joint, in link k's tip frame
    angle = 0.0
    for lk in links[k + 1:]:
        angle += lk.joint.angle0
        c, s = np.cos(angle), np.sin(angle)
        rot = np.array([[c, -s], [s, c]])
        b = lk.beam
        m_beam = b.mass_per_length * b.length
        tip_o = origin + rot @ np.array([b.hub_radius + b.length, 0.0])
        parts += [(lk.hub.mass, origin + rot @ np.asarray(lk.hub.cg, float), lk.hub.inertia),
                  (m_beam, origin + rot @ np.array([b.hub_radius + b.length / 2, 0.0]),
                   m_beam * b.length ** 2 / 12.0),
                  (lk.tip.mass, tip_o + rot @ np.asarray(lk.tip.cg, float), lk.tip.inertia)]
        origin = tip_o + rot @ np.asarray(lk.tip.joint_offset, float)
    mass = sum(m for m, _, _ in parts)
    if mass == 0.0:
        return tip
    cg = sum(m * r for m, r, _ in parts) / mass
    inertia = sum(j + m * float((r - cg) @ (r - cg)) for m, r, j in parts)
    return type(tip)(mass=float(mass), inertia=float(inertia),
                     cg=(float(cg[0]), float(cg[1])), joint_offset=tip.joint_offset)


def discretize(beam, tip, fidelity, hub_inertia=None) -> BeamDiscretization:
    """Build the rung named in ``fidelity`` for one beam (``tip``: the body its modes carry
    at the tip, :func:`modal_load`; ``hub_inertia``: the inertia its hub turns with under
    the free_hub basis, :func:`hub_load`; only the modal rung uses them)."""
    rung = fidelity.rung
    n = fidelity.refine or DEFAULT_REFINE[rung]
    if rung == "rigid":
        return rigid_spring(beam)
    if rung == "cubic":
        return cubic(beam)
    if rung == "modal":
        if n > 40:
            raise SceneError(f"fidelity.refine: got {n}, expected <= 40 modes for the modal "
                             f"rung (use fem for finer models)")
        return natural_modes(beam, tip, n, with_tip=fidelity.modal_basis != "clamped_free",
                             hub_inertia=hub_inertia)
    if rung == "fem":
        if n > 200:
            raise SceneError(f"fidelity.refine: got {n}, expected <= 200 elements")
        return hermite_fem(beam, n)
    if rung == "fd":
        if n > 400:
            raise SceneError(f"fidelity.refine: got {n}, expected <= 400 segments")
        return finite_differences(beam, n)
    if rung == "rod":
        return rod_rung(beam, tip, n, fidelity.rod_points, fidelity.rod_modes)
    raise SceneError(f"fidelity.rung: got {rung!r}, expected one of rigid, cubic, modal, "
                     f"fem, fd, rod")


def rod_rung(beam, tip, terms, points: int = 0, modes: int = 0) -> BeamDiscretization:
    """The geometrically exact rod (:mod:`flexarm_ros.model.rod`) as a discretization:
    its exact kinematics in ``rod``; φ, φ(L), φ′(L) its small-deflection shapes, S zero
    (the chain reads the rod's own kinematics)."""
    from flexarm_ros.model import rod
    basis, x, mass, K, D, M0, shape, curvature = rod.build(beam, tip, terms, points=points,
                                                            modes=modes)
    P = len(x)
    phi = basis.W[:P] @ basis.T[:P]          # transverse at η = 0: ∫ θ
    phi_tip = basis.W[P] @ basis.T[:P]
    ne = basis.T.shape[1]
    S = np.zeros((P, ne, ne))
    for a in (phi, phi_tip, S):
        a.setflags(write=False)

    def point(xq):
        w, t_row, _ = basis.point_rows(xq)
        return w @ basis.T[:P], t_row, np.zeros((ne, ne))

    return BeamDiscretization("rod", terms, tuple(rod.suffixes(ne)), beam.length,
                              beam.hub_radius, x, mass, phi, S, phi_tip, basis.T[P].copy(),
                              np.zeros((ne, ne)), K, D, M0, curvature, shape, point,
                              rod=basis)
