"""The dvs_pixel block against analytic predictions of the paper's model, in both implementations.

Scenes are synthetic ``Irradiance`` values. Where the prediction is exact (deterministic
leak, a contrast step, a decaying current) the tests demand it exactly; where it is a rate
they allow four standard deviations of the counting error.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy import constants

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.params import DvsPixelParams
from evsda.blocks.ports import EventCause
from evsda.graph import InputError, ParameterError, Window

BOTH = ["reference", "fast"]
QUIET = dict(leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0)
CLEAN = dict(QUIET, threshold_sigma=0.0, dark_current_density_A_m2=0.0)


def test_every_parameter_states_its_unit():
    for name, field in DvsPixelParams.model_fields.items():
        assert field.description and field.description.rstrip().endswith("]"), name
        assert "[" in field.description, name


@pytest.mark.parametrize("bad", [dict(leak_rate_hz=-1.0), dict(implementation="gpu"), dict(temperature_K=0.0),
                                 dict(time_step_s=1e-3, shot_noise_rate_hz=600.0), dict(time_step_s=1e-10),
                                 dict(quantum_efficiency=1.5)])
def test_bad_parameters_are_refused_in_one_sentence(bad):
    with pytest.raises(ParameterError, match="dvs_pixel parameter"):
        DvsPixel(**bad)


def test_input_mistakes_are_refused(scenes):
    fp = scenes.focal_plane(4, 4)
    block = DvsPixel(**QUIET)
    with pytest.raises(InputError, match="negative or non-finite"):
        block.step(Window.from_seconds(0, 0.01), irradiance=scenes.uniform(fp, [0], -1.0))
    block = DvsPixel(**QUIET)
    block.step(Window.from_seconds(0, 0.01), irradiance=scenes.uniform(fp, [0], 1e3))
    with pytest.raises(InputError, match="focal plane"):
        block.step(Window.from_seconds(0.01, 0.02), irradiance=scenes.uniform(scenes.focal_plane(5, 4), [0], 1e3))


@pytest.mark.parametrize("implementation", BOTH)
def test_constant_light_without_noise_gives_no_events(scenes, implementation):
    fp = scenes.focal_plane(6, 5)
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, **QUIET)
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, scenes.grid(a, b, 10**6), 5e4),
                                       0.3, 0.1))
    assert ev["t"].size == 0 and ev["n_loss"] == 0


@pytest.mark.parametrize("implementation", BOTH)
def test_junction_leak_rate(scenes, implementation):
    # Eq. 18: every static pixel emits ON leak events at R_leak (uniform initial phases)
    fp, rate, seconds = scenes.focal_plane(8, 8), 10.0, 1.0
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, **dict(QUIET, leak_rate_hz=rate))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 3e4), seconds, 0.25))
    n = fp.width_px * fp.height_px
    assert abs(ev["t"].size - n * rate * seconds) <= 4 * np.sqrt(n / 4)     # each pixel: floor(U + R T)
    assert np.all(ev["cause"] == EventCause.LEAK) and np.all(ev["p"] == 1)
    per_pixel = scenes.counts_image(ev, fp)
    assert per_pixel.min() >= rate * seconds - 1 and per_pixel.max() <= rate * seconds + 1


@pytest.mark.parametrize("implementation", BOTH)
def test_parasitic_rate_follows_illuminance(scenes, implementation):
    # Eq. 19: R_para = M_v f_para with M_v = Phi eta_v / A
    fp, flux, per_lux, seconds = scenes.focal_plane(8, 8), 1e9, 1e-3, 1.0
    power = flux * constants.h * constants.c / scenes.WAVELENGTH_M
    rate = power * 680.0 / scenes.PITCH_M**2 * per_lux
    block = DvsPixel(implementation=implementation, time_step_s=1e-4,
                     **dict(QUIET, parasitic_rate_per_lux_hz=per_lux))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], flux), seconds, 0.5))
    n = fp.width_px * fp.height_px
    assert abs(ev["t"].size - n * rate * seconds) <= 4 * np.sqrt(n / 4)
    assert np.all(ev["cause"] == EventCause.PARASITIC)


@pytest.mark.parametrize("implementation", BOTH)
def test_shot_noise_rate_with_refractory_and_no_rebound(scenes, implementation):
    # Eq. 20 in the dark (I = 0): each step an ON and an OFF trial of probability R_n dt. A shot
    # event leaves the memory alone (no rebound event) and blinds the pixel for k steps, during
    # which trials are lost: a pixel cycles with mean length 1/q - 1 + k steps (q = 2 R_n dt),
    # one SHOT event per cycle, ON and OFF alike.
    fp, r_n, dt, k, seconds = scenes.focal_plane(8, 8), 20.0, 1e-4, 3, 1.0
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt,
                     **dict(CLEAN, shot_noise_rate_hz=r_n))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 0.0), seconds, 0.5))
    q = 2 * r_n * dt
    expected = fp.width_px * fp.height_px * seconds / ((1 / q - 1 + k) * dt)
    assert abs(ev["t"].size - expected) < 4 * np.sqrt(expected)
    assert np.all(ev["cause"] == EventCause.SHOT)
    on, off = int(np.sum(ev["p"] > 0)), int(np.sum(ev["p"] < 0))
    assert abs(on - off) < 4 * np.sqrt(on + off)
    assert abs(ev["n_loss"] - expected * 2 * r_n * dt * (k - 1)) < 4 * np.sqrt(expected * q * (k - 1))


@pytest.mark.parametrize("implementation", BOTH)
def test_constant_light_gives_no_signal_events_and_balanced_drift(scenes, implementation):
    # All noise on: nothing is charged to SIGNAL, and the net ON - OFF count equals the
    # thresholds the leak currents drifted through (the memory stays within a threshold band).
    fp, seconds, leak = scenes.focal_plane(8, 8), 1.0, 4.0
    flux, per_lux = 2e8, 1e-3
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, threshold_sigma=0.0, leak_rate_hz=leak,
                     shot_noise_rate_hz=5.0, parasitic_rate_per_lux_hz=per_lux)
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, scenes.grid(a, b, 10**6), flux),
                                       seconds, 0.25))
    assert ev["counts"][EventCause.SIGNAL] == 0
    assert ev["counts"][EventCause.SHOT] > 0 and ev["counts"][EventCause.LEAK] > 0
    power = flux * constants.h * constants.c / scenes.WAVELENGTH_M
    drift_rate = leak + power * 680.0 / scenes.PITCH_M**2 * per_lux
    n = fp.width_px * fp.height_px
    net = int(np.sum(ev["p"] > 0)) - int(np.sum(ev["p"] < 0))
    assert abs(net - n * drift_rate * seconds) <= 2 * n


@pytest.mark.parametrize("implementation", BOTH)
def test_contrast_step_gives_eq_17_events_and_n_loss(scenes, implementation):
    # A step of contrast C with no filter: floor(C/theta) ON events, one per refractory
    # period; Eq. 17's backlog N_loss = N-1, N-2, ... is owed and then emitted, so nothing is
    # lost (the paper's per-comparison sum would report 4 + 3 + 2 + 1); stepping back gives the
    # same number of OFF events.
    fp, theta, dt, k = scenes.focal_plane(3, 2), 0.2, 1e-5, 5
    contrast = 1.07                                             # 5 thresholds and a remainder
    low = 1e5
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt,
                     cutoff_max_hz=0.0, threshold_on=theta, threshold_off=theta, **CLEAN)
    t = np.array([0, 2_000_000, 6_000_000])
    flux = np.array([low, low * np.exp(contrast), low])
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, t, flux), 0.01, 0.005))
    n_pix, n = fp.width_px * fp.height_px, int(contrast / theta)
    on, off = ev["p"] > 0, ev["p"] < 0
    assert on.sum() == n * n_pix and off.sum() == n * n_pix
    assert np.all(ev["cause"] == EventCause.SIGNAL)
    expected_times = 2_000_000 + np.arange(n) * k * 10_000
    np.testing.assert_array_equal(np.unique(ev["t"][on]), expected_times)
    np.testing.assert_array_equal(np.unique(ev["t"][off]), 6_000_000 + np.arange(n) * k * 10_000)
    assert ev["n_loss"] == 0


@pytest.mark.parametrize("implementation", BOTH)
def test_a_pulse_shorter_than_its_events_loses_the_rest(scenes, implementation):
    # Eq. 17 "potential data loss": a pulse of 5 thresholds that ends after 2 refractory periods.
    # The pixel emits ON at the step and one refractory period later (2 events); at its next
    # comparison the input is back, Ne_total is -2, and the 3 ON events it still owed are lost.
    # The 2 OFF events that bring the memory back are emitted.
    fp, theta, dt, k = scenes.focal_plane(2, 1), 0.2, 1e-5, 5
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt,
                     cutoff_max_hz=0.0, threshold_on=theta, threshold_off=theta, **CLEAN)
    t = np.array([0, 1_000_000, 1_000_000 + 2 * k * 10_000 - 10_000])       # back one step before the 3rd event
    flux = np.array([1e5, 1e5 * np.exp(1.07), 1e5])
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, t, flux), 0.01, 0.005))
    assert int(np.sum(ev["p"] > 0)) == 2 * 2 and int(np.sum(ev["p"] < 0)) == 2 * 2
    assert ev["n_loss"] == 2 * 3


@pytest.mark.parametrize("implementation", BOTH)
def test_linear_knee_prevents_spurious_off_events_of_a_decaying_current(scenes, implementation):
    # Paper Fig. 5a: a current decaying to zero. With Eq. 14's linear piece the pixel emits
    # floor((Y_start - Y_end) / theta) OFF events; a pure log response would keep firing as
    # ln(x) -> -inf (here 79 events instead of 19).
    fp, theta = scenes.focal_plane(2, 2), 0.2
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, cutoff_max_hz=0.0, threshold_on=theta,
                     threshold_off=theta, reference_current_A=1e-15, **CLEAN)
    x_start = 50.0
    flux_start = x_start * 1e-15 / (0.6 * constants.e)
    t = np.arange(0, 400_000_000, 1_000_000)
    flux = flux_start * np.exp(-t / 25e6)                       # x falls to 50 e^-16 ~ 6e-6
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, t, flux), 0.4, 0.1))
    y_start = np.log(x_start)
    y_end = flux[-1] * 0.6 * constants.e / 1e-15 * np.log(5) / 5
    assert ev["t"].size == 4 * int((y_start - y_end) / theta) == 4 * 19
    assert np.all(ev["p"] == -1)
    assert int((y_start - np.log(flux[-1] * 0.6 * constants.e / 1e-15)) / theta) == 79


@pytest.mark.parametrize("implementation", BOTH)
def test_cooling_raises_the_contrast_of_a_faint_source(scenes, implementation):
    # Dark current dilutes the contrast of a faint source: a photocurrent I_s on top of
    # I_dark(T) gives ln(1 + I_s/I_dark) of log contrast. 10 K of cooling lowers I_dark by the
    # Arrhenius factor exp(-E_a/k (1/T2 - 1/T1)) (the form of Nozaki & Delbruck's Arrhenius
    # plots), so the same source gives more events. I_ref is small so both sit on the log
    # branch of Eq. 14; the flash is long enough for the photoreceptor to settle.
    fp, theta, ea = scenes.focal_plane(2, 2), 0.2, 0.56
    density = 4e-3                                              # A/m^2: I_dark(300 K) = 1e-13 A
    i_dark_300 = density * scenes.PITCH_M**2
    i_source = 1.0 * i_dark_300
    counts = {}
    for temperature in (300.0, 290.0):
        block = DvsPixel(implementation=implementation, time_step_s=1e-5, temperature_K=temperature,
                         dark_current_density_A_m2=density, dark_activation_energy_eV=ea,
                         reference_current_A=1e-16, threshold_on=theta, threshold_off=theta,
                         **dict(QUIET, threshold_sigma=0.0))
        flux = np.array([0.0, i_source / (0.6 * constants.e)])
        ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, 10_000_000], flux),
                                           0.1, 0.05))
        counts[temperature] = ev["counts"][EventCause.SIGNAL] / 4
    k_ev = constants.k / constants.e
    i_dark_290 = i_dark_300 * np.exp(-ea / k_ev * (1 / 290.0 - 1 / 300.0))
    assert counts[300.0] == int(np.log(1 + i_source / i_dark_300) / theta) == 3
    assert counts[290.0] == int(np.log(1 + i_source / i_dark_290) / theta) == 5


@pytest.mark.parametrize("implementation", BOTH)
def test_knee_at_dark_current_keeps_a_faint_source_on_the_log_response(scenes, implementation):
    # A 4.86 um pixel at 1 nA/cm^2 has I_dark = 0.24 fA, below the paper's knee (5 I_ref = 5 fA).
    # With the knee at the dark current the response is ln(I_p + I_dark) (Delbruck & Mead 1994), so
    # a source of 0.5 I_dark gives floor(ln 1.5 / theta) = 4 ON events, 12 after cooling by 20 K
    # (Arrhenius factor 0.22); on the paper's linear piece it gives none, cooled or not.
    fp, theta, ea, pitch = scenes.focal_plane(2, 2), 0.1, 0.56, scenes.PITCH_M
    k_ev = constants.k / constants.e
    i_dark_300 = 1e-5 * pitch**2
    counts = {}
    for knee_at_dark in (True, False):
        for temperature in (300.0, 280.0):
            block = DvsPixel(implementation=implementation, time_step_s=1e-5, temperature_K=temperature,
                             dark_current_density_A_m2=1e-5, dark_activation_energy_eV=ea,
                             knee_at_dark_current=knee_at_dark, threshold_on=theta, threshold_off=theta,
                             **dict(QUIET, threshold_sigma=0.0))
            flux = np.array([0.0, 0.5 * i_dark_300 / (0.6 * constants.e)])
            ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, 10_000_000], flux),
                                               0.1, 0.05))
            counts[knee_at_dark, temperature] = ev["counts"][EventCause.SIGNAL] / 4
    i_dark_280 = i_dark_300 * np.exp(-ea / k_ev * (1 / 280.0 - 1 / 300.0))
    assert counts[True, 300.0] == int(np.log(1.5) / theta) == 4
    assert counts[True, 280.0] == int(np.log(1 + 0.5 * i_dark_300 / i_dark_280) / theta) == 12
    assert counts[False, 300.0] == counts[False, 280.0] == 0


@pytest.mark.parametrize("implementation", BOTH)
def test_cooling_slows_a_dark_pixel_by_the_arrhenius_factor(scenes, implementation):
    # With the proportional cutoff law the bandwidth of a dark pixel is proportional to its
    # dark current, so the latency of the first event after a small step scales as 1/I_dark.
    fp, theta, ea, density = scenes.focal_plane(1, 1), 0.2, 0.56, 4e-3
    k_ev = constants.k / constants.e
    latencies = {}
    for temperature in (300.0, 290.0):
        block = DvsPixel(implementation=implementation, time_step_s=1e-5, temperature_K=temperature,
                         dark_current_density_A_m2=density, dark_activation_energy_eV=ea, reference_current_A=1e-16,
                         cutoff_model="proportional", cutoff_saturation=1e5, threshold_on=theta,
                         **dict(QUIET, threshold_sigma=0.0))
        i_dark = density * scenes.PITCH_M**2 * np.exp(-ea / k_ev * (1 / temperature - 1 / 300.0))
        flux = np.array([0.0, 0.3 * i_dark / (0.6 * constants.e)])   # to 1.3 I_dark: ln 1.3 > theta, one event
        ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, 1_000_000], flux), 0.2, 0.1))
        latencies[temperature] = (ev["t"][0] - 1_000_000) * 1e-9
    arrhenius = np.exp(-ea / k_ev * (1 / 290.0 - 1 / 300.0))
    assert latencies[290.0] / latencies[300.0] == pytest.approx(1 / arrhenius, rel=0.01)


@pytest.mark.parametrize("implementation", BOTH)
def test_cooling_raises_the_shot_noise_of_a_dark_pixel_per_eq_20(scenes, implementation):
    # In the dark the only current is I_dark(T). Eq. 20 makes the shot-noise rate fall with
    # the lin-log level I/I_max, so 10 K of cooling (I_dark times the Arrhenius factor 0.47 at
    # E_a = 0.56 eV) lowers Y from 4 to 3.25 and raises the rate from 0.46 R_n to 0.56 R_n.
    # Each shot event is undone one refractory period later (cycles of 1/q - 1 + 2k steps).
    fp, ea, density, r_n, factor, dt, k, seconds = scenes.focal_plane(8, 8), 0.56, 4e-3, 50.0, 0.25, 1e-4, 1, 0.5
    k_ev = constants.k / constants.e
    i_ref = density * scenes.PITCH_M**2 / np.exp(4.0)              # x_dark(300 K) = e^4
    counts = {}
    for temperature in (300.0, 290.0):
        block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt, seed=3,
                         temperature_K=temperature, dark_current_density_A_m2=density, dark_activation_energy_eV=ea,
                         reference_current_A=i_ref, shot_noise_rate_hz=r_n, shot_noise_intensity_factor=factor,
                         leak_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0)
        ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [a], 0.0), seconds, 0.25))
        assert np.all(ev["cause"] == EventCause.SHOT)
        y = 4.0 + (-ea / k_ev * (1 / temperature - 1 / 300.0))       # ln x_dark(T)
        q = 2 * ((factor - 1) * y / 5.54 + 1) * r_n * dt
        expected = fp.width_px * fp.height_px * seconds / ((1 / q - 1 + k) * dt)
        assert abs(ev["t"].size - expected) < 4 * np.sqrt(expected), temperature
        counts[temperature] = ev["t"].size
    assert counts[290.0] > 1.1 * counts[300.0]


@pytest.mark.parametrize("implementation", BOTH)
def test_latency_converges_as_the_step_shrinks(scenes, implementation):
    # First event after a contrast step through the low-pass filter: continuous time gives
    # t* = -ln(1 - theta/C) / (2 pi f); the stepped model approaches it as dt -> 0.
    fp, theta, contrast = scenes.focal_plane(1, 1), 0.2, 0.5
    x1 = 1000.0
    flux = np.array([x1, x1 * np.exp(contrast)]) * 1e-15 / (0.6 * constants.e)
    block_kw = dict(cutoff_model="proportional", cutoff_saturation=1e5, cutoff_max_hz=1e5, threshold_on=theta,
                    dark_current_density_A_m2=0.0, **dict(QUIET, threshold_sigma=0.0))
    f = 1e5 * x1 * np.exp(contrast) / 1e5                         # cutoff at the new input [Hz]
    exact = -np.log(1 - theta / contrast) / (2 * np.pi * f)       # 0.81 ms
    steps = [1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2] if implementation == "fast" else [1e-6, 1e-5, 1e-4, 1e-3, 1e-2]
    errors = []
    for dt in steps:
        block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=dt, **block_kw)
        ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, 1_000_000], flux), 0.03, 0.03))
        errors.append(abs((ev["t"][0] - 1_000_000) * 1e-9 - exact))
        assert errors[-1] <= max(2 * dt, 3e-6 + 0.0 * dt) + 2 * np.pi * f * dt * exact
    assert errors[-1] == max(errors)
    assert errors[0] < 5e-6


@pytest.mark.parametrize("implementation", BOTH)
def test_refractory_period_longer_than_the_window(scenes, implementation):
    fp, refractory = scenes.focal_plane(2, 1), 0.15
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, refractory_period_s=refractory,
                     cutoff_max_hz=0.0, **CLEAN)
    flux = np.array([1e5, 1e5 * np.exp(1.05)])                 # 5 thresholds at once
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0, 10_000_000], flux), 0.5, 0.05))
    for x in range(2):
        t = ev["t"][ev["x"] == x]
        np.testing.assert_array_equal(t, 10_000_000 + np.arange(4) * 150_000_000)   # 4 fit in 0.5 s
    assert ev["n_loss"] == 0                              # the fifth is still owed, not lost


@pytest.mark.parametrize("implementation", BOTH)
def test_very_bright_flash_loses_what_it_took_back_without_overflow(scenes, implementation):
    # A step to 1e8 ... 1e20 photon/s: every one of its n events is emitted, one per step, and
    # nothing is lost; the same step taken back after 10 steps loses the n - 10 ON events still
    # owed (n - 10 = 173 at 1e20: exact integers whatever the flux, no overflow).
    fp, theta = scenes.focal_plane(1, 1), 0.2
    losses = []
    for flux in (1e8, 1e12, 1e16, 1e20):
        block = DvsPixel(implementation=implementation, time_step_s=1e-5, refractory_period_s=1e-5,
                         cutoff_max_hz=0.0, threshold_on=theta, **CLEAN)
        ev = scenes.concat(scenes.simulate(
            block, lambda a, b: scenes.uniform(fp, [0, 1_000_000], [1e3, flux]), 0.02, 0.01))
        x1 = 1e3 * 0.6 * constants.e / 1e-15
        n = int((np.log(flux / 1e3) + (np.log(x1) - np.log(5) / 5 * x1 if x1 < 5 else 0.0)) / theta)
        assert ev["t"].size == n and ev["n_loss"] == 0           # all emitted, one per step
        block = DvsPixel(implementation=implementation, time_step_s=1e-5, refractory_period_s=1e-5,
                         cutoff_max_hz=0.0, threshold_on=theta, threshold_off=theta, **CLEAN)
        ev = scenes.concat(scenes.simulate(
            block, lambda a, b: scenes.uniform(fp, [0, 1_000_000, 1_100_000], [1e3, flux, 1e3]), 0.02, 0.01))
        assert int(np.sum(ev["p"] > 0)) == 10 and int(np.sum(ev["p"] < 0)) == 10
        assert ev["n_loss"] == n - 10 and isinstance(ev["n_loss"], int)
        losses.append(ev["n_loss"])
    assert losses == sorted(losses) and losses[-1] > 100


@pytest.mark.parametrize("implementation", BOTH)
def test_zero_and_saturating_current(scenes, implementation):
    # Zero current (no light, no dark current): Eq. 14 maps it to 0, not -inf; nothing but
    # the leak fires. A step up from zero gives floor(Y / theta) events. Far above I_max the
    # shot-noise rate is clipped at F R_n.
    fp = scenes.focal_plane(4, 4)
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, dark_current_density_A_m2=0.0,
                     **dict(QUIET, leak_rate_hz=10.0))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0], 0.0), 0.5, 0.25))
    assert ev["counts"][EventCause.SIGNAL] == 0
    assert abs(ev["counts"][EventCause.LEAK] - 16 * 10 * 0.5) <= 8
    assert np.all(np.isfinite(block.pixel_field("memorised")))
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, cutoff_max_hz=0.0, **CLEAN)
    x = 50.0
    ev = scenes.concat(scenes.simulate(
        block, lambda a, b: scenes.uniform(fp, [0, 10**6], [0.0, x * 1e-15 / (0.6 * constants.e)]), 0.1, 0.1))
    assert ev["t"].size == 16 * int(np.log(x) / 0.2)
    r_n, factor, dt, k = 30.0, 0.25, 1e-4, 1
    block = DvsPixel(implementation=implementation, time_step_s=dt, refractory_period_s=k * dt,
                     shot_noise_intensity_factor=factor, **dict(CLEAN, shot_noise_rate_hz=r_n))
    ev = scenes.concat(scenes.simulate(block, lambda a, b: scenes.uniform(fp, [0], 1e30), 1.0, 0.5))
    q = 2 * factor * r_n * dt
    expected = 16 / ((1 / q - 1 + k) * dt)
    assert abs(ev["t"].size - expected) < 4 * np.sqrt(expected)


@pytest.mark.parametrize("implementation", BOTH)
def test_uniform_brightening_fires_every_pixel(scenes, implementation):
    # A change of the uniform background (every pixel's input changes at once)
    fp, theta = scenes.focal_plane(5, 4), 0.2
    block = DvsPixel(implementation=implementation, time_step_s=1e-4, cutoff_max_hz=0.0, threshold_on=theta,
                     **CLEAN)
    ev = scenes.concat(scenes.simulate(
        block, lambda a, b: scenes.uniform(fp, scenes.grid(a, b, 10**7), np.where(scenes.grid(a, b, 10**7) >= 50_000_000,
                                                                                  1e5 * np.exp(0.5), 1e5)),
        0.1, 0.03))
    assert ev["t"].size == 20 * 2 and np.all(ev["p"] == 1)
    np.testing.assert_array_equal(np.unique(ev["t"]), [50_000_000, 50_100_000])
