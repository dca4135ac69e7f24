"""The compiled screen kernels are, bit for bit, the sums they document, added in their order.

Reordering a kernel's loops for speed (rows of the canvas in the inner loop, one output row at
a time) must not change a single coefficient or sample: events downstream are compared byte for
byte across versions. The references are plain Python loops over Python floats (IEEE doubles,
no reassociation), in the documented order of the terms.
"""

from __future__ import annotations

import numpy as np

import numba

from evsda.blocks.optics.screen_kernels import (SMALLEST_FAST_POSITION, _sixth, _sixths_exact, _taps, _taps_divided,
                                               sample_grids_transposed)


def sum_in_order(terms) -> float:
    acc = 0.0
    for term in terms:
        acc += float(term)
    return acc


def reference_sample(coefficients, top, left, rows, cols, weight, out):
    """4 coefficient rows combined along y, then 4 of those along x, with the kernels' B-spline weights
    (:func:`_taps`, Unser 1999 Eq. 4; the weights themselves are checked against scipy elsewhere)."""
    def taps(u):
        index, weights = np.empty(u.size, np.int64), np.empty((4, u.size))
        _taps(np.asarray(u, dtype=float), 0.0, index, weights)
        return index, weights.T
    for f in range(rows.shape[0]):
        iy, wy = taps(rows[f] - top)
        ix, wx = taps(cols[f] - left)
        for i, r in enumerate(iy):
            for j, c in enumerate(ix):
                along = [wy[i, 0] * coefficients[r, cc] + wy[i, 1] * coefficients[r + 1, cc]
                         + wy[i, 2] * coefficients[r + 2, cc] + wy[i, 3] * coefficients[r + 3, cc]
                         for cc in range(c, c + 4)]
                out[f, i, j] += weight[f] * (wx[j, 0] * along[0] + wx[j, 1] * along[1] + wx[j, 2] * along[2]
                                             + wx[j, 3] * along[3])


def test_sampler_is_its_sums_in_order():
    rng = np.random.default_rng(8)
    coefficients = rng.standard_normal((40, 60))
    rows = 5 + rng.uniform(0, 3, (3, 1)) + 0.9 * np.arange(7)[None]
    cols = 8 + rng.uniform(0, 30, (3, 1)) + 0.8 * np.arange(9)[None]
    weight = rng.uniform(0.5, 2.0, 3)
    fast, slow = np.ones((3, 9, 7)), np.ones((3, 7, 9))
    assert sample_grids_transposed(coefficients, 2, 3, rows, cols, weight, 0, 3, fast, False)
    reference_sample(coefficients, 2, 3, rows, cols, weight, slow)
    np.testing.assert_array_equal(fast.transpose(0, 2, 1), slow)


def test_transposed_sampler_is_the_same_sums_in_order():
    # the fast path of a walk (output transposed, SIMD along y) against the same plain-Python sums
    rng = np.random.default_rng(9)
    coefficients = rng.standard_normal((50, 80))
    rows = 5 + rng.uniform(0, 3, (4, 1)) + 0.21 * np.arange(42)[None]
    cols = 8 + rng.uniform(0, 40, (4, 1)) + 0.52 * np.arange(40)[None]
    weight = rng.uniform(0.5, 2.0, 4)
    fast, slow = rng.standard_normal((4, 40, 42)), np.empty((4, 42, 40))
    slow[:] = fast.transpose(0, 2, 1)
    assert sample_grids_transposed(coefficients, 2, 3, rows, cols, weight, 1, 4, fast, False)
    reference_sample(coefficients, 2, 3, rows[1:], cols[1:], weight[1:], slow[1:])
    np.testing.assert_array_equal(fast.transpose(0, 2, 1), slow)
    assert not sample_grids_transposed(coefficients, 2, 3, rows + 40, cols, weight, 0, 4, fast, False)


