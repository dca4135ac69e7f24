"""Benchmark of the dvs_pixel block: a full 1280x720 sensor, background noise and one moving source.

Prints the fast implementation's speed against real time and its peak memory, then the
speed-up over the reference implementation on a crop small enough for the reference,
with the agreement of each statistic (fast - reference, in units of its Poisson error).

    python benchmarks/pixel_sensor.py [--seconds 10] [--crop-seconds 0.5] [--lowpass-form large_signal]
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import EventCause, FocalPlane, Irradiance
from evsda.graph import Window

WAVELENGTH_M = 550e-9
CADENCE_NS = 1_000_000               # irradiance samples every 1 ms
STAMP = 11                           # PSF stamp size [pixel]
SIGMA_PX = 1.3                       # PSF width [pixel]


def moving_source(fp: FocalPlane, start_ns: int, stop_ns: int, *, background: float, peak: float,
                  start_xy: tuple[float, float], velocity_px_s: tuple[float, float],
                  sky_step_s: float = 0.0) -> Irradiance:
    """Irradiance of a uniform background plus one Gaussian spot moving in a straight line.

    With ``sky_step_s`` the background brightens by 0.1% every ``sky_step_s`` seconds (a
    sky sampled at that cadence while the field sinks), a new input for every pixel.
    """
    t = np.arange(-(-start_ns // CADENCE_NS) * CADENCE_NS, stop_ns, CADENCE_NS, dtype=np.int64)
    sky = background * (1.0 + 1e-3 * np.floor(t * 1e-9 / sky_step_s)) if sky_step_s else np.full(t.size, background)
    xc = start_xy[0] + velocity_px_s[0] * t * 1e-9
    yc = start_xy[1] + velocity_px_s[1] * t * 1e-9
    x0 = np.floor(xc).astype(np.int64) - STAMP // 2
    y0 = np.floor(yc).astype(np.int64) - STAMP // 2
    gy, gx = np.mgrid[0:STAMP, 0:STAMP]
    dx = gx[None] + x0[:, None, None] - xc[:, None, None]
    dy = gy[None] + y0[:, None, None] - yc[:, None, None]
    stamp = peak * np.exp(-(dx**2 + dy**2) / (2 * SIGMA_PX**2))
    origin = np.stack([x0, y0], axis=-1)[:, None, :].astype(np.int32)
    return Irradiance(fp, WAVELENGTH_M, t, sky, origin, stamp[:, None])


def simulate(implementation: str, fp: FocalPlane, seconds: float, window_s: float, source: dict, **params):
    block = DvsPixel(implementation=implementation, seed=7, **params)
    outs = []
    n = int(round(seconds / window_s))
    tic, cpu = time.perf_counter(), time.process_time()
    for w in range(n):
        win = Window.from_seconds(w * window_s, (w + 1) * window_s, index=w)
        outs.append(block.step(win, irradiance=moving_source(fp, win.start_ns, win.stop_ns, **source))["events"])
        if w == 0:
            first = (time.perf_counter() - tic, time.process_time() - cpu)
    return outs, time.perf_counter() - tic, first


def statistics(outs, n_pixels: int, seconds: float) -> dict:
    cause = np.concatenate([o.cause for o in outs])
    p = np.concatenate([o.p for o in outs])
    t = np.concatenate([o.t_ns for o in outs])
    stats = {f"{c.name.lower()} events": int(np.sum(cause == c)) for c in EventCause}
    stats["ON events"] = int(np.sum(p > 0))
    stats["OFF events"] = int(np.sum(p < 0))
    stats["N_loss"] = int(sum(o.n_loss for o in outs))
    signal_t = t[cause == EventCause.SIGNAL]
    stats["signal mean time [ms]"] = float(signal_t.mean() * 1e-6) if signal_t.size else float("nan")
    return stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated time on the full sensor [s]")
    parser.add_argument("--crop-seconds", type=float, default=0.5, help="simulated time on the crop [s]")
    parser.add_argument("--crop", type=int, default=48, help="crop size for the reference comparison [pixel]")
    parser.add_argument("--no-reference", action="store_true", help="skip the crop comparison with the reference")
    parser.add_argument("--lowpass-form", default="small_signal", choices=("small_signal", "large_signal"),
                        help="the photoreceptor filter's form (dvs_pixel lowpass_form)")
    args = parser.parse_args()

    tic = time.perf_counter()
    tiny = FocalPlane(4, 4, 4.86e-6, 1.0)
    simulate("fast", tiny, 0.01, 0.01, dict(background=2e3, peak=1e4, start_xy=(2.0, 2.0), velocity_px_s=(1.0, 0.0)))
    print(f"compiled pixel loop ready in {time.perf_counter() - tic:.2f} s (Numba: compiled on the first run, "
          f"then loaded from its cache)")
    noise = dict(leak_rate_hz=0.1, shot_noise_rate_hz=0.1, lowpass_form=args.lowpass_form)
    full = FocalPlane(1280, 720, 4.86e-6, 1.0)
    print(f"full sensor {full.width_px}x{full.height_px}, {args.seconds:g} s simulated, dt = 1 us, windows of 0.1 s,")
    print(f"default noise (leak 0.1 Hz, shot noise 0.1 Hz per polarity), one spot moving at 100 px/s, "
          f"lowpass_form {args.lowpass_form}:")
    for label, peak, sky_step_s in (("faint source, peak 5e4 photon/s", 5e4, 0.0),
                                    ("bright source, peak 3e5 photon/s", 3e5, 0.0),
                                    ("bright source, sky brightening every 0.1 s", 3e5, 0.1)):
        source = dict(background=2e3, peak=peak, start_xy=(100.0, 360.0), velocity_px_s=(100.0, 10.0),
                      sky_step_s=sky_step_s)
        cpu = time.process_time()
        outs, wall, first = simulate("fast", full, args.seconds, 0.1, source, **noise)
        cpu = time.process_time() - cpu
        rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        stats = statistics(outs, full.width_px * full.height_px, args.seconds)
        steady = (args.seconds - 0.1) / (cpu - first[1])
        print(f"  {label}: {wall:.2f} s wall ({cpu:.2f} s CPU) = {args.seconds / wall:.2f}x real time "
              f"({args.seconds / cpu:.2f}x on CPU time; first window, with the start of all pixels, {first[0]:.2f} s; "
              f"after it {steady:.2f}x on CPU time), peak RSS {rss_mb:.0f} MB")
        print("    " + ", ".join(f"{name} {value:.6g}" for name, value in stats.items()))

    if args.no_reference:
        return
    crop = FocalPlane(args.crop, args.crop, 4.86e-6, 1.0)
    crop_source = dict(background=2e3, peak=3e5, start_xy=(4.0, args.crop / 2), velocity_px_s=(args.crop / args.crop_seconds * 0.8, 0.0))
    crop_noise = dict(leak_rate_hz=2.0, shot_noise_rate_hz=2.0, time_step_s=1e-5, lowpass_form=args.lowpass_form)
    ref, ref_wall, _ = simulate("reference", crop, args.crop_seconds, 0.05, crop_source, **crop_noise)
    fast, fast_wall, _ = simulate("fast", crop, args.crop_seconds, 0.05, crop_source, **crop_noise)
    print(f"crop {args.crop}x{args.crop}, {args.crop_seconds:g} s, dt = 10 us, noise raised to see its statistics")
    print(f"  reference {ref_wall:.2f} s, fast {fast_wall:.3f} s: speed-up {ref_wall / fast_wall:.0f}x")
    sr, sf = statistics(ref, crop.width_px * crop.height_px, args.crop_seconds), statistics(fast, 0, 0)
    print(f"    {'statistic':24s} {'reference':>10s} {'fast':>10s} {'(f-r)/sigma':>12s}")
    for name in sr:
        r, f = sr[name], sf[name]
        sigma = np.sqrt(max(r + f, 1)) if isinstance(r, int) else float("nan")
        dev = (f - r) / sigma if isinstance(r, int) else float("nan")
        print(f"    {name:24s} {r:10.4g} {f:10.4g} {dev:12.2f}")


if __name__ == "__main__":
    main()
