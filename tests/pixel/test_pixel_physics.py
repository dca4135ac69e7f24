"""The pixel's equations one by one (paper Eq. 12-21), against analytic results and published numbers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import constants, stats

from evsda.blocks.pixel import counter_rng, crossing, dark_current, lowpass, noise, photoreceptor
from evsda.blocks.pixel.refractory import refractory_steps

from .conftest import CROSSING_HORIZON_STEPS, crossing_cases, first_hits


def test_responsivity_matches_the_papers_shortcut():
    # Eq. 12: R = eta q lambda / (h c) ~ eta lambda[um] / 1.23985
    for eta, wl in [(1.0, 1.23985e-6), (0.6, 550e-9), (0.35, 900e-9)]:
        assert photoreceptor.responsivity_A_per_W(eta, wl) == pytest.approx(eta * wl * 1e6 / 1.23985, rel=1e-5)  # hc/q = 1.239842 um V


def test_photocurrent_is_one_charge_per_detected_photon():
    # Eq. 12-13 together: I = R * N h c / lambda = eta q N
    flux, eta, wl = 3.7e5, 0.6, 640e-9
    power = photoreceptor.optical_power_W(flux, wl)
    assert power == pytest.approx(flux * constants.h * constants.c / wl)
    current = photoreceptor.photocurrent_A(power, photoreceptor.responsivity_A_per_W(eta, wl))
    assert current == pytest.approx(eta * constants.e * flux, rel=1e-12)


def test_lin_log_is_continuous_at_the_knee_and_logarithmic_above():
    knee = 5.0
    x = np.array([0.0, 1.0, 4.999999, 5.0, 5.000001, 50.0, 1e6])
    y = photoreceptor.lin_log(x, knee)
    assert y[0] == 0.0
    assert y[1] == pytest.approx(np.log(5) / 5)                # Eq. 14 slope ln(5)/5
    assert y[2] == pytest.approx(np.log(5), abs=1e-6)          # the pieces meet at x = 5
    assert y[4] == pytest.approx(np.log(5), abs=1e-6)
    np.testing.assert_allclose(y[5:], np.log(x[5:]))
    assert np.all(np.diff(photoreceptor.lin_log(np.linspace(0, 20, 1001), knee)) > 0)


def test_dark_current_follows_arrhenius_and_scales_with_area():
    ea, t_ref, density = 0.56, 300.0, 1e-5
    assert dark_current.dark_current_A(t_ref, density, 2e-11, t_ref, ea) == pytest.approx(2e-16)
    ratio = dark_current.dark_current_A(290.0, density, 2e-11, t_ref, ea) / dark_current.dark_current_A(
        300.0, density, 2e-11, t_ref, ea)
    k_ev = constants.k / constants.e
    assert ratio == pytest.approx(np.exp(-ea / k_ev * (1 / 290 - 1 / 300)), rel=1e-12)
    assert 0.45 < ratio < 0.5                                    # ~halved by 10 K of cooling at E_a = E_g/2
    half = dark_current.halving_cooling_K(300.0, ea)
    assert half == pytest.approx(9.6, abs=0.1)
    assert dark_current.dark_current_A(300 - half, density, 1.0, t_ref, ea) == pytest.approx(density / 2, rel=0.04)


def test_paper_cutoff_law_and_its_cap():
    # Eq. 16: f = (Y + 3) / 5.616 f_max, capped at f_max
    f = lowpass.cutoff_hz(0.0, np.array([0.0, 1.0, 2.616, 5.54]), 3000.0, "paper")
    np.testing.assert_allclose(f, [3000 * 3 / 5.616, 3000 * 4 / 5.616, 3000.0, 3000.0])


def test_proportional_cutoff_law():
    f = lowpass.cutoff_hz(np.array([0.0, 27.5, 275.0, 1e4]), 0.0, 3000.0, "proportional", saturation=275.0)
    np.testing.assert_allclose(f, [0.0, 300.0, 3000.0, 3000.0])
    with pytest.raises(ValueError):
        lowpass.cutoff_hz(1.0, 1.0, 3000.0, "other")


def test_power_cutoff_law():
    # f = f_max min(1, (x / x_sat)^n): a square root gives a tenth of f_max at a hundredth of the saturation current
    f = lowpass.cutoff_hz(np.array([0.0, 2.75, 275.0, 1e4]), 0.0, 3000.0, "power", saturation=275.0, exponent=0.5)
    np.testing.assert_allclose(f, [0.0, 300.0, 3000.0, 3000.0])
    # exponent 1 is the proportional law
    x = np.array([1.0, 50.0, 500.0])
    np.testing.assert_allclose(lowpass.cutoff_hz(x, 0.0, 3000.0, "power", 275.0, 1.0),
                               lowpass.cutoff_hz(x, 0.0, 3000.0, "proportional", 275.0))


def test_discrete_filter_converges_to_the_one_pole_response():
    # Eq. 16's backward-Euler filter tends to 1 - exp(-2 pi f t) as the step shrinks
    f, t_end = 200.0, 2e-3
    exact = 1 - np.exp(-2 * np.pi * f * t_end)
    errors = []
    for dt in [1e-4, 1e-5, 1e-6]:
        eps = lowpass.filter_gain(f, dt)
        n = round(t_end / dt)
        response = 1 - np.exp(n * lowpass.log_retention(eps))
        errors.append(abs(response - exact))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3
    assert lowpass.filter_gain(np.inf, 1e-6) == 1.0


def test_leak_drift_gives_the_configured_rate():
    # Eq. 18 (as v2e): drift R theta_ON per second, so one threshold per 1/R seconds
    theta, rate = 0.23, 0.1
    assert theta / noise.leak_drift_per_s(rate, theta) == pytest.approx(1 / rate)


def test_parasitic_rate_is_linear_in_illuminance():
    # Eq. 19: 1 W on 1 m^2 at 680 lm/W is 680 lx
    assert noise.illuminance_lux(1.0, 1.0) == pytest.approx(680.0)
    assert noise.parasitic_rate_hz(noise.illuminance_lux(2e-12, 25e-12), 0.01) == pytest.approx(0.544)


def test_shot_noise_rate_between_dark_and_bright():
    # Eq. 20: R_n in the dark, F R_n at I_max, clipped beyond
    y = np.array([0.0, 2.77, 5.54, 20.0])
    np.testing.assert_allclose(noise.shot_noise_rate_hz(y, 4.0, 0.25, 5.54), [4.0, 2.5, 1.0, 1.0])


def test_refractory_steps_follow_eq_21():
    assert refractory_steps(0, 1000) == 1            # one event per pixel per step at least
    assert refractory_steps(1000, 1000) == 1
    assert refractory_steps(1001, 1000) == 2
    assert refractory_steps(100_000, 1000) == 100


def test_counter_random_numbers_are_uniform_and_independent():
    u = counter_rng.uniform_open(42, 1, np.arange(200_000), 0)
    assert u.min() > 0 and u.max() <= 1
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    v = counter_rng.uniform_open(42, 1, 7, np.arange(200_000))              # along the counter
    assert stats.kstest(v, "uniform").pvalue > 1e-3
    assert abs(np.corrcoef(v[:-1], v[1:])[0, 1]) < 0.01
    w = counter_rng.uniform_open(42, 2, np.arange(200_000), 0)              # another stream
    assert abs(np.corrcoef(u, w)[0, 1]) < 0.01
    z = counter_rng.normal(42, 3, np.arange(200_000), 5)
    assert stats.kstest(z, "norm").pvalue > 1e-3
    np.testing.assert_array_equal(counter_rng.hash64(1, 2, [3, 4], 5), counter_rng.hash64(1, 2, [3, 4], 5))


def test_first_crossing_matches_stepping():
    c, d, log_a, delta, th_on, th_off, j0, horizon = crossing_cases(1, 5000, 0.2, 0.5, 0.8)
    # large=False passed as a runtime bool, as the pixel kernels pass it: omitted, Numba would compile a second
    # specialisation of the whole search (Literal False) for this test alone
    j, pol = crossing.first_crossing(j0, c, d, log_a, delta, th_on, th_off, horizon, False)
    steps = np.arange(1, CROSSING_HORIZON_STEPS + 1)
    g = c[:, None] + d[:, None] * np.exp(steps[None] * log_a[:, None]) + delta[:, None] * steps[None]
    found, first = first_hits(g, th_on, th_off, j0, horizon)
    np.testing.assert_array_equal(j[found], first[found])
    polarity = np.where(g[np.arange(len(g)), first - 1] >= th_on, 1, -1)
    np.testing.assert_array_equal(pol[found], polarity[found])
    assert np.all(j[~found] >= crossing.NEVER)


def test_comparator_counts_thresholds_towards_zero_and_forgives_rounding():
    # Eq. 17: Ne_total = dI / theta rounded towards zero; a change of exactly k thresholds gives k
    # events whether L - M lands on k theta or one ulp short of it
    from evsda.blocks.pixel.comparator import events_possible
    theta = 0.2
    delta = np.array([0.0, 0.19, 0.2, 0.41, -0.39, -0.61, np.nextafter(-0.2, 0.0), np.nextafter(0.2, 0.0)])
    np.testing.assert_array_equal(events_possible(delta, theta, theta), [0, 0, 1, 2, -1, -3, -1, 1])
    assert events_possible(np.array([0.2 - 1e-6]), theta, theta)[0] == 0
