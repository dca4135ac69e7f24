"""A preset pixel's latency to an LED step against NIST's measurements of the same sensors (prints both).

NIST (R. V. Chassagnol, T. J. Blattner, M. Litorja, P. Bajcsy, "Specifications for pixel latency
measurements of event cameras", IEEE TIM 2025; data and figures: github usnistgov/pixel_latency_eventcameras)
timed the first event after an LED step on two CenturyArks SilkyEvCam HD (Sony IMX636, the Gen4 preset's
sensor) and one SilkyEvCam VGA (Prophesee PPS3MVCD, the Gen3 preset's), at default biases, without a lens,
at five irradiances on the chip. :data:`MEASURED` holds the medians read off their published figures
(``web/Images/CAM{1,2,3}/nolens/figures_*/latency_per_ROI_forBias_0.png``: nine 10 x 10-pixel ROIs per
camera; ranges over ROIs and, for the IMX636, both cameras; outlying ROIs left out).

The LED's wavelength (their bench has a 523 nm and a 680 nm LED) and its off level are not stated next
to the figures; the simulation takes the LED fully off (the pixel at its dark current) and shows both
wavelengths (photons per watt differ by 1.3x). The preset pixel runs alone, noise off, threshold spread 0,
settled on the off level; the latency is the first ON event after the rise (50 ms lit) and the first OFF
event after the fall (0.2 s simulated).

:func:`fit_bandwidth` fits the power cutoff law (``cutoff_exponent``, ``cutoff_saturation`` at the preset's
``cutoff_max_hz``) to the five ON rows by weighted least squares in ln latency, with the fixed delay the model
lacks (comparator, arbiter, time stamping: the bright-light floor) as a third parameter that stays out of the
preset; the Gen4 and Gen3 VGA presets hold its result. The OFF rows are predictions, not fitted: the model's
falling step runs at the dark pixel's cutoff, while the measured OFF latency is about the ON one.

    python benchmarks/pixel_latency_nist.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import constants, optimize

from evsda.blocks.pixel import DvsPixel, lowpass
from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import Window
from evsda.graph.graphfile import load_graph

IRRADIANCES_W_M2 = (0.006, 0.046, 0.166, 0.277, 0.398)        # NIST's five LED levels on the chip [W m^-2]
LED_WAVELENGTHS_M = (523.48e-9, 680.61e-9)                      # NIST's green and red LEDs (scripts/irradiance.py)
#: median latency [us] read off NIST's figures at default biases: {preset: {polarity: ((low, high) per irradiance)}}
MEASURED = {
    "prophesee_gen4": {"ON": ((500, 560), (90, 97), (38, 42), (28, 32), (25, 30)),
                       "OFF": ((570, 640), (105, 117), (50, 60), (40, 50), (30, 50))},
    "prophesee_gen3_vga": {"ON": ((810, 850), (420, 450), (375, 395), (360, 390), (360, 380)),
                           "OFF": ((700, 860), (265, 335), (170, 215), (150, 190), (140, 170))},
}
HALF_PERIOD_S = 0.05
OFF_WAIT_S = 0.2                  # time simulated after the fall: a dark pixel's cutoff can be below 1 Hz [s]


def preset_pixel(name: str, saturation_scale: float = 1.0, **cutoff) -> tuple[DvsPixel, float]:
    """The preset's pixel with noise and threshold spread off (cutoff_saturation times ``saturation_scale``, other
    ``cutoff_*`` parameters as given), and its pitch [m]."""
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": 1.0})
    pitch_m = graph.nodes["camera"].block.params.pixel_pitch_m
    params = graph.nodes["pixel"].block.params
    cutoff.setdefault("cutoff_saturation", params.cutoff_saturation)
    cutoff["cutoff_saturation"] *= saturation_scale
    block = DvsPixel(params, leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0,
                     noise_rate_spread_decades=0.0, **cutoff)
    return block, pitch_m


def step_latencies_us(name: str, irradiance_w_m2: float, wavelength_m: float,
                      saturation_scale: float = 1.0, **cutoff) -> tuple[float, float]:
    """(ON, OFF) latency [us] of the preset pixel to an LED going on for 50 ms from off, then off (inf: none in 0.2 s)."""
    block, pitch_m = preset_pixel(name, saturation_scale, **cutoff)
    photons_s = irradiance_w_m2 * pitch_m**2 * wavelength_m / (constants.h * constants.c)
    fp = FocalPlane(1, 1, pitch_m, 1.0)
    rise_ns, fall_ns = int(HALF_PERIOD_S * 1e9), int(2 * HALF_PERIOD_S * 1e9)
    t = np.array([0, rise_ns, fall_ns], dtype=np.int64)
    flux = np.array([0.0, photons_s, 0.0])
    light = Irradiance(fp, wavelength_m, t, flux, np.zeros((3, 0, 2), np.int32), np.zeros((3, 0, 1, 1)))
    events = block.step(Window.from_seconds(0.0, 2 * HALF_PERIOD_S + OFF_WAIT_S), irradiance=light)["events"]
    on = events.t_ns[(events.p > 0) & (events.t_ns >= rise_ns) & (events.t_ns < fall_ns)]
    off = events.t_ns[(events.p < 0) & (events.t_ns >= fall_ns)]
    return ((on.min() - rise_ns) / 1e3 if on.size else np.inf, (off.min() - fall_ns) / 1e3 if off.size else np.inf)


def main() -> None:
    print("first-event latency after an LED step [us]: NIST measured (median range) | this preset, LED off -> on -> off,"
          " at 523 nm / 681 nm")
    for name, measured in MEASURED.items():
        print(f"\n{name}")
        print(f"{'E [W/m2]':>9} {'ON meas.':>11} {'ON sim.':>15} {'OFF meas.':>11} {'OFF sim.':>17}  meas./sim. (ON, OFF)")
        for k, irradiance in enumerate(IRRADIANCES_W_M2):
            sims = [step_latencies_us(name, irradiance, wl) for wl in LED_WAVELENGTHS_M]
            on_m, off_m = measured["ON"][k], measured["OFF"][k]
            ratio_on = np.mean(on_m) / np.exp(np.mean(np.log([s[0] for s in sims])))
            ratio_off = np.mean(off_m) / np.exp(np.mean(np.log([s[1] for s in sims])))
            print(f"{irradiance:9.3f} {on_m[0]:5d}-{on_m[1]:<5d} {sims[0][0]:7.1f}/{sims[1][0]:<7.1f} "
                  f"{off_m[0]:5d}-{off_m[1]:<5d} {sims[0][1]:8.1f}/{sims[1][1]:<8.1f}  {ratio_on:6.2f}x {ratio_off:6.3f}x")
        dim, bright = measured["ON"][0], measured["ON"][2]
        slope = np.log(np.mean(dim) / np.mean(bright)) / np.log(IRRADIANCES_W_M2[2] / IRRADIANCES_W_M2[0])
        print(f"measured ON latency ~ E^-{slope:.2f} from 0.006 to 0.166 W/m2 (a photoreceptor-limited latency goes as "
              f"1/(f dY): steeper than the cutoff law's E^-n while dY = ln(x/x_dark) grows)")
        print_fit(name, fit_bandwidth(name))


def print_fit(name: str, fit: BandwidthFit) -> None:
    """The fitted law, its errors and the residuals, ON (fitted) and OFF (predicted: the simulated pixel) separately."""
    params = preset_pixel(name)[0].params
    law = {"cutoff_saturation": fit.saturation, "cutoff_exponent": fit.exponent}
    off_us = np.array([np.exp(np.mean(np.log([step_latencies_us(name, e, wl, **law)[1] for wl in LED_WAVELENGTHS_M])))
                       for e in IRRADIANCES_W_M2])
    off_residuals = np.log(np.array([np.mean(r) for r in MEASURED[name]["OFF"]]) / off_us)
    print("fit to the five ON rows (t_ON = t0 + the one-pole latency; the LEDs' geometric-mean photon rate; LED off = dark):")
    print(f"  cutoff_exponent {fit.exponent:.3f} +- {fit.exponent_err:.3f}, cutoff_saturation {fit.saturation:.4g} "
          f"(x/ {np.exp(fit.ln_saturation_err):.2f}) at cutoff_max_hz {params.cutoff_max_hz:g}, "
          f"fixed delay t0 {fit.floor_s * 1e6:.1f} +- {fit.floor_err_s * 1e6:.1f} us (not in the model); "
          f"chi2 {fit.chi2:.3f} for 2 degrees of freedom")
    print(f"  preset: cutoff_exponent {params.cutoff_exponent:g}, cutoff_saturation {params.cutoff_saturation:.6g}; "
          f"the fitted law's dark-pixel cutoff {fit.dark_cutoff_hz:.3g} Hz")
    print("  ln(measured / fit)   ON  (fitted, t0 included): " + " ".join(f"{r:+.3f}" for r in fit.on_residuals))
    print("  ln(measured / model) OFF (predicted, simulated): " + " ".join(f"{r:+.2f}" for r in off_residuals)
          + f"  (the model's OFF {np.exp(-off_residuals.max()):.1f}-{np.exp(-off_residuals.min()):.0f}x slower than"
          " measured: its falling step runs at the dark current's cutoff)")


@dataclass(frozen=True)
class BandwidthFit:
    """The power cutoff law ``f = f_max (x / x_sat)^n`` fitted to NIST's ON latencies, plus a fixed delay ``t0``."""

    saturation: float            # cutoff_saturation x_sat at the preset's cutoff_max_hz [1]
    exponent: float              # cutoff_exponent n [1]
    floor_s: float               # fixed delay t0 the pixel model lacks (comparator, arbiter, time stamp) [s]
    ln_saturation_err: float     # 1-sigma errors of ln x_sat, n and t0 [1, 1, s]
    exponent_err: float
    floor_err_s: float
    chi2: float                  # sum of squared weighted residuals, 5 rows - 3 parameters = 2 degrees of freedom
    on_residuals: np.ndarray     # ln(measured / fitted) per irradiance, ON [1]
    dark_cutoff_hz: float        # the fitted law at the dark current (the LED off) [Hz]


