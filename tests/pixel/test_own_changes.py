"""The compiled input changes of pixels under stamps equal the dense [pixel, sample] table's (the former NumPy form)."""

import numpy as np
import pytest

from evsda.blocks.pixel.own_changes import own_changes, under_stamps


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
