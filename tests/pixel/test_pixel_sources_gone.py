"""A window's pixel work follows the sources on the detector now, not those that have come and gone.

The optics keeps a stamp slot for every source it is given, and a star field gives every star the
pointing sweeps over in the whole run (1586 in a 60 s tracked pass, ~20 on the detector at a time): a
source off the detector has a stamp of zero flux at the origin. Those stamps must change nothing (same
events, same pixel state) and cost nothing that grows with their number (the 60 s pass peaked at
1.1-1.4 GB when each window expanded all of them; docs/speed.md, Scaling).
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.sampling import stamp_pixels
from evsda.blocks.ports import Irradiance
from evsda.graph import RunInfo, Window

WINDOW_S, WINDOWS = 0.02, 4


def with_gone(irradiance: Irradiance, n_gone: int) -> Irradiance:
    """``irradiance`` with ``n_gone`` more stamps as the optics writes a source off the detector: zero flux at (0, 0)."""
    n_t, _, h, w = irradiance.stamp_flux.shape
    return Irradiance(irradiance.focal_plane, irradiance.wavelength_m, irradiance.t_ns, irradiance.background,
                      np.concatenate([irradiance.stamp_origin, np.zeros((n_t, n_gone, 2), np.int32)], axis=1),
                      np.concatenate([irradiance.stamp_flux, np.zeros((n_t, n_gone, h, w))], axis=1))


def run(scenes, n_gone: int):
    """Events and final pixel state of a spot crossing a small sensor, with ``n_gone`` departed sources beside it."""
    fp = scenes.focal_plane(40, 12)
    block = DvsPixel(seed=3, leak_rate_hz=2.0, shot_noise_rate_hz=2.0)
    block.setup(RunInfo(duration_ns=round(WINDOWS * WINDOW_S * 1e9)))
    events = []
    for w in range(WINDOWS):
        window = Window.from_seconds(w * WINDOW_S, (w + 1) * WINDOW_S, index=w)
        spot = scenes.moving_spot(fp, scenes.grid(window.start_ns, window.stop_ns, 1_000_000), velocity=(400.0, 0.0))
        events.append(block.step(window, irradiance=with_gone(spot, n_gone))["events"])
    return scenes.concat(events), block.get_state()


def test_departed_sources_change_no_event_and_no_state(scenes):
    alone, state_alone = run(scenes, 0)
    crowded, state_crowded = run(scenes, 300)
    assert alone["t"].size > 50 and np.count_nonzero(alone["cause"] == 0) > 20   # the spot fires, noise too
    for name in ("t", "x", "y", "p", "cause", "counts"):
        np.testing.assert_array_equal(alone[name], crowded[name], err_msg=name)
    assert alone["n_loss"] == crowded["n_loss"]
    pixels_alone, pixels_crowded = state_alone["pixels"], state_crowded["pixels"]
    assert pixels_alone.keys() == pixels_crowded.keys()
    for key in pixels_alone:
        np.testing.assert_array_equal(pixels_alone[key], pixels_crowded[key], err_msg=key)


def test_departed_sources_cost_no_memory(scenes):
    fp = scenes.focal_plane(64, 48)
    spot = scenes.moving_spot(fp, scenes.grid(0, 20_000_000, 1_000_000), velocity=(400.0, 0.0), size=5)
    samples = np.arange(spot.t_ns.size)

    def traced_peak(irradiance: Irradiance) -> tuple[int, object]:
        tracemalloc.start()
        try:
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            result = stamp_pixels(irradiance, samples)
            return tracemalloc.get_traced_memory()[1] - before, result
        finally:
            tracemalloc.stop()

    crowded = with_gone(spot, 2000)                 # 20 samples x 2001 stamps x 5 x 5: 8 MB of stamps
    peak_alone, alone = traced_peak(spot)
    peak_crowded, listed = traced_peak(crowded)
    for name in ("sample", "pixel", "flux"):
        np.testing.assert_array_equal(getattr(alone, name), getattr(listed, name), err_msg=name)
    # a few flags per (sample, stamp) and one sample's stamps as flags, plus 64 kB of slack; expanding every stamp
    # of the window (as before) took several times the stamps' 8 MB
    n_stamps, h, w = crowded.stamp_flux.shape[1:]
    allowance = 3 * samples.size * n_stamps + n_stamps * h * w + (64 << 10)
    assert peak_crowded - peak_alone < allowance < crowded.stamp_flux.nbytes / 20
