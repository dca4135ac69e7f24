"""Path choice from what the pixels see (blocks/optics/pixel_view.py, PathChooser with a detector).

References nobody here wrote: the pixel's first-order response and cutoff law are the Gen4 preset's (NIST fit),
the direct time average below is the pupil path's own frames under frozen flow (Taylor), low-passed as a
first-order filter does (paper Eq. 16); the estimate under test is the chooser's fit and K_eff formula.
"""

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.atmosphere import Atmosphere, Layer
from evsda.blocks.optics.fft_screens import fft_phase_screens
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.paths import averaged_distance, representative_conditions, total_variation
from evsda.blocks.optics.pixel_view import PixelView, averaged_frames, load_pixel_params
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane, PointSources
from evsda.graph import ParameterError, RunInfo, Window
from evsda.library import resolve

GEN4 = "library:sensors/prophesee_gen4.yaml"
FOCAL_PLANE = FocalPlane(1280, 720, 4.86e-6, 0.4)          # the tracked pass's 12.2 urad pixels
WAVELENGTH = 550e-9


def gen4_pixels(focal_plane=FOCAL_PLANE):
    return PixelView.of(load_pixel_params(resolve(GEN4), "optics"), focal_plane.pixel_area_m2, WAVELENGTH)


def imager(atmosphere, diameter=0.2, obscuration=0.4, focal_plane=FOCAL_PLANE, seed=1):
    return Imager(Telescope(diameter, obscuration), focal_plane, WAVELENGTH, atmosphere, PointSourceOptics.Params(),
                  seed=(seed,), pixels=gen4_pixels(focal_plane))


def test_a_fast_faint_star_takes_long_exposure_and_a_tracked_satellite_keeps_the_pupil_path():
    im = imager(Atmosphere.from_table(resolve("library:atmospheres/median_seeing.csv")))
    zenith, sky = np.deg2rad(40.0), 30.0                  # [rad], [photon/s per pixel]
    im.ensure_geometry(zenith)
    # a V ~ 12 star streaking at 800 pixel/s: ~5e3 photon/s, on a pixel for < 1.8 ms of its ~12 ms response
    star = im.chooser.choose(zenith, np.inf, "star", (800.0, 5e3, sky))
    assert star.path == "long_exposure" and "cannot make a pixel fire" in star.reason
    # the same star held still would move its pixel's log intensity by more than the smallest threshold
    assert gen4_pixels().seen_step(8192.0, 16.0, 0.0) > gen4_pixels().threshold_min
    # a bright satellite the mount tracks: a fast pixel (tau < 1 ms) sees every short exposure
    satellite = im.chooser.choose(zenith, 7e5, "satellite", (0.0, 8e6, sky))
    assert satellite.path == "pupil_fft", satellite.reason
    assert satellite.estimates["long_exposure"] > 0.1 >= satellite.estimates["pupil_fft"]
    assert "the pixels average 1.0" in satellite.reason


def test_the_pixels_response_follows_the_presets_cutoff_law():
    pixels = gen4_pixels()
    p = pixels.model.params
    # dark pixel: f_3dB = f_max (x_dark / x_sat)^n with the preset's fitted law
    x_dark = pixels.model.dark_current_A / p.reference_current_A
    f_dark = p.cutoff_max_hz * (x_dark / p.cutoff_saturation) ** p.cutoff_exponent
    assert pixels.response_time_s(0.0) == pytest.approx(1 / (2 * np.pi * f_dark), rel=1e-6)
    # a first-order filter reaches 1 - exp(-t / tau) of a step in a time t: a point at v pixel/s stays sqrt(2)/v
    tau = pixels.response_time_s(16.0 + 5e3)
    full = pixels.log_step(5e3, 16.0)
    assert pixels.seen_step(5e3, 16.0, 400.0) == pytest.approx(full * (1 - np.exp(-np.sqrt(2) / 400.0 / tau)))
    assert pixels.threshold_min == pytest.approx(p.threshold_on - 5 * p.threshold_sigma)


