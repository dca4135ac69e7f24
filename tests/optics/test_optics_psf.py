"""Telescope PSFs: Airy pattern and encircled energy, OTF, long exposure, image motion, pixel integration."""

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import j1

from evsda.blocks.optics.fft_screens import fft_phase_screens
from evsda.blocks.optics.kolmogorov import tilt_variance_one_axis
from evsda.blocks.optics.psf import (
    focal_field_mft, fwhm, long_exposure_encircled_energy, long_exposure_profile, psf_fft)
from evsda.blocks.optics.render import PupilRenderer, RadialRenderer, StampSampler, stamp_placement
from evsda.blocks.optics.telescope import Telescope, airy_encircled_energy, annular_otf

LAMBDA, D = 0.5e-6, 1.0


def _pupil_psf(telescope, theta_x, theta_y, n=256):
    delta = telescope.diameter_m / (n - 8)
    pupil = telescope.pupil(n, delta)
    e = focal_field_mft(pupil.astype(complex), delta, LAMBDA, theta_x, theta_y)
    return np.abs(e) ** 2 / telescope.collecting_area_m2          # [sr^-1] per unit collected power


def test_first_dark_ring_of_the_airy_pattern_is_at_1_22_lambda_over_d():
    # Born & Wolf 1999 Sec. 8.5.2: first zero of 2 J1(v)/v at v = 3.8317, theta = 1.2197 lambda / D
    theta = np.linspace(1.0, 1.45, 451) * LAMBDA / D
    profile = _pupil_psf(Telescope(D), theta, np.zeros(1))[0]
    first_dark = theta[np.argmin(profile)] / (LAMBDA / D)
    assert first_dark == pytest.approx(1.2197, abs=0.002)
    analytic = Telescope(D).airy(theta, LAMBDA)
    assert theta[np.argmin(analytic)] / (LAMBDA / D) == pytest.approx(brentq(j1, 3.5, 4.0) / np.pi, abs=1e-3)


@pytest.mark.parametrize("eps", [0.0, 0.3, 0.5])
def test_numerical_pupil_psf_matches_the_analytic_annular_airy_pattern(eps):
    telescope = Telescope(D, eps)
    theta = np.linspace(0, 6, 121) * LAMBDA / D
    numeric = _pupil_psf(telescope, theta, np.zeros(1))[0]
    analytic = telescope.airy(theta, LAMBDA)
    assert analytic[0] == pytest.approx(telescope.collecting_area_m2 / LAMBDA**2)
    np.testing.assert_allclose(numeric, analytic, atol=2e-3 * analytic[0])


def test_encircled_energy_follows_born_and_wolf():
    # 1 - J0^2 - J1^2: 83.8 %, 91.0 %, 93.8 % inside the first three dark rings (Born & Wolf 1999 Fig. 8.13)
    telescope = Telescope(D)
    rings = np.array([1.2197, 2.2331, 3.2383])
    assert airy_encircled_energy(rings * LAMBDA / D, D, LAMBDA) == pytest.approx([0.838, 0.910, 0.938], abs=1e-3)
    # numerically: integrate the sampled pupil PSF over disks
    step = 0.05 * LAMBDA / D
    theta = (np.arange(160) - 79.5) * step
    image = _pupil_psf(telescope, theta, theta)
    r = np.hypot(theta[None, :], theta[:, None])
    for ring, expected in zip(rings, [0.838, 0.910, 0.938]):
        inside = image[r <= ring * LAMBDA / D].sum() * step**2
        assert inside == pytest.approx(expected, abs=0.01)


def test_mft_equals_fft_on_fft_samples_and_conserves_energy():
    telescope = Telescope(0.3, 0.25)
    n, delta = 64, 0.3 / 56
    rng = np.random.default_rng(1)
    field = telescope.pupil(n, delta) * np.exp(1j * fft_phase_screens(rng, n, delta, 0.05)[0])
    fft_psf, step = psf_fft(field, delta, LAMBDA, 256)
    theta = (np.arange(256) - 128) * step
    mft_psf = np.abs(focal_field_mft(field, delta, LAMBDA, theta, theta)) ** 2
    np.testing.assert_allclose(mft_psf, fft_psf, rtol=1e-9, atol=1e-9 * fft_psf.max())
    # Parseval: one period lambda/delta of the sampled pupil's far field holds all the power
    assert fft_psf.sum() * step**2 == pytest.approx(np.sum(np.abs(field) ** 2) * delta**2, rel=1e-10)


