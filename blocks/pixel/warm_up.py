"""The pixel block's compiled loops, called once on a small scene: what a run's first window compiles.

:func:`run_small_scene` is what :mod:`evsda.graph.compile_ahead` runs in a second process while a run's first
windows compile the optics (the block starts it in ``setup``). The scene takes the paths of a tracked pass: a
320 x 180 sensor under a uniform sky that changes every 10 ms (the background changes the pixels defer) and a
Gaussian spot streaking across it at 1500 px/s (a stamp's own changes, swept and then looped), three 0.05 s windows
sampled every 1 ms, so that the loops are compiled for the same argument types as in a run.
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window

#: the modules of the compiled loops the block calls (the loops they call are compiled and cached with them), for the
#: cache check of :func:`evsda.graph.compile_ahead.start`
MODULES = tuple(f"evsda.blocks.pixel.{name}" for name in ("deferred", "drive_kernel", "own_changes", "pixel_loop",
                                                         "sampling"))


def run_small_scene(params: dict) -> int:
    """Run a pixel block with ``params`` on the small scene; the number of events (the compiles are the point)."""
    from .block import DvsPixel          # this module is imported by the block
    block = DvsPixel(params, seed=1)
    block.setup(RunInfo(duration_ns=150_000_000))
    fp = FocalPlane(320, 180, 4.86e-6, 1.0)
    size, cadence_ns, events = 7, 1_000_000, 0
    gy, gx = np.mgrid[0:size, 0:size]
    for w in range(3):
        window = Window.from_seconds(0.05 * w, 0.05 * (w + 1), index=w)
        t = np.arange(window.start_ns, window.stop_ns, cadence_ns, dtype=np.int64)
        sky = 3e3 * (1.0 - 3e-3 * np.floor(t / 1e7))                      # photon s^-1 pixel^-1
        xc, yc = 20.0 + 1500.0 * t * 1e-9, 90.0 + 200.0 * t * 1e-9           # spot centre [px]
        x0, y0 = np.floor(xc).astype(int) - size // 2, np.floor(yc).astype(int) - size // 2
        stamp = 3e6 * np.exp(-((gx[None] + x0[:, None, None] - xc[:, None, None]) ** 2
                               + (gy[None] + y0[:, None, None] - yc[:, None, None]) ** 2) / (2 * 1.2 ** 2))
        irradiance = Irradiance(fp, 550e-9, t, sky, np.stack([x0, y0], -1).astype(np.int32)[:, None], stamp[:, None])
        events += len(block.step(window, irradiance=irradiance)["events"])
    return events