@pytest.mark.parametrize("tau_s", [0.01, 0.04])
def test_the_averaging_estimate_matches_a_direct_time_average_of_the_frames(tau_s):
    """One frozen-flow layer sliding across the pupil at 20 m/s; the pupil path's frames, low-passed by a
    first-order filter of time constant tau, against the long-exposure PSF at the same positions."""
    atmosphere = Atmosphere((Layer(1000.0, 1.5e-12, 20.0, 0.0),), 25.0)
    im = imager(atmosphere, diameter=0.2, obscuration=0.0, focal_plane=FocalPlane(64, 64, 4.86e-6, 0.4))
    zenith, range_m = representative_conditions(im.chooser.key(0.3, np.inf))
    im.ensure_geometry(zenith)
    g, speed = im.geometry, 20.0
    assert 2.5 < 0.2 / im.r0(zenith) < 3.5
    _, fits = im.chooser._probe(zenith, range_m)
    k_eff = averaged_frames(tau_s, np.array([1.0]), np.array([speed]), 0.2)
    estimate = averaged_distance(fits["long_exposure"], k_eff)

    dt = g.delta_m / speed                                # one screen sample per frame [s]
    gain = -np.expm1(-dt / tau_s)
    burn, kept = int(np.ceil(4 * tau_s / dt)) + 1, 60
    rng = np.random.default_rng(5)
    distances, instantaneous = [], []
    for offset in rng.uniform(-0.5, 0.5, (6, 2)):
        n = 1 << int(np.ceil(np.log2(g.n_pupil + burn + kept)))
        screen = fft_phase_screens(rng, n, g.delta_m, im.r0(zenith), atmosphere.L0)[0]
        phase = np.stack([screen[: g.n_pupil, k : k + g.n_pupil] for k in range(burn + kept)])
        frames = im.pupil_renderer.stamps(im.pupil_amplitude, phase, np.broadcast_to(offset, (len(phase), 2)))
        long_exposure = im.path_named["long_exposure"].renderer(zenith).stamps(offset[None])[0]
        flux = frames.sum(axis=(1, 2)).mean()
        filtered = frames[0].copy()
        for k in range(1, len(frames)):
            filtered += gain * (frames[k] - filtered)
            if k >= burn:
                distances.append(float(total_variation(filtered, long_exposure, flux)))
                instantaneous.append(float(total_variation(frames[k], long_exposure, flux)))
    direct = np.mean(distances)
    assert direct < 0.9 * np.mean(instantaneous)          # the filter does average the turbulence
    assert estimate == pytest.approx(direct, rel=0.25)


def streaking_star(window, cadence_ns=1_000_000, x0=-4.0, vx=800.0, flux=2e5):
    """A star entering the field at 800 pixel/s (NaN while outside), sampled every millisecond."""
    t_ns = window.sample_times_ns(cadence_ns)
    x = x0 + vx * t_ns * 1e-9
    xs = np.where(x >= 0, x, np.nan)[:, None]
    n = len(t_ns)
    return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["HIP 7"]), np.array([1], np.int8), xs,
                        np.full((n, 1), 300.0), np.full((n, 1), flux), np.full((n, 1), 11.0), np.full((n, 1), np.inf),
                        np.full(n, np.deg2rad(30.0)))


@pytest.mark.parametrize("flux", [2e5, 1e7])       # V ~ 12.8: no pixel fires; V ~ 8.5: the chooser probes
def test_choices_from_what_the_pixels_see_do_not_depend_on_the_windows(flux):
    kwargs = dict(aperture_m=0.2, obscuration=0.4, seed=3, detector=GEN4)
    outputs = []
    # windows of 30 and 10 ms, and one holding the star's first input sample (5 ms) alone
    for cuts in ((0.0, 0.03), (0.0, 0.01, 0.02, 0.03), (0.0, 0.005, 0.006, 0.03)):
        block = PointSourceOptics(**kwargs)
        windows = [Window.from_seconds(a, b, index=i) for i, (a, b) in enumerate(zip(cuts, cuts[1:]))]
        block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
        out = [block.step(w, sources=[streaking_star(w, flux=flux)])["irradiance"] for w in windows]
        # per render time, the star's stamp where it is drawn (a window it is out of view in has no slot for it)
        outputs.append([(o.stamp_origin[k, 0], o.stamp_flux[k, 0]) if o.stamp_flux.shape[1] and o.stamp_flux[k, 0].any()
                        else None for o in out for k in range(len(o.t_ns))])
        frames = block._imager.frames_rendered
    for one, other in zip(outputs, outputs[1:]):
        assert [u is None for u in one] == [v is None for v in other]
        for u, v in zip(one, other):
            if u is not None:
                np.testing.assert_array_equal(u[0], v[0])
                np.testing.assert_array_equal(u[1], v[1])
    if flux < 1e6:      # its first frame has no rate (nothing before it, no other source): taken as still
        assert frames["pupil_fft"] == 1 and frames["long_exposure"] == 30 - 5 - 1
    else:
        assert set(frames) == {"pupil_fft"}


@pytest.mark.parametrize("preset", [GEN4, "library:sensors/davis346.yaml", "library:sensors/dvs128.yaml"])
def test_presets_read_by_libyaml_are_those_of_the_python_parser(monkeypatch, preset):
    import yaml
    fast = load_pixel_params(resolve(preset), "optics")
    monkeypatch.delattr(yaml, "CSafeLoader", raising=False)          # a PyYAML built without libyaml
    assert load_pixel_params(resolve(preset), "optics") == fast


def test_a_detector_without_a_pixel_block_is_one_clear_error(tmp_path):
    preset = tmp_path / "camera_only.yaml"
    preset.write_text("evsda: 1\nname: x\nblocks:\n  camera: {type: camera, params: {width_px: 8}}\n")
    block = PointSourceOptics(aperture_m=0.2, detector=str(preset))
    block.setup(RunInfo(duration_ns=10_000_000))
    with pytest.raises(ParameterError, match="one 'dvs_pixel' block, found 0"):
        block.step(Window.from_seconds(0, 0.01), sources=[streaking_star(Window.from_seconds(0, 0.01))])


