"""The optics block: irradiance stamps from point sources, path choice, windows, resume, hard cases."""

import copy
import logging
import re

import numpy as np
import pytest

from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.imaging import Imager, line_of_sight
from evsda.blocks.optics.atmosphere import Atmosphere, Layer
from evsda.blocks.optics.paths import total_variation
from evsda.blocks.optics.psf import long_exposure_encircled_energy
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.ports import FocalPlane, Irradiance, PointSources, SkyBackground
from evsda.graph import InputError, ParameterError, RunInfo, Window

FOCAL_PLANE = FocalPlane(640, 480, 4.86e-6, 1.2)        # 4.05 urad pixels
WAVELENGTH = 550e-9
CADENCE_NS = 1_000_000


def track(window, *, x0=300.0, vx=40.0, y0=200.0, vy=-15.0, flux=(2e4, 5e3), range_m=(6e5, np.inf),
          zenith_deg=30.0, star_xy=(100.0, 400.0)):
    """A satellite crossing the field and a fixed star, sampled every millisecond on the global grid."""
    t_ns = window.sample_times_ns(CADENCE_NS)
    t = t_ns * 1e-9
    n = len(t)
    x = np.c_[x0 + vx * t, np.full(n, star_xy[0])]
    y = np.c_[y0 + vy * t, np.full(n, star_xy[1])]
    return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["25544", "HIP 1"]), np.array([0, 1], np.int8),
                        x, y, np.tile(np.asarray(flux, dtype=float), (n, 1)), np.full((n, 2), 8.0),
                        np.tile(np.asarray(range_m, dtype=float), (n, 1)), np.full(n, np.deg2rad(zenith_deg)))


def run(block, windows, **track_kwargs):
    block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    return [block.step(w, sources=[track(w, **track_kwargs)])["irradiance"] for w in windows]


def windows_of(length_s, total_s):
    n = int(round(total_s / length_s))
    return [Window.from_seconds(i * length_s, (i + 1) * length_s, index=i) for i in range(n)]


def concat(outputs):
    return (np.concatenate([o.t_ns for o in outputs]), np.concatenate([o.stamp_origin for o in outputs]),
            np.concatenate([o.stamp_flux for o in outputs]))


def test_every_parameter_states_its_unit():
    for name, field in PointSourceOptics.Params.model_fields.items():
        assert re.search(r"\[[^\]]+\]$", field.description or ""), name


def test_stamps_carry_the_collected_flux():
    block = PointSourceOptics(aperture_m=0.3, obscuration=0.3, throughput=0.8, atmosphere="none", seed=1)
    out = run(block, windows_of(0.02, 0.02))[0]
    assert isinstance(out, Irradiance) and out.stamp_flux.shape[:2] == (20, 2)
    collected = np.pi / 4 * 0.3**2 * (1 - 0.3**2) * 0.8
    totals = out.stamp_flux.sum(axis=(2, 3))
    # the diffraction-limited stamp keeps all but the far Airy wings (at most tolerance / 2)
    expected = np.array([2e4, 5e3]) * collected
    assert np.all((totals < expected) & (totals > expected * (1 - block.params.tolerance / 2)))
    # the satellite's stamp follows it: the brightest pixel is where the source is
    k = 10
    peak = np.unravel_index(out.stamp_flux[k, 0].argmax(), out.stamp_flux.shape[2:])
    x_sat = 300 + 40 * out.t_ns[k] * 1e-9
    assert out.stamp_origin[k, 0, 0] + peak[1] == round(x_sat)


def test_results_do_not_depend_on_how_the_run_is_cut_into_windows():
    kwargs = dict(aperture_m=0.25, obscuration=0.2, seed=4, render_rate_hz=1000.0)
    a = concat(run(PointSourceOptics(**kwargs), windows_of(0.1, 0.1)))
    b = concat(run(PointSourceOptics(**kwargs), windows_of(0.02, 0.1)))
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    c = concat(run(PointSourceOptics(**{**kwargs, "seed": 5}), windows_of(0.1, 0.1)))
    assert not np.array_equal(a[2], c[2])                 # another seed, other screens


