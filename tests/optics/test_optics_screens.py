"""Phase screens: FFT with subharmonics (structure function, Noll residuals), AR extension, frozen-flow windows."""

import warnings

import numpy as np
import pytest
from scipy.integrate import IntegrationWarning
from scipy.ndimage import map_coordinates, spline_filter

from evsda.blocks.optics.autoregressive import extension_operator, spline_coefficient_covariance
from evsda.blocks.optics.fft_screens import (
    fft_phase_screen_corner,
    fft_phase_screen_corners,
    fft_phase_screens,
    radial_profile,
    structure_function_2d,
)
from evsda.blocks.optics.kolmogorov import (
    kolmogorov_structure_function, phase_psd, structure_function, von_karman_covariance)
from evsda.blocks.optics.layer_screen import PREFILTER_HALF_WIDTH, SELF_START_SAMPLES, LayerScreen, accumulate_layers
from evsda.blocks.optics.screen_kernels import MARGIN
from evsda.blocks.optics import PointSourceOptics
from evsda.blocks.optics.atmosphere import Atmosphere, Layer
from evsda.blocks.optics.imaging import Imager
from evsda.blocks.optics.karhunen_loeve import KarhunenLoeve
from evsda.blocks.optics.modal_screen import ModalScreen
from evsda.blocks.optics.telescope import Telescope
from evsda.blocks.optics.zernike import NOLL_1976_RESIDUALS, zernike_basis
from evsda.blocks.ports import FocalPlane


def test_kolmogorov_constants():
    # D(r) = 6.88 (r/r0)^(5/3) (Fried 1965) and PSD 0.023 r0^(-5/3) f^(-11/3) (Schmidt 2010 Eq. 9.42)
    assert kolmogorov_structure_function(1.0, 1.0) == pytest.approx(6.88, abs=0.005)
    assert phase_psd(1.0, 1.0) == pytest.approx(0.023, abs=0.0002)


def test_von_karman_structure_function_is_the_transform_of_its_psd():
    # D(r) = 2 int (1 - J0(2 pi f r)) PSD(f) 2 pi f df, integrated numerically, against the Bessel-K closed form
    from scipy.integrate import quad
    from scipy.special import j0
    r0, L0 = 0.1, 20.0
    for r in (0.003, 0.05, 0.5, 5.0):
        integrand = lambda f: 2 * (1 - j0(2 * np.pi * f * r)) * phase_psd(f, r0, L0) * 2 * np.pi * f
        edges = [0, 0.1 / r, 1 / r, 10 / r, 100 / r, np.inf]
        with warnings.catch_warnings():                  # the J0 tail oscillates; its share is < 1e-4
            warnings.simplefilter("ignore", IntegrationWarning)
            value = sum(quad(integrand, a, b, limit=500)[0] for a, b in zip(edges[:-1], edges[1:]))
        assert structure_function(r, r0, L0) == pytest.approx(value, rel=2e-3)
    # far below L0 it becomes Kolmogorov's 6.88 (r/r0)^(5/3)
    r = 1e-9 * L0
    assert structure_function(r, r0, L0) / kolmogorov_structure_function(r, r0) == pytest.approx(1.0, abs=2e-3)


def test_fft_screens_follow_kolmogorov_structure_function():
    # Schmidt 2010 Fig. 9.5: averaged D(r) of FFT+subharmonic screens vs 6.88 (r/r0)^(5/3)
    rng = np.random.default_rng(11)
    n, delta, r0 = 128, 0.01, 0.05
    mask = np.zeros((2 * n, 2 * n))
    mask[:n, :n] = 1
    total = np.zeros((2 * n, 2 * n))
    count = 0
    for _ in range(15):
        for screen in fft_phase_screens(rng, n, delta, r0):
            padded = np.zeros((2 * n, 2 * n))
            padded[:n, :n] = screen
            total += structure_function_2d(padded, mask, delta)
            count += 1
    radii = np.array([2, 4, 8, 16, 32]) * delta          # resolved scales: 2 samples to a quarter screen
    measured = radial_profile(total / count, delta, radii)
    np.testing.assert_allclose(measured / kolmogorov_structure_function(radii, r0), 1.0, atol=0.1)


def test_fft_screens_reproduce_noll_residuals():
    # residual variance after removing J Zernike modes over an aperture half the screen (Noll 1976 Table IV),
    # within 3 standard errors of the number of screens (plus 5 % for the known FFT tilt deficit at J <= 2)
    rng = np.random.default_rng(5)
    n, n_pupil = 128, 64
    delta = 1.0 / n_pupil                                 # D = 1 m, r0 = 1 m
    x = (np.arange(n_pupil) - n_pupil / 2 + 0.5) * delta
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= 0.5
    q, _ = np.linalg.qr(zernike_basis(21, xx[inside], yy[inside], 0.5).T)
    residuals = []
    for _ in range(200):
        for screen in fft_phase_screens(rng, n, delta, 1.0):
            row, col = rng.integers(0, n - n_pupil, 2)
            phase = screen[row:row + n_pupil, col:col + n_pupil][inside]
            c2 = np.cumsum((q.T @ phase) ** 2)
            residuals.append((np.sum(phase**2) - c2) / phase.size)
    residuals = np.array(residuals)
    mean, err = residuals.mean(axis=0), residuals.std(axis=0) / np.sqrt(len(residuals))
    for J in (1, 2, 3, 4, 6, 10, 15, 21):
        allowance = 3 * err[J - 1] + (0.05 * NOLL_1976_RESIDUALS[J] if J <= 2 else 0.0)
        assert abs(mean[J - 1] - NOLL_1976_RESIDUALS[J]) < allowance, J


def grid_values(coefficients: np.ndarray) -> np.ndarray:
    """The cubic B-spline's values on the grid, ``(b x b) * c`` with ``b = [1, 4, 1] / 6`` (Unser 1999 Eq. 4); the
    outermost row and column on each side, which need coefficients beyond the array, are left out."""
    c = np.asarray(coefficients)
    rows = (c[..., :-2, :] + 4 * c[..., 1:-1, :] + c[..., 2:, :]) / 6
    return (rows[..., :-2] + 4 * rows[..., 1:-1] + rows[..., 2:]) / 6


