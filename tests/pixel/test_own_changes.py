"""The compiled input changes of pixels under stamps equal the dense [pixel, sample] table's (the former NumPy form)."""

import numpy as np
import pytest

from evsda.blocks.pixel.own_changes import own_changes, under_stamps, window_changes
from evsda.blocks.pixel.pixel_loop import FLUX, REAL


def dense_changes(held, background, row_of, sample, flux):
    """Fill the dense table, add the stamp entries in order, compare each column with the one before."""
    values = np.repeat(background[None, :], held.size, axis=0)
    np.add.at(values, (row_of, sample), flux)
    before = np.concatenate([held[:, None], values[:, :-1]], axis=1)
    row, col = np.nonzero(values != before)
    return row, col, values[row, col], values[:, -1] != background[-1]


@pytest.mark.parametrize("seed", range(20))
def test_own_changes_match_the_dense_table(seed):
    rng = np.random.default_rng(seed)
    n, k = int(rng.integers(1, 30)), int(rng.integers(1, 12))
    background = rng.choice([1.0, 1.5, 2.0], size=k)
    if seed % 3 == 0:
        background[:] = background[0]                                  # a held background
    if seed % 5 == 1:
        background[rng.integers(0, k)] = np.nan                        # NaN is a change each time, as in NumPy
    m = int(rng.integers(0, 3 * n))
    sample = np.sort(rng.integers(0, k, m))                            # entries by sample (duplicates allowed)
    row_of = rng.integers(0, n, m)
    flux = rng.choice([0.0, 0.5, 1e-17, 3.0], size=m)
    held = rng.choice([1.0, 1.5, 2.5], size=n)
    got = own_changes(held, background, row_of, sample, flux, np.zeros(held.size, np.bool_))
    want = dense_changes(held, background, row_of, sample, flux)
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    # a change still to take first (column -1, to the held flux) for the pixels marked lead, the rest the same
    lead = rng.random(n) < 0.5
    row, column, value, off = want
    at = np.searchsorted(row, np.flatnonzero(lead))
    want = (np.insert(row, at, np.flatnonzero(lead)), np.insert(column, at, -1), np.insert(value, at, held[lead]), off)
    for a, b in zip(own_changes(held, background, row_of, sample, flux, lead), want):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", range(6))
def test_pixels_under_stamps_are_those_a_sensor_mask_lists(seed):
    # under_stamps works in the stamps' pixels; the mask over the sensor, listed and searched, is the definition
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    before = np.unique(rng.integers(0, n, int(rng.integers(0, 40))))
    pixel = rng.integers(0, n, int(rng.integers(0, 200)))             # entries repeat pixels across samples
    slot = np.full(n, -1, np.int32)
    touched, rows = under_stamps(before, pixel, slot)
    mask = np.zeros(n, bool)
    mask[before] = True
    mask[pixel] = True
    np.testing.assert_array_equal(touched, np.flatnonzero(mask))
    np.testing.assert_array_equal(rows, np.searchsorted(np.flatnonzero(mask), pixel))
    assert np.all(slot == -1)                                          # the scratch is left as found


def test_sorted_runs_is_numpys_sort():
    from evsda.blocks.pixel.own_changes import _sorted_runs
    rng = np.random.default_rng(4)
    for n in (0, 1, 2, 7, 300, 4001):
        runs = [np.sort(rng.choice(10**6, n // 3 + 1, replace=False)) for _ in range(3)]
        for values in (rng.permutation(n), np.concatenate(runs)[:n], rng.integers(0, 9, n), np.arange(n)[::-1]):
            values = np.ascontiguousarray(values, dtype=np.int64)
            np.testing.assert_array_equal(_sorted_runs(values), np.sort(values))


def numpy_window_changes(touched, stamp_row, sample, flux, real, applied, base, shared_step, shared_input,
                         held_background, background, steps):
    """The NumPy bookkeeping ``run_window`` did before :func:`window_changes` (a window with samples)."""
    kept = shared_step.size
    behind = applied[touched] < base + kept
    shared = np.flatnonzero(background != np.r_[held_background, background[:-1]])
    held = real[touched, FLUX]
    if kept:
        held[behind] = shared_input[kept - 1, FLUX]
    row, col, own_flux, off = own_changes(held, background, stamp_row, sample, flux, behind)
    own_pixel = touched[row]
    own_step = np.r_[shared_step[kept - 1] if kept else 0, steps][col + 1].astype(np.int64)
    first = np.flatnonzero(np.r_[True, own_pixel[1:] != own_pixel[:-1]]) if own_pixel.size else np.zeros(0, np.int64)
    changed, counts = own_pixel[first], np.diff(np.r_[first, own_pixel.size])
    pending = applied[changed] - base
    quiet_from = np.where(pending < kept - 1, pending, -1)
    return shared, own_step, own_flux, touched[off], changed, first, counts, quiet_from


@pytest.mark.parametrize("seed", range(12))
def test_window_changes_are_the_numpy_bookkeeping(seed):
    rng = np.random.default_rng(seed)
    n_pixels, k = int(rng.integers(1, 60)), int(rng.integers(1, 10))
    touched = np.unique(rng.integers(0, n_pixels, int(rng.integers(0, n_pixels + 1))))
    m = int(rng.integers(0, 3 * touched.size + 1)) if touched.size else 0
    sample = np.sort(rng.integers(0, k, m))
    stamp_row = rng.integers(0, max(touched.size, 1), m)
    flux = rng.choice([0.0, 0.5, 3.0], size=m)
    real = rng.choice([1.0, 1.5, 2.5], size=(n_pixels, len(REAL)))
    kept = int(rng.integers(0, 5)) if seed % 4 else 0                  # background changes kept from before
    base = int(rng.integers(0, 4))
    applied = base + rng.integers(0, kept + 1, n_pixels)               # some pixels behind, some up to date
    shared_step = np.sort(rng.integers(0, 100, kept))
    shared_input = rng.choice([1.0, 2.0], size=(kept, len(REAL)))
    background = rng.choice([1.0, 1.5], size=k)
    steps = 100 + np.arange(k, dtype=np.int64) * 7
    held_background = float(rng.choice([1.0, 1.5]))
    args = (touched, stamp_row, sample, flux, real, applied, np.int64(base), shared_step, shared_input,
            held_background, background, steps)
    for got, want in zip(window_changes(*args), numpy_window_changes(*args)):
        np.testing.assert_array_equal(got, want)
        assert got.dtype == want.dtype