def test_results_do_not_depend_on_the_number_of_threads(monkeypatch):
    kwargs = dict(aperture_m=0.25, obscuration=0.2, seed=4, psf_path="pupil_fft")
    outputs = []
    for threads in ("1", "2"):
        monkeypatch.setenv("EVSDA_THREADS", threads)
        outputs.append(concat(run(PointSourceOptics(**kwargs), windows_of(0.02, 0.04))))
    for u, v in zip(*outputs):
        np.testing.assert_array_equal(u, v)


def test_a_resumed_run_is_identical():
    kwargs = dict(aperture_m=0.25, obscuration=0.2, seed=4)
    windows = windows_of(0.02, 0.1)
    whole = concat(run(PointSourceOptics(**kwargs), windows))
    first = PointSourceOptics(**kwargs)
    head = run(first, windows[:3])
    state = copy.deepcopy(first.get_state())
    resumed = PointSourceOptics(**kwargs)
    resumed.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    resumed.set_state(state)
    tail = [resumed.step(w, sources=[track(w)])["irradiance"] for w in windows[3:]]
    for u, v in zip(whole, concat(head + tail)):
        np.testing.assert_array_equal(u, v)


def test_unobservable_sources_and_zero_flux_get_no_stamp():
    block = PointSourceOptics(aperture_m=0.3, seed=1)
    w = Window.from_seconds(0, 0.01)
    block.setup(RunInfo())
    sources = track(w, flux=(0.0, 5e3))
    x = sources.x_px.copy()
    x[5:, 1] = np.nan                                      # the star leaves the field of view
    sources = PointSources(**{**sources.__dict__, "x_px": x})
    out = block.step(w, sources=[sources])["irradiance"]
    assert out.n_stamps == 1                               # zero flux throughout: no stamp slot at all
    assert np.all(out.stamp_flux[5:, 0] == 0) and np.all(out.stamp_flux[:5, 0].sum(axis=(1, 2)) > 0)
    assert np.isfinite(out.stamp_flux).all()


def test_a_source_at_the_edge_of_the_field_puts_only_its_inside_part_on_the_sensor():
    block = PointSourceOptics(aperture_m=0.3, atmosphere="none", seed=1)
    out = run(block, windows_of(0.005, 0.005), x0=-0.5, vx=0.0, y0=479.5, vy=0.0)[0]      # on the corner
    stamp, (x0, y0) = out.stamp_flux[0, 0], out.stamp_origin[0, 0]
    cols = np.arange(stamp.shape[1]) + x0
    rows = np.arange(stamp.shape[0]) + y0
    inside = stamp[np.ix_((rows >= 0) & (rows < 480), (cols >= 0) & (cols < 640))].sum()
    frame = out.frame(0)
    star = out.stamp_flux[0, 1].sum()
    assert frame.sum() == pytest.approx(inside + star)
    assert 0.2 * stamp.sum() < inside < 0.3 * stamp.sum()   # about a quarter


def test_sources_off_the_detector_throughout_a_window_change_nothing():
    # the block leaves out a window's sources off the detector at every render time (a star field lists every star of
    # the run): with two such stars in a second input, one of which comes onto the detector in the third window (its
    # rate from its held sample), the stamps and the truth are those of the same run without them (the truth's
    # source index aside), over windows carrying each source's held sample
    def stars(window, dropped=False):
        t_ns = window.sample_times_ns(CADENCE_NS)
        n = len(t_ns)
        x = np.c_[np.full(n, 500.0), np.full(n, np.nan), np.where(t_ns >= 10_000_000, 80.0 + 1e3 * t_ns * 1e-9, np.nan)]
        y = np.c_[np.full(n, 50.0), np.full(n, np.nan), np.full(n, 300.0)]
        keep = [0, 2] if dropped else [0, 1, 2]
        return PointSources(FOCAL_PLANE, WAVELENGTH, t_ns, np.array(["HIP 2", "HIP 3", "HIP 4"])[keep],
                            np.ones(3, np.int8)[keep], x[:, keep], y[:, keep], np.full((n, 3), 4e3)[:, keep],
                            np.full((n, 3), 9.0)[:, keep], np.full((n, 3), np.inf)[:, keep],
                            np.full(n, np.deg2rad(30.0)))

    windows = windows_of(0.005, 0.015)
    outputs = {}
    for dropped in (False, True):
        block = PointSourceOptics(aperture_m=0.3, psf_path="pupil_fft", seed=3)
        block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
        outputs[dropped] = [block.step(w, sources=[track(w), stars(w, dropped)]) for w in windows]
    for every, some in zip(outputs[False], outputs[True]):
        a, b = every["irradiance"], some["irradiance"]
        assert a.stamp_origin.tobytes() == b.stamp_origin.tobytes() and a.stamp_flux.tobytes() == b.stamp_flux.tobytes()
        ta, tb = every["truth"], some["truth"]
        assert list(ta.source_id[ta.source_index]) == list(tb.source_id[tb.source_index])
        for name in ("t_ns", "x_px", "y_px", "magnitude", "photon_flux", "range_m"):
            assert getattr(ta, name).tobytes() == getattr(tb, name).tobytes()
    assert outputs[False][-1]["irradiance"].n_stamps == 4                  # the star that came onto the detector