def test_spline_coefficient_covariance_gives_von_karman_on_the_grid():
    # the spline through coefficients of covariance C_c takes values of covariance (b*b x b*b) * C_c on the grid,
    # which must be von Karman's B(r) (Assemat et al. 2006 Eq. 5) at every offset
    extent, delta, L0 = 40, 0.02, 25.0
    table = spline_coefficient_covariance(extent, delta, L0)
    full = np.block([[table[::-1, ::-1], table[::-1, 1:]], [table[1:, ::-1], table[1:, 1:]]])   # offsets -40..40
    bb = np.array([1.0, 8.0, 18.0, 8.0, 1.0]) / 36                                               # b * b
    values = sum(bb[i] * bb[j] * full[i:i + 77, j:j + 77] for i in range(5) for j in range(5))[38:, 38:]
    m = np.arange(values.shape[0])
    expected = von_karman_covariance(np.hypot(m[:, None], m[None, :]) * delta, 1.0, L0)
    np.testing.assert_allclose(values, expected, rtol=0, atol=1e-10 * expected[0, 0])
    np.testing.assert_allclose(table, table.T, rtol=1e-12)


@pytest.mark.parametrize("reach, delta, L0", [(105, 0.025, 10.0), (141, 0.0101, 9.709), (33, 0.01, 1.5)])
def test_covariance_quadrant_mirrored_is_the_whole_grids_bit_for_bit(reach, delta, L0):
    # the coefficients' covariance samples von Karman's on one quadrant of offsets and mirrors it: the whole grid's
    # values, each computed where it lies (the arrays' shapes and positions differ)
    from evsda.blocks.optics.autoregressive import _covariance_quadrant

    m = np.arange(-reach, reach + 1)
    whole = von_karman_covariance(np.hypot(m[:, None], m[None, :]) * delta, 1.0, L0)
    mirrored = _covariance_quadrant(reach, delta, L0)[np.abs(m)[:, None], np.abs(m)[None, :]]
    assert whole.tobytes() == mirrored.tobytes()


def test_extension_reproduces_von_karman_statistics_across_the_seam():
    # Assemat et al. 2006: coefficient columns drawn conditionally on an exact (Cholesky) coefficient screen; the
    # spline's values across the seam between old and new columns have von Karman's structure function
    n, k, delta, L0, draws = 14, 4, 0.02, 20.0, 4000
    op = extension_operator(n, k, delta, L0, n)
    yy, xx = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    table = spline_coefficient_covariance(n, delta, L0)
    covariance = table[np.abs(yy.ravel()[:, None] - yy.ravel()[None]), np.abs(xx.ravel()[:, None] - xx.ravel()[None])]
    chol = np.linalg.cholesky(covariance + 1e-10 * table[0, 0] * np.eye(n * n))
    rng = np.random.default_rng(2)
    screens = (chol @ rng.standard_normal((n * n, draws))).T.reshape(-1, n, n)
    blocks = np.stack([op.extend_right(s, rng.standard_normal(n * k)) for s in screens])
    values = grid_values(np.concatenate([screens, blocks], axis=2))    # column j is coefficient column j + 1
    last_old = n - 3                                                    # the last value made of old coefficients only
    for start, gap in ((last_old - 2, 3), (last_old, 1), (last_old, 2), (last_old, 3), (last_old + 1, 2)):
        pairs = np.mean((values[:, :, start + gap] - values[:, :, start]) ** 2, axis=1)
        expected = structure_function(gap * delta, 1.0, L0)
        assert pairs.mean() == pytest.approx(expected, abs=4 * pairs.std() / np.sqrt(draws)), (start, gap)
    variance = np.var(blocks[:, :, -1])
    assert variance == pytest.approx(table[0, 0], rel=0.1)


def _within_standard_errors(per_screen: np.ndarray, expected: np.ndarray, k: float = 3.0) -> None:
    """Mean over screens (axis 0) within ``k`` standard errors of ``expected``."""
    mean = per_screen.mean(axis=0)
    error = per_screen.std(axis=0, ddof=1) / np.sqrt(len(per_screen))
    assert np.all(np.abs(mean - expected) < k * error), (mean / expected, (mean - expected) / error)


