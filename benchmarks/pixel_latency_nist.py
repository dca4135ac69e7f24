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
wavelengths (photons per watt differ by 1.3x), each weighted by the preset detector's response there (its
``quantum_efficiency`` is the QE at 550 nm; a silicon response of 3 um gives 1.05 at 523 nm, 0.55 at 681 nm:
:func:`led_response`). As NIST's figures give the median over a 10 x 10-pixel ROI, the
preset's pixels run as a 10 x 10 array, noise off, with the preset's threshold spread, settled on the off level;
the latency is the median over the pixels of the first ON event after the rise (50 ms lit) and of the first OFF
event after the fall (0.2 s simulated). The spread matters for OFF: after the ON burst a pixel's memory lies a
random fraction of a threshold below the lit level, which adds to the fall its first OFF event needs.

:func:`fit_bandwidth` fits the power cutoff law (``cutoff_exponent``, ``cutoff_saturation`` at the preset's
``cutoff_max_hz``) to the five ON and five OFF rows together by weighted least squares in ln latency, with the
large-signal filter (``lowpass_form: large_signal``, docs/pixel.md) and a fixed delay per polarity that the model
lacks (comparator, arbiter, time stamping: the bright-light floors) as two more parameters kept out of the preset;
the Gen4 and Gen3 VGA presets hold its result. It prints, beside it, the law fitted before (ON rows only, the
small-signal filter), whose OFF latencies are 3-220x too slow: that form's falling step runs at the dark pixel's
cutoff, while the measured OFF latency is about the ON one. It then refits with the exponent held at 1, the
first-order photoreceptor's law (Delbruck & Mead 1994: ``f = I / (2 pi C_eff U_T)``, :func:`effective_capacitance_F`),
and prints the effective capacitance and the electrons per ON threshold that law implies at any current: what the
circuit says below NIST's dimmest step.

    python benchmarks/pixel_latency_nist.py
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import constants, optimize

from evsda.blocks.pixel import DvsPixel, lowpass
from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.blocks.scene import spectra
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
ROI_SIDE = 10                     # NIST's ROIs: 10 x 10 pixels, the median latency over them [pixels]


#: the pixels the presets carried before the large-signal form: laws fitted to the ON rows alone with the small-signal
#: filter (and the Gen3's dark current of then, fitted on sky on that law)
SMALL_SIGNAL_FIT = {"prophesee_gen4": {"cutoff_exponent": 0.599, "cutoff_saturation": 5.42e4, "lowpass_form": "small_signal"},
                    "prophesee_gen3_vga": {"cutoff_exponent": 0.742, "cutoff_saturation": 2.33e5,
                                           "lowpass_form": "small_signal", "dark_current_density_A_m2": 1.55e-6}}


def led_response(name: str, wavelength_m: float) -> float:
    """The preset detector's response at an LED's wavelength, relative to the wavelength at which its
    ``quantum_efficiency`` is given (:func:`evsda.blocks.scene.spectra.response`; 1 for a V-band preset)."""
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": 1.0})
    spec = graph.nodes["camera"].block.focal_plane.spectral_response
    if spec.is_v_band:
        return 1.0
    return float(np.interp(wavelength_m * 1e9, spectra.GRID_NM, spectra.response(spec)))


def preset_pixel(name: str, saturation_scale: float = 1.0, **cutoff) -> tuple[DvsPixel, float]:
    """The preset's pixel with noise off (cutoff_saturation times ``saturation_scale``, other pixel parameters, e.g.
    ``cutoff_*`` and ``lowpass_form``, as given), and its pitch [m]."""
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": 1.0})
    pitch_m = graph.nodes["camera"].block.params.pixel_pitch_m
    params = graph.nodes["pixel"].block.params
    cutoff.setdefault("cutoff_saturation", params.cutoff_saturation)
    cutoff["cutoff_saturation"] *= saturation_scale
    block = DvsPixel(params, leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0,
                     noise_rate_spread_decades=0.0, seed=1, **cutoff)
    return block, pitch_m


