"""The large-signal photoreceptor (``lowpass_form: large_signal``) against the circuit's ODE, and its paths.

Reference nobody here wrote: the first-order logarithmic photoreceptor (Delbruck & Mead 1994),
``C dV/dt = I - I_0 e^V``, integrated by SciPy's ``solve_ivp``. With the ``proportional`` cutoff law
(``2 pi f = k x``, below its cap) the large-signal filter is that ODE discretised; its events must
come when the ODE's ``V`` has moved by the thresholds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evsda.blocks.pixel import DvsPixel, crossing, lowpass
from evsda.blocks.pixel.model import PixelModel

from .conftest import (CROSSING_HORIZON_STEPS, PITCH_M, WAVELENGTH_M, concat, crossing_cases, first_hits,
                       focal_plane, simulate, uniform)

QUIET = dict(leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0,
             refractory_period_s=0.0, dark_current_density_A_m2=0.0)
STEP_S = 0.01                  # the input steps at 10 ms [s]


def _step_run(implementation: str, before: float, after: float, form: str = "large_signal", **params):
    """A 1 x 1 pixel under ``before`` photons/s, then ``after`` from :data:`STEP_S` on; its events (dict)."""
    fp = focal_plane(1, 1)
    block = DvsPixel(implementation=implementation, lowpass_form=form, seed=2, **{**QUIET, **params})

    def irradiance(a, b):
        t = np.array([a, max(a, round(STEP_S * 1e9))], dtype=np.int64)
        return uniform(fp, t, [before if a < STEP_S * 1e9 else after, after])

    return concat(simulate(block, irradiance, 0.03, 0.015)), block


def _ode_crossings(block: DvsPixel, before: float, after: float, n_events: int) -> np.ndarray:
    """Times after the step [s] at which the ODE's V has moved 1, 2, ... thresholds from its settled value."""
    model = PixelModel(block.params, PITCH_M**2, WAVELENGTH_M)
    x0, x1 = model.normalised_current(np.array([before, after]))
    k = 2 * np.pi * block.params.cutoff_max_hz / block.params.cutoff_saturation      # 2 pi f = k x [s^-1]
    theta = block.params.threshold_on if x1 > x0 else block.params.threshold_off
    sign = 1.0 if x1 > x0 else -1.0
    # C dV/dt = I - I_0 e^V in the pixel's units: dV/dt = k (x1 - e^V), V(0) = ln x0
    levels = np.log(x0) + sign * theta * np.arange(1, n_events + 1)
    events = [lambda t, v, lv=lv: v[0] - lv for lv in levels]
    sol = solve_ivp(lambda t, v: [k * (x1 - np.exp(v[0]))], (0.0, 0.02), [np.log(x0)], events=events,
                    rtol=1e-10, atol=1e-12, method="LSODA")
    return np.array([e[0] if e.size else np.inf for e in sol.t_events])


@pytest.mark.parametrize("before, after", [(2e7, 2e5), (2e5, 2e7)])
def test_large_signal_events_follow_the_photoreceptor_ode(before, after):
    # A 100x step down and up. Cutoff 3 kHz at the bright level, 30 Hz at the dim one (proportional law, no
    # dark current): on the falling step the first OFF events come at the bright speed (~10 us apart) although
    # the pixel now has a 30 Hz cutoff, as the ODE's V does; both implementations, within the backward-Euler
    # error (2 pi dt f <= 1.9 %) and one step of the 1 us grid.
    params = dict(cutoff_model="proportional", cutoff_max_hz=3000.0, time_step_s=1e-6)
    model = PixelModel(DvsPixel(**params).params, PITCH_M**2, WAVELENGTH_M)
    params["cutoff_saturation"] = float(model.normalised_current(np.array([max(before, after)]))[0])
    for implementation in ("fast", "reference"):
        events, block = _step_run(implementation, before, after, **params)
        after_step = events["t"] >= STEP_S * 1e9
        t = (events["t"][after_step] - STEP_S * 1e9) * 1e-9
        expected_sign = 1 if after > before else -1
        assert np.all(events["p"][after_step] == expected_sign)
        ode = _ode_crossings(block, before, after, t.size)
        assert t.size >= 20 and np.all(np.isfinite(ode))    # ln 100 / 0.2 = 23.03: the last near the asymptote
        assert np.all(np.abs(t - ode) <= 2e-6 + 0.02 * ode), (implementation, t[:5], ode[:5])
    if after < before:
        assert t[0] < 20e-6               # the first OFF at the bright speed: 1/(2 pi 30 Hz) = 5.3 ms would be small-signal
        small, _ = _step_run("fast", before, after, form="small_signal", **params)
        first_small = (small["t"][small["t"] >= STEP_S * 1e9].min() - STEP_S * 1e9) * 1e-9
        assert first_small > 10 * t[0]


