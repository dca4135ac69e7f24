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


def test_samples_taken_ahead_are_each_windows_own(graz, gen4, iss, pass_start, monkeypatch):
    """The boresight taken for the next SAMPLES_AHEAD samples in one call gives each window (aligned with the
    grid or not, inside the run and at its end) the bytes of a call for its own samples."""
    from evsda.blocks.scene import sky
    from evsda.graph import RunInfo

    def stepped(ahead: int) -> list:
        monkeypatch.setattr(sky, "SAMPLES_AHEAD", ahead)
        block = SkyBackgroundBlock(cadence_s=0.1, moonlight=True, name="sky")
        pointing = Pointing(mode="track", target_line1=iss.line1, target_line2=iss.line2)
        block.setup(RunInfo(epoch=pass_start, duration_ns=2_100_000_000, window_ns=150_000_000, seed=1))
        return [block.step(w, observer=graz, pointing=pointing, focal_plane=gen4)["background"]
                for w in block.run.windows()]

    ahead, own = stepped(8), stepped(1)
    assert len(ahead) == 14
    for a, b in zip(ahead, own):
        assert a.t_ns.tobytes() == b.t_ns.tobytes()
        assert a.photon_flux_per_pixel.tobytes() == b.photon_flux_per_pixel.tobytes()
    assert len({a.photon_flux_per_pixel[0] for a in ahead}) == 14         # the sky changes along the track
