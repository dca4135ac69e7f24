"""Turbulence on a tracking mount: a satellite held still on the detector while the mount turns sweeps the layers
(its PSF evolves without wind); the same pixels read as a stare (no boresight azimuth) keep one frozen PSF. The
screens' frame is fixed at the first render time and kept across windows, threads and a resume."""

import copy

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.graph import RunInfo, Window

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
CADENCE_NS = 1_000_000
# no wind anywhere: only the line of sight moves the footprints (two layers, r0 ~ 5 cm at 500 nm)
PROFILE = "altitude_m,cn2_dh_m13,wind_speed_m_s,wind_direction_deg\n1000,1.5e-13,0,0\n8000,1.0e-13,0,0\n"


@pytest.fixture
def params(tmp_path):
    (tmp_path / "calm.csv").write_text(PROFILE)
    return dict(aperture_m=0.25, obscuration=0.2, psf_path="pupil_fft", seed=5, atmosphere="table",
                profile_file=str(tmp_path / "calm.csv"))
# the mount's elevation rate, ~1 deg/s: the sky turns ~3 pixels per render time
TURN_RAD_S = 3 * FOCAL_PLANE.pixel_scale_rad / (CADENCE_NS * 1e-9)


def tracked(window, mount=True):
    """A satellite held at the detector's centre by a mount rising in elevation at ~1 deg/s from 45 deg (azimuth
    fixed), and a star at the boresight's azimuth that stays put in azimuth/elevation, so streaks down the detector
    along its column (a great circle through the zenith: gnomonic ``y = cy - tan(el_star - el)/pixel``)."""
    t_ns = window.sample_times_ns(CADENCE_NS)
    t = t_ns * 1e-9
    n_t = len(t)
    rise = TURN_RAD_S * t
    star_y = 239.5 - np.tan(-40.5 * FOCAL_PLANE.pixel_scale_rad - rise) / FOCAL_PLANE.pixel_scale_rad
    x = np.stack([np.full(n_t, 320.0), np.full(n_t, 319.5)], axis=1)
    y = np.stack([np.full(n_t, 240.0), star_y], axis=1)
    zenith = np.deg2rad(45.0) - rise
    azimuth = np.full(n_t, 0.3) if mount else None
    return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["25544", "HIP 1"]), np.array([0, 1], np.int8), x, y,
                        np.full((n_t, 2), 3e5), np.full((n_t, 2), 3.0), np.array([[8e5, np.inf]] * n_t), zenith,
                        azimuth, None if azimuth is None else np.zeros(n_t))


def windows_of(length_s, total_s):
    n = int(round(total_s / length_s))
    return [Window.from_seconds(i * length_s, (i + 1) * length_s, index=i) for i in range(n)]


def run(params, windows, mount=True, block=None):
    block = block or PointSourceOptics(**params)
    block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    return np.concatenate([block.step(w, sources=[tracked(w, mount)])["irradiance"].stamp_flux for w in windows])


def change(stamps):
    """Distance between consecutive frames' normalised stamps (half the L1 distance) [1]."""
    s = stamps / stamps.sum(axis=(-2, -1), keepdims=True)
    return 0.5 * np.abs(np.diff(s, axis=0)).sum(axis=(-2, -1))


def test_tracked_satellite_psf_evolves_and_the_star_stays_frozen(params):
    stamps = run(params, windows_of(0.02, 0.02))
    satellite, star = stamps[:, 0], stamps[:, 1]
    # the satellite's footprint moves ~L omega = 6 m/s per layer km at 45 deg: it crosses D = 0.25 m in tens of ms
    assert change(satellite).mean() > 0.02
    # the star: its footprints stand still (no wind, fixed azimuth/elevation); it moves ~3 whole pixels a frame
    # down the detector (the same sub-pixel offset to 1e-5 pixel): the same stamp but for the airmass's change
    assert change(star).max() < 0.01 * change(satellite).mean()
    # read as a stare (no boresight azimuth), the held satellite keeps one frozen PSF but for the airmass's change:
    # the old, backward, result
    staring = run(params, windows_of(0.02, 0.02), mount=False)[:, 0]
    assert change(staring).max() < 1e-4


@pytest.mark.parametrize("threads", ["1", "3"])
def test_tracked_run_does_not_depend_on_windows_threads_or_resume(params, monkeypatch, threads):
    monkeypatch.setenv("EVSDA_THREADS", threads)
    whole = run(params, windows_of(0.02, 0.02))
    np.testing.assert_array_equal(whole, run(params, windows_of(0.004, 0.02)))
    windows = windows_of(0.01, 0.02)
    first = PointSourceOptics(**params)
    run(params, windows[:1], block=first)
    state = copy.deepcopy(first.get_state())
    assert state["optics_state"]["frame"] == pytest.approx([0.3, np.deg2rad(45.0), 0.0])
    resumed = PointSourceOptics(**params)
    resumed.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    resumed.set_state(state)
    tail = resumed.step(windows[1], sources=[tracked(windows[1])])["irradiance"].stamp_flux
    np.testing.assert_array_equal(tail, whole[10:])


def test_path_choice_reads_the_line_of_sight_rate_not_the_streak(params):
    """The pixels see a streaking star and a still satellite; the layers see the reverse: the chooser's bins keep
    the apparent rate (the pixels' dwell) and the line of sight's rate in the ground frame (footprint speeds)."""
    window = windows_of(0.02, 0.02)[0]
    block = PointSourceOptics(**params)
    block.setup(RunInfo(duration_ns=window.stop_ns))
    kept, held, _ = block._held_samples("0", tracked(window), window.sample_times_ns(CADENCE_NS))
    np.testing.assert_array_equal(kept, [0, 1])                            # both on the detector
    turn_px_s = TURN_RAD_S / FOCAL_PLANE.pixel_scale_rad                   # 3000 pixel/s
    satellite, star = 0, 1
    later = slice(1, None)                                                 # the run's first sample: still (NaN)
    np.testing.assert_allclose(held["rate"][later, satellite], 0.0, atol=1e-9)
    np.testing.assert_allclose(held["sky_rate"][later, satellite], turn_px_s, rtol=1e-6)
    np.testing.assert_allclose(held["rate"][later, star], turn_px_s, rtol=1e-3)  # gnomonic tan over 80 pixels
    assert np.abs(held["sky_rate"][later, star]).max() < 1e-3
    # read as a stare, the line of sight turns with the apparent rate
    _, staring, _ = block._held_samples("1", tracked(window, mount=False), window.sample_times_ns(CADENCE_NS))
    np.testing.assert_array_equal(staring["sky_rate"], staring["rate"])