def test_large_signal_filter_is_the_small_signal_filter_near_equilibrium():
    # Small steps: the two forms agree to second order in the step (Eq. 16 is the linearisation).
    y, eps = 1.3, 0.02
    for d in (1e-3, -1e-3):
        small = y + (1 - eps) * d
        large = lowpass.large_signal_step(y + d, y, eps)
        assert abs(large - small) < 2 * d**2


def test_crossing_search_matches_stepping_the_large_signal_filter():
    # The closed-form search (crossing.py) against g(j) stepped in w = exp(-L) with NumPy, random cases.
    c, d, log_a, delta, th_on, th_off, j0, horizon = crossing_cases(3, 4000, 0.3, 2.0, 0.85)
    j, pol = crossing.first_crossing(j0, c, d, log_a, delta, th_on, th_off, horizon, True)
    steps = np.arange(1, CROSSING_HORIZON_STEPS + 1)
    # w_j / w_inf = 1 + (exp(-D) - 1) a^j  (e^-L relaxing to e^-Y)
    with np.errstate(divide="ignore", invalid="ignore"):
        decay = np.where(np.isinf(log_a)[:, None], 0.0, np.exp(steps[None] * log_a[:, None]))
    relax = -np.log1p(np.expm1(-d)[:, None] * decay)
    g = c[:, None] + relax + delta[:, None] * steps[None]
    found, first = first_hits(g, th_on, th_off, j0, horizon)
    # ties within rounding of a threshold may fall either side: allow one step where g is that close
    near = np.abs(np.minimum(np.abs(g - th_on[:, None]), np.abs(g + th_off[:, None]))) < 1e-12
    exact = j[found] == first[found]
    assert np.mean(exact) > 0.999 and np.all(exact | near[found].any(axis=1))
    polarity = np.where(g[np.arange(len(g)), first - 1] >= th_on, 1, -1)
    assert np.mean(pol[found] == polarity[found]) > 0.999
    assert np.all(j[~found] >= crossing.NEVER)


@pytest.mark.parametrize("before, after, params", [
    (1e14, 0.0, dict(dark_current_density_A_m2=1e-9)),                   # 1e9 x step down onto a faint dark current
    (0.0, 1e14, dict(dark_current_density_A_m2=1e-9)),                   # and up
    (1e12, 0.0, dict(cutoff_model="power", cutoff_saturation=1e12, cutoff_exponent=2.0)),   # dark cutoff ~ 1e-30 Hz
    (1e9, 0.0, dict(dark_current_density_A_m2=0.0, knee_at_dark_current=False)),   # no dark current: the linear knee
])
def test_large_signal_stays_finite_on_hard_cases(before, after, params):
    # Huge steps, a vanishing dark-pixel cutoff (e^-L nearly frozen while its target moves by e^20), a pixel with no
    # dark current at all: no NaN, no overflow, events in order, and both implementations make the same events.
    runs = {}
    for implementation in ("fast", "reference"):
        with np.errstate(all="raise"):
            events, block = _step_run(implementation, before, after, **{**params, "time_step_s": 1e-5})
        runs[implementation] = events
        assert np.all(np.diff(events["t"]) >= 0)
        state = block.pixel_field("filtered") if implementation == "fast" else block.pixels["filtered"]
        assert np.all(np.isfinite(state))
    for key in ("t", "p"):
        np.testing.assert_array_equal(runs["fast"][key], runs["reference"][key])