def step_latencies_us(name: str, irradiance_w_m2: float, wavelength_m: float,
                      saturation_scale: float = 1.0, **cutoff) -> tuple[float, float]:
    """(ON, OFF) latency [us] of the preset's pixels to an LED going on for 50 ms from off, then off: the medians
    over a :data:`ROI_SIDE` square of pixels of their first events (inf: a pixel without one in 0.2 s)."""
    block, pitch_m = preset_pixel(name, saturation_scale, **cutoff)
    photons_s = irradiance_w_m2 * pitch_m**2 * wavelength_m / (constants.h * constants.c) * led_response(name, wavelength_m)
    fp = FocalPlane(ROI_SIDE, ROI_SIDE, pitch_m, 1.0)
    rise_ns, fall_ns = int(HALF_PERIOD_S * 1e9), int(2 * HALF_PERIOD_S * 1e9)
    t = np.array([0, rise_ns, fall_ns], dtype=np.int64)
    flux = np.array([0.0, photons_s, 0.0])
    light = Irradiance(fp, wavelength_m, t, flux, np.zeros((3, 0, 2), np.int32), np.zeros((3, 0, 1, 1)))
    events = block.step(Window.from_seconds(0.0, 2 * HALF_PERIOD_S + OFF_WAIT_S), irradiance=light)["events"]
    pixel = events.y.astype(np.int64) * ROI_SIDE + events.x

    def median_first_us(selected: np.ndarray, since_ns: int) -> float:
        first = np.full(ROI_SIDE**2, np.inf)
        np.minimum.at(first, pixel[selected], (events.t_ns[selected] - since_ns) / 1e3)
        return float(np.median(first))

    return (median_first_us((events.p > 0) & (events.t_ns >= rise_ns) & (events.t_ns < fall_ns), rise_ns),
            median_first_us((events.p < 0) & (events.t_ns >= fall_ns), fall_ns))


def main() -> None:
    print("first-event latency after an LED step [us]: NIST measured (median range) | the preset pixel, LED off -> on -> off,"
          " at 523 nm / 681 nm (no fixed delay)")
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
        print_fit(name, fit_bandwidth(name))
        print_first_order(name)


def print_fit(name: str, fit: BandwidthFit) -> None:
    """The fitted law, its errors and residuals (ON, OFF), against the small-signal law fitted to the ON rows before."""
    params = preset_pixel(name)[0].params
    print("joint fit to the five ON and five OFF rows (large-signal filter; a fixed delay per polarity beside the law;"
          " both LEDs' latencies, geometric mean; LED off = dark):")
    print(f"  cutoff_exponent {fit.exponent:.3f} +- {fit.exponent_err:.3f}, cutoff_saturation {fit.saturation:.4g} "
          f"(x/ {np.exp(fit.ln_saturation_err):.2f}) at cutoff_max_hz {params.cutoff_max_hz:g}; fixed delays (not in "
          f"the model) ON {fit.floor_s[0] * 1e6:.1f} +- {fit.floor_err_s[0] * 1e6:.1f} us, OFF {fit.floor_s[1] * 1e6:.1f} "
          f"+- {fit.floor_err_s[1] * 1e6:.1f} us; chi2 {fit.chi2:.2f} for 6 degrees of freedom")
    print(f"  preset: lowpass_form {params.lowpass_form}, cutoff_exponent {params.cutoff_exponent:g}, cutoff_saturation "
          f"{params.cutoff_saturation:.6g}; the fitted law's dark-pixel cutoff {fit.dark_cutoff_hz:.3g} Hz")
    print("  ln(measured / fit)  ON  (delay included): " + " ".join(f"{r:+.3f}" for r in fit.on_residuals))
    print("  ln(measured / fit)  OFF (delay included): " + " ".join(f"{r:+.3f}" for r in fit.off_residuals))
    law = {"cutoff_saturation": fit.saturation, "cutoff_exponent": fit.exponent, "lowpass_form": "large_signal"}
    sim = np.array([[np.exp(np.mean(np.log([step_latencies_us(name, e, wl, **law)[k] for wl in LED_WAVELENGTHS_M])))
                     for k in (0, 1)] for e in IRRADIANCES_W_M2]) * 1e-6 + np.array(fit.floor_s)
    meas = np.array([[np.mean(MEASURED[name][pol][k]) for pol in ("ON", "OFF")] for k in range(5)]) * 1e-6
    print("  ln(measured / simulated + delay), ON: " + " ".join(f"{r:+.3f}" for r in np.log(meas / sim)[:, 0])
          + "; OFF: " + " ".join(f"{r:+.3f}" for r in np.log(meas / sim)[:, 1]) + " (the simulated pixel, 1 us steps)")
    old = SMALL_SIGNAL_FIT[name]
    x, x_dark, block = row_currents(name, **old)
    on_old, off_old = step_latencies_s(x, x_dark, block.params, old["cutoff_saturation"], old["cutoff_exponent"],
                                       "small_signal")
    on_old, off_old = np.exp(np.log(on_old).mean(0)), np.exp(np.log(off_old).mean(0))
    t0_old = {"prophesee_gen4": 12e-6, "prophesee_gen3_vga": 358e-6}[name]
    print(f"  before (small-signal, ON rows alone: n {old['cutoff_exponent']}, x_sat {old['cutoff_saturation']:.4g}, "
          f"delay {t0_old * 1e6:.0f} us on both): ln(measured / model) ON "
          + " ".join(f"{r:+.3f}" for r in np.log(meas[:, 0] / (t0_old + on_old)))
          + "; OFF " + " ".join(f"{r:+.2f}" for r in np.log(meas[:, 1] / (t0_old + off_old))))


