"""The pixel model where it is comparable with v2e (Hu, Liu & Delbruck 2021, CVPR Workshops; SensorsINI/v2e).

The paper takes Eqs. 14, 16, 18 and 20 from v2e. v2e's formulas are transcribed here from
its source, ``v2ecore/emulator_utils.py`` (``lin_log``, ``low_pass_filter``,
``subtract_leak_current``, ``generate_shot_noise``), and the block must reproduce them where
the two models coincide:

* lin-log (Eq. 14): identical, with v2e's knee of 20 in place of the paper's 5;
* leak (Eq. 18): v2e lowers the memory by ``dt R_leak theta_ON`` per step, so a static pixel
  fires ON events exactly every ``1/R_leak`` (no jitter: ``leak_jitter_fraction = 0``);
* shot noise (Eq. 20): v2e's ``shot_noise_rate_hz`` is the ON + OFF rate in the dark, a
  probability ``(R/2) dt`` per polarity and step: evsda's ``shot_noise_rate_hz`` is ``R/2``;
* cutoff (Eq. 16, ``cutoff_model='proportional'``): v2e's bandwidth is proportional to the
  intensity, ``eps = (DN + 20)/275 dt 2 pi f_3dB`` (forward Euler); evsda uses the paper's
  backward-Euler gain ``w / (1 + w)`` of the same ``w``, equal to first order in ``dt``.

Where they differ (v2e applies Eq. 20 to the linear intensity ``(DN + 20)/275``, the paper
to the lin-log value over ``I_max = ln 255``; v2e scales the shot-noise probability by the
pixel's nominal/actual threshold ratio) evsda follows the paper.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import constants

from evsda.blocks.pixel import DvsPixel, photoreceptor
from evsda.blocks.ports import EventCause

BOTH = ["reference", "fast"]
CLEAN = dict(leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0,
             dark_current_density_A_m2=0.0)


def v2e_lin_log(x, threshold=20.0):
    """v2e ``lin_log`` (without its 1e-8 rounding): linear below ``threshold``, ``ln x`` above."""
    x = np.asarray(x, dtype=float)
    return np.where(x <= threshold, x * math.log(threshold) / threshold, np.log(np.maximum(x, threshold)))


def test_lin_log_is_v2es_with_its_knee():
    x = np.concatenate([np.linspace(0, 40, 4001), np.logspace(1, 6, 200)])
    np.testing.assert_allclose(photoreceptor.lin_log(x, knee=20.0), v2e_lin_log(x), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("implementation", BOTH)
def test_leak_events_are_periodic_at_the_leak_rate(scenes, implementation):
    # v2e subtract_leak_current: M -= dt R_leak theta_ON each step -> one ON event every 1/R_leak
    fp, rate, dt = scenes.focal_plane(4, 3), 20.0, 1e-4
    block = DvsPixel(implementation=implementation, time_step_s=dt, seed=6,
                     **dict(CLEAN, leak_rate_hz=rate, threshold_sigma=0.03))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 1e5), 0.5, 0.1))
    assert np.all(ev["p"] == 1) and np.all(ev["cause"] == EventCause.LEAK)
    period_steps = round(1 / (rate * dt))
    for pixel in range(fp.width_px * fp.height_px):
        mine = (ev["y"].astype(int) * fp.width_px + ev["x"]) == pixel
        gaps = np.diff(ev["t"][mine]) // round(dt * 1e9)
        assert gaps.size == 9 and np.all(np.abs(gaps - period_steps) <= 1)


@pytest.mark.parametrize("implementation", BOTH)
def test_shot_noise_rate_is_half_of_v2es_parameter(scenes, implementation):
    # v2e generate_shot_noise in the dark: ON and OFF each with probability (R_v2e / 2) dt per step.
    # evsda's shot events leave the memory alone (no rebound) and blind the pixel for k steps:
    # cycles of 1/q - 1 + k steps, one event each, q = R_v2e dt.
    fp, r_v2e, dt, k, seconds = scenes.focal_plane(8, 8), 40.0, 1e-4, 1, 1.0
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt, seed=2,
                     **dict(CLEAN, shot_noise_rate_hz=r_v2e / 2))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 0.0), seconds, 0.5))
    q = r_v2e * dt
    expected = fp.width_px * fp.height_px * seconds / ((1 / q - 1 + k) * dt)
    assert abs(ev["t"].size - expected) < 4 * np.sqrt(expected)


def v2e_first_event_latency(x0, x1, theta, cutoff_hz, dt, saturation=275.0):
    """Filter updates until the first ON event after a step ``x0 -> x1`` through v2e's ``low_pass_filter``."""
    eps = min(x1 / saturation * dt * 2 * math.pi * cutoff_hz, 1.0)     # v2e: inten01 (delta_time / tau)
    y0, y1 = math.log(x0), math.log(x1)
    # L_n - M = (y1 - y0) (1 - (1 - eps)^n) >= theta
    return math.ceil(math.log(1 - theta / (y1 - y0)) / math.log(1 - eps))


@pytest.mark.parametrize("implementation", BOTH)
@pytest.mark.parametrize("dt", [1e-6, 1e-5])
def test_proportional_cutoff_follows_v2es_filter(scenes, implementation, dt):
    # The same step through v2e's forward-Euler filter and evsda's backward-Euler one: the
    # latencies agree to first order in w = 2 pi f dt (here w <= 0.02).
    fp, theta, f_max = scenes.focal_plane(1, 1), 0.2, 3000.0
    x0, x1 = 60.0, 60.0 * math.exp(0.5)                            # normalised currents, log branch
    to_flux = 1e-15 / (0.6 * constants.e)
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt,
                     cutoff_model="proportional", cutoff_saturation=275.0, cutoff_max_hz=f_max,
                     threshold_on=theta, **CLEAN)
    ev = scenes.concat(scenes.simulate(
        block, lambda a, b: scenes.uniform(fp, [0, 1_000_000], [x0 * to_flux, x1 * to_flux]), 0.01, 0.01))
    ours = (ev["t"][0] - 1_000_000) / round(dt * 1e9) + 1          # filter updates: the first at the change
    v2e = v2e_first_event_latency(x0, x1, theta, f_max, dt)
    w = 2 * math.pi * f_max * x1 / 275.0 * dt
    assert abs(ours - v2e) <= 1 + w * v2e                         # rounding of either, plus O(w)
    assert ev["t"].size == int(0.5 / theta)
