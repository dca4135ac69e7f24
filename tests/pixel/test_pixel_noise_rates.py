"""The noise the parameters configure is the noise the pixels show (issue 11.2), in both implementations.

Configured rates per pixel: ON ``R_leak + R_para + r``, OFF ``r`` (``r`` of Eq. 20 at the
pixel's current), less the trials that fall in a refractory period. Each test allows four
standard deviations of the Poisson counting error, over the whole run and over each of its
first windows (a stationary start: no burst, no deficit).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import constants

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.ports import EventCause
from evsda.graph import Window

BOTH = ["reference", "fast"]
# a preset-like photoreceptor: logarithmic down to its dark current, bandwidth proportional to its current
PRESET_LIKE = dict(knee_at_dark_current=True, dark_current_density_A_m2=1e-5, cutoff_model="proportional",
                   cutoff_saturation=9288.0)


def _within(count, expected, sigmas=4.0):
    return abs(count - expected) <= sigmas * np.sqrt(max(expected, 1.0))


def _rates(scenes, block, fp, flux, seconds, window_s):
    outs = scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], flux), seconds, window_s)
    return [(int(np.sum(o.p > 0)), int(np.sum(o.p < 0))) for o in outs], scenes.concat(outs)


@pytest.mark.parametrize("implementation", BOTH)
def test_dark_background_rates_are_the_configured_ones_from_the_start(scenes, implementation):
    # In the dark a pixel shows ON at R_leak + R_n and OFF at R_n: each shot event once, no rebound
    # (the paper's reset of the memory by a shot event made 1.5-2x the rate, issue 11.2).
    fp, leak, r_n, dt, seconds, window = scenes.focal_plane(32, 32), 2.0, 3.0, 1e-4, 1.0, 0.25
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, leak_rate_hz=leak,
                     shot_noise_rate_hz=r_n, parasitic_rate_per_lux_hz=0.0, seed=5, **PRESET_LIKE)
    per_window, ev = _rates(scenes, block, fp, 0.0, seconds, window)
    n = fp.width_px * fp.height_px
    on_rate, off_rate = leak + r_n, r_n                         # refractory of one step: no trial is lost
    for on, off in per_window:                                 # every quarter second, the first one included
        assert _within(on, on_rate * n * window) and _within(off, off_rate * n * window), (on, off)
    assert _within(int(np.sum(ev["p"] > 0)), on_rate * n * seconds)
    assert _within(int(np.sum(ev["p"] < 0)), off_rate * n * seconds)
    assert ev["counts"][EventCause.SIGNAL] == 0 and ev["counts"][EventCause.PARASITIC] == 0


@pytest.mark.parametrize("implementation", BOTH)
def test_lit_background_rates_follow_eq_19_and_20(scenes, implementation):
    # Under light the parasitic leak adds ON events (Eq. 19) and the shot noise falls to r(I) (Eq. 20).
    fp, leak, r_n, per_lux, dt, seconds = scenes.focal_plane(24, 24), 1.0, 4.0, 1.0, 1e-4, 1.0
    params = dict(time_step_s=dt, refractory_period_s=dt, leak_rate_hz=leak, shot_noise_rate_hz=r_n, parasitic_rate_per_lux_hz=per_lux,
                  seed=6, **PRESET_LIKE)
    block = DvsPixel(implementation=implementation, **params)
    flux = 3e5                                                  # 2.9 lx, 0.05 pA: halfway up Eq. 20 scale
    model = PixelModel(block.params, scenes.PITCH_M**2, scenes.WAVELENGTH_M)
    drive = model.drive(np.array([flux]))
    r, para = float(drive.shot_p[0] / dt), float(drive.parasitic_hz[0])
    assert 0.3 * r_n < r < 0.9 * r_n and para > 1.0
    per_window, ev = _rates(scenes, block, fp, flux, seconds, 0.25)
    n = fp.width_px * fp.height_px
    assert _within(int(np.sum(ev["p"] > 0)), (leak + para + r) * n * seconds)
    assert _within(int(np.sum(ev["p"] < 0)), r * n * seconds)
    on, off = per_window[0]
    assert _within(on, (leak + para + r) * n * 0.25) and _within(off, r * n * 0.25)


@pytest.mark.parametrize("implementation", BOTH)
def test_parasitic_rate_is_bounded_by_the_refractory_period(scenes, implementation):
    # Eq. 19 at an absurd illuminance would drift the memory by thousands of thresholds a second;
    # the rate stops at one event per refractory period and the memory stays with the input.
    fp, dt, k = scenes.focal_plane(4, 4), 1e-4, 10
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt, leak_rate_hz=0.5,
                     shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=1.0, threshold_sigma=0.0, seed=1)
    _, ev = _rates(scenes, block, fp, 1e12, 0.5, 0.25)
    per_pixel = ev["t"].size / (fp.width_px * fp.height_px)
    assert per_pixel == pytest.approx(0.5 / (k * dt), rel=0.01)
    drift = block.pixel_field("filtered") - block.pixel_field("memorised")
    assert np.all(np.abs(drift) < 2 * 0.2)


@pytest.mark.parametrize("implementation", BOTH)
@pytest.mark.parametrize("model, exponent, saturation", [("proportional", 1.0, 1e6), ("power", 0.5, 1e8)])
def test_a_dark_pixel_is_slower_than_a_lit_one(scenes, implementation, model, exponent, saturation):
    # Bandwidth growing with the current (Lichtsteiner et al. 2008): a flash of 100x the dark
    # current on a dark pixel. The first ON event comes after -tau_lit ln(1 - theta/C), C = ln 101,
    # the first OFF event after the flash after about -tau_dark ln(1 - theta/C): 101^n x later. The OFF
    # tail of a bright source outlasts its ON burst by the ratio of the currents to the power n
    # (1 proportional; 0.5 the presets' law, from the DVS128's measured curves).
    fp, theta, dt = scenes.focal_plane(1, 1), 0.2, 2e-6
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, threshold_on=theta,
                     threshold_off=theta, leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0,
                     threshold_sigma=0.0, **dict(PRESET_LIKE, dark_current_density_A_m2=1e-2, cutoff_saturation=saturation,
                                                 cutoff_model=model, cutoff_exponent=exponent))
    i_dark = 1e-2 * scenes.PITCH_M**2                          # 0.25 pA: f_dark 0.75 / 4.7 Hz, f_lit 76 / 48 Hz
    flux = np.array([0.0, 100 * i_dark / (0.6 * constants.e), 0.0])
    t_on, t_off = 1_000_000, 41_000_000
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, t_on, t_off], flux), 0.06, 0.03))
    on, off = ev["t"][ev["p"] > 0], ev["t"][ev["p"] < 0]
    assert on.size >= 20 and off.size >= 1
    f_lit, f_dark = 3000.0 * (101 * i_dark / 1e-15 / saturation) ** exponent, 3000.0 * (i_dark / 1e-15 / saturation) ** exponent
    first = -np.log(1 - theta / np.log(101))
    assert (on[0] - t_on) * 1e-9 == pytest.approx(first / (2 * np.pi * f_lit), rel=0.05)
    # the memory sits ln 101 - n theta below the settled lit level: the first OFF needs that much more
    fall = theta + np.log(101) - on.size * theta
    assert (off[0] - t_off) * 1e-9 == pytest.approx(-np.log(1 - fall / np.log(101)) / (2 * np.pi * f_dark), rel=0.05)
    assert on[-1] < t_off                                      # the whole ON burst within the flash


@pytest.mark.parametrize("implementation", BOTH)
def test_hot_pixels_spread_the_rates_log_normally_around_the_configured_mean(scenes, implementation):
    # noise_rate_spread_decades: each pixel's leak and shot-noise rates carry a factor with
    # std(log10) = the spread and mean 1, so the array keeps the configured mean rate while a few
    # pixels are hot; each pixel's own counts follow its factor.
    fp, leak, r_n, dt, seconds, spread = scenes.focal_plane(24, 24), 30.0, 30.0, 2e-4, 1.0, 0.3
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, leak_rate_hz=leak,
                     shot_noise_rate_hz=r_n, parasitic_rate_per_lux_hz=0.0, noise_rate_spread_decades=spread,
                     seed=9, **PRESET_LIKE)
    _, ev = _rates(scenes, block, fp, 0.0, seconds, 0.5)
    scale = block.pixel_field("noise_scale").reshape(fp.shape)
    n = scale.size
    assert np.std(np.log10(scale)) == pytest.approx(spread, rel=4 / np.sqrt(2 * n))
    assert abs(scale.mean() - 1.0) < 4 * np.std(scale) / np.sqrt(n)
    on = scenes.counts_image(ev, fp, ev["p"] > 0)
    off = scenes.counts_image(ev, fp, ev["p"] < 0)
    assert _within(on.sum(), (leak + r_n) * seconds * scale.sum()) and _within(off.sum(), r_n * seconds * scale.sum())
    hot = scale > np.percentile(scale, 90)
    cold = scale < np.percentile(scale, 10)
    assert off[hot].mean() / off[cold].mean() == pytest.approx(scale[hot].mean() / scale[cold].mean(), rel=0.25)
    # without a spread every pixel has the configured rates
    plain = DvsPixel(implementation=implementation, time_step_s=dt, seed=9, **PRESET_LIKE)
    plain.step(Window.from_seconds(0, 0.01), irradiance=scenes.uniform(fp, [0], 0.0))
    assert np.all(plain.pixel_field("noise_scale") == 1.0)


@pytest.mark.parametrize("implementation", BOTH)
def test_timing_jitter_delays_events_half_normally_and_keeps_them_in_order(scenes, implementation):
    # Leak events of a static pixel come exactly every 1/R_leak on the grid; with timing_jitter_s
    # each is delayed by sigma |z|: mean sigma sqrt(2/pi), std sigma sqrt(1 - 2/pi), never early.
    # Events delayed past a window's end come in the next window; the windows do not matter.
    fp, leak, dt, sigma = scenes.focal_plane(12, 12), 100.0, 2e-5, 3e-4
    runs = {}
    for window in (0.1, 0.04):
        block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, leak_rate_hz=leak,
                         shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0,
                         timing_jitter_s=sigma, seed=4)
        outs = scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 1e4), 0.2, window)
        for out, w in zip(outs, range(len(outs))):
            assert np.all(np.diff(out.t_ns) >= 0) and np.all(out.t_ns < round((w + 1) * window * 1e9) + 1)
            assert out.counts_by_cause[EventCause.LEAK] == len(out)
        runs[window] = scenes.concat(outs)
    a, b = runs[0.1], runs[0.04]
    order_a, order_b = np.lexsort((a["x"], a["y"], a["t"])), np.lexsort((b["x"], b["y"], b["t"]))
    np.testing.assert_array_equal(a["t"][order_a], b["t"][order_b])
    reference = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, leak_rate_hz=leak,
                         shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0, seed=4)
    plain = scenes.concat(scenes.simulate(reference, lambda a_, b_: scenes.uniform(fp, [a_], 1e4), 0.2, 0.1))
    key = lambda e: e["y"].astype(np.int64) * 1000 + e["x"]        # noqa: E731  (pixel of each event)
    delays = []
    for pixel in np.unique(key(plain)):
        t0, t1 = plain["t"][key(plain) == pixel], np.sort(a["t"][key(a) == pixel])
        n = min(t0.size, t1.size) - 1                              # the last may fall past the run's end
        delays.append(t1[:n] - t0[:n])
    delays = np.concatenate(delays) * 1e-9
    assert delays.min() >= 0 and delays.size > 1500
    assert delays.mean() == pytest.approx(sigma * np.sqrt(2 / np.pi), rel=4 * 0.76 / np.sqrt(delays.size))
    assert delays.std() == pytest.approx(sigma * np.sqrt(1 - 2 / np.pi), rel=0.1)
