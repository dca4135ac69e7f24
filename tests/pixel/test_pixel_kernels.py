"""The compiled arithmetic of the fast implementation against NumPy: elementary functions and Eqs. 12-20."""

from __future__ import annotations

from pathlib import Path

import numba
import numpy as np
import pytest
import yaml

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.drive_kernel import drive_constants, drive_into, drive_rows
from evsda.blocks.pixel.fastmath import exp_, log1p_, log_
from evsda.blocks.pixel.model import PixelModel, distinct_values
from evsda.blocks.pixel.pixel_loop import ACCEPT, FLUX, LOG_A, PARA, REAL, Y


@numba.njit
def _apply(f, x):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = f(x[i])
    return out


def _ulps(a, b):
    return np.abs(a - b) / np.spacing(np.abs(b))


def test_elementary_functions_match_numpy_to_an_ulp():
    rng = np.random.default_rng(0)
    x = np.concatenate([-rng.random(200_000) * 708.0, rng.random(100_000) * 709.0, [0.0, -1e-300, 1e-17]])
    assert _ulps(_apply(exp_, x), np.exp(x)).max() <= 1.0
    y = np.concatenate([np.exp(rng.normal(0, 50, 200_000)), [1.0, 2.0, 0.5, 1e-310, 5e-324, 1.7e308]])
    assert _ulps(_apply(log_, y), np.log(y)).max() <= 1.0
    w = np.concatenate([10.0 ** rng.uniform(-20, 3, 200_000), -rng.random(1000) * 0.9, [0.0, 1e-300]])
    assert _ulps(_apply(log1p_, w), np.log1p(w)).max() <= 4.0
    special = np.array([0.0, -1.0, np.inf, np.nan])
    with np.errstate(divide="ignore", invalid="ignore"):
        np.testing.assert_array_equal(_apply(log_, special), np.log(special))


@pytest.mark.parametrize("params", [
    {},                                                                          # paper: knee at 5, paper cutoff
    dict(knee_at_dark_current=True, cutoff_model="proportional", cutoff_saturation=67290.0,
         shot_noise_intensity_factor=0.25, parasitic_rate_per_lux_hz=0.01),     # DAVIS346-like
    dict(cutoff_max_hz=0.0, log_current_max=0.5, time_step_s=1e-4),              # no filter, flat shot noise
    dict(knee_at_dark_current=True, cutoff_model="power", cutoff_saturation=500.0, cutoff_exponent=0.5),
    dict(cutoff_model="power", cutoff_saturation=50.0, cutoff_exponent=1.7, dark_current_density_A_m2=0.0),
])
def test_compiled_drive_agrees_with_the_numpy_model(params):
    model = PixelModel(DvsPixel.Params(**params), (10e-6) ** 2, 550e-9)
    flux = np.concatenate([[0.0], 10.0 ** np.linspace(0, 13, 2001)])           # dark to saturating [photon/s]
    rows = np.empty((flux.size, len(REAL)))
    drive_rows(flux, drive_constants(model), rows)
    one_by_one = np.empty_like(rows)
    for row, value in zip(one_by_one, flux):                # the scalar function, one flux at a time: same bits
        drive_into(row, value, drive_constants(model))
    np.testing.assert_array_equal(rows[:, [FLUX, Y, LOG_A, PARA, ACCEPT]].view(np.int64),
                                  one_by_one[:, [FLUX, Y, LOG_A, PARA, ACCEPT]].view(np.int64))
    drive = model.drive(flux)
    np.testing.assert_array_equal(rows[:, FLUX], flux)
    np.testing.assert_allclose(rows[:, Y], drive.y, rtol=1e-14, atol=1e-15)    # ln x near x = 1: absolute
    with np.errstate(divide="ignore"):
        np.testing.assert_allclose(rows[:, LOG_A], drive.log_a, rtol=1e-13)
    np.testing.assert_allclose(rows[:, PARA], drive.parasitic_hz, rtol=1e-15)
    np.testing.assert_allclose(rows[:, ACCEPT], drive.shot_p / model.shot_p_max, rtol=1e-14)


