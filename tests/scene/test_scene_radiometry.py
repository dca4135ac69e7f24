"""Radiometry: the Sun's V magnitude, the V zero point, energy conservation of the phase functions,
airmass, and a published satellite standard magnitude."""

import numpy as np
import pytest
from scipy import integrate

from evsda.blocks.scene import radiometry
from evsda.blocks.scene.radiometry import V_BAND

SUN_V_MAG_ALLEN = -26.74    # Allen's Astrophysical Quantities (Cox 2000), Sec. 14.1
SUN_V_MAG_WILLMER = 4.81 - 5 * np.log10(10 * 648_000 / np.pi)   # Willmer 2018 Table 3: M_V = 4.81 (Vega) at 1 au
TSI_W_M2 = 1361.0           # IAU 2015 Resolution B3 nominal total solar irradiance


def test_solar_spectrum_integrates_to_the_nominal_tsi():
    lam = np.geomspace(50, 1e6, 400_000)
    assert np.trapezoid(radiometry.blackbody_sun_irradiance_w_m2_nm(lam), lam) == pytest.approx(TSI_W_M2, rel=2e-3)


def test_sun_puts_the_measured_v_band_photons_on_a_satellite():
    """Issue 11.6: a 5772 K blackbody gave V_sun = -26.69, 6 % too few photons. The Sun's
    photon flux is normalised to Willmer (2018) and agrees with Allen's -26.74 (a second,
    older measurement) within 0.03 mag."""
    sun_mag = radiometry.magnitude(V_BAND.sun_photon_flux, V_BAND)
    assert SUN_V_MAG_WILLMER == pytest.approx(-26.76, abs=0.005)
    assert sun_mag == pytest.approx(SUN_V_MAG_WILLMER, abs=1e-9)
    assert sun_mag == pytest.approx(SUN_V_MAG_ALLEN, abs=0.03)
    # the blackbody the flux no longer comes from is 0.07 mag (6 %) short of it
    assert V_BAND.blackbody_sun_magnitude - sun_mag == pytest.approx(0.067, abs=0.01)


def test_v_zero_point_and_effective_wavelength():
    # the classic "V = 0 is ~1000 photons cm^-2 s^-1 A^-1" over the band's ~89 nm equivalent width
    width_nm = np.trapezoid(V_BAND.response, V_BAND.wavelength_nm)
    assert V_BAND.zero_point_photon_flux / (width_nm * 10) / 1e4 == pytest.approx(1000, rel=0.03)
    assert V_BAND.effective_wavelength_m == pytest.approx(551e-9, abs=3e-9)


def test_lambertian_sphere_reflects_rho_e_a_in_total():
    """Eq. 1 with Eq. 2: Phi = pi L A = rho E A, so the phase function integrates to 1 over 4 pi."""
    total, _ = integrate.quad(lambda phi: radiometry.lambertian_sphere_phase(np.pi - phi) * 2 * np.pi * np.sin(phi),
                              0, np.pi)
    assert total == pytest.approx(1.0, rel=1e-9)
    # full phase: geometric albedo of a Lambert sphere is 2/3 of its Bond albedo (Russell 1916)
    assert radiometry.lambertian_sphere_phase(0.0) * np.pi == pytest.approx(2 / 3)


def test_flat_plate_reflects_rho_e_a_cos_into_its_hemisphere():
    rng = np.random.default_rng(1)
    normal = np.array([[0.0, 0.0, 1.0]])
    to_sun = np.array([[np.sin(0.4), 0.0, np.cos(0.4)]])
    directions = rng.normal(size=(400_000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    f = radiometry.flat_plate_phase(normal, to_sun, directions)
    assert f.mean() * 4 * np.pi == pytest.approx(np.cos(0.4), rel=0.01)     # power = rho E A cos(theta_sun)
    assert radiometry.flat_plate_phase(normal, -to_sun, directions).max() == 0.0  # lit from behind


def test_inverse_square_range_falloff():
    near = radiometry.reflected_photon_flux(V_BAND, 0.2, 4.0, 0.05, 500e3)
    far = radiometry.reflected_photon_flux(V_BAND, 0.2, 4.0, 0.05, 1000e3)
    assert near / far == pytest.approx(4.0)


def test_kasten_young_airmass():
    """Kasten & Young (1989): 1.0 at the zenith, 1.993 at 60 deg, 38.09 at the horizon (their table)."""
    x = radiometry.airmass(np.radians([0.0, 60.0, 90.0]))
    assert x[0] == pytest.approx(1.0, abs=5e-4)
    assert x[1] == pytest.approx(1.9927, abs=2e-3)
    assert x[2] == pytest.approx(38.0868, rel=5e-3)       # their fit formula is within 0.5% of the table
    assert np.isnan(radiometry.airmass(np.radians(95.0)))
    assert radiometry.transmission(0.2, 0.0) == pytest.approx(10 ** (-0.08), rel=1e-3)


def test_iss_standard_magnitude():
    """The ISS's published standard ("intrinsic") magnitude, -1.3 at 1000 km and 90 deg phase
    (Heavens-Above; the McCants/Molczan convention of 1000 km, 50% illuminated), from a
    diffuse sphere with the ISS's ~2500 m^2 of solar arrays (NASA) and albedo 0.3."""
    flux = radiometry.reflected_photon_flux(V_BAND, 0.3, 2500.0, radiometry.lambertian_sphere_phase(np.pi / 2), 1e6)
    assert radiometry.magnitude(flux, V_BAND) == pytest.approx(-1.3, abs=0.5)
