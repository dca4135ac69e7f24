"""Large scales of walked screens: the modes added to the conditional draws (blocks/optics/large_scales.py)."""

import numpy as np
import pytest

from evsda.blocks.optics.kolmogorov import structure_function, von_karman_covariance
from evsda.blocks.optics.large_scales import SECTORS, STRIDE, LargeScales, cells, split_outer_scale
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.optics.normal_draws import SeededDraws, entropy_words

DELTA, L0 = 0.02, 25.0


def grid_values(coefficients: np.ndarray) -> np.ndarray:
    """The cubic B-spline's values on the grid, ``(b x b) * c`` with ``b = [1, 4, 1] / 6`` (Unser 1999 Eq. 4)."""
    rows = (coefficients[:-2] + 4 * coefficients[1:-1] + coefficients[2:]) / 6
    return (rows[:, :-2] + 4 * rows[:, 1:-1] + rows[:, 2:]) / 6


def test_modes_carry_the_difference_of_two_von_karman_spectra():
    # the rings' powers add up to B(0; L0) - B(0; L1), and over many draws the modes' structure function along x, along
    # y and diagonally is D(r; L0) - D(r; L1) (von Karman's closed form, kolmogorov.structure_function) within 3 SE
    L1 = split_outer_scale(24, DELTA, L0)
    c = cells(L0, L1)
    assert c.power.sum() == pytest.approx(von_karman_covariance(0.0, 1.0, L0) - von_karman_covariance(0.0, 1.0, L1),
                                          rel=1e-12)
    assert np.all(c.power > 0)
    lags = np.array([1, 16, 64, 256, 1024])
    draws = 600
    along_x, along_y, diagonal = [], [], []
    for seed in range(draws):
        modes = LargeScales(np.random.default_rng(seed), DELTA, L0, L1)
        row = grid_values(modes.add_to(np.zeros((3, 1027)), -1, -1))[0]          # values at x = 0 .. 1024
        column = grid_values(modes.add_to(np.zeros((1027, 3)), -1, -1))[:, 0]
        corner = grid_values(modes.add_to(np.zeros((67, 67)), -1, -1))
        along_x.append((row[lags] - row[0]) ** 2)
        along_y.append((column[lags] - column[0]) ** 2)
        diagonal.append((corner[64, 64] - corner[0, 0]) ** 2)
    expected = structure_function(lags * DELTA, 1.0, L0) - structure_function(lags * DELTA, 1.0, L1)
    for values in (np.array(along_x), np.array(along_y)):
        error = values.std(axis=0, ddof=1) / np.sqrt(draws)
        assert np.all(np.abs(values.mean(axis=0) - expected) < 3 * error), (values.mean(axis=0) / expected, error)
    r = 64 * np.sqrt(2) * DELTA
    assert np.mean(diagonal) == pytest.approx(structure_function(r, 1.0, L0) - structure_function(r, 1.0, L1),
                                              abs=3 * np.std(diagonal, ddof=1) / np.sqrt(draws))


def test_modes_are_the_same_wherever_an_array_holds_them():
    # a value depends on its absolute position only (batches and windows read the same screen)
    modes = LargeScales(np.random.default_rng(3), DELTA, L0, split_outer_scale(24, DELTA, L0))
    whole = modes.add_to(np.zeros((40, 700)), -70, -130)
    part = modes.add_to(np.zeros((9, 100)), -50, 300)
    np.testing.assert_array_equal(part, whole[20:29, 430:530])