@pytest.mark.parametrize("preset", sorted(p.name for p in (Path(__file__).parents[2] / "library" / "sensors").glob("*.yaml")))
def test_compiled_drive_agrees_for_every_sensor_preset(preset):
    params = yaml.safe_load((Path(__file__).parents[2] / "library" / "sensors" / preset).read_text())
    model = PixelModel(DvsPixel.Params(**params["blocks"]["pixel"]["params"]), (10e-6) ** 2, 550e-9)
    flux = 10.0 ** np.linspace(0, 12, 1001)
    rows = np.empty((flux.size, len(REAL)))
    drive_rows(flux, drive_constants(model), rows)
    drive = model.drive(flux)
    np.testing.assert_allclose(rows[:, Y], drive.y, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(rows[:, LOG_A], drive.log_a, rtol=1e-13)
    np.testing.assert_allclose(rows[:, PARA], drive.parasitic_hz, rtol=1e-15)
    np.testing.assert_allclose(rows[:, ACCEPT], drive.shot_p / model.shot_p_max, rtol=1e-14)


@pytest.mark.parametrize("spread", [4, 60])           # stamps overlapping often; seldom (rows taken in order)
def test_summed_stamps_are_the_stable_sort_of_the_stamps_pixels(spread):
    # each sample's keys in the order of a stable sort of all its stamps' pixels, each key's flux summed from 0 in
    # the stamps' order, whichever way _summed_stamps orders them; stamps reach past every edge of the sensor
    from evsda.blocks.pixel.sampling import _summed_stamps
    rng = np.random.default_rng(3)
    height, width, n_t, n_s, h, w = 60, 80, 12, 9, 5, 5
    flux = rng.normal(0.0, 1.0, (n_t, n_s, h, w)) * rng.choice([0.0, 1.0, 1e-300], (n_t, n_s, h, w), p=[0.1, 0.8, 0.1])
    origin = np.stack([rng.integers(-h, width + 1, (n_t, n_s)), rng.integers(-h, min(height, spread) + 1, (n_t, n_s))],
                      -1).astype(np.int32)
    samples = np.arange(n_t, dtype=np.int64)
    which, stamp = np.nonzero(rng.random((n_t, n_s)) < 0.8)
    key, summed = _summed_stamps(flux, origin, samples, which.astype(np.int64), stamp.astype(np.int64), height, width)
    want_key, want_flux = [], []
    for k in range(n_t):
        keys, values = [], []
        for s in stamp[which == k]:
            for a in range(h):
                for b in range(w):
                    row, col = origin[k, s, 1] + a, origin[k, s, 0] + b
                    if 0 <= row < height and 0 <= col < width:
                        keys.append(k * height * width + row * width + col)
                        values.append(flux[k, s, a, b])
        keys, values = np.array(keys, np.int64), np.array(values)
        order = np.argsort(keys, kind="stable")
        for j in order:
            if not want_key or want_key[-1] != keys[j]:
                want_key.append(keys[j])
                want_flux.append(0.0)
            want_flux[-1] += values[j]
    np.testing.assert_array_equal(key, want_key)
    assert np.asarray(want_flux).tobytes() == summed.tobytes()


def teststable_order_is_numpys_stable_argsort():
    # _summed_stamps' own sort against np.argsort(kind="stable"): ties in index order, runs, edge sizes
    from evsda.blocks.pixel.sampling import stable_order
    rng = np.random.default_rng(11)
    cases = [np.zeros(0, np.int64), np.array([7], np.int64), np.array([2, 2, 1, 1, 0, 0], np.int64),
             np.arange(50, dtype=np.int64), np.arange(50, dtype=np.int64)[::-1].copy(), np.full(33, 4, np.int64)]
    cases += [rng.integers(0, hi, n).astype(np.int64) for n in (2, 3, 17, 1000, 4097) for hi in (2, 5, 1 << 40)]
    cases += [np.concatenate([np.sort(rng.integers(0, 30, rng.integers(0, 12))) for _ in range(40)]).astype(np.int64)]
    for keys in cases:
        np.testing.assert_array_equal(stable_order(keys), np.argsort(keys, kind="stable"))


def test_distinct_values_are_numpys_unique():
    """The drive's distinct fluxes (``model.distinct_values``: only the values other than the first sorted) are
    ``np.unique``'s values and inverse, bit for bit, with zeros of either sign, infinities and NaN among them."""
    rng = np.random.default_rng(3)
    for trial in range(120):
        n = int(rng.integers(1, 100_000))
        background = (3.7, 1e5, 0.0, -0.0, 2.5e-300, np.nan, float(rng.random()))[trial % 7]
        flux = np.full(n, background)
        k = int(rng.integers(0, max(1, n // (10 if trial % 2 else 40))))
        flux[rng.integers(0, n, k)] = rng.choice([0.0, -0.0, 1.0, 7.25, background, np.inf, 3.3e-310]
                                                 + list(rng.random(5)), k)
        values, inverse = np.unique(flux, return_inverse=True)
        got, got_inverse = distinct_values(flux)
        assert got.tobytes() == values.tobytes()
        assert got_inverse.dtype == inverse.dtype and np.array_equal(got_inverse, inverse)
