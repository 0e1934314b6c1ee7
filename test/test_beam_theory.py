"""Tests of flexarm_ros.testing.beam_theory against published numbers, limits and an
independent Hermite-cubic finite-element model written here (not the project's model).

The FEM gets its boundary conditions only by adding lumped inertia to nodal DOFs
(tip body on the last node's (w, w'), hub inertia on the root rotation), so it checks
the sign conventions of the closed-form characteristic equations independently.
"""

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import quad

from flexarm_ros.testing import beam_theory as bt

# A realistic aluminium strip (SI): E = 70 GPa, 50 mm x 3 mm, rho = 2700 kg/m^3.
EI = 70e9 * 0.05 * 0.003**3 / 12.0  # 7.875 N m^2
RHO_A = 2700.0 * 0.05 * 0.003  # 0.405 kg/m
L = 1.2  # m
N_EL = 60  # Hermite elements in the eigen FEM (discretisation error < 6e-7 on modes 1-3)


def hz_to_beta(f_hz):
    """Inverse of beta_to_hz: beta L = L sqrt(2 pi f) (rho_A / EI)^(1/4)."""
    return L * np.sqrt(2.0 * np.pi * np.asarray(f_hz)) * (RHO_A / EI) ** 0.25


# ------------------------------------------------------------------ independent FEM
def _element_matrices(ei, rho_a, le):
    k = ei / le**3 * np.array([
        [12.0, 6 * le, -12.0, 6 * le],
        [6 * le, 4 * le**2, -6 * le, 2 * le**2],
        [-12.0, -6 * le, 12.0, -6 * le],
        [6 * le, 2 * le**2, -6 * le, 4 * le**2]])
    m = rho_a * le / 420.0 * np.array([
        [156.0, 22 * le, 54.0, -13 * le],
        [22 * le, 4 * le**2, 13 * le, -3 * le**2],
        [54.0, 13 * le, 156.0, -22 * le],
        [-13 * le, -3 * le**2, -22 * le, 4 * le**2]])
    return k, m


def fem_beam(n_el, ei=EI, rho_a=RHO_A, length=L):
    """Global K, M with DOFs (w_0, w'_0, w_1, w'_1, ...), no BCs applied."""
    le = length / n_el
    ke, me = _element_matrices(ei, rho_a, le)
    ndof = 2 * (n_el + 1)
    K = np.zeros((ndof, ndof))
    M = np.zeros((ndof, ndof))
    for e in range(n_el):
        s = slice(2 * e, 2 * e + 4)
        K[s, s] += ke
        M[s, s] += me
    return K, M


def fem_frequencies_hz(n_modes, tip_mass=0.0, tip_inertia=0.0, tip_cg_offset=0.0,
                       hub_inertia=None, n_el=N_EL):
    """Natural frequencies [Hz]. hub_inertia None: clamped root (w0 = w0' = 0);
    else root w0 fixed, root rotation free with hub_inertia added to it and the 0 Hz
    rigid mode dropped. Tip body: mass matrix [[M, M e], [M e, J + M e^2]] on (w_N, w'_N).

    Solved in flexibility form, eigh(M, K + sigma M) -> nu = 1/(lambda + sigma): the low
    modes are then the LARGEST eigenvalues and keep full relative accuracy. (The direct
    eigh(K, M) loses 1e-5..1e-4 on low modes with 100-200 elements and a heavy tip, because
    its absolute error scales with the highest FE eigenvalue.) sigma > 0 only for the
    hub, whose K is singular (rigid rotation).
    """
    K, M = fem_beam(n_el)
    e = tip_cg_offset
    M[-2:, -2:] += np.array([[tip_mass, tip_mass * e],
                             [tip_mass * e, tip_inertia + tip_mass * e * e]])
    if hub_inertia is None:
        keep, sigma, n_rigid = np.arange(2, K.shape[0]), 0.0, 0
    else:
        M[1, 1] += hub_inertia
        keep, sigma, n_rigid = np.arange(1, K.shape[0]), EI / (RHO_A * L**4), 1
    K, M = K[np.ix_(keep, keep)], M[np.ix_(keep, keep)]
    nd = K.shape[0]
    nu = scipy.linalg.eigh(M, K + sigma * M, eigvals_only=True,
                           subset_by_index=[nd - n_modes - n_rigid, nd - 1])[::-1]
    lam = 1.0 / nu - sigma
    if n_rigid:
        assert abs(lam[0]) < 1e-6 * lam[1], "FEM hub model lost its rigid mode"
        lam = lam[1:]
    return np.sqrt(lam) / (2.0 * np.pi)