def test_fresh_window_joins_its_extension_without_a_seam():
    # a fresh window (conditional draws from exact columns) extended by half its width: pairs straddling the seam
    # between its coefficients and the new ones, along the walk, and pairs across it in the new columns have von
    # Karman's structure function, 1 sample to the footprint (benchmarks/screen_statistics.py: 1500 screens)
    delta, L0, across, screens = 0.02, 25.0, 12, 1000
    n = across + across // 2 + 2 * MARGIN + 2
    lags = np.array([1, 4, across])
    along, transverse = [], []
    for seed in range(screens):
        screen = LayerScreen(n, delta, (seed,), L0=L0)
        screen.cover(np.array([100.0, 100.0]), np.array([100.0, 100.0]) + across)
        first_new = int(screen.origin[1]) + n
        screen.cover(np.array([100.0, 100.0 + n // 2]), np.array([100.0, 100.0 + n // 2]) + across)
        top, left = screen.origin + MARGIN
        grid = screen.sample(np.arange(top, top + n - 2 * MARGIN, dtype=float)[None],
                             np.arange(left, left + n - 2 * MARGIN, dtype=float)[None])[0]
        cols = np.arange(left, left + n - 2 * MARGIN)
        new = cols >= first_new
        straddle = [(cols[:-k] < first_new) & (cols[k:] >= first_new) for k in lags]
        along.append([np.mean((grid[:, k:][:, s] - grid[:, :-k][:, s]) ** 2) for k, s in zip(lags, straddle)])
        transverse.append([np.mean((grid[k:, new] - grid[:-k, new]) ** 2) for k in lags])
    expected = structure_function(lags * delta, 1.0, L0)
    _within_standard_errors(np.array(along), expected)
    _within_standard_errors(np.array(transverse), expected)


def test_walked_screens_keep_von_karman_and_noll_statistics_on_the_pupil():
    # footprints of 12 samples walked 2400 columns, one per frame, read on their integer grids (the spline's values):
    # the structure function along and across the walk, 1 sample to the footprint, and the residual variances after
    # removing J = 1..21 Zernike modes on the pupil against their exact expectation for von Karman phase on the same
    # points, tr(P C P) / N with C = -D/2 (Noll 1976 Table IV is its L0 -> inf limit: within 1 % for J >= 3 here);
    # no drift of the piston-removed variance along the walk
    delta, L0, across, screens, columns = 0.02, 25.0, 12, 24, 2400
    n = across + across // 2 + 2 * MARGIN + 2
    x = np.arange(across + 1.0) - across / 2
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= across / 2
    q, _ = np.linalg.qr(zernike_basis(21, xx[inside], yy[inside], across / 2).T)
    px, py = xx[inside], yy[inside]
    c = -0.5 * structure_function(np.hypot(px[:, None] - px[None], py[:, None] - py[None]) * delta, 1.0, L0)
    noll = (np.trace(c) - np.cumsum(np.einsum("ij,ij->j", q, c @ q))) / len(px)
    scale = (across * delta) ** (5 / 3)
    for J in (3, 6, 10, 21):
        assert noll[J - 1] == pytest.approx(NOLL_1976_RESIDUALS[J] * scale, rel=0.035), J
    lags = np.array([1, 4, across])
    along, transverse, residuals, drift = [], [], [], []
    for seed in range(screens):
        grid = np.arange(across + 1.0)
        left = 100.0 + np.arange(columns)
        out_t = np.zeros((columns, across + 1, across + 1))
        LayerScreen(n, delta, (seed,), L0=L0).accumulate(np.tile(100.0 + grid, (columns, 1)), left[:, None] + grid,
                                                         np.zeros(columns, np.int64), np.ones(columns), out_t)
        v = out_t.transpose(0, 2, 1)[2 * n:]              # past the fresh window
        along.append([np.mean((v[:, :, k:] - v[:, :, :-k]) ** 2) for k in lags])
        transverse.append([np.mean((v[:, k:, :] - v[:, :-k, :]) ** 2) for k in lags])
        phase = v[:, inside]
        r = (np.sum(phase**2, axis=1)[:, None] - np.cumsum((phase @ q) ** 2, axis=1)) / phase.shape[1]
        residuals.append(r.mean(axis=0))
        drift.append(np.polyfit(np.arange(8), [b.mean() for b in np.array_split(r[:, 0], 8)], 1)[0])
    expected = structure_function(lags * delta, 1.0, L0)
    _within_standard_errors(np.array(along), expected)
    _within_standard_errors(np.array(transverse), expected)
    _within_standard_errors(np.array(residuals), noll)
    _within_standard_errors(np.array(drift)[:, None], np.zeros(1))


def test_walked_screen_keeps_von_karman_statistics_up_to_several_footprints():
    # a window 1.5 footprints wide plus margins, walked 1500 columns one conditional column at a time: the
    # structure function along the walk (1 sample to 4 footprints) and across it stays within 8 % of von Karman's
    delta, L0, across, seeds = 0.02, 25.0, 10, 40
    n = across + across // 2 + 2 * MARGIN + 2
    seps = np.array([1, 4, across, 2 * across, 4 * across])
    along, transverse = np.zeros(len(seps)), 0.0
    for seed in range(seeds):
        steps = 1500
        c = 20.0 + np.arange(steps)
        rows, cols = np.tile([20.0, 20.0 + across], (steps, 1)), np.c_[c, c + 1]
        out_t = np.zeros((steps, 2, 2))
        LayerScreen(n, delta, (seed,), L0=L0).accumulate(rows, cols, np.zeros(steps, np.int64), np.ones(steps), out_t)
        out = out_t.transpose(0, 2, 1)
        v = out[100:, 0, 0]
        along += [np.mean((v[k:] - v[:-k]) ** 2) for k in seps]
        transverse += np.mean((out[100:, 0, 0] - out[100:, 1, 0]) ** 2)
    np.testing.assert_allclose(along / seeds / structure_function(seps * delta, 1.0, L0), 1.0, atol=0.08)
    assert transverse / seeds == pytest.approx(structure_function(across * delta, 1.0, L0), rel=0.08)


def test_spline_sampling_matches_scipy_map_coordinates():
    # the compiled 4-tap sampler on a screen's B-spline coefficients against scipy's B-spline interpolation
    screen = LayerScreen(96, 0.01, (1,), L0=25.0)
    screen.cover(np.array([40.0, 40.0]), np.array([50.0, 50.0]))
    rng = np.random.default_rng(0)
    rows = screen.origin[0] + 30 + rng.uniform(0, 5, (4, 1)) + 0.9 * np.arange(20)[None]
    cols = screen.origin[1] + 30 + rng.uniform(0, 5, (4, 1)) + 0.95 * np.arange(18)[None]
    sampled = screen.sample(rows, cols)
    for f in range(4):
        r, c = np.meshgrid(rows[f] - screen.origin[0], cols[f] - screen.origin[1], indexing="ij")
        coefficients = screen.spline_coefficients()
        np.testing.assert_allclose(sampled[f], map_coordinates(coefficients, [r, c], order=3, prefilter=False),
                                   rtol=0, atol=1e-12 * np.abs(coefficients).max())


def test_regenerated_screen_interpolates_its_fft_screen():
    # a regeneration makes the B-spline coefficients of an FFT screen in the Fourier domain (Unser 1999 Eq. 10's
    # inverse filter, exactly): the spline through them (Unser 1999 Eq. 4) takes the values of the FFT screen made
    # the usual way (fft_phase_screens, Schmidt 2010 Listing 9.3) on the grid to rounding, for both halves of the
    # draw (the twin's); such wide windows keep the one outer scale L0 (no large-scale modes)
    n = SELF_START_SAMPLES + 2                           # wider windows (the reference path's) are cut from FFT screens
    screen = LayerScreen(n, 0.02, (5,), L0=25.0, keep_twin=True)
    assert screen.L1 == 25.0 and LayerScreen(SELF_START_SAMPLES, 0.02, (5,), L0=25.0).L1 < 25.0
    screen.cover(np.array([10.0, 10.0]), np.array([20.0, 20.0]))
    twin = screen.twin((6,))
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([5, 0, 0])))
    for coefficients, values in zip((screen.coefficients, twin.coefficients), fft_phase_screens(rng, 2 * n, 0.02,
                                                                                                 1.0, 25.0)):
        window = values[PREFILTER_HALF_WIDTH:PREFILTER_HALF_WIDTH + n, PREFILTER_HALF_WIDTH:PREFILTER_HALF_WIDTH + n]
        np.testing.assert_allclose(grid_values(coefficients), window[1:-1, 1:-1], rtol=0,
                                   atol=1e-12 * np.abs(values).max())
        assert np.abs(grid_values(coefficients) - window[1:-1, 1:-1]).max() > 0      # not a copy of the values
        assert np.abs(coefficients - window).max() > 0.01 * np.abs(values).max()    # coefficients, not samples


def test_batched_walk_reads_what_frame_by_frame_covers_read():
    # accumulate (one planned walk, canvases, compiled reads) against cover + sample one frame at a time,
    # on a walk that extends on every side, turns back and regenerates when it jumps far
    path = np.r_[np.c_[np.zeros(40), 2.3 * np.arange(40)], np.c_[1.7 * np.arange(30), np.full(30, 90.0)],
                 np.c_[np.full(30, 50.0), 90.0 - 3.1 * np.arange(30)], [[400.0, 400.0], [401.0, 398.0]]]
    grid = 0.8 * np.arange(12)
    rows, cols = path[:, :1] + grid, path[:, 1:] + grid
    epochs = np.zeros(len(path), dtype=np.int64)
    batched = LayerScreen(40, 0.02, (4,), L0=25.0)
    out_t = np.zeros((len(path), 12, 12))
    batched.accumulate(rows, cols, epochs, np.full(len(path), 2.0), out_t)
    out = out_t.transpose(0, 2, 1)
    single = LayerScreen(40, 0.02, (4,), L0=25.0)
    for f in range(len(path)):
        single.cover(np.array([rows[f, 0], cols[f, 0]]), np.array([rows[f, -1], cols[f, -1]]))
        np.testing.assert_allclose(out[f], 2.0 * single.sample(rows[f:f + 1], cols[f:f + 1])[0], rtol=0, atol=1e-12)
    assert single.n_regenerations == batched.n_regenerations == 1
    np.testing.assert_array_equal(single.coefficients, batched.coefficients)



def test_walks_draw_numpys_normals_inside_the_compiled_walk(monkeypatch):
    # the conditional columns' noise drawn in the compiled walk from the screen's PCG64 words against NumPy's own
    # draws (the path where the compiled draws are not NumPy's): the same screens, reads and generator states
    from evsda.blocks.optics import layer_screen

    def walk():
        screens = [LayerScreen(20, 0.025, (7, 0), L0=25.0), LayerScreen(38, 0.0101, (7, 1), L0=25.0)]
        frames, grid = 40, np.linspace(0.0, 7.0, 16)
        path = np.array([[0.6, 0.9], [-0.7, 0.3]])[:, None] * np.arange(frames)[None, :, None]
        rows, cols = path[..., :1] + grid, path[..., 1:] + grid
        out = np.zeros((frames, len(grid), len(grid)))
        for epoch in (0, 0, 1):
            accumulate_layers(screens, rows + 30 * epoch, cols, np.full(frames, epoch, np.int64),
                              np.ones((2, frames)), out)
        return out, [(s.coefficients.tobytes(), s.state()["rng"]) for s in screens]

    compiled = walk()
    monkeypatch.setattr(layer_screen, "same_as_numpy", lambda: False)     # also NumPy's seeding (regenerations, modes)
    numpys = walk()
    assert compiled[0].tobytes() == numpys[0].tobytes() and compiled[1] == numpys[1]


def test_a_twins_generator_is_seeded_as_numpy_seeds_it(monkeypatch):
    from evsda.blocks.optics import layer_screen

    def twin():
        screen = LayerScreen(SELF_START_SAMPLES + 8, 0.02, (4, 1), L0=20.0, keep_twin=True)
        screen.regenerate(np.array([0.0, 0.0]), 3)
        return screen.twin((6,)).state()["rng"]

    compiled = twin()
    monkeypatch.setattr(layer_screen, "same_as_numpy", lambda: False)
    assert compiled == twin()


def test_a_fresh_walk_writes_what_adding_to_zeros_gives():
    # accumulate_layers(fresh=True) into an array full of garbage against the same walk added to zeros, bit for bit
    # (a frame of zero weight included: 0 + 0 x keeps the sign of the zero), with a regeneration mid-walk
    def walk(out, fresh):
        screens = [LayerScreen(20, 0.025, (5, 0), L0=25.0), LayerScreen(20, 0.03, (5, 1), L0=25.0)]
        frames, grid = 30, np.linspace(0.0, 6.0, 12)
        path = np.array([[0.4, 0.8], [0.3, -0.6]])[:, None] * np.arange(frames)[None, :, None]
        path[1, frames // 2:] += 400.0
        weight = np.ones((2, frames))
        weight[:, 3] = 0.0
        accumulate_layers(screens, path[..., :1] + grid, path[..., 1:] + grid, np.zeros(frames, np.int64), weight,
                          out, fresh=fresh)
        return out

    added = walk(np.zeros((30, 12, 12)), False)
    written = walk(np.full((30, 12, 12), np.nan), True)
    assert written.tobytes() == added.tobytes()


def test_layer_grids_are_the_footprints_and_weights_in_numpy():
    # the compiled footprint grids and weights against Imager.footprints_of's broadcast sums and the weights' numpy
    # expression, bit for bit (a source at infinity, a near one, a frame below the horizon)
    from evsda.blocks.optics.screen_kernels import layer_grids

    layers = [Layer(105.3, 2e-13, 5.7, 0.3), Layer(4403.8, 5e-14, 15.2, 2.1), Layer(16299.3, 1e-14, 8.8, -1.0)]
    frames, rng = 9, np.random.default_rng(4)
    t_s, sight = 0.5 + 0.002 * np.arange(frames), rng.normal(0.0, 1e-3, (frames, 2))
    zenith_rad = rng.uniform(0.1, 1.2, frames)
    zenith_rad[3] = np.nan
    range_m = np.where(np.arange(frames) < 5, np.inf, rng.uniform(4e5, 2e6, frames))
    xp, delta, k2 = (np.arange(40) - 20) * (0.1 / 19), np.array([0.025, 0.0101, 0.03]), (2 * np.pi / 6e-7) ** 2
    turbulent = np.isfinite(zenith_rad)
    zenith = np.where(turbulent, zenith_rad, 0.0)
    centre, scale = Imager.footprints_of(layers, t_s, sight, zenith, range_m)
    cn2 = np.array([layer.cn2_dh for layer in layers])
    expected_weight = np.where(turbulent, np.sqrt((0.423 * k2 / np.cos(zenith))[None] * cn2[:, None]), 0.0)
    rows, cols = np.empty((2, len(layers), frames, len(xp)))
    weight = np.empty((len(layers), frames))
    layer_grids(np.array([layer.altitude_m for layer in layers]), np.array([layer.wind_m_s for layer in layers]),
                cn2, delta, t_s, sight, np.cos(zenith), range_m, turbulent, xp, k2, rows, cols, weight)
    assert rows.tobytes() == ((centre[..., 1:] + scale[..., None] * xp) / delta[:, None, None]).tobytes()
    assert cols.tobytes() == ((centre[..., :1] + scale[..., None] * xp) / delta[:, None, None]).tobytes()
    assert weight.tobytes() == expected_weight.tobytes() and weight[0, 3] == 0.0


def test_layers_walked_together_read_what_each_walked_in_turn_reads():
    # accumulate_layers (one plan, one compiled walk for all layers) against each layer's own accumulate in turn into
    # the same output, bit for bit, over three calls: screens of two sizes, one regenerate-only, one without
    # large-scale modes (a window cut from an FFT screen), a fresh start, extensions on every side, a jump far away
    # (regenerated mid-walk) and a new revisit epoch
    def make():
        return [LayerScreen(20, 0.025, (1, 0), L0=25.0), LayerScreen(38, 0.0101, (1, 1), L0=25.0),
                LayerScreen(20, 0.025, (1, 2), L0=25.0, update="regenerate"),
                LayerScreen(SELF_START_SAMPLES + 4, 0.02, (1, 3), L0=25.0), LayerScreen(20, 0.03, (1, 4), L0=25.0)]
    frames, grid = 60, np.linspace(0.0, 7.0, 16)
    steps = np.array([[0.3, 0.7], [0.5, 0.0], [0.0, 0.6], [-0.4, 0.2], [0.2, -0.5]])
    together, alone = make(), make()
    start = np.zeros((len(steps), 2))
    for call in range(3):
        path = start[:, None] + steps[:, None] * np.arange(frames)[None, :, None]          # (L, F, 2)
        if call == 1:
            path[0, frames // 2:] += 500.0                                                 # jumps far: regenerates
        rows, cols = path[..., :1] + grid, path[..., 1:] + grid
        epochs = np.full(frames, 3 if call == 2 else 0, np.int64)
        weight = 1.0 + np.arange(len(steps))[:, None] * np.ones(frames)
        out_together, out_alone = np.zeros((2, frames, len(grid), len(grid)))
        accumulate_layers(together, rows, cols, epochs, weight, out_together)
        for i, screen in enumerate(alone):
            screen.accumulate(rows[i], cols[i], epochs, weight[i], out_alone)
        assert out_together.tobytes() == out_alone.tobytes()
        for a, b in zip(together, alone):
            assert a.coefficients.tobytes() == b.coefficients.tobytes() and np.array_equal(a.origin, b.origin)
            assert a.state()["rng"] == b.state()["rng"] and a.n_regenerations == b.n_regenerations
        assert together[0].n_regenerations == (1 if call == 1 else 0) and np.all(out_together != 0)
        start = path[:, -1]


def test_lines_of_sight_walked_together_read_what_each_walked_alone_reads():
    # accumulate_layers with an output per line of sight (a window's sources in one walk: Imager.render_many) against
    # each source's layers walked alone into its own output, bit for bit, fresh outputs (written, not added to,
    # whatever they held) over two calls: layers of two sizes, one source jumping far (regenerated mid-walk)
    def make(source):
        return [LayerScreen(20, 0.025, (2, source, 0), L0=25.0), LayerScreen(38, 0.0101, (2, source, 1), L0=25.0),
                LayerScreen(20, 0.03, (2, source, 2), L0=25.0)]
    sources, frames, grid = 3, 40, np.linspace(0.0, 7.0, 16)
    steps = np.array([[[0.3, 0.7], [0.5, 0.0], [0.0, 0.6]], [[-0.4, 0.2], [0.2, -0.5], [0.1, 0.1]],
                      [[0.6, -0.3], [-0.2, -0.2], [0.4, 0.0]]])                            # (S, L, 2)
    together = [screen for source in range(sources) for screen in make(source)]
    alone = [make(source) for source in range(sources)]
    start = np.zeros(steps.shape)
    for call in range(2):
        path = start[..., None, :] + steps[..., None, :] * np.arange(frames)[:, None]    # (S, L, F, 2)
        if call == 1:
            path[1, 0, frames // 2:] += 500.0                                              # jumps far: regenerates
        rows, cols = path[..., :1] + grid, path[..., 1:] + grid                            # (S, L, F, n)
        epochs = np.zeros(frames, np.int64)
        weight = 1.0 + np.arange(sources * 3).reshape(sources, 3, 1) * np.ones(frames)
        out_together = np.full((sources, frames, len(grid), len(grid)), np.nan)
        accumulate_layers(together, rows.reshape(-1, frames, len(grid)), cols.reshape(-1, frames, len(grid)), epochs,
                          weight.reshape(-1, frames), out_together, fresh=True,
                          outputs=np.repeat(np.arange(sources, dtype=np.int64), 3))
        for k in range(sources):
            out_alone = np.full((frames, len(grid), len(grid)), np.nan)
            accumulate_layers(alone[k], rows[k], cols[k], epochs, weight[k], out_alone, fresh=True)
            assert out_together[k].tobytes() == out_alone.tobytes()
            for a, b in zip(together[3 * k:3 * k + 3], alone[k]):
                assert a.coefficients.tobytes() == b.coefficients.tobytes() and np.array_equal(a.origin, b.origin)
                assert a.state()["rng"] == b.state()["rng"] and a.n_regenerations == b.n_regenerations
        assert together[3].n_regenerations == (1 if call == 1 else 0) and np.all(np.isfinite(out_together))
        start = path[..., -1, :]


@pytest.mark.parametrize("n, delta", [(20, 0.025), (38, 0.0101), (7, 0.05), (64, 0.02), (128, 0.01)])
def test_a_fresh_window_in_one_call_is_its_stages_one_by_one(n, delta):
    # LayerScreen._fresh grows its canvas through every stage's operator in one compiled call (extend_in_stages); the
    # reference: extend_columns called once a stage, with that stage's operator, bit for bit
    from evsda.blocks.optics.autoregressive import FULL_COLUMNS, first_columns
    from evsda.blocks.optics.layer_screen import BURN_IN, _fresh_stages
    from evsda.blocks.optics.screen_kernels import extend_columns
    screen = LayerScreen(n, delta, (3, n), L0=25.0)
    width = n + BURN_IN * n
    noise = np.random.default_rng(n).standard_normal(n * width)
    canvas = np.empty((n, width))
    canvas[:, :FULL_COLUMNS] = (first_columns(n, delta, screen.L1)
                                @ noise[:FULL_COLUMNS * n]).reshape(FULL_COLUMNS, n).T
    for made, tops, lefts, sides in _fresh_stages(n, width):
        operator = extension_operator(n, 1, delta, screen.L1, min(made, n))
        extend_columns(canvas, tops, lefts, sides, operator.A, operator.B, operator.stencil_rows,
                       operator.stencil_cols, noise[n * made:n * (made + len(tops))], n)
    assert screen._fresh(noise).tobytes() == np.ascontiguousarray(canvas[:, width - n:]).tobytes()


def test_modes_pool_holds_each_screens_tables_as_packing_per_walk_does(monkeypatch):
    # the walks' ModesPool (each screen's large-scale modes packed once, rows handed out) against _packed (the
    # reference: a walk's modes concatenated afresh), bit for bit, across the pool's growth; then walks with a pool
    # started afresh at every walk against the default one, over three calls
    from evsda.blocks.optics import layer_screen
    screens = [LayerScreen(20, 0.025, (4, i), L0=25.0) for i in range(6)] + [LayerScreen(38, 0.0101, (4, 9), L0=25.0)]
    for screen in screens:
        screen.epoch = 0
    modes = [screen._large_scales() for screen in screens]
    pool = layer_screen.ModesPool()
    rows = [pool.row(m) for m in modes[3:] + modes]                # some twice, in another order: packed once
    (low, amplitudes, frequencies), at = layer_screen._packed(tuple(modes),
                                                              lambda m: (m.low, m.amplitudes, m.frequencies))
    assert pool.tables[0].size > 1 << 12 and rows[:4] == rows[-4:]                       # grown; the same rows
    for m, row, packed in zip(modes, rows[4:], at):
        for kind, (table, reference, size) in enumerate(zip(pool.tables, (low, amplitudes, frequencies),
                                                            (m.low.size, m.amplitudes.size, m.frequencies.size))):
            assert table[row[kind]:row[kind] + size].tobytes() == reference[packed[kind]:packed[kind] + size].tobytes()

    def walked(limit):
        monkeypatch.setattr(layer_screen._threads, "modes", layer_screen.ModesPool(limit), raising=False)
        walkers, out = [LayerScreen(20, 0.025, (5, i), L0=25.0) for i in range(3)], []
        for call in range(3):
            path = 0.4 * call * 40 + np.array([0.4, 0.3]) * np.arange(40)[:, None]
            rows, cols = path[:, :1] + np.linspace(0.0, 7.0, 16), path[:, 1:] + np.linspace(0.0, 7.0, 16)
            phase = np.zeros((40, 16, 16))
            accumulate_layers(walkers, np.stack([rows + 5 * i for i in range(3)]), np.stack([cols] * 3),
                              np.zeros(40, np.int64), np.ones((3, 40)), phase)
            out.append(phase)
        return np.array(out)

    assert walked(-1).tobytes() == walked(1 << 21).tobytes()


def _walk(screen, boxes, chunks):
    """Sample a sequence of footprints, cutting it into the given chunk sizes (as windows would)."""
    out, start = [], 0
    for size in chunks:
        for low, high in boxes[start:start + size]:
            screen.cover(low, high)
            out.append(screen.sample(np.array([[low[0] + 2.5]]), np.array([[low[1] + 1.5]]))[0, 0, 0])
        start += size
    return np.array(out)


@pytest.mark.parametrize("update", ["extend", "regenerate"])
def test_screen_values_do_not_depend_on_how_the_walk_is_cut(update):
    boxes = [(np.array([5.0 + 0.3 * i, 5.0 - 0.7 * i]), np.array([15.0 + 0.3 * i, 15.0 - 0.7 * i])) for i in range(120)]
    a = _walk(LayerScreen(40, 0.02, (7, 1), update=update), boxes, [120])
    b = _walk(LayerScreen(40, 0.02, (7, 1), update=update), boxes, [7, 50, 13, 50])
    np.testing.assert_array_equal(a, b)
    c = _walk(LayerScreen(40, 0.02, (7, 2), update=update), boxes, [120])
    assert not np.allclose(a, c)                          # another seed, another screen


def test_screen_state_round_trip_continues_identically():
    boxes = [(np.array([5.0, 5.0 + 2 * i]), np.array([15.0, 15.0 + 2 * i])) for i in range(80)]
    whole = _walk(LayerScreen(40, 0.02, (3,)), boxes, [80])
    first = LayerScreen(40, 0.02, (3,))
    head = _walk(first, boxes[:30], [30])
    resumed = LayerScreen(40, 0.02, (3,))
    resumed.set_state(first.state())
    tail = _walk(resumed, boxes[30:], [50])
    np.testing.assert_array_equal(whole, np.r_[head, tail])


def _noll_tail(n_modes: int) -> float:
    """Delta_J beyond the last mode of a screen of modes 2..n_modes+1: Noll 1976's asymptotic 0.2944 J^(-sqrt(3)/2)."""
    return 0.2944 * (n_modes + 1) ** (-np.sqrt(3) / 2)


def test_zernike_screens_reproduce_noll_residuals_on_the_pupil():
    # the modal screens the optics block renders, measured on its pupil: residual variance after removing J modes
    # is Noll 1976 Table IV's Delta_J less the modes the screen does not carry (issue 11.6: a disk 4 pupils wide
    # gave 0.34 / 0.05 / 0.007 of Delta_J at J = 3 / 6 / 10)
    n_modes, frames = 65, 400
    atmosphere = Atmosphere((Layer(2000.0, 1.0, 5.0, 0.0),)).scaled_to_r0(0.1)
    params = PointSourceOptics.Params(psf_path="pupil_fft", screen_method="zernike", screen_update="regenerate",
                                      n_zernike_modes=n_modes)
    imager = Imager(Telescope(0.3), FocalPlane(640, 480, 4.86e-6, 1.2), 550e-9, atmosphere, params, seed=(3,))
    zenith = np.deg2rad(30)
    g = imager.ensure_geometry(zenith)
    t = 1.0 * np.arange(frames)                           # the wind carries each footprint 17 D from the last
    sight = imager.sight(np.full(frames, 320.0), np.full(frames, 240.0), np.full(frames, zenith))
    phase = imager.pupil.turbulent_phase("s", t, sight, np.full(frames, zenith), np.full(frames, np.inf))
    x = (np.arange(g.n_pupil) - g.n_pupil // 2) * g.delta_m
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= 0.15
    q, _ = np.linalg.qr(zernike_basis(21, xx[inside], yy[inside], 0.15).T)
    values = phase[:, inside]
    residuals = (np.sum(values**2, axis=1)[:, None] - np.cumsum((values @ q) ** 2, axis=1)) / inside.sum()
    scale = (0.3 / imager.r0(zenith)) ** (5 / 3)
    mean, err = residuals.mean(axis=0) / scale, residuals.std(axis=0) / scale / np.sqrt(frames)
    for J in (1, 3, 6, 10, 21):
        expected = NOLL_1976_RESIDUALS[J] - _noll_tail(n_modes)
        assert abs(mean[J - 1] - expected) < 4 * err[J - 1] + 0.01 * expected, J


def test_modal_screen_tilt_decorrelates_like_frozen_flow():
    # tip/tilt correlation against the shift of the footprint, modal lattice vs frozen-flow FFT screens (L0 = 25 m)
    rng = np.random.default_rng(2)
    n, nd, aperture = 256, 32, 0.2
    delta = aperture / nd
    x = (np.arange(nd) - nd / 2 + 0.5) * delta
    xx, yy = np.meshgrid(x, x)
    inside = np.hypot(xx, yy) <= aperture / 2
    fit = np.linalg.pinv(zernike_basis(2, xx[inside], yy[inside], aperture / 2, first=2).T)
    shifts = (8, 16)                                      # D/4, D/2
    products, power = np.zeros(len(shifts)), 0.0
    for _ in range(30):
        for screen in fft_phase_screens(rng, n, delta, 0.1, 25.0):
            for row in range(0, n - nd, 32):
                a0 = fit @ screen[row:row + nd, :nd][inside]
                power += a0 @ a0
                products += [a0 @ (fit @ screen[row:row + nd, s:s + nd][inside]) for s in shifts]
    frozen = products / power
    screen = ModalScreen((5,), aperture, 5)
    start = np.c_[rng.uniform(-50, 50, 3000), rng.uniform(-50, 50, 3000)]
    a0 = screen.coefficients(start, np.zeros(3000))[:, :2]
    for shift, expected in zip(shifts, frozen):
        a1 = screen.coefficients(start + [shift * delta, 0.0], np.zeros(3000))[:, :2]
        assert np.sum(a0 * a1) / np.sum(a0 * a0) == pytest.approx(expected, abs=0.08), shift


def test_modal_screens_change_continuously_and_keep_their_variance():
    screen = ModalScreen((1,), 0.3, 20)
    path = np.c_[np.linspace(0.0, 3.0, 3001), np.zeros(3001)]          # 10 lattice cells, 1 mm steps
    a = screen.coefficients(path, np.zeros(3001))
    assert np.abs(np.diff(a, axis=0)).max() < 0.05 * np.abs(a).max()   # no jumps at the lattice nodes
    many = screen.coefficients(np.random.default_rng(0).uniform(-100, 100, (4000, 2)), np.zeros(4000))
    variance = np.diag(KarhunenLoeve.of(20).vectors @ np.diag(KarhunenLoeve.of(20).variances)
                       @ KarhunenLoeve.of(20).vectors.T)
    np.testing.assert_allclose(many.var(axis=0) / variance, 1.0, atol=0.12)
    other = screen.coefficients(path[:5], np.ones(5))                   # another revisit epoch, another draw
    assert not np.allclose(other, a[:5])


@pytest.mark.parametrize("n, m", [(256, 160), (301, 200), (526, 295), (602, 333), (1052, 558)])
def test_fft_screen_corner_is_the_full_screens_corner_bit_for_bit(n, m):
    """fft_phase_screen_corner (the reference probes' screens) against the full computation: the first screen
    of fft_phase_screens cut to m x m, the same numbers and the generator left in the same state (odd sizes and
    sizes with large prime factors, 263 and 43, take pocketfft's other algorithms)."""
    full_rng, corner_rng = np.random.default_rng(n), np.random.default_rng(n)
    full, _ = fft_phase_screens(full_rng, n, 0.013, 0.1, 25.0)
    corner = fft_phase_screen_corner(corner_rng, n, m, 0.013, 0.1, 25.0)
    assert np.array_equal(corner, full[:m, :m])
    assert full_rng.bit_generator.state == corner_rng.bit_generator.state


@pytest.mark.parametrize("n, r0, L0", [(160, 0.05, 25.0), (160, 0.11, np.inf), (301, 0.1, 30.0)])
def test_fft_screen_corners_are_both_full_screens_corners_bit_for_bit(n, r0, L0):
    """fft_phase_screen_corners (the analytic-path probes' pupil screens) against fft_phase_screens: both halves cut
    to n/2 x n/2, the same numbers."""
    for seed in range(3):
        full = fft_phase_screens(np.random.default_rng(seed), n, 0.005, r0, L0)
        corners = fft_phase_screen_corners(np.random.default_rng(seed), n, n // 2, 0.005, r0, L0)
        assert np.array_equal(corners.real, full[0][:n // 2, :n // 2])
        assert np.array_equal(corners.imag, full[1][:n // 2, :n // 2])


def test_fft_screen_halves_are_independent_von_karman_screens():
    """The reference probes take two frames from each complex FFT draw (fft_phase_screen_corners, as cut for
    their screens: an n x n draw, its m x m corner): the real and imaginary parts are independent screens of
    the same statistics (Lane, Glindemann & Dainty 1992; Johansson & Gavel 1994). Each half's structure
    function against von Karman's (Schmidt 2010 Listing 3.7's estimator, as for the FFT screens above), the
    correlation of the halves' increments over 1 and 8 samples against 0 (the values' own correlation is
    dominated by a few large-scale modes per draw), and the structure function of their normalised sum,
    which independence leaves von Karman's (a correlation rho would scale it by 1 + rho)."""
    rng = np.random.default_rng(3)
    n, m, delta, r0, L0 = 256, 160, 0.01, 0.05, 25.0       # the probes' cut: twice the window, window + 32
    mask = np.zeros((2 * m, 2 * m))
    mask[:m, :m] = 1
    sums = {"real": 0.0, "imag": 0.0, "sum": 0.0}
    correlations = {1: [], 8: []}
    draws = 20
    for _ in range(draws):
        corner = fft_phase_screen_corners(rng, n, m, delta, r0, L0)
        halves = {"real": corner.real, "imag": corner.imag, "sum": (corner.real + corner.imag) / np.sqrt(2)}
        for name, screen in halves.items():
            padded = np.zeros((2 * m, 2 * m))
            padded[:m, :m] = screen
            sums[name] = sums[name] + structure_function_2d(padded, mask, delta)
        for lag, found in correlations.items():
            a, b = (np.diff(half[:, ::lag], axis=1) for half in (corner.real, corner.imag))
            found.append(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))
    radii = np.array([2, 4, 8, 16, 32, 64]) * delta         # resolved scales: 2 samples to 0.4 of the corner
    expected = structure_function(radii, r0, L0)
    for name, total in sums.items():
        measured = radial_profile(total / draws, delta, radii)
        np.testing.assert_allclose(measured / expected, 1.0, atol=0.12, err_msg=name)
    for lag, found in correlations.items():
        found = np.array(found)
        assert abs(found.mean()) < min(0.1, 3 * found.std(ddof=1) / np.sqrt(draws)), lag
    # the real half is fft_phase_screen_corner's screen, bit for bit, from the same draws
    np.testing.assert_array_equal(fft_phase_screen_corners(np.random.default_rng(4), n, m, delta, r0, L0).real,
                                  fft_phase_screen_corner(np.random.default_rng(4), n, m, delta, r0, L0))


def test_a_walk_that_draws_no_column_makes_no_extension_operator(monkeypatch):
    # the operator of a window as wide as the reference path's (278 samples) takes seconds to make: a footprint
    # inside the fresh window (every reference probe's) must not make it; one that runs off it does
    from evsda.blocks.optics import layer_screen
    made = []
    real = layer_screen.extension_operator
    monkeypatch.setattr(layer_screen, "extension_operator", lambda *a: made.append(a) or real(*a))
    screen = LayerScreen(SELF_START_SAMPLES + 2, 0.02, (5,), L0=25.0)
    screen.cover(np.array([10.0, 10.0]), np.array([20.0, 20.0]))
    screen.cover(np.array([12.0, 12.0]), np.array([30.0, 30.0]))
    assert not made
    small = LayerScreen(24, 0.02, (5,), L0=25.0)
    small.cover(np.array([0.0, 0.0]), np.array([4.0, 4.0]))           # a fresh window (its own draws' operators)
    fresh = len(made)
    small.cover(np.array([0.0, 20.0]), np.array([4.0, 24.0]))          # runs off the window: columns drawn
    assert made[fresh:] == [(24, 1, 0.02, small.L1, 24)]


@pytest.mark.parametrize("n, delta, L0", [(556, 0.0123, 20.0), (556, 0.00731, np.inf), (160, 0.005, 25.0),
                                          (557, 0.01, 30.0)])
def test_fft_spectra_from_a_quarter_are_the_full_grids(n, delta, L0):
    """The amplitudes computed on the frequencies 0..n/2 and mirrored equal Schmidt 2010 Listing 9.2's on the whole
    grid (``sqrt(PSD(|f|)) df``, the B-spline's inverse response along each axis), bit for bit."""
    from scipy import fft as sfft

    from evsda.blocks.optics.fft_screens import _spectra, spline_response

    fx = sfft.fftfreq(n, delta)
    psd = phase_psd(np.hypot(fx[:, None], fx[None, :]), 0.1, L0)
    psd[0, 0] = 0.0
    full = np.sqrt(psd) * (1.0 / (n * delta) * n * n)
    assert np.array_equal(_spectra.__wrapped__(n, delta, 0.1, L0, False)[0], full)
    inverse = 1.0 / spline_response(fx, delta)
    full *= inverse[:, None] * inverse[None, :]
    assert np.array_equal(_spectra.__wrapped__(n, delta, 0.1, L0, True, True)[0], full)


def test_fft_spectra_computed_in_full_where_a_kernel_rounds_by_position(monkeypatch):
    """Where the PSD's kernel gave position-dependent numbers (simulated), the mirror check fails and the amplitudes
    are the full grid's."""
    from scipy import fft as sfft

    from evsda.blocks.optics import fft_screens

    def by_position(f, r0, L0=np.inf):
        f = np.asarray(f, dtype=float)
        return phase_psd(f, r0, L0) * (1.0 + 1e-15 * np.arange(f.size).reshape(f.shape))

    monkeypatch.setattr(fft_screens, "phase_psd", by_position)
    n, delta = 64, 0.01
    fx = sfft.fftfreq(n, delta)
    psd = by_position(np.hypot(fx[:, None], fx[None, :]), 0.1, 20.0)
    psd[0, 0] = 0.0
    full = np.sqrt(psd) * (1.0 / (n * delta) * n * n)
    assert np.array_equal(fft_screens._amplitudes(n, delta, 0.1, 20.0, False), full)


def test_spline_corners_sum_their_subharmonics_into_contiguous_rows_bit_for_bit():
    # fft_spline_corners adds the screen's transform and its subharmonics into the subharmonics' contiguous rows: the
    # numbers of the sum written into the transform's strided cut, as before (a sum is the same either way round)
    from scipy import fft as sfft

    from evsda.blocks.optics import fft_screens
    n, m, first, delta, r0, L0 = 132, 64, 4, 0.02, 0.1, 25.0
    got = fft_screens.fft_spline_corners(np.random.default_rng(8), n, m, first, delta, r0, L0)
    rng = np.random.default_rng(8)
    amplitude, low = fft_screens._spectra(n, delta, r0, L0, True, True)
    columns = sfft.ifft(fft_screens._coefficients(rng, amplitude), axis=0, norm="forward", workers=1)[first:first + m]
    columns.view(np.float64)[...] *= np.float64(np.longdouble(1) / np.longdouble(n * n))
    expected = sfft.ifft(columns, axis=1, norm="forward", workers=1)[:, first:first + m]
    powers, ey, ex, ey_mean, ex_mean, gains = low
    expected += fft_screens._subharmonics(rng, powers, ey[first:first + m], ex[:, first:first + m], ey_mean, ex_mean,
                                          gains=gains)
    assert got.flags.c_contiguous
    assert np.array_equal(got.view(np.uint64), expected.view(np.uint64))


def test_a_layers_plan_is_the_same_planned_alone_or_after_others():
    # plan_layers plans each layer into arrays made once for all layers and grown where a plan needs more operations
    # than they hold (here the fourth, after three slower ones have grown the packed outputs past them): every layer's
    # operations, frame counts and runs are those of planning it alone
    from evsda.blocks.optics.screen_kernels import plan_layers
    frames, grid = 30, np.linspace(3.0, 11.0, 40)
    rows = np.array([[grid + 0.01 * f for f in range(frames)]] * 5)
    cols = np.array([[grid + speed * f for f in range(frames)] for speed in (3.0, 3.0, 3.0, 6.0, 0.5)])
    layers = len(rows)
    common = (np.zeros(frames, np.int64), np.full(layers, 20), MARGIN, np.zeros(layers, bool),
              np.zeros((layers, 2), np.int64), np.zeros(layers, np.int64), np.ones(layers, bool), 2048)
    failed, sides, before, centre, op_epoch, op_at, frame_ops, edges, segments = plan_layers(rows, cols, *common)
    assert failed == -1 and op_at[-1] > 4 * frames + 16
    for layer in range(layers):
        alone = plan_layers(rows[layer:layer + 1], cols[layer:layer + 1],
                            *(c[layer:layer + 1] if isinstance(c, np.ndarray) and c.shape[:1] == (layers,) else c
                              for c in common))
        ops = slice(op_at[layer], op_at[layer + 1])
        for together, single in zip((sides[ops], before[ops], centre[ops], op_epoch[ops], frame_ops[layer]),
                                    (alone[1], alone[2], alone[3], alone[4], alone[6][0])):
            np.testing.assert_array_equal(together, single)
        (_, e0, e1, as_is, renew), = segments[segments[:, 0] == layer]
        np.testing.assert_array_equal(edges[e0:e1], alone[7][alone[8][0, 1]:alone[8][0, 2]])
