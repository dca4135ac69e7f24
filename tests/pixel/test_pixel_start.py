"""The event-driven pixels' start (:meth:`EventDrivenPixels.new_state`, :func:`.pixel_loop.start_pixels` from the
distinct fluxes' drive and :func:`.initial.initial_draws`) against its reference: :func:`.initial.initial_pixels`
(NumPy, the reference implementation's start), every flux driven (:func:`.drive_kernel.drive_rows`) and each
pixel's first schedules made one at a time. The same bits in every table, and the generator left alike."""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel.block import DvsPixel
from evsda.blocks.pixel.drive_kernel import drive_constants, drive_rows
from evsda.blocks.pixel.eventdriven import EventDrivenPixels
from evsda.blocks.pixel.initial import initial_pixels
from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.pixel.pixel_loop import (C_LEAK, C_PARA, CMP_NEXT, COUNT, L_, LOG_A, M_, NEVER, NOISE_SCALE, PARA,
                                           READY, REAL, SHOT_NEXT, STEP, TH_OFF, TH_ON, Y, kept_schedule,
                                           schedule_bound, shot_gap)


def _reference_state(model: PixelModel, flux: np.ndarray, seed: int, n_start: int):
    """The state tables the way the start made them before it read the distinct fluxes (NumPy's arrays of the
    whole sensor, then the schedules), and the key drawn after them."""
    rng = np.random.default_rng(seed)
    init = initial_pixels(model, flux, rng)
    key = int(rng.integers(0, 2**63 - 1))
    n = flux.size
    real, count, next_step = np.zeros((n, len(REAL))), np.zeros((n, len(COUNT)), np.int64), np.zeros(n, np.int64)
    drive_rows(flux, drive_constants(model), real)
    real[:, L_], real[:, M_], real[:, TH_ON], real[:, TH_OFF] = init.filtered, init.memorised, init.theta_on, \
        init.theta_off
    real[:, C_LEAK], real[:, C_PARA], real[:, NOISE_SCALE] = init.credit[0], init.credit[1], init.noise_scale
    p, dt = model.params, model.dt_s
    q = 2.0 * model.shot_p_max
    for pixel in range(n):
        r = real[pixel]
        step, ready = n_start - 1, n_start
        shot_next = step + shot_gap(np.int64(key), np.int64(pixel), np.int64(0), q * r[NOISE_SCALE])
        cmp_next = kept_schedule(np.int64(step), np.int64(ready), r[Y], r[M_], r[L_], r[LOG_A], r[PARA], r[TH_ON],
                                 r[TH_OFF], r[NOISE_SCALE], p.leak_rate_hz * dt, dt, p.lowpass_form == "large_signal")
        count[pixel, STEP], count[pixel, READY], count[pixel, SHOT_NEXT], count[pixel, CMP_NEXT] = step, ready, \
            shot_next, cmp_next
        next_step[pixel] = min(schedule_bound(cmp_next), shot_next, NEVER)
    return real, count, next_step, key, rng


@pytest.mark.parametrize("n, distinct", [(3_000, False), (70_000, True), (70_000, False)])
@pytest.mark.parametrize("params", [dict(leak_rate_hz=2.0, shot_noise_rate_hz=2.0, parasitic_rate_per_lux_hz=1e-3,
                                         noise_rate_spread_decades=0.5),
                                    dict(leak_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, lowpass_form="large_signal")])
def test_the_start_gives_the_references_tables_bit_for_bit(n, distinct, params):
    model = PixelModel(DvsPixel.Params(**params), (10e-6) ** 2, 550e-9)
    rng = np.random.default_rng(5)
    background = 4e3
    flux = np.full(n, background)
    if distinct:            # a uniform sky and a few stamps: driven once per distinct flux
        flux[rng.choice(n, 300, replace=False)] = rng.choice([0.0, 2e2, 5e5, 3e7], 300)
    else:                   # every pixel its own flux
        flux = rng.uniform(0.0, 1e6, n)
    fluxes = model.distinct_drive(flux)[0]
    assert (fluxes.size < n) == distinct
    real, count, next_step, key, after = _reference_state(model, flux, 9, 40)
    generator = np.random.default_rng(9)
    state = EventDrivenPixels.new_state(model, flux, generator, 40, background)
    np.testing.assert_array_equal(state["real"].view(np.int64), real.view(np.int64))     # the bits, NaN or not
    np.testing.assert_array_equal(state["count"], count)
    np.testing.assert_array_equal(state["next"], next_step)
    assert state["key"] == key and generator.random() == after.random()


def test_the_drive_of_the_distinct_fluxes_is_the_drive_of_every_pixel():
    model = PixelModel(DvsPixel.Params(), (10e-6) ** 2, 550e-9)
    flux = np.full(100_000, 3e3)
    flux[::997] = np.linspace(0.0, 1e7, flux[::997].size)
    values, drive, inverse = model.distinct_drive(flux)
    assert values.size < 200
    for whole, few in zip(model.drive(flux), drive):
        np.testing.assert_array_equal(whole, few[inverse])


def test_fluxes_are_called_many_only_where_they_are():
    # The start leaves out the sort of every flux where a strided subset already holds one distinct value per
    # _FEW_SHARE pixels (model._many_distinct): never where the whole holds fewer, and always on a noisy frame.
    from evsda.blocks.pixel.model import _FEW_SHARE, _many_distinct

    rng = np.random.default_rng(3)
    n = 90_000
    noisy = 2e5 * (1 + 0.02 * rng.standard_normal(n))
    uniform = np.full(n, 4e3)
    uniform[rng.choice(n, 300, replace=False)] = 5e5
    for period in (_FEW_SHARE - 1, _FEW_SHARE, _FEW_SHARE + 1):         # about n / period distinct values, in runs
        runs = np.repeat(rng.permutation(-(-n // period)).astype(float), period)[:n]
        cycled = np.tile(np.arange(-(-n // period), dtype=float), period)[:n]     # the subset sees each a few times
        for flux in (runs, cycled):
            assert not _many_distinct(flux) or np.unique(flux).size >= n // _FEW_SHARE
    assert _many_distinct(noisy) and not _many_distinct(uniform)
    model = PixelModel(DvsPixel.Params(), (10e-6) ** 2, 550e-9)
    values, _, inverse = model.distinct_drive(noisy)                     # every pixel driven on its own
    np.testing.assert_array_equal(values, noisy)
    np.testing.assert_array_equal(inverse, np.arange(n))


def test_the_distinct_count_is_numpys():
    # model._distinct_count (the start's count without np.unique, whose first call imports numpy.ma): NaNs one value,
    # -0.0 and 0.0 one, infinities their own
    from evsda.blocks.pixel.model import _distinct_count

    rng = np.random.default_rng(4)
    pool = np.array([0.0, -0.0, np.nan, 1.0, 2.5, -3.0, np.inf, -np.inf, 7.0])
    for _ in range(300):
        values = rng.choice(pool, int(rng.integers(1, 60)))
        assert _distinct_count(values) == np.unique(values).size