def test_an_input_sampled_at_the_render_times_is_held_as_it_is():
    # such an input's samples are the held ones without a search (the usual input): the same numbers as an input
    # with one sample more, after the render times, which is searched; a star off the detector throughout left out
    w = Window.from_seconds(0, 0.01)
    t_ns = w.sample_times_ns(CADENCE_NS)
    held = []
    for longer in (False, True):
        block = PointSourceOptics(aperture_m=0.3, seed=1)
        block.setup(RunInfo())
        sources = track(Window.from_seconds(0, 0.011) if longer else w, star_xy=(np.nan, 400.0))
        held.append(block._held_samples("0", sources, t_ns))
    (kept, samples, boresight), (kept_longer, samples_longer, boresight_longer) = held
    np.testing.assert_array_equal(kept, [0])
    np.testing.assert_array_equal(kept_longer, kept)
    np.testing.assert_array_equal(boresight_longer, boresight)
    assert samples.keys() == samples_longer.keys()
    for name in samples:
        assert samples[name].tobytes() == samples_longer[name].tobytes(), name


def test_sky_background_is_uniform_and_scaled_by_the_collecting_area():
    block = PointSourceOptics(aperture_m=0.5, obscuration=0.4, throughput=0.7, atmosphere="none", seed=1)
    w = Window.from_seconds(0, 0.004)
    block.setup(RunInfo())
    sky = SkyBackground(np.array([0], np.int64), np.array([100.0]))
    out = block.step(w, sources=[track(w)], background=sky)["irradiance"]
    np.testing.assert_allclose(out.background, 100.0 * np.pi / 4 * 0.25 * (1 - 0.16) * 0.7)
    none = block.step(w, sources=[track(w)])["irradiance"]
    assert np.all(none.background == 0)


def test_several_inputs_are_merged_and_must_agree():
    block = PointSourceOptics(aperture_m=0.3, atmosphere="none", seed=1)
    w = Window.from_seconds(0, 0.003)
    block.setup(RunInfo())
    out = block.step(w, sources=[track(w), track(w, star_xy=(500.0, 50.0))])["irradiance"]
    assert out.n_stamps == 4
    other = PointSources(**{**track(w).__dict__, "wavelength_m": 700e-9})
    with pytest.raises(InputError, match="wavelength"):
        block.step(w, sources=[track(w), other])


def _choice(caplog, **params):
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="evsda.blocks.optics"):
        block = PointSourceOptics(**params, seed=2)
        run(block, windows_of(0.003, 0.003))
    return [r.getMessage() for r in caplog.records if "path '" in r.getMessage()]


def test_path_choice_follows_the_physics_and_is_logged(caplog):
    vacuum = _choice(caplog, aperture_m=0.3, atmosphere="none")
    assert vacuum and all("path 'airy'" in m and "no atmosphere" in m for m in vacuum)
    gentle = _choice(caplog, aperture_m=0.05, r0_500nm_m=2.0)        # D/r0 ~ 0.02
    assert gentle and all("path 'airy'" in m and "D/r0 = 0.0" in m for m in gentle)
    seeing = _choice(caplog, aperture_m=0.3, r0_500nm_m=0.1)         # D/r0 ~ 3
    assert seeing and all("path 'pupil_fft'" in m for m in seeing)
    forced = _choice(caplog, aperture_m=0.3, psf_path="long_exposure")
    assert forced and all("forced by psf_path" in m for m in forced)


