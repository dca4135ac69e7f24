"""The compiled event order of ``EventLog.to_port`` is NumPy's argsort of the events' keys (the former form)."""

import numpy as np
import pytest

from evsda.blocks.pixel.eventlog import EventLog
from evsda.blocks.ports import FocalPlane


def numpy_port(step, pixel, polarity, cause, width, n_pixels, dt_ns):
    """``to_port``'s arrays as NumPy made them before the compiled sort."""
    order = np.argsort(step * np.int64(n_pixels) + pixel)
    step, pixel, polarity, cause = step[order], pixel[order], polarity[order], cause[order]
    row = pixel // width
    counts = tuple(int(c) for c in np.bincount(cause, minlength=4)[:4])
    return (step * np.int64(dt_ns), (pixel - row * width).astype(np.uint16), row.astype(np.uint16), polarity, cause,
            counts)


@pytest.mark.parametrize("seed, wide", [(seed, False) for seed in range(8)] + [(1, True), (3, True)])
def test_time_order_is_numpys_argsort_of_the_keys(seed, wide):
    # wide: the steps span too many bits for the keys to carry polarity and cause (gathered through their order)
    rng = np.random.default_rng(seed)
    width, height = [(5, 3), (1280, 720), (7, 1), (640, 480)][seed % 4]
    n_pixels = width * height
    n = int(rng.integers(1, 3000)) if seed else 1
    span = 2**40 if wide else int(rng.choice([1, 50, 100_000, 10**7]))
    keys = np.unique(rng.integers(0, span * n_pixels, n))             # one event per pixel and step
    step, pixel = int(rng.integers(0, 10**9)) + keys // n_pixels, keys % n_pixels
    cuts = np.sort(rng.integers(0, keys.size, 3))
    pieces = np.split(np.lexsort((step, pixel)), cuts)                 # chunks in turn, each by pixel, then step
    if seed % 2 == 0:                                                  # or neither
        pieces = [rng.permutation(p) for p in pieces][::-1]
    polarity = rng.choice(np.array([-1, 1, -128, 127], np.int8), keys.size)     # any int8 carried as bits
    cause = rng.integers(0, 6, keys.size).astype(np.uint8)
    log = EventLog()
    for piece in pieces:
        log.add(step[piece], pixel[piece], polarity[piece], cause[piece])
    port = log.to_port(FocalPlane(width, height, 5e-6, 1.0), 1000)
    order = np.concatenate(pieces)
    want = numpy_port(step[order], pixel[order], polarity[order], cause[order], width, n_pixels, 1000)
    for name, value in zip(("t_ns", "x", "y", "p", "cause"), want):
        np.testing.assert_array_equal(getattr(port, name), value)
        assert getattr(port, name).dtype == value.dtype
    assert port.counts_by_cause == want[-1]
