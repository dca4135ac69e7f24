"""Cn^2 profiles, layer Fried parameters and scintillation against published values and closed forms."""

import numpy as np
import pytest
from scipy.integrate import quad

from evsda.blocks.optics.atmosphere import Atmosphere, Layer, bufton_wind, hufnagel_valley_cn2, read_profile_table
from evsda.library import path as library_path


def test_hv57_gives_five_centimetre_r0_and_seven_microradian_theta0():
    # the definition of HV5/7 (Valley 1980; Hardy 1998 Sec. 3.3.5): r0 ~ 5 cm, theta0 ~ 7 urad at 0.5 um
    atmosphere = Atmosphere.hufnagel_valley(6)
    assert atmosphere.r0(0.5e-6, 0.0) == pytest.approx(0.05, rel=0.02)
    assert atmosphere.isoplanatic_angle(0.5e-6, 0.0) == pytest.approx(7e-6, rel=0.03)


@pytest.mark.parametrize("n_layers", [1, 3, 7])
def test_lumped_layers_preserve_r0_and_theta0_of_the_continuous_profile(n_layers):
    k = 2 * np.pi / 0.5e-6
    pts = [100.0, 1000.0, 10e3]
    j = quad(hufnagel_valley_cn2, 0, 30e3, points=pts, limit=200)[0]
    jh = quad(lambda h: hufnagel_valley_cn2(h) * h ** (5 / 3), 0, 30e3, points=pts, limit=200)[0]
    atmosphere = Atmosphere.hufnagel_valley(n_layers)
    assert atmosphere.r0(0.5e-6, 0.0) == pytest.approx((0.423 * k**2 * j) ** (-3 / 5), rel=1e-6)
    assert atmosphere.isoplanatic_angle(0.5e-6, 0.0) == pytest.approx((2.914 * k**2 * jh) ** (-3 / 5), rel=1e-6)
    assert len(atmosphere.layers) == n_layers


def test_r0_scales_with_wavelength_and_air_mass():
    atmosphere = Atmosphere.hufnagel_valley(3)
    r0 = atmosphere.r0(0.5e-6, 0.0)
    assert atmosphere.r0(1.0e-6, 0.0) == pytest.approx(r0 * 2 ** (6 / 5))            # r0 ~ lambda^(6/5)
    assert atmosphere.r0(0.5e-6, np.pi / 3) == pytest.approx(r0 * 0.5 ** (3 / 5))    # r0 ~ cos(zeta)^(3/5)
    layers = atmosphere.layer_r0(0.5e-6, 0.0)
    assert np.sum(layers ** (-5 / 3)) ** (-3 / 5) == pytest.approx(r0)


def test_scaled_profile_has_the_requested_r0():
    atmosphere = Atmosphere.hufnagel_valley(4).scaled_to_r0(0.12)
    assert atmosphere.r0(500e-9, 0.0) == pytest.approx(0.12)


def test_bufton_wind_peaks_at_the_jet_stream():
    assert bufton_wind(9400.0) == pytest.approx(35.0)
    assert bufton_wind(0.0) == pytest.approx(5.0 + 30 * np.exp(-((9400 / 4800) ** 2)))


def test_scintillation_tends_to_rytov_for_small_apertures_and_dravins_for_large_ones():
    layers = (Layer(3000.0, 2e-13, 10.0, 0.0), Layer(11000.0, 1e-13, 25.0, 0.0))
    atmosphere = Atmosphere(layers)
    lam, zenith = 0.55e-6, np.deg2rad(30)
    k, airmass = 2 * np.pi / lam, 1 / np.cos(zenith)
    # plane-wave Rytov variance 2.25 k^(7/6) sec^(11/6) sum J h^(5/6) (Andrews & Phillips 2005 Eq. 12.38)
    rytov = 2.25 * k ** (7 / 6) * airmass ** (11 / 6) * sum(l.cn2_dh * l.altitude_m ** (5 / 6) for l in layers)
    assert atmosphere.scintillation_index(1e-5, lam, zenith) == pytest.approx(rytov, rel=0.01)
    # large aperture: 17.34 D^(-7/3) sec^3 sum J h^2 (Dravins et al. 1997 Eq. 10)
    d = 20.0
    dravins = 17.34 * d ** (-7 / 3) * airmass**3 * sum(l.cn2_dh * l.altitude_m**2 for l in layers)
    assert atmosphere.scintillation_index(d, lam, zenith) == pytest.approx(dravins, rel=0.03)
    # a point source nearer than the layers' Fresnel weighting z (1 - z/R) twinkles less than a star (spherical
    # wave) through a small aperture; far away it is a plane wave
    assert atmosphere.scintillation_index(1e-5, lam, zenith, 2e4) < 0.9 * rytov
    assert atmosphere.scintillation_index(0.3, lam, zenith, 1e13) == pytest.approx(
        atmosphere.scintillation_index(0.3, lam, zenith), rel=1e-6)


def test_profile_tables_in_the_library_load(tmp_path):
    for name in ("mauna_kea.csv", "las_campanas.csv", "hv57.csv"):
        layers = read_profile_table(library_path(f"atmospheres/{name}"))
        assert all(l.cn2_dh > 0 for l in layers)
    las_campanas = Atmosphere.from_table(library_path("atmospheres/las_campanas.csv"))
    assert las_campanas.r0(500e-9, 0.0) == pytest.approx(0.16, rel=0.01)
    hv = Atmosphere.from_table(library_path("atmospheres/hv57.csv"))
    assert hv.r0(500e-9, 0.0) == pytest.approx(Atmosphere.hufnagel_valley(7).r0(500e-9, 0.0), rel=1e-3)
    bad = tmp_path / "bad.csv"
    bad.write_text("altitude_m,cn2\n100,1e-13\n")
    with pytest.raises(ValueError, match="expected the columns"):
        read_profile_table(bad)