THERMAL_VOLTAGE_V = constants.k * 300.0 / constants.e       # U_T at 300 K, NIST's room-temperature bench [V]


def effective_capacitance_F(saturation: float, max_hz: float, reference_current_A: float) -> float:
    """``C_eff`` of the first-order photoreceptor whose cutoff is ``f = f_max x / x_sat`` [F].

    Delbruck & Mead 1994 (and Liu et al. 2002, ch. 13): the photodiode node, held by the feedback transistor (source
    conductance ``g_s = I / U_T``, gate driven by the amplifier of gain ``-A``), relaxes at
    ``2 pi f_3dB = I (1 + kappa A) / (C_pd U_T)``; the feedback transistor's gate-source (Miller) capacitance ``C_m``
    adds ``C_m (1 + A) / (1 + kappa A) ~ C_m / kappa``. So ``f_3dB = I / (2 pi C_eff U_T)`` with
    ``C_eff = (C_pd + (1 + A) C_m) / (1 + kappa A)``, constant in ``I``: the bandwidth is proportional to the current
    (``cutoff_exponent`` 1) while the amplifier's own pole, set by its bias and not by the light, is far above it.
    In the large-signal form a rise of ``Delta L`` (ln units) then costs ``Delta L C_eff U_T / q`` electrons,
    whatever the current that delivers them.
    """
    return reference_current_A * saturation / (2.0 * np.pi * max_hz * THERMAL_VOLTAGE_V)


def print_first_order(name: str) -> None:
    """The same fit with ``n`` held at 1, the first-order photoreceptor's law (:func:`effective_capacitance_F`)."""
    free, first = fit_bandwidth(name), fit_bandwidth(name, exponent=1.0)
    params = preset_pixel(name)[0].params
    c_eff = effective_capacitance_F(first.saturation, params.cutoff_max_hz, params.reference_current_A)
    electrons = params.threshold_on * c_eff * THERMAL_VOLTAGE_V / constants.e
    print(f"  first-order photoreceptor (n held at 1): cutoff_saturation {first.saturation:.4g} (x/ "
          f"{np.exp(first.ln_saturation_err):.2f}), chi2 {first.chi2:.2f} for 7 degrees of freedom (free n: {free.chi2:.2f} "
          f"for 6); dark-pixel cutoff {first.dark_cutoff_hz:.3g} Hz ({free.dark_cutoff_hz / first.dark_cutoff_hz:.2f}x "
          f"below the free law's); C_eff = C_pd/(1 + kappa A) + Miller = {c_eff * 1e15:.2f} fF, "
          f"theta_ON C_eff U_T / q = {electrons:.0f} electrons per ON threshold at any current")
    print("  ln(measured / fit) ON: " + " ".join(f"{r:+.3f}" for r in first.on_residuals)
          + "; OFF: " + " ".join(f"{r:+.3f}" for r in first.off_residuals))