def row_currents(name: str) -> tuple[np.ndarray, float, DvsPixel]:
    """Normalised current x of the preset pixel at each NIST irradiance (geometric mean over the two LEDs), the
    dark pixel's x, and the pixel block."""
    block, pitch_m = preset_pixel(name)
    logs = []
    for wavelength_m in LED_WAVELENGTHS_M:
        model = PixelModel(block.params, pitch_m**2, wavelength_m)
        photons_s = np.asarray(IRRADIANCES_W_M2) * pitch_m**2 * wavelength_m / (constants.h * constants.c)
        logs.append(np.log(model.normalised_current(photons_s)))
    return np.exp(np.mean(logs, axis=0)), float(model.normalised_current(np.zeros(1))[0]), block


def on_latency_s(x: np.ndarray, x_dark: float, params, saturation: float, exponent: float) -> np.ndarray:
    """First ON event's latency [s] of the one-pole photoreceptor (paper Eq. 16) after a step from dark to ``x``.

    ``L`` approaches ``ln x`` at the lit pixel's cutoff ``f(x)`` and fires once it has risen theta_ON of
    ``dY = ln(x / x_dark)``: ``t = -ln(1 - theta_ON / dY) / (2 pi f(x))`` (continuous time; the 1 us
    backward-Euler step changes it by < 1 % below 1 kHz).
    """
    cutoff = lowpass.cutoff_hz(x, None, params.cutoff_max_hz, "power", saturation, exponent)
    return -np.log1p(-params.threshold_on / np.log(x / x_dark)) / (2 * np.pi * cutoff)


