"""Dense input to the pixel block: a 346 x 260 video at 1 kHz with noise on every pixel (issue 13 item 2).

Prints the time per frame of

* the pixel block's fast implementation on its dense path (``auto`` picks it: the frame is a
  stamp covering the sensor) and on its sparse path (per-pixel change lists, forced), with
  whether the two give identical events;
* a frame-by-frame simulator written here as v2e and IEBCS work: every pixel's state is
  updated every frame with NumPy (the same photoreceptor physics, ``PixelModel.drive``, then
  the low-pass filter, the comparator, leak and shot noise per frame). It is vectorised over
  the frame as those simulators are, and skips what they would not do: ``PixelModel.drive``'s
  search for repeated values (``distinct=True``; a noisy frame has none, and the search, meant
  for a uniform sky, would cost it 1.9 ms per frame).

Target (issue 13): the pixel block >= 10x faster than the frame-by-frame simulator, events
identical on both of its paths. Input frames are made before the clock starts. The dense path and
the frame-by-frame simulator run ``--repeats`` times, alternately (same load), and the medians are
printed, as wall time and as CPU time of the process (all threads); the sparse path runs once. Last,
the dense path's CPU is split into a cost per pixel-sample (the video with thresholds nothing reaches)
and a cost per event (the rest), and the elementary functions of an exact pixel-sample (the drive, the
relaxation's ``exp``, vectorised) and of an event's crossing search (scalar ``exp``, one waiting for the
last) are timed on their own.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/pixel_dense.py [--seconds 0.5] [--noise 0.02] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np
import yaml

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.crossing import power
from evsda.blocks.pixel.drive_kernel import SQUARE_LAW, drive_constants, drive_cutoff, drive_log, drive_rest
from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window
from evsda.library import resolve

FP = FocalPlane(346, 260, 18.5e-6, 0.05)             # DAVIS346 pixels
WINDOW_S = 0.1
FRAME_NS = 1_000_000                                 # 1 kHz video


#: The workload the documented figures were measured on (docs/pixel.md "Dense input"): the DAVIS346 preset as it was
#: before it took its datasheet thresholds and measured noise (fc624aa: 0.1337 / 0.2029, 0.2 Hz leak, 5 Hz shot), so
#: that a better-measured preset does not move a speed comparison between implementations (~2 200 events per frame).
WORKLOAD = {"threshold_on": 0.2, "threshold_off": 0.2, "leak_rate_hz": 0.1, "shot_noise_rate_hz": 0.1}


def davis346_params() -> dict:
    """The DAVIS346 preset's pixel parameters (library:sensors/davis346.yaml), with the benchmark's fixed ``WORKLOAD``."""
    with open(resolve("library:sensors/davis346.yaml")) as f:
        return {**yaml.safe_load(f)["blocks"]["pixel"]["params"], **WORKLOAD}


def frames_of(window: Window, noise: float) -> Irradiance:
    """A bright bar sweeping over a textured scene, ``noise`` (relative, Gaussian) on every pixel of every frame."""
    t = np.arange(-(-window.start_ns // FRAME_NS) * FRAME_NS, window.stop_ns, FRAME_NS, dtype=np.int64)
    height, width = FP.shape
    y, x = np.mgrid[0:height, 0:width]
    scene = 2e5 * (1.5 + np.sin(x / 9.0) * np.cos(y / 13.0))
    frames = np.empty((t.size, 1, height, width))
    for i, tk in enumerate(t * 1e-9):
        rng = np.random.default_rng(round(tk * 1e3))
        bar = 4e6 * np.exp(-((x - 346 * (tk % 1.0)) ** 2) / 50.0)
        frames[i, 0] = (scene + bar) * (1 + noise * rng.standard_normal((height, width)))
    return Irradiance(FP, 550e-9, t, np.zeros(t.size), np.zeros((t.size, 1, 2), np.int32), frames)


class FrameByFrame:
    """Every pixel, every frame (v2e, IEBCS): photoreceptor, low-pass, comparator, leak and shot noise in NumPy."""

    def __init__(self, params: dict, first: np.ndarray, seed: int = 1):
        self.model = PixelModel(DvsPixel.Params(**params), FP.pixel_area_m2, 550e-9)
        p = self.model.params
        self.rng = np.random.default_rng(seed)
        self.on = np.maximum(p.threshold_on + p.threshold_sigma * self.rng.standard_normal(first.size), p.threshold_floor)
        self.off = np.maximum(p.threshold_off + p.threshold_sigma * self.rng.standard_normal(first.size),
                              p.threshold_floor)
        drive = self.model.drive(first)
        self.filtered = drive.y.copy()
        self.memorised = drive.y - self.rng.random(first.size) * self.on
        self.dt = FRAME_NS * 1e-9

    def frame(self, flux: np.ndarray) -> int:
        """One frame of ``dt``: returns the number of events."""
        p = self.model.params
        drive = self.model.drive(flux, distinct=True)      # every value of a noisy frame differs: no np.unique pass
        gain = 1.0 - np.exp(drive.log_a * (self.dt / self.model.dt_s))           # the filter over a whole frame
        self.filtered += gain * (drive.y - self.filtered)
        self.memorised -= (p.leak_rate_hz + drive.parasitic_hz) * self.on * self.dt
        delta = self.filtered - self.memorised
        n_on = np.floor(np.maximum(delta, 0) / self.on)
        n_off = np.floor(np.maximum(-delta, 0) / self.off)
        self.memorised += n_on * self.on - n_off * self.off
        shot = self.rng.random(flux.size) < drive.shot_p * (self.dt / self.model.dt_s)
        self.events = (np.nonzero(n_on)[0], np.nonzero(n_off)[0], np.nonzero(shot)[0])      # this frame's pixels
        return int(n_on.sum() + n_off.sum() + shot.sum())


@numba.njit(error_model="numpy")
def _drives(flux, k, square_law, out):
    for i in range(flux.size):                        # as the dense sweep's first loops: vectorised
        out[0, i], out[1, i] = drive_log(flux[i], k)
    for i in range(flux.size):
        out[0, i], out[1, i] = drive_cutoff(out[0, i], out[1, i], k, square_law)
    for i in range(flux.size):
        out[0, i], out[1, i], out[2, i], out[3, i] = drive_rest(flux[i], out[0, i], out[1, i], k)


@numba.njit(error_model="numpy")
def _powers(log_a, span, out):
    for i in range(log_a.size):                       # the relaxation to the next sample, vectorised
        out[i] = power(log_a[i], span)


@numba.njit(error_model="numpy")
def _power_chain(log_a, n):
    total = 0.0
    for i in range(n):                                # one after the other, as an event's search takes them
        total += power(log_a - total * 1e-30, 500 + (i & 7))
    return total


def elementary_costs(params: dict, flux: np.ndarray) -> tuple[float, float, float]:
    """CPU [ns] of the drive (Eqs. 12-20) and of the relaxation's ``exp`` per pixel-sample in vectorised loops
    over one frame, and of one scalar ``exp`` when each waits for the last (minima of 20 runs)."""
    model = PixelModel(DvsPixel.Params(**params), FP.pixel_area_m2, 550e-9)
    k = drive_constants(model)
    drives = np.empty((4, flux.size))
    log_a = np.empty(flux.size)
    args = [(_drives, (flux, k, k[SQUARE_LAW] != 0.0, drives), flux.size),
            (_powers, (drives[1], np.int64(999), log_a), flux.size), (_power_chain, (-1e-3, 100_000), 100_000)]
    costs = []
    for function, arguments, n in args:
        function(*arguments)
        best = np.inf
        for _ in range(20):
            c = time.process_time()
            function(*arguments)
            best = min(best, time.process_time() - c)
        costs.append(best / n * 1e9)
    return tuple(costs)


def run_block(params: dict, path: str, windows: list[Window], inputs: list[Irradiance]):
    """The pixel block on ``path``: its events and the (wall, CPU) seconds its steps took."""
    block = DvsPixel(seed=3, **params)
    block.input_path = path
    block.setup(RunInfo(duration_ns=windows[-1].stop_ns))
    out, wall, cpu = [], 0.0, 0.0
    for window, irradiance in zip(windows, inputs):
        t, c = time.perf_counter(), time.process_time()
        e = block.step(window, irradiance=irradiance)["events"]
        wall, cpu = wall + time.perf_counter() - t, cpu + time.process_time() - c
        out.append((e.t_ns, e.x, e.y, e.p))
    return [np.concatenate(parts) for parts in zip(*out)], (wall, cpu)


def run_frame_by_frame(params: dict, inputs: list[Irradiance]):
    """The frame-by-frame simulator over the video: its event count and (wall, CPU) seconds."""
    reference = FrameByFrame(params, inputs[0].frame(0).ravel())
    events, t, c = 0, time.perf_counter(), time.process_time()
    for irradiance in inputs:
        for k in range(len(irradiance.t_ns)):
            events += reference.frame(irradiance.stamp_flux[k, 0].ravel())
    return events, (time.perf_counter() - t, time.process_time() - c)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=0.5, help="video length [s]")
    parser.add_argument("--noise", type=float, default=0.02, help="relative noise on every pixel and frame [1]")
    parser.add_argument("--repeats", type=int, default=3, help="runs of the dense path and the simulator [1]")
    args = parser.parse_args()
    params = davis346_params()
    windows = [Window.from_seconds(i * WINDOW_S, (i + 1) * WINDOW_S, index=i)
               for i in range(int(round(args.seconds / WINDOW_S)))]
    inputs = [frames_of(w, args.noise) for w in windows]
    n_frames = sum(len(i.t_ns) for i in inputs)
    print(f"346 x 260 pixels, {n_frames} frames at 1 kHz, noise {args.noise:g}; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.2f}; EVSDA_THREADS={os.environ.get('EVSDA_THREADS', 'all')}")

    run_block(params, "auto", windows[:1], inputs[:1])                  # compiled code loaded before the clock
    dense_times, reference_times = [], []
    for _ in range(args.repeats):                                          # alternately: the same load for both
        dense, times = run_block(params, "auto", windows, inputs)
        dense_times.append(times)
        events, times = run_frame_by_frame(params, inputs)
        reference_times.append(times)
    sparse, sparse_s = run_block(params, "sparse", windows, inputs)
    identical = all(np.array_equal(a, b) for a, b in zip(dense, sparse))
    dense_s, reference_s = np.median(dense_times, axis=0), np.median(reference_times, axis=0)

    per = lambda s: f"{s[0] / n_frames * 1e3:7.2f} ms/frame ({s[1] / n_frames * 1e3:6.2f} CPU)"
    print(f"  pixel block, dense path (auto):  {per(dense_s)}  {dense[0].size:9d} events   "
          f"{reference_s[0] / dense_s[0]:5.1f}x the frame-by-frame simulator in wall time, "
          f"{reference_s[1] / dense_s[1]:5.1f}x in CPU time (target >= 10x)")
    print(f"  pixel block, sparse path:        {per(sparse_s)}  {sparse[0].size:9d} events   "
          f"{reference_s[0] / sparse_s[0]:5.1f}x; events identical to the dense path: {identical}")
    print(f"  frame-by-frame simulator:        {per(reference_s)}  {events:9d} events")
    # where the dense path's CPU goes: the same video with thresholds no input reaches (no event, no solve)
    silent = dict(params, threshold_on=5.0, threshold_off=5.0, threshold_sigma=0.0, leak_rate_hz=0.0,
                  shot_noise_rate_hz=0.0, parasitic_rate_per_lux_hz=0.0)
    _, (_, silent_cpu) = run_block(silent, "auto", windows, inputs)
    samples = n_frames * FP.width_px * FP.height_px
    print(f"  dense path without events: {silent_cpu / samples * 1e9:.1f} ns of CPU per pixel-sample; "
          f"with them {(dense_s[1] - silent_cpu) / max(dense[0].size, 1) * 1e6:.2f} us of CPU per event")
    drive_ns, exp_ns, scalar_ns = elementary_costs(params, np.ascontiguousarray(inputs[0].stamp_flux[0, 0].ravel()))
    print(f"  its elementary functions: the drive (two logarithms, a square root) {drive_ns:.1f} ns and the "
          f"relaxation's exp {exp_ns:.1f} ns of CPU per pixel-sample, vectorised; one scalar exp waiting for the "
          f"last {scalar_ns:.1f} ns")
    print(f"medians of {args.repeats}; load average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