def test_space_observer_sees_no_turbulence(caplog):
    # a NaN zenith angle means an observer above the atmosphere: the diffraction-limited path, static PSF
    block = PointSourceOptics(aperture_m=0.3, seed=2)
    w = Window.from_seconds(0, 0.002)
    block.setup(RunInfo())
    with caplog.at_level(logging.INFO, logger="evsda.blocks.optics"):
        out = block.step(w, sources=[track(w, zenith_deg=float("nan"), vx=0.0, vy=0.0)])["irradiance"]
    assert any("path 'airy'" in r.getMessage() and "no atmosphere" in r.getMessage() for r in caplog.records)
    np.testing.assert_array_equal(out.stamp_flux[0], out.stamp_flux[1])


@pytest.mark.parametrize("path", ["airy", "long_exposure", "pupil_fft"])
def test_forced_fast_paths_conserve_the_flux_in_their_stamps(path):
    block = PointSourceOptics(aperture_m=0.3, obscuration=0.3, psf_path=path, seed=3)
    out = run(block, windows_of(0.004, 0.004))[0]
    collected = np.pi / 4 * 0.09 * 0.91
    fraction = out.stamp_flux[:, 0].sum(axis=(1, 2)) / (2e4 * collected)
    assert np.all((fraction > 0.95) & (fraction <= 1.0 + 1e-9))


def test_strong_turbulence_spreads_the_image():
    weak = run(PointSourceOptics(aperture_m=0.3, r0_500nm_m=0.5, psf_path="long_exposure", seed=1),
               windows_of(0.002, 0.002))[0]
    strong = run(PointSourceOptics(aperture_m=0.3, r0_500nm_m=0.01, psf_path="long_exposure", seed=1),
                 windows_of(0.002, 0.002))[0]
    peak = lambda out: out.stamp_flux[0, 0].max() / out.stamp_flux[0, 0].sum()
    assert peak(strong) < 0.3 * peak(weak)
    assert strong.stamp_flux.shape[2] > weak.stamp_flux.shape[2]    # D/r0 = 30 needs a wider stamp


def test_strong_turbulence_short_exposures_resolve_r0_and_average_to_the_seeing_disc():
    # D/r0 = 29 through the pupil path: the pupil grid resolves r0, the stamp holds the seeing halo without the
    # sampled pupil's far field wrapping, and independent short exposures (a new screen every frame) spread
    # their light like the long-exposure PSF (Fried 1966): half-light radius within 20 % of its own
    atmosphere = Atmosphere.hufnagel_valley(1).scaled_to_r0(0.01)
    imager = Imager(Telescope(0.3), FOCAL_PLANE, WAVELENGTH, atmosphere,
                    PointSourceOptics.Params(psf_path="pupil_fft", screen_revisit_s=0.05), seed=(1,))
    zenith = np.deg2rad(30)
    g = imager.ensure_geometry(zenith)
    r0 = imager.r0(zenith)
    assert 0.3 / r0 > 25 and g.delta_m <= r0 / 4
    assert g.stamp_size * imager.pixel_scale < WAVELENGTH / g.delta_m
    frames = 4
    _, stamps, paths = imager.render("s", 0.05 * np.arange(frames), np.full(frames, 320.3), np.full(frames, 240.1),
                                     np.full(frames, zenith), np.full(frames, 6e5))
    assert set(paths) == {"pupil_fft"}
    fraction = stamps.sum(axis=(1, 2))
    assert np.all((fraction > 1 - imager.tolerance / 2 - 0.01) & (fraction <= 1.0 + 1e-6))
    assert np.all(stamps.max(axis=(1, 2)) < 0.05 * fraction)           # no diffraction-limited core
    m = g.stamp_size
    rows, cols = np.indices((m, m)) - m // 2
    radius = np.hypot(cols - 0.3, rows - 0.1).ravel() * imager.pixel_scale
    order = np.argsort(radius)
    mean = stamps.mean(axis=0).ravel()[order]
    half_light = radius[order][np.searchsorted(np.cumsum(mean) / mean.sum(), 0.5)]
    theta = np.linspace(0, 10 * WAVELENGTH / r0, 2000)
    seeing = theta[np.searchsorted(long_exposure_encircled_energy(imager.telescope, WAVELENGTH, r0, atmosphere.L0,
                                                                  theta), 0.5)]
    assert half_light == pytest.approx(seeing, rel=0.2)


