"""Source spectra and detector responses (evsda.blocks.scene.spectra) against published values and closed forms."""

import numpy as np
import pytest
from scipy import constants

from evsda.blocks.ports import FocalPlane, SpectralResponse
from evsda.blocks.scene import radiometry, spectra
from evsda.blocks.scene.sky import sky_photon_flux_per_pixel

SILICON = SpectralResponse("silicon", 3e-6)
#: Bessell (1990, PASP 102, 1181) Table 2, B passband, 360-560 nm every 10 nm
BESSELL_B_NM = np.arange(360.0, 561.0, 10.0)
BESSELL_B = np.array([0.0, 0.030, 0.134, 0.567, 0.920, 0.978, 1.000, 0.978, 0.935, 0.853, 0.740, 0.640, 0.536,
                      0.424, 0.325, 0.235, 0.150, 0.095, 0.043, 0.009, 0.0])
B_ZERO_POINT_W_M2_NM = 6.32e-11          # B = 0 (Bessell, Castelli & Plez 1998, Table A2: 632e-11 erg s^-1 cm^-2 A^-1)


def magnitude(flux_w_m2_nm, weight, zero_point_w_m2_nm):
    return -2.5 * np.log10(spectra.photon_rate(flux_w_m2_nm, weight)
                           / spectra.photon_rate(np.full_like(spectra.GRID_NM, zero_point_w_m2_nm), weight))


def test_photon_rate_of_a_blackbody_matches_the_closed_form():
    # photons of B_lambda between l1 and l2: 2 c (kT/hc)^3 [F(x2) - F(x1)], x = hc / (l k T),
    # F(x) = sum_n e^(-n x) (x^2/n + 2x/n^2 + 2/n^3) (the series of integral x^2 / (e^x - 1) dx)
    temperature, low, high = 5000.0, 400.0, 900.0
    weight = ((spectra.GRID_NM >= low) & (spectra.GRID_NM <= high)).astype(float)
    weight[np.isin(spectra.GRID_NM, (low, high))] = 0.5        # the trapezoid's share of the edge samples
    numeric = spectra.photon_rate(radiometry.planck_w_m2_nm_sr(spectra.GRID_NM, temperature), weight)

    def series(x):
        n = np.arange(1, 60)[:, None]
        return np.sum(np.exp(-n * x) * (x**2 / n + 2 * x / n**2 + 2 / n**3), axis=0)

    hc_kt = constants.h * constants.c / (constants.k * temperature)
    x = hc_kt / (np.array([low, high]) * 1e-9)
    closed = 2 * constants.c * (1 / hc_kt) ** 3 * (series(x[1]) - series(x[0]))
    assert numeric == pytest.approx(closed, rel=2e-4)


def test_the_bundled_solar_spectrum_gives_the_suns_measured_v_and_b_minus_v():
    sun = spectra.sun_irradiance_w_m2_nm()
    v = magnitude(sun, spectra.v_response(), radiometry.V_ZERO_POINT_W_M2_NM)
    b = magnitude(sun, np.interp(spectra.GRID_NM, BESSELL_B_NM, BESSELL_B, left=0, right=0), B_ZERO_POINT_W_M2_NM)
    assert v == pytest.approx(radiometry.SUN_V_MAG, abs=0.02)          # -26.76 (Willmer 2018)
    assert b - v == pytest.approx(0.653, abs=0.03)                       # Ramirez et al. 2012: 0.653 +- 0.003


def test_colour_temperature_of_the_suns_b_minus_v_is_the_suns():
    assert spectra.temperature_of_b_v(0.653) == pytest.approx(5772.0, rel=0.005)    # IAU 2015 B3 nominal T_eff