def fem_static_tip(gravity, tip_mass, rho_a=RHO_A, n_el=10):
    """Clamped cantilever, consistent uniform load + tip load; Hermite cubics are
    nodally exact for this case. Returns (tip deflection, tip slope)."""
    K, _ = fem_beam(n_el, rho_a=rho_a)
    le = L / n_el
    q = rho_a * gravity
    F = np.zeros(K.shape[0])
    for e in range(n_el):
        F[2 * e:2 * e + 4] += q * np.array([le / 2, le**2 / 12, le / 2, -le**2 / 12])
    F[-2] += tip_mass * gravity
    u = np.linalg.solve(K[2:, 2:], F[2:])
    return u[-2], u[-1]


# ----------------------------------------------------------------------- clamped-free
def test_clamped_free_published_betas():
    # Blevins (1979) Table 8-1, clamped-free lambda_i.
    published = [1.875104, 4.694091, 7.854757, 10.995541, 14.137168]
    np.testing.assert_allclose(bt.clamped_free_betas(5), published, rtol=0, atol=1e-6)


def test_clamped_free_large_n_asymptote():
    n = 30
    b = bt.clamped_free_betas(n)
    assert b.shape == (n,) and np.all(np.isfinite(b))
    k = np.arange(1, n + 1)
    b0 = (2 * k - 1) * np.pi / 2
    assert np.all(np.diff(b) > 0)
    # Root k -> (2k-1) pi/2; from cos b = -sech b: b - b0 = (-1)^(k+1) 2 e^(-b0) + O(e^(-2 b0)).
    assert np.all(np.abs(b - b0)[2:] < 1e-3)
    assert np.all(np.abs(b - b0)[6:] < 1e-8)
    corr = (-1.0) ** (k + 1) * 2.0 * np.exp(-b0)
    tol = 4.0 * (2.0 * np.exp(-b0)) ** 2 + 1e-14 * b0
    assert np.all(np.abs((b - b0) - corr)[2:] <= tol[2:])


def test_clamped_free_frequencies_hz_matches_fem():
    f = bt.clamped_free_frequencies_hz(EI, RHO_A, L, 3)
    np.testing.assert_allclose(f, fem_frequencies_hz(3), rtol=1e-5)
    # explicit conversion f = beta^2 / (2 pi L^2) sqrt(EI / rho_A)
    np.testing.assert_allclose(
        f, bt.clamped_free_betas(3) ** 2 / (2 * np.pi * L**2) * np.sqrt(EI / RHO_A),
        rtol=1e-14)


# ------------------------------------------------------------------------ tip-loaded
def test_tip_loaded_zero_load_is_clamped_free():
    np.testing.assert_allclose(
        bt.tip_loaded_frequencies_hz(EI, RHO_A, L, 0.0, 0.0, 6),
        bt.clamped_free_frequencies_hz(EI, RHO_A, L, 6), rtol=1e-12)


def test_tip_loaded_published_mu_1():
    # mu = M/(rho_A L) = 1, J = 0: beta_1 L = 1.24792 (Blevins ch. 8; Laura et al. 1974).
    f = bt.tip_loaded_frequencies_hz(EI, RHO_A, L, 1.0 * RHO_A * L, 0.0, 1)
    assert hz_to_beta(f[0]) == pytest.approx(1.24792, abs=5e-6)


def test_tip_loaded_huge_end_body_tends_to_clamped_clamped():
    # M, J -> inf pins w(L) = w'(L) = 0: the third root -> 4.730041 (1 - cos cosh = 0);
    # this fixes the sign of the + mu j beta^4 (1 - cos cosh) term.
    b = bt.tip_loaded_betas(1e8, 1e8, 3)
    assert b[2] == pytest.approx(4.730041, abs=1e-5)


@pytest.mark.parametrize("mu, j, eps", [
    (0.5, 0.0, 0.0),
    (1.0, 0.0, 0.0),
    (0.0, 0.05, 0.0),
    (1.0, 0.1, 0.0),
    (5.0, 2.0, 0.0),
    (2.0, 0.05, 0.1),
    (1.0, 0.02, -0.05),
])
def test_tip_loaded_matches_fem(mu, j, eps):
    M, J, e = mu * RHO_A * L, j * RHO_A * L**3, eps * L
    f = bt.tip_loaded_frequencies_hz(EI, RHO_A, L, M, J, 3, tip_cg_offset=e)
    np.testing.assert_allclose(f, fem_frequencies_hz(3, M, J, e), rtol=1e-5)


# ---------------------------------------------------------------------------- hub
def test_hub_limits():
    cf = bt.clamped_free_betas(3)
    np.testing.assert_allclose(hz_to_beta(bt.hub_beam_frequencies_hz(EI, RHO_A, L, 1e9, 3)),
                               cf, atol=1e-6)
    np.testing.assert_allclose(
        bt.hub_beam_frequencies_hz(EI, RHO_A, L, np.inf, 3),
        bt.clamped_free_frequencies_hz(EI, RHO_A, L, 3), rtol=1e-12)
    # Pinned-free (tan b = tanh b), Blevins Table 8-1: 3.926602, 7.068583.
    np.testing.assert_allclose(
        hz_to_beta(bt.hub_beam_frequencies_hz(EI, RHO_A, L, 1e-9, 2)),
        [3.926602, 7.068583], atol=1e-6)