def test_sources_rendered_together_get_the_stamps_each_gets_alone():
    # Imager.render_many (a window's sources at the same render times on the pupil path: one walk of all their screens,
    # one stamps call) against each source's own render in an imager of the same seed, bit for bit, over two windows
    # (the screens carried on), a satellite at finite range (defocus) among stars
    atmosphere = Atmosphere.hufnagel_valley(3)
    imagers = [Imager(Telescope(0.2, 0.3), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(
        psf_path="pupil_fft", focus="infinity"), seed=(5,)) for _ in range(2)]
    rng = np.random.default_rng(3)
    sources, frames = ["sat", "star a", "star b"], 20
    for imager in imagers:
        imager.ensure_geometry(0.6)
    assert imagers[0].renders_together("pupil_fft") and not imagers[0].renders_together("long_exposure")
    for window in range(2):
        t = 0.001 * (np.arange(frames) + window * frames)
        x = rng.uniform(100, 500, (len(sources), 1)) + 0.3 * np.arange(frames)
        y = rng.uniform(100, 400, (len(sources), 1)) - 0.2 * np.arange(frames)
        zenith = 0.6 + rng.uniform(0, 1e-3, (len(sources), frames))
        range_m = np.array([[4e5], [np.inf], [np.inf]]) * np.ones(frames)
        placed = imagers[0].placement(x, y, zenith)
        together = imagers[0].render_many(sources, t, zenith, range_m, placed)
        for k, source in enumerate(sources):
            _, own, _ = imagers[1].render(source, t, x[k], y[k], zenith[k], range_m[k], paths=["pupil_fft"] * frames)
            assert together[k].tobytes() == own.tobytes()
    assert imagers[0].frames_rendered == imagers[1].frames_rendered


def test_a_windows_placement_at_once_is_each_tracks_own_and_renders_the_same():
    # the block places every track in view at once (Imager.placement on render times x tracks, the ground frame's
    # lines of sight included, frames out of view NaN): each track's column is what its own frames give, and a
    # render handed it gives the stamps of a render that places its frames itself
    atmosphere = Atmosphere.hufnagel_valley(2)
    imagers = [Imager(Telescope(0.2), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(psf_path="pupil_fft"),
                      seed=(4,)) for _ in range(2)]
    rng = np.random.default_rng(2)
    frames, tracks = 6, 3
    x, y = rng.uniform(100, 500, (2, frames, tracks))
    x[2:4, 1] = np.nan
    zenith = np.full((frames, tracks), 0.5) + rng.uniform(0, 1e-3, (frames, tracks))
    azimuth, rotation = np.full((frames, tracks), 1.1), np.full((frames, tracks), 0.2)
    for imager in imagers:
        imager.ensure_geometry(0.5)
        imager.set_frame(1.1, 0.5, 0.2)
    together = imagers[0].placement(x, y, zenith, azimuth, rotation)
    for j in range(tracks):
        alone = imagers[0].placement(x[:, j].copy(), y[:, j].copy(), zenith[:, j].copy(), azimuth[:, j].copy(),
                                     rotation[:, j].copy())
        for a, b in zip(together, alone):
            np.testing.assert_array_equal(a[:, j], b)
    t = 0.001 * np.arange(frames)
    placed = tuple(p[:, 0] for p in together)
    given = imagers[0].render("s", t, x[:, 0], y[:, 0], zenith[:, 0], 4e5, placed=placed)
    own = imagers[1].render("s", t, x[:, 0], y[:, 0], zenith[:, 0], 4e5, azimuth_rad=azimuth[:, 0],
                            rotation_rad=rotation[:, 0])
    np.testing.assert_array_equal(given[0], own[0])
    np.testing.assert_array_equal(given[1], own[1])


def test_zernike_screens_and_revisits_run_deterministically():
    kwargs = dict(aperture_m=0.2, screen_method="zernike", screen_update="regenerate", n_zernike_modes=20,
                  screen_revisit_s=0.005, psf_path="pupil_fft", seed=9)
    a = concat(run(PointSourceOptics(**kwargs), windows_of(0.01, 0.01)))
    b = concat(run(PointSourceOptics(**kwargs), windows_of(0.002, 0.01)))
    np.testing.assert_array_equal(a[2], b[2])
    with pytest.raises(ParameterError, match="regenerate"):
        PointSourceOptics(screen_method="zernike", screen_update="extend")