def fit_bandwidth(name: str, measured_on_us=None) -> BandwidthFit:
    """Weighted least squares in ln(latency) over the five ON rows: ``t_ON = t0 + on_latency_s(x; x_sat, n)``.

    ``measured_on_us``: (low, high) per irradiance, NIST's by default. Each row's sigma is half its ln-range
    (over ROIs and cameras). The bright rows keep a fixed delay the model lacks, so ``t0`` is fitted beside
    the law and left out of the preset. The OFF rows are not fitted: the model's falling step runs at the
    dark current's cutoff, which the measured OFF ~ ON denies (:func:`print_fit` prints them as predictions).
    """
    x, x_dark, block = row_currents(name)
    params = block.params
    rows = MEASURED[name]["ON"] if measured_on_us is None else measured_on_us
    on_s = np.array([np.mean(r) for r in rows]) * 1e-6
    sigma = np.array([0.5 * np.log(hi / lo) for lo, hi in rows])

    def residuals(p: np.ndarray) -> np.ndarray:
        return (np.log(on_s) - np.log(p[2] * 1e-6 + on_latency_s(x, x_dark, params, np.exp(p[0]), p[1]))) / sigma

    start = np.array([np.log(params.cutoff_saturation), params.cutoff_exponent, 0.5e6 * on_s.min()])
    sol = optimize.least_squares(residuals, start, bounds=([-np.inf, 0.05, 0.0], [np.inf, 2.0, 1e6 * on_s.min()]),
                                 x_scale=[1.0, 0.1, 10.0])
    chi2 = float(np.sum(sol.fun**2))
    err = np.sqrt(np.diag(np.linalg.inv(sol.jac.T @ sol.jac) * max(1.0, chi2 / (len(x) - 3))))
    saturation, exponent, floor_s = float(np.exp(sol.x[0])), float(sol.x[1]), float(sol.x[2]) * 1e-6
    dark_hz = float(lowpass.cutoff_hz(np.array([x_dark]), None, params.cutoff_max_hz, "power", saturation, exponent)[0])
    return BandwidthFit(saturation, exponent, floor_s, float(err[0]), float(err[1]), float(err[2]) * 1e-6, chi2,
                        np.log(on_s / (floor_s + on_latency_s(x, x_dark, params, saturation, exponent))), dark_hz)


def off_matching_scale(name: str, measured_us: float) -> float:
    """The factor on cutoff_saturation at which the OFF latency at the dimmest level (both LEDs' mean) is ``measured_us``."""
    def off_us(log_scale: float) -> float:
        return np.mean([step_latencies_us(name, IRRADIANCES_W_M2[0], wl, np.exp(log_scale))[1] for wl in LED_WAVELENGTHS_M])
    low, high = -np.log(1e6), np.log(1e6)
    for _ in range(30):                       # bisection in ln(scale): the latency grows with the scale
        mid = 0.5 * (low + high)
        low, high = (mid, high) if off_us(mid) < measured_us else (low, mid)
    return float(np.exp(0.5 * (low + high)))


if __name__ == "__main__":
    main()