@dataclass(frozen=True)
class BandwidthFit:
    """The power cutoff law ``f = f_max (x / x_sat)^n`` fitted to NIST's ON and OFF latencies, plus a fixed delay each."""

    saturation: float            # cutoff_saturation x_sat at the preset's cutoff_max_hz [1]
    exponent: float              # cutoff_exponent n [1]
    floor_s: tuple               # fixed delays (ON, OFF) the pixel model lacks (comparator, arbiter, time stamp) [s]
    ln_saturation_err: float     # 1-sigma errors of ln x_sat, n and the delays [1, 1, s]
    exponent_err: float
    floor_err_s: tuple
    chi2: float                  # sum of squared weighted residuals, 10 rows - 4 parameters = 6 degrees of freedom
    on_residuals: np.ndarray     # ln(measured / fitted) per irradiance, ON [1]
    off_residuals: np.ndarray    # the same, OFF [1]
    dark_cutoff_hz: float        # the fitted law at the dark current (the LED off) [Hz]


def row_currents(name: str, **pixel) -> tuple[np.ndarray, float, DvsPixel]:
    """Normalised current x of the preset pixel (parameters ``pixel`` changed) at each NIST irradiance
    ``[LED, irradiance]``, the dark pixel's x, and the pixel block."""
    block, pitch_m = preset_pixel(name, **pixel)
    logs = []
    for wavelength_m in LED_WAVELENGTHS_M:
        model = PixelModel(block.params, pitch_m**2, wavelength_m)
        photons_s = (np.asarray(IRRADIANCES_W_M2) * pitch_m**2 * wavelength_m / (constants.h * constants.c)
                     * led_response(name, wavelength_m))
        logs.append(np.log(model.normalised_current(photons_s)))
    return np.exp(np.array(logs)), float(model.normalised_current(np.zeros(1))[0]), block


def step_latencies_s(x: np.ndarray, x_dark: float, params, saturation: float, exponent: float,
                     form: str) -> tuple[np.ndarray, np.ndarray]:
    """(ON, OFF) latency [s] of the one-pole photoreceptor (paper Eq. 16, ``form`` small- or large-signal) to the
    benchmark's step, dark -> ``x`` for :data:`HALF_PERIOD_S` -> dark, in continuous time (the 1 us backward-Euler
    step changes it by < 1 % below 1 kHz).

    ON: the filter leaves ``ln x_dark`` at the lit cutoff ``a = 2 pi f(x)``; the first ON event comes when it has
    risen theta_ON. The memory then lies a fraction of theta_ON below the filter's level at the fall, half of it
    for the median pixel of an ROI (thresholds spread over pixels: the fraction is spread over [0, theta_ON)),
    and the first OFF event comes when the filter, relaxing at the dark cutoff ``2 pi f(x_dark)`` from its level
    at the fall, is theta_OFF below the memory. Small-signal: ``L - Y`` decays as ``e^(-a t)``; large-signal: ``e^-L - e^-Y``
    does (:mod:`evsda.blocks.pixel.lowpass`).
    """
    def cutoff(z):
        return 2 * np.pi * lowpass.cutoff_hz(np.asarray(z, dtype=float), None, params.cutoff_max_hz, "power",
                                             saturation, exponent)

    a_lit, a_dark = cutoff(x), cutoff(x_dark)
    y, y_dark = np.log(x), np.log(x_dark)
    th_on, th_off = params.threshold_on, params.threshold_off
    if form == "large_signal":
        on = -np.log((np.exp(-th_on) - x_dark / x) / (1.0 - x_dark / x)) / a_lit
        w_fall = 1.0 / x + (1.0 / x_dark - 1.0 / x) * np.exp(-a_lit * HALF_PERIOD_S)
        level = -np.log(w_fall)
    else:
        on = -np.log1p(-th_on / (y - y_dark)) / a_lit
        level = y - (y - y_dark) * np.exp(-a_lit * HALF_PERIOD_S)
    memory = level - 0.5 * th_on
    if form == "large_signal":
        off = -np.log((np.exp(th_off - memory) - 1.0 / x_dark) / (w_fall - 1.0 / x_dark)) / a_dark
    else:
        off = -np.log((memory - th_off - y_dark) / (level - y_dark)) / a_dark
    return on, off


