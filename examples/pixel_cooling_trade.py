"""Cooling trade study: how many events, and how late, does a faint source give as the sensor is cooled?

A faint source (a Gaussian spot of 2e4 photon/s at its peak, ~1 fA on the brightest pixel)
appears at t = 0.5 s on a DAVIS346 (library:sensors/davis346.yaml) and stays, as a GEO does
under sidereal tracking, on a dark sky. Dark current dilutes its log contrast,
ln(1 + I_s / I_dark), and halves about every 10 K of cooling (Arrhenius form of the paper's
Eq. 15), so the same source gives more events on a colder sensor. The preset's photoreceptor
is logarithmic down to its dark current and its bandwidth grows as the square root of its
current (3 kHz at 56 lx on the pixel, Lichtsteiner et al. 2008; 50-180 Hz here): the source is
seen within milliseconds, where the colder sensor, for which it is a larger contrast, fires more.

    python examples/pixel_cooling_trade.py
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.dark_current import dark_current_A
from evsda.blocks.ports import EventCause, FocalPlane, Irradiance
from evsda.graph import Window
from evsda.graph.graphfile import load_graph

WIDTH, HEIGHT, PITCH_M = 346, 260, 18.5e-6
CADENCE_NS = 10_000_000
ON_NS = 500_000_000
SECONDS, WINDOW_S = 6.0, 0.5


def faint_source(fp: FocalPlane, start_ns: int, stop_ns: int, peak=2e4, sky=50.0, size=9, sigma=1.5):
    """A spot at the sensor's centre from ``ON_NS`` on, over a dark sky [photon/s per pixel]."""
    t = np.arange(-(-start_ns // CADENCE_NS) * CADENCE_NS, stop_ns, CADENCE_NS, dtype=np.int64)
    xc, yc = WIDTH / 2, HEIGHT / 2
    x0, y0 = int(xc) - size // 2, int(yc) - size // 2
    gy, gx = np.mgrid[0:size, 0:size]
    spot = peak * np.exp(-((gx + x0 - xc) ** 2 + (gy + y0 - yc) ** 2) / (2 * sigma**2))
    stamp = np.where((t >= ON_NS)[:, None, None], spot[None], 0.0)
    origin = np.tile(np.array([[x0, y0]], np.int32), (t.size, 1, 1))
    return Irradiance(fp, 550e-9, t, np.full(t.size, sky), origin, stamp[:, None])


def main() -> None:
    sensor = load_graph("library:sensors/davis346.yaml", overrides={"camera.focal_length_m": 0.5})
    preset = sensor.nodes["pixel"].block.params
    fp = FocalPlane(WIDTH, HEIGHT, PITCH_M, 0.5)
    print(f"{'T [K]':>6} {'I_dark [fA]':>12} {'signal':>7} {'first [s]':>10} {'leak':>6} {'shot':>6}")
    for temperature in (320.0, 300.0, 290.0, 280.0, 260.0):
        pixel = DvsPixel(preset, temperature_K=temperature, seed=1)
        counts = np.zeros(4, int)
        first = np.inf
        for w in range(int(SECONDS / WINDOW_S)):
            window = Window.from_seconds(w * WINDOW_S, (w + 1) * WINDOW_S, index=w)
            out = pixel.step(window, irradiance=faint_source(fp, window.start_ns, window.stop_ns))["events"]
            counts += out.counts_by_cause
            signal = out.t_ns[out.cause == EventCause.SIGNAL]
            if signal.size:
                first = min(first, (signal.min() - ON_NS) * 1e-9)
        p = pixel.params
        i_dark_fA = 1e15 * dark_current_A(temperature, p.dark_current_density_A_m2, PITCH_M**2,
                                          p.dark_reference_temperature_K, p.dark_activation_energy_eV)
        print(f"{temperature:6.0f} {i_dark_fA:12.3g} {counts[EventCause.SIGNAL]:7d} {first:10.2f} "
              f"{counts[EventCause.LEAK]:6d} {counts[EventCause.SHOT]:6d}")


if __name__ == "__main__":
    main()
