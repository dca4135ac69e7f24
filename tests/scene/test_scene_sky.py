"""Sky background: surface brightness to photons per pixel, zenith-angle dependence, sample and hold."""

import numpy as np
import pytest

from evsda.blocks.ports.scene import Pointing
from evsda.blocks.scene import radiometry
from evsda.blocks.scene.sky import SkyBackgroundBlock, sky_brightness_at_zenith_angle, sky_photon_flux_per_pixel
from evsda.graph import Window


def test_magnitudes_per_square_arcsecond_to_photons_per_pixel(gen4):
    # 4.86 um at 1 m: 1.0024 arcsec pixels; 21 mag/arcsec^2 is a 21st-magnitude star per arcsec^2
    omega = (np.degrees(gen4.pixel_scale_rad) * 3600) ** 2
    expected = radiometry.V_BAND.zero_point_photon_flux * 10 ** (-0.4 * 21.0) * omega
    assert sky_photon_flux_per_pixel(21.0, gen4) == pytest.approx(expected)
    assert 30 < expected < 40                                    # photon s^-1 m^-2 per pixel
    assert sky_photon_flux_per_pixel(16.0, gen4) / expected == pytest.approx(100.0)


def test_krisciunas_schaefer_zenith_dependence():
    assert sky_brightness_at_zenith_angle(21.0, 0.0, 0.2) == pytest.approx(21.0)
    x60 = 1 / np.sqrt(1 - 0.96 * np.sin(np.radians(60)) ** 2)      # K&S (1991) Eq. 3 path length, 1.890
    expected = 21.0 - 2.5 * np.log10(x60) + 0.2 * (x60 - 1)
    assert sky_brightness_at_zenith_angle(21.0, np.radians(60), 0.2) == pytest.approx(expected)
    assert expected < 21.0                                          # brighter towards the horizon


def test_block_samples_hold_across_windows(graz, gen4, pass_start):
    block = SkyBackgroundBlock(cadence_s=0.1)
    pointing = Pointing(mode="stare", azimuth_deg=343.75, elevation_deg=30.0)
    inside = block.step(Window(0, 150_000_000, 350_000_000, pass_start), observer=graz, pointing=pointing,
                        focal_plane=gen4)["background"]
    np.testing.assert_array_equal(inside.t_ns, [150_000_000, 200_000_000, 300_000_000])
    aligned = block.step(Window(0, 100_000_000, 200_000_000, pass_start), observer=graz, pointing=pointing,
                         focal_plane=gen4)["background"]
    assert inside.photon_flux_per_pixel[0] == aligned.photon_flux_per_pixel[0]   # the value held from t = 0.1 s
    zenith_flux = sky_photon_flux_per_pixel(21.0, gen4)
    assert inside.photon_flux_per_pixel[0] > zenith_flux                          # 60 deg from the zenith
