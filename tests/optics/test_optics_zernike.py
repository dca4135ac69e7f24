"""Zernike modes (paper Eq. 5-6), Noll's covariance (Eq. 8-10) and Karhunen-Loeve screens (Eq. 7, 11)."""

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import eval_jacobi, jv

from evsda.blocks.optics.karhunen_loeve import (
    KarhunenLoeve, noll_covariance, noll_covariance_element, noll_residual_variance, zernike_phase_screen)
from evsda.blocks.optics.kolmogorov import PSD_COEFFICIENT
from evsda.blocks.optics.zernike import NOLL_1976_RESIDUALS, noll_to_nm, radial_polynomial, zernike, zernike_basis

# Noll 1976 Table I: (n, m) of modes 1..22
NOLL_TABLE_I = [(0, 0), (1, 1), (1, 1), (2, 0), (2, 2), (2, 2), (3, 1), (3, 1), (3, 3), (3, 3), (4, 0),
                (4, 2), (4, 2), (4, 4), (4, 4), (5, 1), (5, 1), (5, 3), (5, 3), (5, 5), (5, 5), (6, 0)]


def test_noll_indices_follow_noll_table_i():
    assert [noll_to_nm(j) for j in range(1, 23)] == NOLL_TABLE_I


def test_radial_polynomial_matches_jacobi_form():
    # R_n^m(rho) = (-1)^((n-m)/2) rho^m P_((n-m)/2)^(m, 0)(1 - 2 rho^2)  (Born & Wolf 1999, Eq. 9.2.19 / App. VII)
    rho = np.linspace(0, 1, 101)
    for n in range(0, 11):
        for m in range(n % 2, n + 1, 2):
            k = (n - m) // 2
            expected = (-1) ** k * rho**m * eval_jacobi(k, m, 0, 1 - 2 * rho**2)
            np.testing.assert_allclose(radial_polynomial(n, m, rho), expected, atol=1e-10)


def test_modes_are_orthonormal_on_the_unit_disk():
    # polar Gauss-Legendre x uniform quadrature, exact for these polynomials
    nodes, weights = np.polynomial.legendre.leggauss(40)
    rho = 0.5 * (nodes + 1)
    w_rho = 0.5 * weights * rho
    theta = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    r, t = np.meshgrid(rho, theta, indexing="ij")
    w = w_rho[:, None] * (2 * np.pi / 64) / np.pi          # mean over the disk of area pi
    modes = np.stack([zernike(j, r, t) for j in range(1, 37)])
    gram = np.einsum("aij,bij,ij->ab", modes, modes, w)
    np.testing.assert_allclose(gram, np.eye(36), atol=1e-12)


def test_tip_and_tilt_have_noll_normalisation():
    x, y = np.array([0.5, 0.0]), np.array([0.0, 0.5])
    basis = zernike_basis(3, x, y, radius=1.0)
    np.testing.assert_allclose(basis[1], [1.0, 0.0], atol=1e-15)        # Z2 = 2 rho cos(theta)
    np.testing.assert_allclose(basis[2], [0.0, 1.0], atol=1e-15)        # Z3 = 2 rho sin(theta)


def _hankel_covariance(j, jp):
    """E[a_j a_j'] for D/r0 = 1 by numerical integration of Noll 1976 Eq. 23 (independent of Eq. 8)."""
    (n, m), (n_, m_) = noll_to_nm(j), noll_to_nm(jp)
    sign = (-1) ** ((n + n_ - 2 * m) // 2)
    radius = 0.5

    def integrand(f):
        q = jv(n + 1, 2 * np.pi * f * radius) * jv(n_ + 1, 2 * np.pi * f * radius) / (np.pi * f * radius) ** 2
        return PSD_COEFFICIENT * f ** (-11 / 3) * np.sqrt((n + 1) * (n_ + 1)) * q * 2 * np.pi * f

    value = sum(quad(integrand, a, b, limit=400)[0] for a, b in [(0, 1), (1, 10), (10, 100)])
    return sign * value


@pytest.mark.parametrize("j, jp", [(2, 2), (4, 4), (2, 8), (4, 11), (7, 7), (11, 22)])
def test_covariance_matches_direct_integral_of_kolmogorov_spectrum(j, jp):
    assert noll_covariance_element(j, jp) == pytest.approx(_hankel_covariance(j, jp), rel=2e-3)


def test_covariance_selection_rules():
    assert noll_covariance_element(2, 3) == 0.0          # cos and sin tilt
    assert noll_covariance_element(2, 7) == 0.0          # x-tilt and y-coma
    assert noll_covariance_element(2, 8) < 0             # x-tilt and x-coma anticorrelated (Noll 1976)
    c = noll_covariance(20)
    np.testing.assert_allclose(c, c.T)


def test_residual_variances_reproduce_noll_table_iv():
    # Delta_J - Delta_21 = sum of the diagonal from J+1 to 21: compare with Noll 1976 Table IV
    for J in (1, 2, 3, 4, 5, 6, 10, 15):
        expected = NOLL_1976_RESIDUALS[J] - NOLL_1976_RESIDUALS[21]
        assert noll_residual_variance(J, 20) == pytest.approx(expected, rel=0.01, abs=2e-4)
    # and the full Delta_J with 1000 modes plus Noll's asymptotic tail 0.2944 J^(-sqrt(3)/2) beyond
    tail = 0.2944 * 1001 ** (-np.sqrt(3) / 2)
    for J in (1, 3, 6, 21):
        assert noll_residual_variance(J, 1000) + tail == pytest.approx(NOLL_1976_RESIDUALS[J], rel=0.01)


def test_karhunen_loeve_coefficients_have_noll_covariance():
    kl = KarhunenLoeve.of(20)
    np.testing.assert_allclose(kl.vectors @ np.diag(kl.variances) @ kl.vectors.T, noll_covariance(20), atol=1e-12)
    rng = np.random.default_rng(3)
    a = kl.sample_coefficients(rng, d_over_r0=4.0, size=20000)
    expected = noll_covariance(20, 4.0)
    sample = a.T @ a / len(a)
    err = np.sqrt((np.diag(expected)[:, None] * np.diag(expected)[None, :] + expected**2) / len(a))
    assert np.all(np.abs(sample - expected) < 5 * err)


def test_kl_screen_residual_variance_after_removing_modes():
    # a screen of n modes keeps Delta_J - Delta_n after removing J modes (Noll 1976 Table IV)
    rng = np.random.default_rng(4)
    n_modes = 65                                          # modes 2..66: radial orders up to 10
    kl = KarhunenLoeve.of(n_modes)
    x = (np.arange(96) - 47.5) / 48
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= 1
    basis = zernike_basis(n_modes, xx[inside], yy[inside], 1.0, first=2)
    q, _ = np.linalg.qr(basis.T)
    screens = zernike_phase_screen(kl.sample_coefficients(rng, 1.0, size=1000), xx[inside], yy[inside], 1.0)
    coefficients = screens @ q
    for J in (1, 3, 6, 10):
        residual = (coefficients[:, J - 1:] ** 2).sum(axis=1) / inside.sum()
        expected = noll_residual_variance(J, n_modes)
        assert residual.mean() == pytest.approx(expected, abs=4 * residual.std() / np.sqrt(len(residual)))
