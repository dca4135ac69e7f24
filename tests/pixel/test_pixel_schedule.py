"""The comparator schedule a pixel keeps between calls is the crossing search's, or a bound of it that
the search replaces where it is read; the search's shortcut for a settled filter changes no bit.

``run_pixels`` searches for a pixel's next comparator crossing only where the result can be used before
the pixel's next input change, shot-noise trial or the window's end (``pixel_loop._schedule_before``:
elsewhere a bound shows no crossing). The step it stores (``CMP_NEXT``), which the next window, the
deferral's choice of pixels, the dense path and checkpoints read, must be the full search from the
pixel's state, or a bound ``R`` of it kept as ``-2 - R`` (``pixel_loop.kept_schedule``) that is never
after the search's step and that ``resolve_schedules`` (before the dense path) makes the search's.
"""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel, crossing
from evsda.blocks.pixel.crossing import NEVER
from evsda.blocks.pixel.pixel_loop import (CMP_NEXT, L_, LATER, LOG_A, M_, NOISE_SCALE, OWED, PARA, READY, SHOT_NEXT,
                                           STEP, TH_OFF, TH_ON, Y, next_crossing_known, resolve_schedules)
from evsda.graph import RunInfo, Window

WINDOW_S, WINDOWS = 0.02, 4


@pytest.mark.parametrize("form", ["small_signal", "large_signal"])
def test_stored_schedule_is_the_search_from_each_pixels_state_or_a_bound_of_it(scenes, form):
    fp = scenes.focal_plane(40, 12)
    block = DvsPixel(seed=5, leak_rate_hz=20.0, shot_noise_rate_hz=20.0, lowpass_form=form)
    block.setup(RunInfo(duration_ns=round(WINDOWS * WINDOW_S * 1e9)))
    n_events = 0
    for w in range(WINDOWS):
        window = Window.from_seconds(w * WINDOW_S, (w + 1) * WINDOW_S, index=w)
        t = scenes.grid(window.start_ns, window.stop_ns, 1_000_000)
        # a streak, and a sky that changes at each window's start (changes the pixels take late)
        irradiance = scenes.moving_spot(fp, t, background=2e3 * (1.0 - 0.01 * w), velocity=(400.0, 0.0))
        n_events += len(block.step(window, irradiance=irradiance)["events"])
    assert n_events > 100                                   # the streak and the noise fire: schedules were used
    real, count = block.pixels["real"], block.pixels["count"]
    leak_hz, dt, large = block._engine._constants[:3]
    searched = np.array([next_crossing_known(count[p, STEP], count[p, READY], real[p, Y], real[p, M_], real[p, L_],
                                             real[p, LOG_A], real[p, PARA], real[p, TH_ON], real[p, TH_OFF],
                                             real[p, NOISE_SCALE], NEVER, leak_hz * dt, dt, large)[0]
                         for p in range(count.shape[0])])
    kept = count[:, CMP_NEXT]
    assert not np.any(kept == LATER)
    bound = kept < 0
    assert 0 < bound.sum() < bound.size                     # both kinds kept
    np.testing.assert_array_equal(kept[~bound], searched[~bound])
    assert np.all(-2 - kept[bound] <= searched[bound])      # a bound: never after the crossing
    assert np.all(-2 - kept[bound] > count[bound, STEP])
    next_step = block.pixels["next"]
    resolve_schedules(real, count, next_step, leak_hz, dt, large)
    np.testing.assert_array_equal(count[:, CMP_NEXT], searched)
    settle = np.where(count[:, OWED] != 0, count[:, READY], NEVER)
    np.testing.assert_array_equal(next_step, np.minimum(np.minimum(searched, count[:, SHOT_NEXT]), settle))


def test_settled_filter_shortcut_gives_the_comparator_input_bit_for_bit():
    # crossing._g takes the large-signal relaxation of a settled filter (a^j flushed to 0) as -0 without its
    # logarithm: the same bits as the full expression, on both sides of the flush and at the clamps of e^-D
    rng = np.random.default_rng(7)
    n = 4000
    c, d = rng.normal(0, 2, n), rng.normal(0, 3, n) * rng.choice([1.0, 1e-6, 300.0], n)
    log_a = -10.0 ** rng.uniform(-6, 0, n)
    delta = rng.choice([0.0, 1e-9, 1e-6], n)
    j = np.maximum(1, np.round(rng.uniform(0.5, 1.5, n) * 707.0 / -log_a)).astype(np.int64)   # around the flush
    for large in (True, False):
        for k in range(n):
            e = crossing.large_weight(d[k]) if large else 0.0
            got = crossing._g(j[k], c[k], d[k], e, log_a[k], delta[k], np.int64(-1), 0.0, large)
            want = crossing.comparator_input(j[k], c[k], d[k], log_a[k], delta[k], large)
            assert np.float64(got).tobytes() == np.float64(want).tobytes(), (k, large, got, want)
