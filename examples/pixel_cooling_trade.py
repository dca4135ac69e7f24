"""Cooling trade study: how many events does a faint satellite give as the sensor is cooled?

A faint satellite (a Gaussian spot of 2e4 photon/s at its peak) crosses a DAVIS346
(library:sensors/davis346.yaml) in one second, on a dark sky. Dark current dilutes the
log contrast of the spot, ln(1 + I_s / I_dark), and halves about every 10 K of cooling
(Arrhenius form of the paper's Eq. 15), so the same satellite gives more events on a
colder sensor. The dilution only acts on the log branch of Eq. 14: below the linear knee
(knee x reference_current_A) a current step gives the same response whatever the dark
current. The study therefore sets the knee below the dark current (reference_current_A
= 1e-17 A), as in a real logarithmic photoreceptor, where the dark current itself is the
knee.

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
CADENCE_NS = 1_000_000


def faint_satellite(fp: FocalPlane, start_ns: int, stop_ns: int, peak=2e4, sky=50.0, size=9, sigma=1.5):
    """A spot crossing the sensor left to right in one second, over a dark sky [photon/s per pixel]."""
    t = np.arange(-(-start_ns // CADENCE_NS) * CADENCE_NS, stop_ns, CADENCE_NS, dtype=np.int64)
    xc, yc = 20.0 + 300.0 * t * 1e-9, 130.0 + 0.0 * t
    x0, y0 = np.floor(xc).astype(int) - size // 2, np.floor(yc).astype(int) - size // 2
    gy, gx = np.mgrid[0:size, 0:size]
    stamp = peak * np.exp(-((gx[None] + x0[:, None, None] - xc[:, None, None]) ** 2
                            + (gy[None] + y0[:, None, None] - yc[:, None, None]) ** 2) / (2 * sigma**2))
    origin = np.stack([x0, y0], -1)[:, None, :].astype(np.int32)
    return Irradiance(fp, 550e-9, t, np.full(t.size, sky), origin, stamp[:, None])


def main() -> None:
    sensor = load_graph("library:sensors/davis346.yaml", overrides={"camera.focal_length_m": 0.5})
    preset = sensor.nodes["pixel"].block.params
    fp = FocalPlane(WIDTH, HEIGHT, PITCH_M, 0.5)
    print(f"{'T [K]':>6} {'I_dark [fA]':>12} {'signal':>7} {'leak':>6} {'shot':>6} {'ON':>6} {'OFF':>6}")
    for temperature in (320.0, 300.0, 290.0, 280.0, 260.0):
        pixel = DvsPixel(preset, temperature_K=temperature, reference_current_A=1e-17, seed=1)
        counts = np.zeros(4, int)
        on = off = 0
        for w in range(10):
            window = Window.from_seconds(w * 0.1, (w + 1) * 0.1, index=w)
            out = pixel.step(window, irradiance=faint_satellite(fp, window.start_ns, window.stop_ns))["events"]
            counts += out.counts_by_cause
            on += int(np.sum(out.p > 0))
            off += int(np.sum(out.p < 0))
        p = pixel.params
        i_dark_fA = 1e15 * dark_current_A(temperature, p.dark_current_density_A_m2, PITCH_M**2,
                                          p.dark_reference_temperature_K, p.dark_activation_energy_eV)
        print(f"{temperature:6.0f} {i_dark_fA:12.3g} {counts[EventCause.SIGNAL]:7d} {counts[EventCause.LEAK]:6d} "
              f"{counts[EventCause.SHOT]:6d} {on:6d} {off:6d}")


if __name__ == "__main__":
    main()