def test_reference_path_renders_and_checks_its_grid():
    params = dict(aperture_m=0.1, r0_500nm_m=0.05, n_layers=2, psf_path="reference", seed=1, render_rate_hz=500.0)
    out = run(PointSourceOptics(**params), windows_of(0.004, 0.004), range_m=(4e5, 4e5))[0]
    collected = np.pi / 4 * 0.01
    fraction = out.stamp_flux[:, 0].sum(axis=(1, 2)) / (2e4 * collected)
    assert np.all((fraction > 0.7) & (fraction < 1.3))     # scintillation moves the collected flux a little
    with pytest.raises(ParameterError, match="grid_size.*constraint"):
        run(PointSourceOptics(**params, grid_size=32), windows_of(0.002, 0.002), range_m=(4e5, 4e5))


def _paths_apart(atmosphere, diameter, frames=4, distance=5e5):
    """Distance between pupil_fft and reference stamps fed the same screens, and the block's estimate."""
    imager = Imager(Telescope(diameter, 0.0), FOCAL_PLANE, WAVELENGTH, atmosphere, PointSourceOptics.Params(), seed=(1,))
    zenith = np.deg2rad(20)
    imager.ensure_geometry(zenith)
    errors = []
    for k in range(frames):
        t = 0.05 * k
        sight = imager.sight(320.0, 240.0, zenith)
        field = imager.reference.field("s", t, sight, zenith, distance)
        phase = imager.reference.pupil_phase("s", t, sight, zenith, distance)
        offset = np.array([[0.2, -0.1]])
        reference = imager.pupil_renderer.stamps_from_field(field[None], offset)
        fast = imager.pupil_renderer.stamps(imager.pupil_amplitude, phase[None], offset)
        errors.append(total_variation(fast, reference, reference.sum())[0])
    return np.array(errors), imager.chooser.estimate_errors(zenith, distance)["pupil_fft"]


@pytest.mark.parametrize("distance", [4e5, 36_000e3])          # LEO and GEO
def test_pupil_path_equals_the_reference_when_the_turbulence_is_near_the_aperture(distance):
    # a layer 30 m up: Fresnel scale sqrt(lambda z) = 4 mm << r0 = 5 cm, the near-field limit of the pupil path;
    # at GEO the reference's source-plane chirps span ~1e5 rad and must keep float64 precision through the screens
    near = Atmosphere((Layer(30.0, 1.0, 5.0, 0.0),)).scaled_to_r0(0.05)
    errors, estimate = _paths_apart(near, 0.1, frames=2, distance=distance)
    assert errors.max() < 0.01 and estimate < 0.01


def test_pupil_path_error_estimate_matches_what_the_reference_shows():
    # HV5/7-like layers up to 10 km on a 10 cm aperture: scintillation and diffraction between layers
    errors, estimate = _paths_apart(Atmosphere.hufnagel_valley(2).scaled_to_r0(0.1), 0.1)
    assert 0.5 * estimate < errors.mean() < 2 * estimate



def test_lines_of_sight_with_one_boresight_a_render_time_are_each_tracks_own_bit_for_bit():
    # a window's tracks share the boresight at each render time: Imager.sight then takes its sines and cosines once
    # a render time (a column, broadcast); every finite number is the bits each track's frames give alone
    imager = Imager(Telescope(0.2), FOCAL_PLANE, WAVELENGTH, Atmosphere.hufnagel_valley(2),
                    PointSourceOptics.Params(psf_path="pupil_fft"), seed=(4,))
    imager.ensure_geometry(0.5)
    imager.set_frame(1.1, 0.5, 0.2)
    rng = np.random.default_rng(5)
    frames, tracks = 7, 4
    x, y = rng.uniform(0, 640, (2, frames, tracks))
    x[1:3, 2] = np.nan
    zenith, azimuth, rotation = (np.repeat(rng.uniform(lo, hi, (frames, 1)), tracks, axis=1)
                                 for lo, hi in ((0.4, 0.6), (1.0, 1.2), (0.1, 0.3)))
    azimuth[4] = np.nan                                  # a render time without the boresight's azimuth: staring
    together = imager.sight(x, y, zenith, azimuth, rotation)
    for j in range(tracks):
        alone = imager.sight(x[:, j].copy(), y[:, j].copy(), zenith[:, j].copy(), azimuth[:, j].copy(),
                             rotation[:, j].copy())
        finite = np.isfinite(alone)
        np.testing.assert_array_equal(np.isfinite(together[:, j]), finite)
        np.testing.assert_array_equal(together[:, j][finite].view(np.uint64), alone[finite].view(np.uint64))