def test_walked_screens_keep_the_large_scales():
    # one point of a 24-sample screen (a 12-sample footprint's) walked 1200 columns: its structure function at 16, 64
    # and 256 samples (5 and 21 footprints) within 3 SE of von Karman's; the conditional draws alone, whose stencil
    # reaches back 15 columns, gave 0.92 and 0.78 at 64 and 256 (-6 and -11 SE)
    lags = np.array([16, 64, 256])
    seeds, columns = 250, 1200
    rows = np.full((columns, 1), 100.0)
    cols = 100.0 + np.arange(columns)[:, None] + np.array([[0.0, 12.0]])
    per = []
    for seed in range(seeds):
        out_t = np.zeros((columns, 2, 1))
        LayerScreen(24, DELTA, (seed,), L0=L0).accumulate(rows, cols, np.zeros(columns, np.int64), np.ones(columns),
                                                          out_t)
        v = out_t[:, 0, 0]
        per.append([np.mean((v[k:] - v[:-k]) ** 2) for k in lags])
    per = np.array(per)
    expected = structure_function(lags * DELTA, 1.0, L0)
    error = per.std(axis=0, ddof=1) / np.sqrt(seeds)
    assert np.all(np.abs(per.mean(axis=0) - expected) < 3 * error), (per.mean(axis=0) / expected, error / expected)


@pytest.mark.parametrize("modes, width", [(20, 13), (22, 13), (20, 75), (3, 75)])
def test_add_modes_sums_each_value_mode_by_mode(modes, width):
    # add_modes adds every mode to 32 columns of a row at once (vectors of 8, masked at a span's end): each value is
    # still the sum of the terms u cos x + v sin x in mode order from 0.0, then added to the coefficient, bit for bit;
    # columns outside the spans are left as they were
    from evsda.blocks.optics.screen_kernels import add_modes
    rng = np.random.default_rng(modes + width)
    height = 5
    source = rng.standard_normal((height, width))
    cos_y, sin_y = rng.standard_normal((2, modes, height))
    cos_x, sin_x = rng.standard_normal((2, modes, width))
    a, b = rng.standard_normal((2, modes))
    first, stop = np.array([0, 3, 5, 7, 2]), np.array([13, 11, 5, 13, 9])
    if width > 13:                          # spans of 1 to 3 vectors of 32, and ends at every lane
        first, stop = np.array([0, 1, 40, 7, 2]), np.array([75, 34, 41, 70, 35])
    out = np.full((height, width), np.nan)
    add_modes(source, out, cos_y, sin_y, cos_x, sin_x, a, b, first, stop)
    expected = np.full((height, width), np.nan)
    for r in range(height):
        for c in range(first[r], stop[r]):
            total = 0.0
            for k in range(modes):
                u = float(a[k] * cos_y[k, r] + b[k] * sin_y[k, r])
                v = float(b[k] * cos_y[k, r] - a[k] * sin_y[k, r])
                total += u * float(cos_x[k, c]) + v * float(sin_x[k, c])
            expected[r, c] = float(source[r, c]) + total
    np.testing.assert_array_equal(out, expected)


def test_mode_phasors_of_a_part_are_the_wholes_there():
    # a walk tabulates the modes' phasors of the rows and columns its frames read only (from column `at` of the
    # tables): each value depends on its absolute position alone, so a part's are the whole range's, bit for bit;
    # and the strides' cosines and sines kept in a cache between calls (a few slots: each made again and again as
    # positions move on and come back) give the same bits as made afresh
    from evsda.blocks.optics.screen_kernels import mode_phasors
    modes = LargeScales(np.random.default_rng(5), DELTA, 25.0, 2.0)
    k = len(modes.a)

    def fresh():
        return np.full((2, k + k + 1), np.nan)

    whole, part = np.full((2, k, 90), np.nan), np.full((2, k, 90), np.nan)
    mode_phasors(modes.frequencies[1], modes.low[2], modes.low[3], -37, 90, STRIDE, whole[0], whole[1], 0, fresh())
    mode_phasors(modes.frequencies[1], modes.low[2], modes.low[3], -37 + 13, 50, STRIDE, part[0], part[1], 13,
                 fresh())
    np.testing.assert_array_equal(part[:, :, 13:63], whole[:, :, 13:63])
    assert np.isnan(part[:, :, :13]).all() and np.isnan(part[:, :, 63:]).all()
    kept = fresh()
    for start, count in ((-37, 90), (100, 7), (-200, 40), (-37, 90), (5, 33), (-37, 90)):
        again, reference = np.empty((2, k, count)), np.empty((2, k, count))
        mode_phasors(modes.frequencies[1], modes.low[2], modes.low[3], start, count, STRIDE, again[0], again[1], 0,
                     kept)
        mode_phasors(modes.frequencies[1], modes.low[2], modes.low[3], start, count, STRIDE, reference[0],
                     reference[1], 0, fresh())
        assert again.tobytes() == reference.tobytes()
        if count == 90:
            assert again.tobytes() == whole.tobytes()