@pytest.mark.parametrize("size, oversample", [(7, 10), (13, 7), (5, 16), (9, 3)])
def test_compiled_analytic_stamps_are_the_reference_renderers_bit_for_bit(size, oversample):
    from evsda.blocks.optics.analytic_path import AnalyticPath
    from evsda.blocks.optics.psf import long_exposure_profile
    from evsda.blocks.optics.render import RadialRenderer, StampSampler

    sampler = StampSampler(size, 12.15e-6, oversample)
    theta = np.linspace(0.0, (size / 2 + 2) * np.sqrt(2) * sampler.pixel_scale_rad, 2048)
    renderer = RadialRenderer(sampler, theta, long_exposure_profile(Telescope(0.2, 0.4), WAVELENGTH, 0.05, 25.0,
                                                                    theta, 2048))
    offsets = np.random.default_rng(1).uniform(-0.5, 0.5, (50, 2))
    offsets[:2] = [[0.0, 0.0], [0.5, -0.5]]
    np.testing.assert_array_equal(AnalyticPath.stamps(renderer, offsets), renderer.stamps(offsets))


def test_the_array_keys_are_each_frames_key():
    # PathChooser.keys (every frame at once, Imager._paths) against key() frame by frame: zenith angles with and
    # without turbulence (NaN: above the atmosphere), ranges near, far and infinite, what the pixels see below, at and
    # above each bin's least value and unknown (NaN), with and without the line of sight's own rate
    im = imager(Atmosphere.from_table(resolve("library:atmospheres/median_seeing.csv")))
    rng = np.random.default_rng(4)
    frames = 400
    zenith = np.where(rng.random(frames) < 0.2, np.nan, rng.uniform(0.0, 1.4, frames))
    range_m = np.choose(rng.integers(0, 3, frames), [rng.uniform(3e5, 4e7, frames), np.full(frames, np.inf),
                                                      np.full(frames, 1e12)])
    seen = 10.0 ** rng.uniform(-1.0, 7.0, (frames, 4))
    seen[rng.random((frames, 4)) < 0.1] = np.nan
    seen[rng.random((frames, 4)) < 0.1] = 1.0
    for given in (seen, seen[:, :3], None):
        keys = im.chooser.keys(zenith, range_m, given)
        expected = [im.chooser.key(z, r, None if given is None else tuple(s)) for z, r, s in
                    zip(zenith, range_m, given if given is not None else [None] * frames)]
        assert keys == expected


def test_long_exposure_table_in_halves_is_the_whole_table(monkeypatch):
    """AnalyticPath's long-exposure table, its halves on two threads (or on the path probes' threads, which take
    table_parts), equals long_exposure_profile on all radii."""
    from evsda.blocks.optics import analytic_path
    from evsda.blocks.optics.psf import long_exposure_profile

    monkeypatch.setenv("EVSDA_THREADS", "2")
    atmosphere = Atmosphere.hufnagel_valley(2).scaled_to_r0(0.05)
    im = imager(atmosphere)
    zenith = np.deg2rad(30.3)
    im.ensure_geometry(zenith)
    path = im.path_named["long_exposure"]
    parts = path.table_parts(zenith)
    assert len(parts) == 2
    r0 = im.r0(representative_conditions((int(np.floor(zenith / np.deg2rad(1.0))), -1))[0])
    theta = np.linspace(0.0, (im.sampler.size / 2 + 2) * np.sqrt(2) * im.pixel_scale, analytic_path.PROFILE_SAMPLES)
    whole = long_exposure_profile(im.telescope, WAVELENGTH, r0, atmosphere.L0, theta, analytic_path.PROFILE_FREQUENCIES)
    np.testing.assert_array_equal(path.renderer(zenith).profile, whole)
    np.testing.assert_array_equal(np.concatenate([part() for part in parts[::-1]][::-1]), whole)


def test_long_exposure_tables_share_their_bessel_functions():
    """Every zenith-angle bin's long-exposure table of an AnalyticPath, the later ones from the Bessel functions the
    first one made and kept (HankelKernel), equals long_exposure_profile computed afresh, bit for bit."""
    from evsda.blocks.optics import analytic_path
    from evsda.blocks.optics.psf import long_exposure_profile

    atmosphere = Atmosphere.hufnagel_valley(2).scaled_to_r0(0.05)
    im = imager(atmosphere)
    path = im.path_named["long_exposure"]
    for degrees in (30.3, 31.4, 45.6):
        zenith = np.deg2rad(degrees)
        im.ensure_geometry(zenith)
        _, r0 = path.table_key(zenith)
        theta = np.linspace(0.0, (im.sampler.size / 2 + 2) * np.sqrt(2) * im.pixel_scale,
                            analytic_path.PROFILE_SAMPLES)
        whole = long_exposure_profile(im.telescope, WAVELENGTH, r0, atmosphere.L0, theta,
                                      analytic_path.PROFILE_FREQUENCIES)
        np.testing.assert_array_equal(path.renderer(zenith).profile.view(np.uint64), whole.view(np.uint64))
    assert len(path._kernel._blocks) == analytic_path.PROFILE_SAMPLES // 512