def test_silicon_absorption_follows_greens_coefficients():
    # Green 2008, Table 1: alpha at 300 K = 1.11e4 (500 nm), 4.14e3 (600), 1.9e3 (700), 850 (800), 306 (900) cm^-1
    alpha = np.interp([500, 600, 700, 800, 900], spectra.GRID_NM, spectra.silicon_absorption_per_m()) / 100.0
    assert alpha == pytest.approx([1.11e4, 4.14e3, 1.9e3, 850.0, 306.0], rel=0.02)


def test_a_v_band_detector_counts_v_photons():
    assert spectra.sun_band_factor(SpectralResponse()) == 1.0
    assert np.all(spectra.star_band_factor(SpectralResponse(), [-0.3, 0.66, 2.0]) == 1.0)
    assert spectra.effective_wavelength_m(SpectralResponse()) == radiometry.V_BAND.effective_wavelength_m


def test_band_factor_of_a_flat_photon_spectrum_is_the_ratio_of_equivalent_widths():
    # photons per nm flat (F ~ 1/lambda): kappa = integral r / integral V, V's width from Bessell's table itself
    flat = 1.0 / spectra.GRID_NM
    v_width = np.trapezoid(radiometry.BESSELL_V_RESPONSE, radiometry.BESSELL_V_NM)
    assert spectra.band_factor(SILICON, flat) == pytest.approx(np.trapezoid(spectra.response(SILICON),
                                                                            spectra.GRID_NM) / v_width, rel=1e-3)


def test_unfiltered_silicon_counts_several_times_the_v_photons_and_a_v_filter_brings_it_back():
    response = spectra.response(SILICON)
    assert np.interp(550.0, spectra.GRID_NM, response) == pytest.approx(1.0)
    kappa = spectra.sun_band_factor(SILICON)
    assert 3.0 < kappa < 5.0                 # 400-1000 nm against V's ~90 nm
    filtered = spectra.sun_band_factor(SpectralResponse("silicon", 3e-6, "V"))
    assert filtered == pytest.approx(1.0, abs=0.15)                     # silicon is nearly flat across V
    red, blue = spectra.star_band_factor(SILICON, [1.5, -0.2])
    assert red > spectra.star_band_factor(SILICON, 0.66) and blue > 0       # redder stars: more photons outside V


def test_the_sky_takes_the_sensors_band_factor():
    v_plane = FocalPlane(64, 64, 4.86e-6, 0.135)
    si_plane = FocalPlane(64, 64, 4.86e-6, 0.135, SILICON)
    ratio = sky_photon_flux_per_pixel(20.3, si_plane) / sky_photon_flux_per_pixel(20.3, v_plane)
    assert ratio == pytest.approx(spectra.sun_band_factor(SILICON))


def test_catalogue_stars_carry_their_hipparcos_colour():
    from evsda import library
    from evsda.blocks.scene.catalog import load_hipparcos

    stars = load_hipparcos(str(library.resolve("library:stars/hip_main.dat.gz")))
    colour = dict(zip(stars.name, stars.colour))
    assert colour["HIP 32349"] == pytest.approx(0.009)       # Sirius (Hipparcos field H37)
    assert colour["HIP 27989"] == pytest.approx(1.500)       # Betelgeuse
    faint = (stars.vmag >= 6.0) & (stars.vmag < 6.5)
    assert np.nanmean(stars.colour[faint]) == pytest.approx(spectra.FIELD_STAR_B_V, abs=0.005)


@pytest.mark.parametrize("spec", [SILICON, SpectralResponse("silicon", 2e-6, "V")])
def test_star_factor_table_is_band_factor_colour_by_colour(spec):
    """The stars' table, its 141 blackbodies as one array, holds each colour's band_factor bytes."""
    table = spectra._star_factors.__wrapped__(spectra._key(spec))
    one_by_one = [spectra.band_factor(spec, radiometry.planck_w_m2_nm_sr(spectra.GRID_NM, t))
                  for t in spectra.temperature_of_b_v(spectra.B_V_GRID)]
    assert table.tobytes() == np.array(one_by_one).tobytes()