def test_read_spans_are_the_columns_the_reads_touch():
    # read_spans gives each row's columns exactly as _taps indexes them (from the same `u - top`, which may round up
    # to the next integer: -1e-17 - (-5) is 5.0), so the modes are added where the reads look and nowhere else
    from evsda.blocks.optics.screen_kernels import _taps, read_spans
    rng = np.random.default_rng(3)
    top, left, height, width = -5, 7, 24, 40
    base = np.linspace(0.0, 6.0, 9)
    rows = top + 3.0 + base + np.cumsum(rng.uniform(0, 0.4, 12))[:, None]
    cols = left + 3.0 + base + np.cumsum(rng.uniform(0, 2.0, 12))[:, None]
    rows[0] = -1e-17 + base
    touched = np.zeros((height, width), bool)
    for r, c in zip(rows, cols):
        iy, ix, w = np.empty(len(r), np.int64), np.empty(len(c), np.int64), np.empty((4, len(r)))
        _taps(r, top, iy, w)
        _taps(c, left, ix, w)
        touched[iy[0]:iy[-1] + 4, ix[0]:ix[-1] + 4] = True
    first, stop = np.empty(height, np.int64), np.empty(height, np.int64)
    read_spans(rows, cols, top, left, height, width, first, stop)
    for r in range(height):
        at = np.flatnonzero(touched[r])
        assert (first[r], stop[r]) == ((at[0], at[-1] + 1) if len(at) else (width, 0))


def numpy_modes(rng, delta, L0, L1):
    """The modes' frequencies, amplitudes and tables by NumPy's array arithmetic (LargeScales before its tables were
    compiled, screen_kernels.mode_tables): the reference."""
    c = cells(L0, L1)
    rings = len(c.power)
    u = rng.random((rings, SECTORS, 2))
    radius = c.radius(u[:, :, 0])
    angle = np.pi * (np.arange(SECTORS)[None, :] + u[:, :, 1]) / SECTORS
    k = rings * SECTORS
    frequencies = np.empty((2, k))
    np.multiply(2 * np.pi * delta * radius, np.sin(angle), out=frequencies[0].reshape(rings, SECTORS))
    np.multiply(2 * np.pi * delta * radius, np.cos(angle), out=frequencies[1].reshape(rings, SECTORS))
    gain = 3.0 / (2.0 + np.cos(frequencies[0])) * 3.0 / (2.0 + np.cos(frequencies[1]))
    amplitudes = np.sqrt(np.repeat(c.power / SECTORS, SECTORS)) * gain * rng.standard_normal((2, k))
    within = np.multiply.outer(frequencies.ravel(), np.arange(float(STRIDE)))
    low = np.empty((4, k, STRIDE))
    for axis in (0, 1):
        np.cos(within[axis * k:(axis + 1) * k], out=low[2 * axis])
        np.sin(within[axis * k:(axis + 1) * k], out=low[2 * axis + 1])
    return frequencies, amplitudes, low


def test_compiled_modes_are_numpys():
    # the compiled tables (screen_kernels.mode_tables) are NumPy's arithmetic bit for bit, for NumPy's generator and
    # the compiled seeded draws, screens of several sizes and spacings
    for delta, L0, n in [(0.02, 25.0, 20), (0.02, 25.0, 38), (0.05, 10.0, 24), (0.01, 50.0, 64)]:
        L1 = split_outer_scale(n, delta, L0)
        for seed in range(150):
            for draws in (lambda: np.random.default_rng(seed), lambda: SeededDraws(entropy_words((seed, 7, 0)))):
                modes, expected = LargeScales(draws(), delta, L0, L1), numpy_modes(draws(), delta, L0, L1)
                for got, want in zip((modes.frequencies, modes.amplitudes, modes.low), expected):
                    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
