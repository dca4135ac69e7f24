"""Configured against measured background activity of every sensor preset (issue 11.2 target: within 5 %).

Each preset's whole pixel array (fast implementation) looks at a uniform field for a few
seconds, in the dark and under a sky of ``--sky-lux`` on the pixel. The configured rates per
pixel are the parameters' own: ON ``R_leak + R_para + r``, OFF ``r`` (Eq. 18-20 at that
current, :class:`~evsda.blocks.pixel.model.PixelModel`); measured are the events per pixel and
second, ON and OFF apart, in the first second and over the whole run. Prints a table with the
relative difference and its Poisson standard error.

    python benchmarks/pixel_noise_rates.py [--seconds 2] [--sky-lux 0.01] [--presets prophesee_gen4 ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import constants

from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import Window
from evsda.graph.graphfile import load_graph

WAVELENGTH_M = 555e-9
LUX_PER_W_AT_555NM = 683.0            # SI definition of the candela [lm W^-1]
PRESETS = ("prophesee_gen4", "prophesee_gen3_vga", "davis346", "dvs128", "cooled_bsi")


def uniform(fp: FocalPlane, start_ns: int, flux: float) -> Irradiance:
    """A uniform photon flux on every pixel from ``start_ns`` [photon s^-1 pixel^-1]."""
    return Irradiance(fp, WAVELENGTH_M, np.array([start_ns], np.int64), np.array([flux]),
                      np.zeros((1, 0, 2), np.int32), np.zeros((1, 0, 1, 1)))


def flux_at_lux(lux: float, pitch_m: float) -> float:
    """Photons per second on a pixel of pitch ``pitch_m`` under ``lux`` of 555 nm light [photon s^-1]."""
    power_W = lux / LUX_PER_W_AT_555NM * pitch_m**2
    return power_W * WAVELENGTH_M / (constants.h * constants.c)


def measure(name: str, lux: float, seconds: float) -> dict:
    graph = load_graph(f"library:sensors/{name}.yaml", overrides={"camera.focal_length_m": 1.0})
    camera = graph.nodes["camera"].block.params
    pixel = graph.nodes["pixel"].block
    fp = FocalPlane(camera.width_px, camera.height_px, camera.pixel_pitch_m, 1.0)
    flux = flux_at_lux(lux, camera.pixel_pitch_m)
    model = PixelModel(pixel.params, fp.pixel_area_m2, WAVELENGTH_M)
    drive = model.drive(np.array([flux]))
    r = float(drive.shot_p[0] / model.dt_s)
    configured = (pixel.params.leak_rate_hz + float(drive.parasitic_hz[0]) + r, r)
    counts = np.zeros((int(np.ceil(seconds)), 2), np.int64)
    started = time.perf_counter()
    for w in range(int(round(seconds / 0.5))):
        window = Window.from_seconds(w * 0.5, (w + 1) * 0.5, index=w)
        out = pixel.step(window, irradiance=uniform(fp, window.start_ns, flux))["events"]
        counts[int(w * 0.5), 0] += int(np.sum(out.p > 0))
        counts[int(w * 0.5), 1] += int(np.sum(out.p < 0))
    return {"name": name, "lux": lux, "pixels": fp.width_px * fp.height_px, "configured": configured,
            "counts": counts, "wall_s": time.perf_counter() - started, "seconds": seconds}


def report(m: dict) -> None:
    n = m["pixels"]
    for polarity, label in ((0, "ON"), (1, "OFF")):
        want = m["configured"][polarity]
        first = m["counts"][0, polarity]
        total = m["counts"][:, polarity].sum()
        rows = [("first second", first, 1.0), (f"all {m['seconds']:g} s", total, m["seconds"])]
        for span, count, seconds in rows:
            got = count / (n * seconds)
            rel = got / want - 1.0 if want > 0 else float("nan")
            err = 1.0 / np.sqrt(max(want * n * seconds, 1.0))
            print(f"{m['name']:<20} {m['lux']:>8.3g} {label:>4} {span:>13} {want:>12.4f} {got:>12.4f} "
                  f"{100 * rel:>+8.2f}% {100 * err:>7.2f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--sky-lux", type=float, default=0.01, help="illuminance on the pixel of the lit case [lx]")
    parser.add_argument("--presets", nargs="*", default=list(PRESETS))
    args = parser.parse_args()
    print(f"{'preset':<20} {'lux':>8} {'pol':>4} {'span':>13} {'configured':>12} {'measured':>12} "
          f"{'diff':>9} {'1 sigma':>8}   [events per pixel and second]")
    for name in args.presets:
        for lux in (0.0, args.sky_lux):
            m = measure(name, lux, args.seconds)
            report(m)
    print("(run on the fast implementation; diff = measured / configured - 1, 1 sigma = Poisson error)")


if __name__ == "__main__":
    main()