def test_vector_blocks_and_their_tails_are_the_same_sums_in_order():
    # the reads' 4 x 4 blocks along y (transposed in registers) and 8-lane runs along x, with every kind of tail:
    # output rows and columns not multiples of 4 or 8, spans of coefficient columns of any length, fewer than 4 rows
    rng = np.random.default_rng(10)
    coefficients = rng.standard_normal((60, 90))
    for ny, nx, span in [(40, 40, 8.4), (41, 43, 20.8), (3, 5, 1.3), (13, 9, 6.1), (8, 8, 0.2)]:
        rows = 5 + rng.uniform(0, 3, (3, 1)) + np.linspace(0, span, ny)[None]
        cols = 8 + rng.uniform(0, 40, (3, 1)) + np.linspace(0, 1.3 * span, nx)[None]
        weight = rng.uniform(0.5, 2.0, 3)
        for assign in (False, True):
            fast = rng.standard_normal((3, nx, ny))
            slow = np.zeros((3, ny, nx)) if assign else fast.transpose(0, 2, 1).copy()
            assert sample_grids_transposed(coefficients, 2, 3, rows, cols, weight, 0, 3, fast, assign)
            reference_sample(coefficients, 2, 3, rows, cols, weight, slow)
            np.testing.assert_array_equal(fast.transpose(0, 2, 1), slow)



def test_last_columns_by_an_overlapping_block_are_the_same_sums_in_order():
    # the y pass makes the columns past its last whole block of four by the block of the last four: every count of
    # such columns (0-3), spans of 4 columns and more, up to the array's last column (nothing read beyond it)
    rng = np.random.default_rng(11)
    height, width = 30, 24
    coefficients = rng.standard_normal((height, width))
    for columns in range(4, 13):
        for at_edge in (False, True):
            # cols - 3 spans taps from floor(first) - 1 to floor(last) + 2: columns = floor(last) - floor(first) + 4
            first = width - columns + 1.0 if at_edge else 1.0 + rng.integers(0, width - columns)
            cols = 3 + first + rng.uniform(0.01, 0.3) + np.linspace(0, columns - 4, 9)[None]
            rows = 2 + 4 + rng.uniform(0, 2, (2, 1)) + 0.37 * np.arange(12)[None]
            cols = np.repeat(cols, 2, axis=0)
            weight = rng.uniform(0.5, 2.0, 2)
            fast = rng.standard_normal((2, 9, 12))
            slow = fast.transpose(0, 2, 1).copy()
            assert sample_grids_transposed(coefficients, 2, 3, rows, cols, weight, 0, 2, fast, False)
            reference_sample(coefficients, 2, 3, rows, cols, weight, slow)
            np.testing.assert_array_equal(fast.transpose(0, 2, 1), slow)

@numba.njit
def sixths(a, out):
    for i in range(a.shape[0]):
        out[i] = _sixth(a[i])


def same_bits(a, b) -> bool:
    return np.array_equal(np.asarray(a).view(np.int64), np.asarray(b).view(np.int64))


