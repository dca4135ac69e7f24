"""The fast (event-driven) implementation against the reference (dense) one, and run-structure invariance.

Both implementations draw the same per-pixel thresholds and initial state from the seed
and differ only in the random numbers of the shot noise, so signal events, which are
deterministic given the thresholds, agree pixel by pixel; noise statistics agree within
their Poisson errors (four standard deviations).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy import stats

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import EventCause
from evsda.graph import RunInfo, Window

NOISY = dict(leak_rate_hz=3.0, shot_noise_rate_hz=3.0, parasitic_rate_per_lux_hz=1e-3)


def _poisson_close(a: int, b: int, sigmas: float = 4.0) -> bool:
    return abs(a - b) <= sigmas * np.sqrt(max(a + b, 1))


def _moving(scenes, fp, **kw):
    return lambda a, b: scenes.moving_spot(fp, scenes.grid(a, b, 10**6), **kw)


def _run_both(scenes, fp, irradiance, duration_s, window_s, **params):
    runs = {}
    for implementation in ("reference", "fast"):
        block = DvsPixel(implementation=implementation, **params)
        runs[implementation] = scenes.concat(scenes.simulate(block, irradiance, duration_s, window_s))
    return runs


@pytest.fixture(scope="module")
def moving_runs():
    """A spot crossing a 20x12 sensor with noise, in both implementations (shared by several tests)."""
    import sys
    scenes = sys.modules[[m for m in sys.modules if m.endswith("pixel.conftest")][0]]
    fp = scenes.focal_plane(20, 12)
    return fp, _run_both(scenes, fp, _moving(scenes, fp, velocity=(120.0, 0.0)), 0.15, 0.05,
                         time_step_s=1e-5, seed=11, **NOISY)


@pytest.mark.parametrize("form", ["small_signal", "large_signal"])
def test_signal_events_agree_pixel_by_pixel(scenes, form):
    # Without noise the event stream is deterministic given the thresholds, which both
    # implementations share: they must agree pixel by pixel (up to floating-point ties), with either filter form.
    fp = scenes.focal_plane(20, 12)
    runs = _run_both(scenes, fp, _moving(scenes, fp, velocity=(120.0, 20.0), start=(2.0, 3.0)), 0.15, 0.05,
                     time_step_s=1e-5, seed=4, leak_rate_hz=0.0, shot_noise_rate_hz=0.0, lowpass_form=form)
    signal = {k: scenes.counts_image(v, fp, v["cause"] == EventCause.SIGNAL) for k, v in runs.items()}
    lit = signal["reference"] > 0
    assert lit.sum() > 60
    assert np.mean(signal["reference"][lit] == signal["fast"][lit]) > 0.98
    assert np.abs(signal["reference"] - signal["fast"]).max() <= 1
    ref, fast = runs["reference"], runs["fast"]
    assert abs(ref["t"].size - fast["t"].size) <= 0.01 * ref["t"].size
    assert np.mean(np.isin(ref["t"] * 10**6 + ref["y"] * 1000 + ref["x"],
                           fast["t"] * 10**6 + fast["y"] * 1000 + fast["x"])) > 0.98     # same times too


def test_signal_counts_with_noise_agree(scenes, moving_runs):
    fp, runs = moving_runs
    signal = {k: scenes.counts_image(v, fp, v["cause"] == EventCause.SIGNAL) for k, v in runs.items()}
    lit = signal["reference"] > 0
    # a leak event moves the memory by a threshold and a shot event blinds the pixel for a
    # refractory period, either of which can add or remove a signal event; the two noise
    # realisations differ, but neither implementation may be biased
    diff = (signal["fast"] - signal["reference"])[lit]
    assert abs(diff.mean()) <= 4 * diff.std() / np.sqrt(diff.size)
    assert np.abs(diff).max() <= 4
    assert _poisson_close(int(runs["reference"]["counts"][0]), int(runs["fast"]["counts"][0]), 1.0)


def test_statistics_agree(moving_runs):
    _, runs = moving_runs
    ref, fast = runs["reference"], runs["fast"]
    for cause in EventCause:
        assert _poisson_close(int(ref["counts"][cause]), int(fast["counts"][cause])), cause.name
    for polarity in (1, -1):
        assert _poisson_close(int(np.sum(ref["p"] == polarity)), int(np.sum(fast["p"] == polarity)))
    assert _poisson_close(ref["n_loss"], fast["n_loss"])


def test_at_most_one_event_per_pixel_per_step(moving_runs):
    # Eq. 17 and the shot noise of Eq. 20 share one output per pixel and step
    fp, runs = moving_runs
    for run in runs.values():
        key = (run["t"] // 10_000) * (fp.width_px * fp.height_px) + run["y"].astype(np.int64) * fp.width_px + run["x"]
        assert np.unique(key).size == key.size
        assert run["n_loss"] > 0


def test_timing_distributions_agree(moving_runs):
    _, runs = moving_runs
    for cause in (EventCause.SIGNAL, EventCause.SHOT, EventCause.LEAK):
        a = runs["reference"]["t"][runs["reference"]["cause"] == cause]
        b = runs["fast"]["t"][runs["fast"]["cause"] == cause]
        assert stats.ks_2samp(a, b).pvalue > 1e-3, cause.name


@pytest.mark.parametrize("sigma", [0.03, 0.25])
def test_noise_rates_agree_including_extreme_threshold_mismatch(scenes, sigma):
    # sigma = 0.25 around 0.2 puts a fifth of the thresholds on the 0.01 floor
    fp = scenes.focal_plane(10, 10)
    runs = {}
    for implementation in ("reference", "fast"):
        block = DvsPixel(implementation=implementation, time_step_s=1e-4, threshold_sigma=sigma, seed=5,
                         **dict(NOISY, shot_noise_rate_hz=2.0))
        runs[implementation] = scenes.concat(scenes.simulate(
            block, lambda a, b: scenes.uniform(fp, scenes.grid(a, b, 10**7), 1e8), 1.0, 0.25))
    for cause in EventCause:
        assert _poisson_close(int(runs["reference"]["counts"][cause]), int(runs["fast"]["counts"][cause])), cause
    assert runs["fast"]["counts"][EventCause.SIGNAL] == 0


@pytest.mark.parametrize("implementation", ["fast", "reference"])
def test_thresholds_are_frozen_per_pixel_without_redraw(scenes, implementation):
    fp = scenes.focal_plane(10, 10)
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, seed=2, **NOISY)
    scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 1e8), 0.1, 0.1)
    before = block.pixel_field("theta_on"), block.pixel_field("theta_off")
    later = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 1e8), 0.5, 0.5))
    assert later["t"].size > 100
    np.testing.assert_array_equal(block.pixel_field("theta_on"), before[0])
    np.testing.assert_array_equal(block.pixel_field("theta_off"), before[1])
    assert 0.02 < before[0].std() < 0.04 and before[0].min() >= 0.01      # N(0.2, 0.03), floored


def test_threshold_redraw_agrees(scenes):
    fp = scenes.focal_plane(10, 10)
    runs, blocks = {}, {}
    for implementation in ("reference", "fast"):
        blocks[implementation] = block = DvsPixel(implementation=implementation, time_step_s=1e-4,
                                                  threshold_redraw=True, threshold_sigma=0.05, seed=2, **NOISY)
        runs[implementation] = scenes.concat(scenes.simulate(
            block, lambda a, b: scenes.uniform(fp, [a], 1e8), 1.0, 0.5))
    for cause in EventCause:
        assert _poisson_close(int(runs["reference"]["counts"][cause]), int(runs["fast"]["counts"][cause])), cause
    theta = blocks["fast"].pixel_field("theta_on")
    assert 0.03 < theta.std() < 0.07 and abs(theta.mean() - 0.2) < 0.02


@pytest.mark.parametrize("implementation", ["fast", "reference"])
def test_events_do_not_depend_on_the_window_length(scenes, implementation):
    fp = scenes.focal_plane(16, 10)
    step = 1e-5 if implementation == "fast" else 1e-4
    runs = []
    for window in (0.05, 0.1):
        block = DvsPixel(implementation=implementation, time_step_s=step, seed=3, **NOISY)
        runs.append(scenes.concat(scenes.simulate(block, _moving(scenes, fp, start=(0.0, 5.0), velocity=(80.0, 3.0)),
                                                  0.2, window)))
    for key in ("t", "x", "y", "p", "cause"):
        np.testing.assert_array_equal(runs[0][key], runs[1][key])
    assert runs[0]["n_loss"] == runs[1]["n_loss"]
    assert runs[0]["t"].size > 100


def test_events_do_not_depend_on_threads_or_chunk_room(scenes, monkeypatch):
    # The fast path runs chunks of pixels in threads and reruns the pixels of a chunk that ran
    # out of room for events; neither may change an event. Starting with room for only two
    # events per pixel of a chunk forces reruns along a bright spot's track.
    from evsda.blocks.pixel import eventdriven

    fp = scenes.focal_plane(24, 10)
    irradiance = _moving(scenes, fp, start=(0.0, 5.0), velocity=(100.0, 0.0), peak=3e6)
    runs = []
    for threads, room in ((1, 1024), (3, 1024), (2, 0)):
        monkeypatch.setenv("EVSDA_THREADS", str(threads))
        monkeypatch.setattr(eventdriven, "_FIRST_CAPACITY", room)
        block = DvsPixel(time_step_s=1e-5, seed=5, **NOISY)
        runs.append(scenes.concat(scenes.simulate(block, irradiance, 0.2, 0.1)))
    assert runs[0]["counts"][EventCause.SIGNAL] > 200
    for run in runs[1:]:
        for key in ("t", "x", "y", "p", "cause"):
            np.testing.assert_array_equal(run[key], runs[0][key])
        assert run["n_loss"] == runs[0]["n_loss"]


@pytest.mark.parametrize("implementation", ["fast", "reference"])
def test_killed_and_resumed_run_is_identical(scenes, implementation):
    fp = scenes.focal_plane(12, 8)
    irradiance = _moving(scenes, fp, start=(0.0, 4.0), velocity=(60.0, 0.0))
    windows = [Window.from_seconds(w * 0.05, (w + 1) * 0.05, index=w) for w in range(4)]
    kw = dict(implementation=implementation, time_step_s=1e-5 if implementation == "fast" else 1e-4, seed=9, **NOISY)

    whole = DvsPixel(**kw)
    whole.setup(RunInfo(duration_ns=200_000_000, window_ns=50_000_000, seed=9))
    expected = [whole.step(w, irradiance=irradiance(w.start_ns, w.stop_ns))["events"] for w in windows]

    first = DvsPixel(**kw)
    first.setup(RunInfo(duration_ns=200_000_000, window_ns=50_000_000, seed=9))
    for w in windows[:2]:
        first.step(w, irradiance=irradiance(w.start_ns, w.stop_ns))
    checkpoint = copy.deepcopy(first.get_state())          # what a checkpoint store writes and reads back
    del first

    resumed = DvsPixel(**kw)
    resumed.setup(RunInfo(duration_ns=200_000_000, window_ns=50_000_000, seed=9))
    resumed.set_state(checkpoint)
    for w, want in zip(windows[2:], expected[2:]):
        got = resumed.step(w, irradiance=irradiance(w.start_ns, w.stop_ns))["events"]
        for name in ("t_ns", "x", "y", "p", "cause"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert got.n_loss == want.n_loss and got.counts_by_cause == want.counts_by_cause


@pytest.mark.parametrize("form", ["small_signal", "large_signal"])
def test_changing_background_agrees(scenes, form):
    # The uniform background brightens in steps (every pixel's input changes) while a spot
    # moves: the fast path's every-pixel route against the reference, pixel by pixel.
    fp = scenes.focal_plane(12, 9)

    def irradiance(a, b):
        t = scenes.grid(a, b, 10**6)
        spot = scenes.moving_spot(fp, t, velocity=(60.0, 0.0), start=(1.0, 4.0))
        background = 2e3 * np.exp(np.floor(t / 2e7) * 0.07)           # +7% every 20 ms
        return type(spot)(fp, spot.wavelength_m, t, background, spot.stamp_origin, spot.stamp_flux)

    runs = _run_both(scenes, fp, irradiance, 0.15, 0.05, time_step_s=1e-5, seed=8, leak_rate_hz=0.0,
                     shot_noise_rate_hz=0.0, lowpass_form=form)
    images = {k: scenes.counts_image(v, fp) for k, v in runs.items()}
    assert images["reference"].sum() > 300
    assert np.mean(images["reference"] == images["fast"]) > 0.98
    assert np.abs(images["reference"] - images["fast"]).max() <= 1