def fit_bandwidth(name: str, measured=None, exponent: float | None = None) -> BandwidthFit:
    """Weighted least squares in ln(latency) over the five ON and five OFF rows (large-signal filter):
    ``t_ON = t0_ON + on(x; x_sat, n)``, ``t_OFF = t0_OFF + off(x; x_sat, n)`` (:func:`step_latencies_s`).

    ``measured``: ``{"ON": rows, "OFF": rows}``, (low, high) per irradiance, NIST's by default. Each row's sigma is
    half its ln-range (over ROIs and cameras). The bright rows keep fixed delays the model lacks, ON and OFF apart
    (the Gen3 VGA's OFF floor, ~150 us, lies below its ON one, ~360 us), fitted beside the law, kept out of the preset.
    ``exponent``: ``n`` held at this value (1: the first-order photoreceptor, :func:`effective_capacitance_F`) and
    not fitted (its error then 0; 7 degrees of freedom).
    """
    x, x_dark, block = row_currents(name)
    params = block.params
    rows = MEASURED[name] if measured is None else measured
    on_s, off_s = (np.array([np.mean(r) for r in rows[pol]]) * 1e-6 for pol in ("ON", "OFF"))
    sigma = np.r_[[0.5 * np.log(hi / lo) for lo, hi in rows["ON"]], [0.5 * np.log(hi / lo) for lo, hi in rows["OFF"]]]

    def full(p: np.ndarray) -> np.ndarray:          # (ln x_sat, n, t0_ON, t0_OFF), n inserted when held
        return p if exponent is None else np.r_[p[0], exponent, p[1:]]

    def model_s(p: np.ndarray) -> np.ndarray:       # delay + the geometric mean over the two LEDs
        p = full(p)
        on, off = step_latencies_s(x, x_dark, params, np.exp(p[0]), p[1], "large_signal")
        return np.r_[p[2] * 1e-6 + np.exp(np.log(on).mean(0)), p[3] * 1e-6 + np.exp(np.log(off).mean(0))]

    def residuals(p: np.ndarray) -> np.ndarray:
        return (np.log(np.r_[on_s, off_s]) - np.log(model_s(p))) / sigma

    keep = [0, 1, 2, 3] if exponent is None else [0, 2, 3]
    start = np.array([np.log(params.cutoff_saturation), params.cutoff_exponent, 1.0, 1.0])[keep]
    low, high = np.array([-np.inf, 0.05, 0.0, 0.0]), np.array([np.inf, 2.0, 1e6 * on_s.min(), 1e6 * off_s.min()])
    sol = optimize.least_squares(residuals, start, bounds=(low[keep], high[keep]),
                                 x_scale=np.array([1.0, 0.1, 10.0, 10.0])[keep])
    chi2 = float(np.sum(sol.fun**2))
    err = np.sqrt(np.diag(np.linalg.inv(sol.jac.T @ sol.jac) * max(1.0, chi2 / (2 * x.shape[1] - len(keep)))))
    err = err if exponent is None else np.r_[err[0], 0.0, err[1:]]
    resid = np.log(np.r_[on_s, off_s] / model_s(sol.x))
    p = full(sol.x)
    saturation, n = float(np.exp(p[0])), float(p[1])
    dark_hz = float(lowpass.cutoff_hz(np.array([x_dark]), None, params.cutoff_max_hz, "power", saturation, n)[0])
    return BandwidthFit(saturation, n, (p[2] * 1e-6, p[3] * 1e-6), float(err[0]), float(err[1]),
                        (err[2] * 1e-6, err[3] * 1e-6), chi2, resid[:5], resid[5:], dark_hz)


if __name__ == "__main__":
    main()