def test_annular_otf_is_the_pupil_autocorrelation():
    telescope = Telescope(1.0, 0.4)
    n, delta = 512, 1 / 200
    pupil = telescope.pupil(n, delta)
    spectrum = np.fft.fft2(pupil)
    autocorrelation = np.fft.ifft2(np.abs(spectrum) ** 2).real
    autocorrelation /= autocorrelation[0, 0]
    shifts = np.array([10, 40, 60, 70, 100, 140, 180])
    np.testing.assert_allclose(autocorrelation[0, shifts], annular_otf(shifts * delta, 0.4), atol=0.006)


def test_long_exposure_fwhm_is_0_98_lambda_over_r0_for_large_telescopes():
    # Dierickx 1992 (J. Mod. Opt. 39, 569): FWHM = 0.976 lambda / r0 for Kolmogorov turbulence, D >> r0
    r0 = 0.02
    theta = np.linspace(0, 3, 3001) * LAMBDA / r0
    profile = long_exposure_profile(Telescope(D), LAMBDA, r0, np.inf, theta, 8192)
    assert fwhm(theta, profile) / (LAMBDA / r0) == pytest.approx(0.976, rel=0.01)
    # and the short exposures of turbulent pupils average to the long-exposure PSF: compare the energy
    # within 0.5, 1 and 1.5 lambda/r0 (D/r0 = 12, Kolmogorov FFT screens)
    telescope, n = Telescope(D), 64
    delta = D / (n - 4)
    r0 = D / 12
    rng = np.random.default_rng(1)
    step = 0.1 * LAMBDA / r0
    axis = (np.arange(64) - 32) * step
    pupil = telescope.pupil(n, delta)
    fields = np.array([pupil * np.exp(1j * screen[:n, :n])
                       for _ in range(150) for screen in fft_phase_screens(rng, 4 * n, delta, r0)])
    average = (np.abs(focal_field_mft(fields, delta, LAMBDA, axis, axis)) ** 2).mean(axis=0)
    average /= telescope.collecting_area_m2
    r = np.hypot(axis[None, :], axis[:, None])
    radii = np.array([0.5, 1.0, 1.5]) * LAMBDA / r0
    measured = [average[r <= radius].sum() * step**2 for radius in radii]
    expected = long_exposure_encircled_energy(telescope, LAMBDA, r0, np.inf, radii)
    np.testing.assert_allclose(measured, expected, rtol=0.05)


