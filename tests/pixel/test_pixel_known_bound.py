"""A pixel advanced by the steps its last bound reached takes the bound's ``a^j`` and relaxation: the same bits.

:func:`.pixel_loop.run_pixels` advances a pixel to its next change or event with the ``a^j`` and (large-signal)
relaxation of the bound it took last at the same state (:func:`.crossing.band_bound`), handed on by the sweep
(:func:`.own_sweep.sweep_own`) where the sweep took it: the advance must give the bits of the advance without them.
"""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel.crossing import NO_STEP, band_bound
from evsda.blocks.pixel.pixel_loop import advanced


@pytest.mark.parametrize("large", [False, True])
def test_advance_by_the_bounds_steps_is_the_advance_without_it(large):
    rng = np.random.default_rng(13)
    leak_hz, dt, th_off = 0.1, 1e-6, 0.2
    for _ in range(3000):
        y = rng.normal(2.0, 1.5)
        filtered = y + rng.normal() * rng.choice([0.0, 1e-9, 1e-3, 0.3, 3.0])       # settled to far off
        memorised = filtered - rng.uniform(-0.19, 0.19)
        log_a = -(10.0 ** rng.uniform(-8.0, 0.5))              # cutoffs from 1e-2 Hz to beyond the step's rate
        j = int(10.0 ** rng.uniform(0.0, 7.0))                 # some with a^j flushed to 0
        th_on, scale, para = rng.uniform(0.05, 0.35), rng.lognormal(0.0, 0.5), rng.uniform(0.0, 0.5)
        c_leak, c_para = rng.normal(0.0, 0.1), rng.normal(0.0, 0.1)
        drift = (leak_hz * dt * scale + para * dt) * th_on
        _, known, relaxed = band_bound(j, y - memorised, filtered - y, log_a, drift, th_on, th_off, large)
        state = (filtered, memorised, c_leak, c_para, y, log_a, para, th_on, scale, leak_hz, dt, large)
        taken = advanced(j, j, known, relaxed, *state)
        alone = advanced(j, NO_STEP, 0.0, 0.0, *state)
        assert np.array(taken).tobytes() == np.array(alone).tobytes()
