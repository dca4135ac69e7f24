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
settled on the off level; the latency is the first ON event after the rise and the first OFF event after
the fall (50 ms each). The model has no fixed delay (comparator, arbiter, time stamping): in bright light
the measured latency keeps a floor the simulation does not have, so the comparison is in the dim rows.

    python benchmarks/pixel_latency_nist.py
"""

from __future__ import annotations

import numpy as np
from scipy import constants

from evsda.blocks.pixel import DvsPixel
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


def preset_pixel(name: str, saturation_scale: float = 1.0) -> tuple[DvsPixel, float]:
    """The preset's pixel with noise and threshold spread off (cutoff_saturation times ``saturation_scale``), and its pitch [m]."""
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": 1.0})
    pitch_m = graph.nodes["camera"].block.params.pixel_pitch_m
    params = graph.nodes["pixel"].block.params
    block = DvsPixel(params, leak_rate_hz=0.0, shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0, threshold_sigma=0.0,
                     noise_rate_spread_decades=0.0, cutoff_saturation=params.cutoff_saturation * saturation_scale)
    return block, pitch_m


def step_latencies_us(name: str, irradiance_w_m2: float, wavelength_m: float,
                      saturation_scale: float = 1.0) -> tuple[float, float]:
    """(ON, OFF) latency [us] of the preset pixel to an LED going on for 50 ms from off, then off again."""
    block, pitch_m = preset_pixel(name, saturation_scale)
    photons_s = irradiance_w_m2 * pitch_m**2 * wavelength_m / (constants.h * constants.c)
    fp = FocalPlane(1, 1, pitch_m, 1.0)
    rise_ns, fall_ns = int(HALF_PERIOD_S * 1e9), int(2 * HALF_PERIOD_S * 1e9)
    t = np.array([0, rise_ns, fall_ns], dtype=np.int64)
    flux = np.array([0.0, photons_s, 0.0])
    light = Irradiance(fp, wavelength_m, t, flux, np.zeros((3, 0, 2), np.int32), np.zeros((3, 0, 1, 1)))
    events = block.step(Window.from_seconds(0.0, 3 * HALF_PERIOD_S), irradiance=light)["events"]
    on = events.t_ns[(events.p > 0) & (events.t_ns >= rise_ns) & (events.t_ns < fall_ns)]
    off = events.t_ns[(events.p < 0) & (events.t_ns >= fall_ns)]
    return ((on.min() - rise_ns) / 1e3 if on.size else np.inf, (off.min() - fall_ns) / 1e3 if off.size else np.inf)


def main() -> None:
    print("first-event latency after an LED step [us]: NIST measured (median range) | this preset, LED off -> on -> off,"
          " at 523 nm / 681 nm")
    for name, measured in MEASURED.items():
        print(f"\n{name}")
        print(f"{'E [W/m2]':>9} {'ON meas.':>11} {'ON sim.':>15} {'OFF meas.':>11} {'OFF sim.':>15}  meas./sim. (ON, OFF)")
        for k, irradiance in enumerate(IRRADIANCES_W_M2):
            sims = [step_latencies_us(name, irradiance, wl) for wl in LED_WAVELENGTHS_M]
            on_m, off_m = measured["ON"][k], measured["OFF"][k]
            ratio_on = np.mean(on_m) / np.mean([s[0] for s in sims])
            ratio_off = np.mean(off_m) / np.mean([s[1] for s in sims])
            print(f"{irradiance:9.3f} {on_m[0]:5d}-{on_m[1]:<5d} {sims[0][0]:7.1f}/{sims[1][0]:<7.1f} "
                  f"{off_m[0]:5d}-{off_m[1]:<5d} {sims[0][1]:7.1f}/{sims[1][1]:<7.1f}  {ratio_on:5.1f}x {ratio_off:5.1f}x")
        dim, bright = measured["ON"][0], measured["ON"][2]
        slope = np.log(np.mean(dim) / np.mean(bright)) / np.log(IRRADIANCES_W_M2[2] / IRRADIANCES_W_M2[0])
        print(f"measured ON latency ~ E^-{slope:.2f} from 0.006 to 0.166 W/m2 (a photoreceptor-limited latency "
              f"follows 1/f: E^-0.5 for the presets' square-root law, E^-1 for a cutoff proportional to the current)")
        scale = off_matching_scale(name, np.mean(measured["OFF"][0]))
        print(f"cutoff_saturation x {scale:.0f} (cutoffs / {np.sqrt(scale):.1f}) makes the dim OFF latency the measured one "
              f"(a what-if, not applied: --set sensor/pixel.cutoff_saturation=...)")


def off_matching_scale(name: str, measured_us: float) -> float:
    """The factor on cutoff_saturation at which the OFF latency at the dimmest level (both LEDs' mean) is ``measured_us``."""
    def off_us(log_scale: float) -> float:
        return np.mean([step_latencies_us(name, IRRADIANCES_W_M2[0], wl, np.exp(log_scale))[1] for wl in LED_WAVELENGTHS_M])
    low, high = 0.0, np.log(1e6)
    for _ in range(30):                       # bisection in ln(scale): the latency grows with the scale
        mid = 0.5 * (low + high)
        low, high = (mid, high) if off_us(mid) < measured_us else (low, mid)
    return float(np.exp(0.5 * (low + high)))


if __name__ == "__main__":
    main()