def test_image_motion_follows_the_tilt_variance():
    # centroid of the short-exposure image = G-tilt; its variance per axis is 0.170 (lambda/D)^2 (D/r0)^(5/3)
    # (Tyler 1994, JOSA A 11, 358), just under Noll's Z-tilt 0.182 (tilt_variance_one_axis)
    telescope, n = Telescope(D), 48
    delta = D / (n - 4)
    r0 = D / 4
    pupil = telescope.pupil(n, delta)
    x = (np.arange(n) - n // 2) * delta
    rng = np.random.default_rng(2)
    centroids = []
    for _ in range(600):
        for screen in fft_phase_screens(rng, 4 * n, delta, r0):
            phase = screen[:n, :n]
            # centroid of |E|^2 = intensity-weighted mean phase gradient / k (Primot et al. 1990)
            gy, gx = np.gradient(phase, delta)
            centroids.append([np.sum(pupil * gx) / pupil.sum(), np.sum(pupil * gy) / pupil.sum()])
    variance = np.var(np.array(centroids) / (2 * np.pi / LAMBDA), axis=0).mean()
    g_tilt = 0.170 * (LAMBDA / D) ** 2 * (D / r0) ** (5 / 3)
    assert variance == pytest.approx(g_tilt, rel=0.12)
    assert tilt_variance_one_axis(LAMBDA, D, r0) == pytest.approx(0.182 * (LAMBDA / D) ** 2 * (D / r0) ** (5 / 3),
                                                                   rel=0.01)


def test_pixel_integration_conserves_flux_and_converges():
    telescope = Telescope(0.3, 0.3)
    pixel = 1.5 * LAMBDA / 0.3
    theta = np.linspace(0, 60 * LAMBDA / 0.3, 30000)
    profile = telescope.airy(theta, LAMBDA)
    offsets = np.array([[0.0, 0.0], [0.31, -0.42]])
    fine = RadialRenderer(StampSampler(41, pixel, 36), theta, profile).stamps(offsets)
    for oversample, error in [(6, 0.01), (12, 0.003)]:
        coarse = RadialRenderer(StampSampler(41, pixel, oversample), theta, profile).stamps(offsets)
        assert np.abs(coarse - fine).sum(axis=(1, 2)).max() / 2 < error
    # flux inside a 41-pixel stamp = the annular Airy energy within that square (vs radial integration)
    inside = fine.sum(axis=(1, 2))
    assert np.all((inside > 0.97) & (inside < 1.0))
    # sub-pixel placement: a source at +0.5 px is the source at -0.5 px of the next pixel, and the
    # centro-symmetric Airy pattern at (a, b) is the one at (-a, -b) turned by 180 degrees
    halves = RadialRenderer(StampSampler(41, pixel, 12), theta, profile).stamps(np.array([[0.5, 0.2], [-0.5, 0.2]]))
    np.testing.assert_allclose(halves[0][:, 1:], halves[1][:, :-1], atol=1e-12)
    mirrored = RadialRenderer(StampSampler(41, pixel, 12), theta, profile).stamps(np.array([[0.31, -0.42],
                                                                                            [-0.31, 0.42]]))
    np.testing.assert_allclose(mirrored[0], mirrored[1][::-1, ::-1], atol=1e-12)


def test_pupil_renderer_agrees_with_the_analytic_airy_stamps():
    telescope = Telescope(0.3, 0.3)
    sampler = StampSampler(21, 1.5 * LAMBDA / 0.3, 6)
    n = 96
    delta = 0.3 / (n - 2)
    renderer = PupilRenderer(sampler, n, delta, LAMBDA, telescope.collecting_area_m2, dtype=np.complex128)
    offsets = np.array([[0.0, 0.0], [0.4, 0.25], [-0.5, 0.5]])
    numeric = renderer.stamps(telescope.pupil(n, delta), np.zeros((3, n, n)), offsets)
    theta = np.linspace(0, 40 * LAMBDA / 0.3, 20000)
    analytic = RadialRenderer(sampler, theta, telescope.airy(theta, LAMBDA)).stamps(offsets)
    assert np.abs(numeric - analytic).sum(axis=(1, 2)).max() / 2 < 0.01
    single = PupilRenderer(sampler, n, delta, LAMBDA, telescope.collecting_area_m2)      # complex64 fast path
    fast = single.stamps(telescope.pupil(n, delta), np.zeros((3, n, n)), offsets)
    np.testing.assert_allclose(fast, numeric, atol=1e-5 * numeric.max())


def _fourier_series_stamps(field, delta, wavelength, sampler, area):
    """The pixel integrals of ``|E|^2`` by their definition, in double precision: the field's autocorrelation
    ``C_k = sum_m P_(m+k) P*_m`` at every lag, each term ``C_k exp(-2 pi i k delta . theta / lambda)`` integrated over
    each pixel in closed form (Goodman 2005 Sec. 6.3), no FFT."""
    n, m, p = field.shape[0], sampler.size, sampler.pixel_scale_rad
    lags = np.arange(-(n - 1), n)
    c = np.zeros((lags.size, lags.size), complex)
    for iy, ky in enumerate(lags):
        for ix, kx in enumerate(lags):
            shifted = field[max(ky, 0):n + min(ky, 0), max(kx, 0):n + min(kx, 0)]
            c[iy, ix] = np.sum(shifted * np.conj(field[max(-ky, 0):n + min(-ky, 0), max(-kx, 0):n + min(-kx, 0)]))
    f = lags * delta / wavelength
    centres = (np.arange(m) - m // 2) * p
    a = p * np.sinc(f * p)[None, :] * np.exp(-2j * np.pi * np.outer(centres, f))
    return (a @ c @ a.T).real * (delta**2 / wavelength) ** 2 / area


@pytest.mark.parametrize("n, size, pixels_per_period", [(12, 5, 0.8), (13, 7, 0.5), (16, 3, 1.7), (21, 9, 0.3)])
def test_pupil_stamps_are_the_exact_pixel_integrals_of_the_fourier_series(n, size, pixels_per_period):
    # random complex pupils (amplitude and phase) and tilts up to the pixel's edge, odd and even pupils (FFT lengths
    # 24, 27, 32, 45: even with a Nyquist lag, odd without), stamps from a third of the image's period to wider
    # than it: the renderer's real B (no Nyquist term) against the definition, to 1e-10 of the flux
    rng = np.random.default_rng(n)
    delta, wavelength = 0.01, 600e-9
    pixel = pixels_per_period * wavelength / delta / size
    sampler = StampSampler(size, pixel, 4)
    renderer = PupilRenderer(sampler, n, delta, wavelength, 0.02, dtype=np.complex128)
    single = PupilRenderer(sampler, n, delta, wavelength, 0.02)
    frames = 5
    amplitude = rng.uniform(0.0, 1.0, (frames, n, n))
    phase = rng.uniform(-np.pi, np.pi, (frames, n, n))
    offsets = np.vstack([[[0.5, -0.5], [0.0, 0.0]], rng.uniform(-0.5, 0.5, (frames - 2, 2))])
    stamps = renderer.stamps(amplitude, phase, offsets)
    fast = single.stamps(amplitude, phase, offsets)
    k = 2 * np.pi / wavelength
    for f in range(frames):
        tilt = k * (offsets[f, 1] * pixel * renderer.x[:, None] + offsets[f, 0] * pixel * renderer.x[None, :])
        exact = _fourier_series_stamps(amplitude[f] * np.exp(1j * (phase[f] + tilt)), delta, wavelength, sampler, 0.02)
        np.testing.assert_allclose(stamps[f], exact, rtol=0, atol=1e-10 * np.abs(exact).sum())
        np.testing.assert_allclose(fast[f], exact, rtol=0, atol=1e-6 * np.abs(exact).sum())


@pytest.mark.parametrize("pixels_per_period", [7 * 12.15e-6 * (0.2 / 38) / 568.3e-9, 1.0])
def test_single_precision_stamps_match_double_precision_and_conserve_flux(pixels_per_period):
    # the tracked pass's geometry (40-sample annular pupil, 7 x 7 stamps; benchmarks/pupil_stamps.py), turbulent
    # phases at r0 = 7 cm, sub-pixel offsets and every other frame defocused: the float32 renderer (phase rounded to
    # single precision, complex64 FFT, float32 |.|^2 and B) against float64 within 1e-6 of each stamp's peak and of
    # its flux; on a stamp spanning one whole period lambda/delta of the sampled pupil's image, the pixels hold all
    # the power (Parseval): sum = delta^2 sum |A|^2 / area, to 1e-6 in single precision and 1e-12 in double
    n, delta, wavelength, size = 40, 0.2 / 38, 568.3e-9, 7
    telescope = Telescope(0.2, 0.4)
    sampler = StampSampler(size, pixels_per_period * wavelength / delta / size, 9)
    single = PupilRenderer(sampler, n, delta, wavelength, telescope.collecting_area_m2)
    double = PupilRenderer(sampler, n, delta, wavelength, telescope.collecting_area_m2, dtype=np.complex128)
    amplitude = telescope.pupil(n, delta)
    rng = np.random.default_rng(7)
    frames = 24
    phase = np.concatenate([fft_phase_screens(rng, 2 * n, delta, 0.07)[0][None, :n, :n] for _ in range(frames)])
    offsets = rng.uniform(-0.5, 0.5, (frames, 2))
    curvature = np.where(np.arange(frames) % 2 == 0, np.pi / wavelength / 7.4e5, 0.0)     # a LEO at 740 km
    fast, reference = single.stamps(amplitude, phase, offsets, curvature), double.stamps(amplitude, phase, offsets,
                                                                                            curvature)
    assert fast.dtype == reference.dtype == np.float64
    assert (np.abs(fast - reference).max(axis=(1, 2)) <= 1e-6 * reference.max(axis=(1, 2))).all()
    assert (np.abs(fast - reference).sum(axis=(1, 2)) <= 1e-6 * reference.sum(axis=(1, 2))).all()
    if pixels_per_period == 1.0:
        power = np.sum(amplitude**2) * delta**2 / telescope.collecting_area_m2
        np.testing.assert_allclose(fast.sum(axis=(1, 2)), power, rtol=1e-6)
        np.testing.assert_allclose(reference.sum(axis=(1, 2)), power, rtol=1e-12)


def test_stamp_placement_rounds_to_the_nearest_pixel():
    origin, offset = stamp_placement(np.array([10.4, 10.6, np.nan]), np.array([3.5, -0.2, 1.0]), 5)
    np.testing.assert_array_equal(origin[:2], [[8, 2], [9, -2]])
    np.testing.assert_allclose(offset[:2], [[0.4, -0.5], [-0.4, -0.2]])
    np.testing.assert_array_equal(offset[2], [0.0, 0.0])


def test_pupil_stamps_from_a_phase_equal_those_from_its_field():
    # the fast entry (tilt folded into the phase, one exp) against the field entry (separate tilt products)
    telescope = Telescope(0.3, 0.2)
    sampler = StampSampler(9, 4e-6, 4)
    renderer = PupilRenderer(sampler, 40, 0.3 / 38, 550e-9, telescope.collecting_area_m2)
    amplitude = telescope.pupil(40, 0.3 / 38)
    rng = np.random.default_rng(3)
    phase = fft_phase_screens(rng, 80, 0.3 / 38, 0.08)[0][None, :40, :40]
    offsets = np.array([[0.31, -0.27]])
    fast = renderer.stamps(amplitude, phase, offsets)
    field = renderer.stamps_from_field(amplitude * np.exp(1j * phase), offsets)
    np.testing.assert_allclose(fast, field, rtol=0, atol=1e-6 * field.sum())


def test_compiled_column_transforms_are_pocketffts_bit_for_bit():
    # the length-80 transforms along y and x (column_fft) against scipy.fft.fft on padded spectra and fields over 12
    # decades, then the renderer with them against the same renderer through scipy for 40 and 39 pupil samples (both
    # pad to 80; 40 fill the rows' first half, for the transforms along x; with 39 the row the compiled pass along y
    # reads but the pupil leaves empty must stay zero between chunks); with 40, frame by frame in one compiled call
    # (BLAS's products through Numba) against chunk by chunk (numpy's matmul)
    import scipy.fft as sfft

    from evsda.blocks.optics import column_fft

    rng = np.random.default_rng(11)
    scratch = np.empty((4, 80 * 80), np.float32)
    for scale in 10.0 ** np.arange(-6, 7, 3):
        grid = np.zeros((5, 80, 80), np.complex64)
        grid[:, :40] = scale * (rng.standard_normal((5, 40, 80)) + 1j * rng.standard_normal((5, 40, 80)))
        expected = sfft.fft(grid, axis=1)
        grid[:, 40:] = np.nan                                            # not read
        power = np.empty((5, 80, 80), np.float32)
        column_fft.column_powers(grid, power, scratch)
        np.testing.assert_array_equal(power, expected.real**2 + expected.imag**2)
        column_fft.columns(grid, scratch)
        np.testing.assert_array_equal(grid.view(np.uint64), expected.view(np.uint64))
        # the rows' field made as they read it: numpy's complex64 field times a real amplitude (1 or per frame)
        cosine, sine = (scale * rng.standard_normal((2, 5, 40, 40))).astype(np.float32)
        for amplitude in (rng.uniform(0, 2, (1, 40, 40)), rng.uniform(0, 2, (5, 40, 40))):
            amplitude = amplitude.astype(np.float32)
            field = (cosine + 1j * sine).astype(np.complex64) * amplitude
            column_fft.rows(*(np.ascontiguousarray(a.transpose(0, 2, 1)) for a in (amplitude, cosine, sine)), grid,
                            scratch)
            np.testing.assert_array_equal(grid[:, :40].view(np.uint64), sfft.fft(field, n=80, axis=2).view(np.uint64))
            # and both in one frame's call, each radix-2 pass inside its radix-8 pass, the rows' spectra planar
            padded = np.zeros((5, 80, 80), np.complex64)
            padded[:, :40] = sfft.fft(field, n=80, axis=2)
            spectrum = sfft.fft(padded, axis=1)
            rows_planar = np.full(80 * 80, np.nan, np.float32)
            for f in range(5):
                flat = [np.ascontiguousarray(a[min(f, len(a) - 1)].T).reshape(-1) for a in (amplitude, cosine, sine)]
                column_fft.field_powers(*flat, rows_planar, power[f].reshape(-1), scratch, *column_fft.TWIDDLES)
            np.testing.assert_array_equal(power.view(np.uint32),
                                          (spectrum.real**2 + spectrum.imag**2).view(np.uint32))
    # the rows' spectra into real and imaginary rows, 16 x 16 floats at a time in vector registers: a transposition of
    # the 80 x 80 floats, every bit pattern kept (NaNs' payloads, signed zeros)
    lanes = rng.integers(0, 2**32, 6400, dtype=np.uint32).view(np.float32)
    split = np.empty(6400, np.float32)
    column_fft._lanes_to_split_rows(lanes, split)
    np.testing.assert_array_equal(split.view(np.uint32).reshape(80, 80), lanes.view(np.uint32).reshape(80, 80).T)
    telescope = Telescope(0.2, 0.4)
    for n in (40, 39):
        delta = 0.2 / (n - 2)
        compiled = PupilRenderer(StampSampler(7, 12.15e-6, 9), n, delta, 568.3e-9, telescope.collecting_area_m2)
        through_scipy = PupilRenderer(StampSampler(7, 12.15e-6, 9), n, delta, 568.3e-9, telescope.collecting_area_m2)
        through_scipy._columns = through_scipy._rows = False
        # and the compiled steps chunk by chunk (numpy's products) against frame by frame in one call (BLAS's)
        chunked = PupilRenderer(StampSampler(7, 12.15e-6, 9), n, delta, 568.3e-9, telescope.collecting_area_m2)
        chunked._frames = False
        assert compiled.padded == 80 and compiled._columns and compiled._rows == (n == 40)
        assert compiled._frames == (n == 40)
        amplitude = telescope.pupil(n, delta)
        phase = fft_phase_screens(rng, 2 * n, delta, 0.07)[0][None, :n, :n] + rng.standard_normal((37, n, n))
        offsets = rng.uniform(-0.5, 0.5, (37, 2))
        for frames in (slice(0, 37), slice(3, 20)):                      # buffers reused between calls
            expected = through_scipy.stamps(amplitude, phase[frames], offsets[frames])
            np.testing.assert_array_equal(compiled.stamps(amplitude, phase[frames], offsets[frames]), expected)
            np.testing.assert_array_equal(chunked.stamps(amplitude, phase[frames], offsets[frames]), expected)


def test_pupil_stamps_do_not_depend_on_how_frames_are_grouped():
    # the renderer works in blocks of PHASE_FRAMES and chunks of STAMP_CHUNK frames in reused buffers: 137 frames at
    # once, one by one and in another thread give the same bits, its one-pass |.|^2 is numpy's real**2 + imag**2 bit
    # for bit (and clears the rows asked), and its FFTs are scipy.fft.fft's
    import threading

    import scipy.fft as sfft

    from evsda.blocks.optics.render import (PHASE_FRAMES, _fft, pupil_field, squared_modulus, tilted_phase,
                                            tilted_phase_transposed)

    telescope = Telescope(0.2, 0.0)
    renderer = PupilRenderer(StampSampler(7, 4.86e-6, 10), 42, 0.005, 550e-9, telescope.collecting_area_m2)
    amplitude = telescope.pupil(42, 0.005)
    rng = np.random.default_rng(5)
    frames = PHASE_FRAMES + 9
    phase = 3.0 * rng.standard_normal((frames, 42, 42))
    offsets = rng.uniform(-0.5, 0.5, (frames, 2))
    together = renderer.stamps(amplitude, phase, offsets)
    one_by_one = np.concatenate([renderer.stamps(amplitude, phase[f:f + 1], offsets[f:f + 1]) for f in range(frames)])
    elsewhere = []
    worker = threading.Thread(target=lambda: elsewhere.append(renderer.stamps(amplitude, phase[5:30], offsets[5:30])))
    worker.start()
    worker.join()
    np.testing.assert_array_equal(together, one_by_one)
    np.testing.assert_array_equal(together[5:30], elsewhere[0])
    spectrum = (rng.standard_normal((3, 8, 8)) + 1j * rng.standard_normal((3, 8, 8))).astype(np.complex64)
    out = np.empty((3, 8, 8), np.float32)
    expected = spectrum.real**2 + spectrum.imag**2
    squared_modulus(spectrum.copy(), out)
    np.testing.assert_array_equal(out, expected)
    cleared = spectrum.copy()
    squared_modulus(cleared, out, 5)
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(cleared[:, :5], spectrum[:, :5])
    np.testing.assert_array_equal(cleared[:, 5:], 0)
    for axis in (1, 2):                                  # in place on a view, as the renderer calls it
        values = spectrum.copy()
        _fft(values[:, :6], axis)
        np.testing.assert_array_equal(values[:, :6], sfft.fft(spectrum[:, :6], axis=axis))
        np.testing.assert_array_equal(values[:, 6:], spectrum[:, 6:])
    # and its one-pass defocused, tilted phase is numpy's broadcast sums, rounded to single precision, also read
    # from a transposed view (as the screens hand it over)
    phase = phase[:37]
    ky, kx, x = rng.standard_normal(37) * 1e3, rng.standard_normal(37) * 1e3, renderer.x
    curvature = rng.uniform(0, 1e4, 37)
    defocused = phase + curvature[:, None, None] * renderer.r2[None]
    expected = (defocused + ky[:, None, None] * x[None, :, None]
                + kx[:, None, None] * x[None, None, :]).astype(np.float32)
    for given in (phase, np.ascontiguousarray(phase.transpose(0, 2, 1)).transpose(0, 2, 1)):
        tilted = np.empty(phase.shape, np.float32)
        tilted_phase(given, curvature, renderer.r2, ky, kx, x, tilted)
        np.testing.assert_array_equal(tilted, expected)
    # and written transposed from the transposed sum (the row transforms' layout)
    tilted_t = np.empty(phase.shape, np.float32)
    tilted_phase_transposed(np.ascontiguousarray(phase.transpose(0, 2, 1)), curvature, renderer.r2, ky, kx, x, tilted_t)
    np.testing.assert_array_equal(tilted_t, expected.transpose(0, 2, 1))
    # and its one-pass field is numpy's complex product with the real amplitude, the padding zeroed
    grid = np.full((37, 50, 50), 7 + 7j, np.complex64)
    cosine, sine = np.cos(tilted), np.sin(tilted)
    for given in (amplitude.astype(np.float32)[None], rng.uniform(0, 1, (37, 42, 42)).astype(np.float32)):
        pupil_field(given, cosine, sine, grid)
        field = (cosine + 1j * sine).astype(np.complex64)
        field *= given
        np.testing.assert_array_equal(grid[:, :42, :42], field)
        np.testing.assert_array_equal(grid[:, :42, 42:], 0)


def test_stamp_width_by_bisection_is_the_searchsorted_over_every_radius():
    # the fast path (encircled energy at the ~10 radii a bisection visits) against its reference: the energy at all
    # 1024 radii, then numpy's searchsorted
    from evsda.blocks.optics.psf import long_exposure_encircled_energy
    from evsda.blocks.optics.sizing import stamp_width_px
    rng = np.random.default_rng(4)
    for _ in range(3):                                    # the reference costs ~1 s each
        telescope = Telescope(rng.uniform(0.05, 1.0), rng.uniform(0.0, 0.5))
        wavelength, pixel, r0 = rng.uniform(400e-9, 900e-9), 10 ** rng.uniform(-6.5, -4.5), 10 ** rng.uniform(-2.5, 0)
        tolerance = rng.choice([0.02, 0.1, 0.2])
        theta = np.arange(1, 1025) * pixel / 4
        enclosed = long_exposure_encircled_energy(telescope, wavelength, r0, 25.0, theta)
        radius = theta[min(np.searchsorted(enclosed, 1 - tolerance / 2), theta.size - 1)]
        expected = int(np.clip(2 * np.ceil(radius / pixel) + 1, 3, 129))
        assert stamp_width_px(telescope, wavelength, pixel, r0, 25.0, tolerance) == expected


def test_encircled_energy_from_one_transfer_function_is_that_made_at_each_radius():
    # stamp_width_px makes the transfer function once for the radii its bisection visits: the numbers of making it
    # again for each radius (the formula as it was written before, turbulent and not)
    from scipy.special import j1

    from evsda.blocks.optics.kolmogorov import atmospheric_mtf
    from evsda.blocks.optics.psf import encircled_energy, long_exposure_transfer
    telescope, wavelength, n = Telescope(0.6, 0.3), 600e-9, 8192
    cutoff = telescope.diameter_m / wavelength
    f = (np.arange(n) + 0.5) * cutoff / n
    for r0 in (0.05, np.inf):
        transfer = telescope.otf(f, wavelength)
        if np.isfinite(r0):
            transfer = transfer * atmospheric_mtf(f, wavelength, r0, 25.0)
        once = long_exposure_transfer(telescope, wavelength, r0, 25.0, n)
        for radius in np.arange(1, 40) * 1.5e-6:
            theta = np.array([radius])
            expected = 2 * np.pi * theta * (j1(2 * np.pi * np.outer(theta, f)) @ transfer) * (cutoff / n)
            np.testing.assert_array_equal(encircled_energy(once, theta), expected)


def test_pupil_fft_falls_back_to_scipy_without_a_usable_private_binding(monkeypatch):
    # scipy's private pocketfft binding is used only if it imports, takes the call and gives scipy.fft.fft's bits;
    # a scipy where it is absent or changed runs the public transform, the same numbers
    import sys

    import scipy.fft as sfft

    from evsda.blocks.optics import render

    assert render._pocketfft_binding() is not None                  # this scipy has it, with scipy's bits
    render._pocketfft_binding.cache_clear()
    monkeypatch.setitem(sys.modules, "scipy.fft._pocketfft.pypocketfft", None)       # the import fails
    try:
        assert render._pocketfft_binding() is None
        values = (np.random.default_rng(3).standard_normal((4, 10, 16)) * (1 + 1j)).astype(np.complex64)
        expected = sfft.fft(values, axis=1)
        render._fft(values, 1)
        np.testing.assert_array_equal(values, expected)
    finally:
        render._pocketfft_binding.cache_clear()


def test_tilted_sine_and_cosine_are_numpys(monkeypatch):
    # the stamps' one-pass tilted phase with its float32 sine and cosine (render.tilted_sincos_transposed) gives
    # numpy's bits where the process's check says so (on 1.8 million phases here, every quadrant boundary's
    # neighbours among them), says False beyond its range or at NaN, and the stamps are the same either way: frame by
    # frame from the phase in one call, block by block, and with numpy's sine and cosine
    from evsda.blocks.optics import render

    rng = np.random.default_rng(8)
    frames, n = 37, 40
    phase_t = np.concatenate([rng.uniform(-1.0, 1.0, (frames, n, n)) * scale for scale in (0.1, 3.0, 100.0, 7e4)])
    boundaries = ((np.arange(-1000, 1000) + 0.5) * (np.pi / 2)).astype(np.float32).view(np.int32)
    near = (boundaries[:, None] + np.arange(-400, 400, dtype=np.int32)).view(np.float32).astype(float)
    phase_t = np.concatenate([phase_t, near.reshape(-1, n, n)])
    zero, x, r2 = np.zeros(len(phase_t)), np.zeros(n), np.zeros((n, n))
    cosine, sine = np.empty(phase_t.shape, np.float32), np.empty(phase_t.shape, np.float32)
    assert render.tilted_sincos_transposed(phase_t, zero, r2, zero, zero, x, cosine, sine)
    if render._sincos_agree():
        rounded = phase_t.astype(np.float32)
        np.testing.assert_array_equal(sine.view(np.uint32), np.sin(rounded).view(np.uint32))
        np.testing.assert_array_equal(cosine.view(np.uint32), np.cos(rounded).view(np.uint32))
    for outside in (np.nan, 8e4):
        given = phase_t[:2].copy()
        given[1, 3, 5] = outside
        assert not render.tilted_sincos_transposed(given, zero[:2], r2, zero[:2], zero[:2], x, cosine[:2], sine[:2])
    telescope = Telescope(0.2, 0.4)
    renderer = render.PupilRenderer(render.StampSampler(7, 12.15e-6, 9), n, 0.2 / 38, 568.3e-9,
                                    telescope.collecting_area_m2)
    amplitude = telescope.pupil(n, 0.2 / 38)
    phase = 4.0 * rng.standard_normal((render.PHASE_FRAMES + 5, n, n))
    phase[-1, 7, 9] = 9e4                                           # its block takes numpy's sine and cosine
    offsets = rng.uniform(-0.5, 0.5, (len(phase), 2))
    curvature = rng.uniform(0, 1e5, len(phase))
    fused = renderer.stamps(amplitude, phase, offsets, curvature)
    # every frame from its phase to its stamp in one compiled call (render._stamp_frames) against block by block
    # (the compiled sine and cosine, then chunk by chunk), with one amplitude and with one a frame
    chunked = render.PupilRenderer(render.StampSampler(7, 12.15e-6, 9), n, 0.2 / 38, 568.3e-9,
                                   telescope.collecting_area_m2)
    assert renderer._frames == render._sincos_agree()
    chunked._frames = False
    inside = slice(3, len(phase) - 1)
    amplitudes = amplitude[None] * rng.uniform(0.5, 1.0, (len(phase), 1, 1))
    for given in (amplitude, amplitudes[inside]):
        np.testing.assert_array_equal(renderer.stamps(given, phase[inside], offsets[inside], curvature[inside]),
                                      chunked.stamps(given, phase[inside], offsets[inside], curvature[inside]))
    np.testing.assert_array_equal(chunked.stamps(amplitude, phase, offsets, curvature), fused)
    monkeypatch.setattr(render, "_sincos_agree", lambda: False)
    np.testing.assert_array_equal(renderer.stamps(amplitude, phase, offsets, curvature), fused)


def test_renderer_buffers_start_on_a_cache_line():
    # the compiled passes read and write the renderer's buffers in vector lanes: each starts on a 64-byte boundary
    # (numpy gives 16), whatever its shape and type, and holds what numpy's would
    from evsda.blocks.optics import render

    for shape, dtype in (((4, 6400), np.float32), (6400, np.float32), ((7, 7), float), ((3, 80, 80), np.complex64)):
        for _ in range(5):
            array = render.aligned_empty(shape, dtype)
            assert array.ctypes.data % render.ALIGNMENT == 0
            assert array.shape == np.empty(shape).shape and array.dtype == dtype and array.flags.c_contiguous
    assert not render.aligned_zeros((3, 80, 80), np.complex64).any()
    renderer = PupilRenderer(StampSampler(7, 12.15e-6, 9), 40, 0.2 / 38, 568.3e-9, 0.03)
    for buffer in (*renderer._frame_buffers(), *renderer._per_frame(3), *renderer._workspace(2),
                   renderer._local.scratch):
        assert buffer.ctypes.data % render.ALIGNMENT == 0


def test_wide_vectors_only_ask_llvm_for_wider_vectors():
    # column_fft.wide_vectors tags the compiled function that calls it with LLVM's vector-width attributes (512-bit
    # vectors where the CPU has them); the function computes what it computes without the call, bit for bit
    import numba

    from evsda.blocks.optics import column_fft

    def scaled(values, out):
        for i in range(values.size):
            out[i] = values[i] * np.float32(3.0) + values[i] / np.float32(7.0)

    scaled_inline = numba.njit(inline="always")(scaled)

    @numba.njit
    def wide(values, out):
        column_fft.wide_vectors()
        scaled_inline(values, out)

    values = (np.random.default_rng(5).standard_normal(1001) * 1e3).astype(np.float32)
    out, expected = np.empty_like(values), np.empty_like(values)
    wide(values, out)
    scaled(values, expected)
    np.testing.assert_array_equal(out.view(np.uint32), expected.view(np.uint32))
    llvm = next(iter(wide.inspect_llvm().values()))
    assert all(attribute in llvm for attribute in column_fft.WIDE_VECTOR_ATTRIBUTES)