def test_sixth_is_the_correctly_rounded_division():
    # Markstein's multiply-and-correct gives a / 6's bits for every finite |a| >= 2^-1019 (and +0): random
    # significands over the whole exponent range, significands divisible by 3 (exact quotients), both ends of a binade
    rng = np.random.default_rng(11)
    n = 200_000
    for significands in (rng.integers(2**52, 2**53, n), 3 * rng.integers(2**52 // 3 + 1, 2**53 // 3, n),
                         2**53 - 1 - rng.integers(0, 4096, n), 2**52 + rng.integers(0, 4096, n)):
        a = np.ldexp(significands.astype(float), rng.integers(-1019 - 52, 1023 - 52, n)) * rng.choice([-1.0, 1.0], n)
        a = np.concatenate([a, [0.0, 2.0**-1019, 4.0, 1.0, 3.0, 6.0, 5.0]])
        out = np.empty_like(a)
        sixths(a, out)
        assert same_bits(out, a / 6.0)


def test_sixth_needs_its_bound():
    # below it (subnormal dividends) the correction can round a tie the other way: why _taps checks its positions
    a = np.ldexp(np.arange(3, 3000, 6, dtype=float), -1074)
    out = np.empty_like(a)
    sixths(a, out)
    assert not same_bits(out, a / 6.0)


def test_taps_are_the_divided_taps():
    rng = np.random.default_rng(12)
    awkward = [0.0, 3.0, -3.0, 1 - 2**-53, -2.0**-60, -1e-300, SMALLEST_FAST_POSITION, 0.5, -0.5]
    for u, fast in [(rng.uniform(-50, 1000, 5000), True), (rng.uniform(-1, 1, 5000), True), (np.array(awkward), True),
                    (np.array([2.5, 1e-200]), False), (np.array([2.5, 1e-320]), False), (np.array([2.5, -0.0]), False), (np.array([2.5, np.nan]), False),
                    (np.array([np.inf, 2.5]), False)]:
        assert _sixths_exact(u, 0.0) == fast
        index, weights = np.empty(u.size, np.int64), np.empty((4, u.size))
        divided_index, divided = np.empty(u.size, np.int64), np.empty((4, u.size))
        _taps(u, 0.0, index, weights)
        _taps_divided(u, 0.0, divided_index, divided)
        np.testing.assert_array_equal(index, divided_index)
        assert same_bits(weights, divided)


def test_extensions_on_every_side_are_the_right_extension_of_the_turned_canvas():
    # extend_columns reads and writes a window seen with its growing side on the right through flat indices
    # (screen_kernels._window_strides): growing left, down or up must be growing right on the canvas flipped,
    # transposed or both, bit for bit (the same stencil values in the same order, the same sums), and touch only the
    # new columns; growing right matches the operator's own A z + B w to rounding
    from evsda.blocks.optics.screen_kernels import DOWN, LEFT, RIGHT, UP, extend_columns
    rng = np.random.default_rng(21)
    n, n_stencil, steps = 6, 11, 4
    a, b = rng.standard_normal((n, n_stencil)), np.tril(rng.standard_normal((n, n)))
    stencil_rows, stencil_back = rng.integers(0, n, n_stencil), rng.integers(0, 5, n_stencil)
    noise = rng.standard_normal(steps * n)
    canvas = rng.standard_normal((23, 29))
    height, width = canvas.shape
    top, left = 8, 9
    turned = {RIGHT: (lambda c: c, lambda t, l: (t, l)),
              LEFT: (lambda c: c[:, ::-1], lambda t, l: (t, width - n - l)),
              DOWN: (lambda c: c.T, lambda t, l: (l, t)),
              UP: (lambda c: c.T[:, ::-1], lambda t, l: (l, height - n - t))}
    # each side's windows step away from the start along its own direction (one column or row a step)
    moves = {RIGHT: (0, 1), LEFT: (0, -1), DOWN: (1, 0), UP: (-1, 0)}
    for side, (turn, place) in turned.items():
        tops = np.array([top + moves[side][0] * k for k in range(steps)])
        lefts = np.array([left + moves[side][1] * k for k in range(steps)])
        grown = canvas.copy()
        extend_columns(grown, tops, lefts, np.full(steps, side, np.int8), a, b, stencil_rows, stencil_back, noise, n)
        right = np.array(turn(canvas), order="C")                  # a copy, also for RIGHT
        at = np.array([place(t, l) for t, l in zip(tops, lefts)])
        extend_columns(right, at[:, 0], at[:, 1], np.full(steps, RIGHT, np.int8), a, b, stencil_rows, stencil_back,
                       noise, n)
        assert same_bits(turn(grown), right), side
        assert np.count_nonzero(grown != canvas) == steps * n, side
        if side == RIGHT:
            window = canvas[top:top + n, left:left + n]
            expected = a @ window[stencil_rows, n - 1 - stencil_back] + b @ noise[:n]
            np.testing.assert_allclose(grown[top:top + n, left + n], expected, rtol=1e-12, atol=1e-12)