def test_hub_stiff_limit_with_tip_body_is_tip_loaded():
    M, J = 1.0 * RHO_A * L, 0.1 * RHO_A * L**3
    np.testing.assert_allclose(
        bt.hub_beam_frequencies_hz(EI, RHO_A, L, 1e9, 3, M, J),
        bt.tip_loaded_frequencies_hz(EI, RHO_A, L, M, J, 3), rtol=1e-7)


@pytest.mark.parametrize("h, mu, j, eps", [
    (0.0, 0.0, 0.0, 0.0),
    (0.1, 0.0, 0.0, 0.0),
    (1.0, 0.0, 0.0, 0.0),
    (10.0, 0.0, 0.0, 0.0),
    (1.0, 1.0, 0.0, 0.0),
    (0.5, 1.0, 0.1, 0.0),
    (2.0, 0.5, 0.05, 0.1),
])
def test_hub_matches_fem(h, mu, j, eps):
    Ih, M, J, e = h * RHO_A * L**3, mu * RHO_A * L, j * RHO_A * L**3, eps * L
    f = bt.hub_beam_frequencies_hz(EI, RHO_A, L, Ih, 3, M, J, tip_cg_offset=e)
    assert np.all(f > 0)
    np.testing.assert_allclose(f, fem_frequencies_hz(3, M, J, e, hub_inertia=Ih),
                               rtol=1e-5)


# ------------------------------------------------------------------------- statics
@pytest.mark.parametrize("rho_a, tip_mass", [(RHO_A, 0.0), (RHO_A, 0.3), (0.0, 0.3),
                                             (1.7, 2.5)])
def test_static_tip_matches_fem(rho_a, tip_mass):
    g = 9.80665
    w_fem, th_fem = fem_static_tip(g, tip_mass, rho_a=rho_a)
    d = bt.cantilever_static_tip_deflection(EI, rho_a, L, g, tip_mass)
    s = bt.cantilever_static_tip_slope(EI, rho_a, L, g, tip_mass)
    assert d > 0 and s > 0
    assert d == pytest.approx(w_fem, rel=1e-9)
    assert s == pytest.approx(th_fem, rel=1e-9)
    # gravity is a magnitude
    assert bt.cantilever_static_tip_deflection(EI, rho_a, L, -g, tip_mass) == d


@pytest.mark.parametrize("tip_mass", [0.0, 0.3])
def test_curvature_integrates_to_slope_and_deflection(tip_mass):
    g = 9.81

    def kappa(x):
        return bt.cantilever_curvature(EI, RHO_A, L, g, tip_mass, x)

    # w'(L) = int kappa dx ; w(L) = int kappa(x) (L - x) dx  (w(0) = w'(0) = 0)
    slope = quad(kappa, 0.0, L, epsabs=0, epsrel=1e-13)[0]
    defl = quad(lambda x: kappa(x) * (L - x), 0.0, L, epsabs=0, epsrel=1e-13)[0]
    assert slope == pytest.approx(bt.cantilever_static_tip_slope(EI, RHO_A, L, g, tip_mass),
                                  rel=1e-11)
    assert defl == pytest.approx(
        bt.cantilever_static_tip_deflection(EI, RHO_A, L, g, tip_mass), rel=1e-11)
    q, P = RHO_A * g, tip_mass * g
    assert kappa(0.0) == pytest.approx((q * L**2 / 2 + P * L) / EI, rel=1e-14)
    assert kappa(L) == 0.0
    xs = np.linspace(0, L, 7)
    np.testing.assert_allclose(bt.cantilever_curvature(EI, RHO_A, L, g, tip_mass, xs),
                               [kappa(x) for x in xs], rtol=1e-15)


# ---------------------------------------------------------------------- validation
@pytest.mark.parametrize("call", [
    lambda: bt.clamped_free_betas(0),
    lambda: bt.clamped_free_frequencies_hz(-1.0, RHO_A, L, 3),
    lambda: bt.tip_loaded_frequencies_hz(EI, RHO_A, L, -1.0, 0.0, 3),
    lambda: bt.hub_beam_frequencies_hz(EI, RHO_A, L, float("nan"), 3),
    lambda: bt.cantilever_curvature(EI, RHO_A, L, 9.81, 0.0, 1.5 * L),
])
def test_invalid_input_raises(call):
    with pytest.raises(ValueError):
        call()