def test_line_of_sight_rates_per_render_time_are_the_stacked_sums_bit_for_bit():
    # PointSourceOptics._sky_distance: the boresight and the times one column a sample (broadcast, the block's
    # usual input) or one a source, and the reference (np.linalg.norm of stacked vectors): the same finite bits
    rng = np.random.default_rng(6)
    samples, sources = 9, 5
    both = {"x": rng.uniform(0, 640, (samples, sources)), "y": rng.uniform(0, 480, (samples, sources))}
    both["x"][3, 1] = np.nan
    for name, (lo, hi) in (("zenith", (0.4, 0.6)), ("azimuth", (1.0, 1.2)), ("rotation", (0.1, 0.3))):
        both[name] = rng.uniform(lo, hi, (samples, 1))
    apparent = PointSourceOptics._apparent_distance(both)
    distance = PointSourceOptics._sky_distance(FOCAL_PLANE)
    with np.errstate(invalid="ignore"):
        per_sample = distance(both, apparent)
        per_source = distance({k: np.ascontiguousarray(np.broadcast_to(v, (samples, sources))) for k, v in both.items()},
                              apparent)
        centre = np.array([(FOCAL_PLANE.width_px - 1) / 2, (FOCAL_PLANE.height_px - 1) / 2])
        scale = FOCAL_PLANE.pixel_scale_rad
        theta = (np.stack([both["x"], both["y"]], axis=-1) - centre) * scale
        u = np.stack(line_of_sight(theta, both["zenith"], both["azimuth"], both["rotation"]), axis=-1)
        units = u / np.linalg.norm(u, axis=-1, keepdims=True)
        chord = np.linalg.norm(units[1:] - units[:-1], axis=-1)
        reference = 2.0 * np.arcsin(np.minimum(chord / 2.0, 1.0)) / scale
    finite = np.isfinite(reference)
    assert finite.sum() == reference.size - 2
    for result in (per_sample, per_source):
        np.testing.assert_array_equal(np.isfinite(result), finite)
        np.testing.assert_array_equal(result[finite].view(np.uint64), reference[finite].view(np.uint64))


def test_wavelengths_agree_as_numpy_isclose_says():
    from evsda.blocks.optics.block import _isclose
    values = [5.5e-7, 5.5e-7 + 5e-9, 5.5e-7 + 2e-8, 0.0, 1e-8, np.inf, -np.inf, np.nan, 1.0, 1.0 + 1e-9, 1.0 + 3e-9]
    for a in values:
        for b in values:
            assert _isclose(a, b, rtol=1e-9) == bool(np.isclose(a, b, rtol=1e-9)), (a, b)


def test_a_tracks_paths_one_bin_or_several_are_each_frames_choice():
    imager = Imager(Telescope(0.2), FOCAL_PLANE, WAVELENGTH, Atmosphere.hufnagel_valley(2), PointSourceOptics.Params(),
                    seed=(4,))
    zenith, range_m = np.full(6, 0.5), np.full(6, np.inf)
    keys = imager.chooser.keys(zenith, range_m)
    one = imager._paths("s", zenith, range_m, None, keys=keys)
    assert len(set(keys)) == 1 and one == [imager.chooser.choose_key(keys[0], 0.5, "s").path] * 6
    zenith[3:] = 1.0                                     # two bins: each frame its bin's choice
    keys = imager.chooser.keys(zenith, range_m)
    several = imager._paths("s", zenith, range_m, None, keys=keys)
    assert len(set(keys)) == 2
    assert several == [imager.chooser.choose_key(key, float(z), "s").path for key, z in zip(keys, zenith)]
