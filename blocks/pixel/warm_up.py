"""The pixel block's compiled loops, with the argument types a run's first window calls them with.

:data:`TASKS` is what :mod:`evsda.graph.compile_ahead` compiles in a second process (and in the run's own, once it
waits) while a run's first windows compile the optics (the block starts it in ``setup``): each cached loop the block
calls, with its argument types. :func:`run_small_scene` is the small scene they come from, and what the tests check
them against: the paths of a tracked pass, a 320 x 180 sensor under a uniform sky that changes every 10 ms (the
background changes the pixels defer) and a Gaussian spot streaking across it at 1500 px/s (a stamp's own changes,
swept and then looped), three 0.05 s windows sampled every 1 ms.
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window

#: the modules of the compiled loops the block calls (the loops they call are compiled and cached with them), for the
#: cache check of :func:`evsda.graph.compile_ahead.start`
MODULES = tuple(f"evsda.blocks.pixel.{name}" for name in ("deferred", "drive_kernel", "eventlog", "own_changes",
                                                         "pixel_loop", "sampling"))

_DEFERRED, _LOOP, _OWN, _SAMPLING = (f"evsda.blocks.pixel.{name}" for name in ("deferred", "pixel_loop",
                                                                                   "own_changes", "sampling"))

#: the loops the block calls and their argument types (Numba's spelling), as the scene calls them: the child that
#: compiles ahead takes them from the first, the run's process from the last. ``take_and_run`` first: with the loops
#: it calls (``run_pixels``, the sweep and ``drive_rows``, the searches, ``start_pixels``' schedule) it is ~4/5 of the
#: compile, and each later one is independent of the others
TASKS = (
    (f"{_DEFERRED}:take_and_run", "f8[:, ::1], i8[:, ::1], i8[::1], i4[::1], f8[::1], i8[::1], i8[::1], i8, i8[::1], "
                                  "f8[:, ::1], i8[::1], i8[::1], i8[::1], f8[:, ::1], i8, f8[::1], f8[::1], i8, f8, f8, "
                                  "b1, i8, f8, i8, b1, f8, f8, f8, f8, i8[::1], i8[::1], i1[::1], u1[::1]"),
    ("evsda.blocks.pixel.drive_kernel:drive_rows", "f8[::1], f8[::1], f8[:, ::1]"),
    (f"{_LOOP}:start_pixels", "f8[:, ::1], i8[:, ::1], i8[::1], i8[::1], f8[:, ::1], f8[::1], f8[::1], f8[::1], "
                              "f8[::1], f8[::1], f8[::1], i8, f8, f8, b1, i8, f8"),
    (f"{_SAMPLING}:_summed_stamps", "f8[:, :, :, ::1], i4[:, :, ::1], i8[::1], i8[::1], i8[::1], i8, i8"),
    (f"{_DEFERRED}:select_pixels", "f8[:, ::1], i8[:, ::1], i8[::1], i4[::1], i8[::1], i8[::1], i8[::1], i8, i8, i8, "
                                   "f8[::1], f8[::1], f8[::1], f8[::1], f8, f8, b1, b1, i8, i8, i8, i8[::1], i8[::1], "
                                   "i8[::1], i8, i8"),
    (f"{_OWN}:window_changes", "i8[::1], i8[::1], i8[::1], f8[::1], f8[:, ::1], i8[::1], i8, i8[::1], f8[:, ::1], f8, "
                               "f8[::1], i8[::1]"),
    (f"{_OWN}:under_stamps", "i8[::1], i8[::1], i4[::1]"),
    (f"{_SAMPLING}:_adds_flux", "f8[:, :, ::1], i8[::1], b1[:, ::1]"),
    ("evsda.blocks.pixel.eventlog:time_ordered", "i8[::1], i8[::1], i1[::1], u1[::1], i8, i8, i8, i8[::1], u2[::1], u2[::1], "
                                                "i1[::1], u1[::1], i8[::1], i8[::1], i8[::1], i8[::1], i8[::1]"),
)


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
