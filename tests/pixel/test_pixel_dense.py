"""The dense input path (whole frames read block by block) against the sparse one (per-pixel change lists).

Video frames, or noise added upstream, change almost every pixel at every sample; the fast
implementation then reads each pixel's changes off whole frames instead of sorting and
scattering change lists. Both paths feed the same compiled loop the same inputs, so the
events must be identical, event for event, whatever the windows or the threads.
"""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.sampling import DENSE_FRACTION, stamp_coverage
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window

FP = FocalPlane(48, 36, 10e-6, 0.5)
NOISY = dict(leak_rate_hz=3.0, shot_noise_rate_hz=3.0, parasitic_rate_per_lux_hz=1e-3)


def video(window: Window, spots: bool = True) -> Irradiance:
    """1 kHz frames: a gradient with 2 % noise on every pixel, a moving spot, two small overlapping stamps, a sky step."""
    t = np.arange(-(-window.start_ns // 10**6) * 10**6, window.stop_ns, 10**6, dtype=np.int64)
    height, width = FP.shape
    y, x = np.mgrid[0:height, 0:width]
    frames = []
    for tk in t * 1e-9:
        noise = np.random.default_rng(round(tk * 1e3)).standard_normal((height, width))     # each frame's own
        base = 2e5 * (1 + x / width) * (1 + 0.02 * noise)
        base += 3e6 * np.exp(-((x - 5 - 200 * tk) ** 2 + (y - 18) ** 2) / 4.0)
        frames.append(base)
    stamps = [np.stack(frames)[:, None]]
    origin = [np.zeros((t.size, 1, 2), np.int32)]
    if spots:                                    # two 5 x 5 stamps on top of the frame, overlapping each other
        stamps.append(np.pad(np.full((t.size, 2, 5, 5), 4e5), ((0, 0), (0, 0), (0, height - 5), (0, width - 5))))
        origin.append(np.tile(np.array([[[20, 10], [22, 12]]], np.int32), (t.size, 1, 1)))
    sky = np.where(t < 60_000_000, 1e4, 1.2e4)
    return Irradiance(FP, 550e-9, t, sky, np.concatenate(origin, axis=1), np.concatenate(stamps, axis=1))


def events(path: str, window_s: float, duration_s: float = 0.12, threads: str | None = None, monkeypatch=None,
           **params):
    if threads is not None:
        monkeypatch.setenv("EVSDA_THREADS", threads)
    block = DvsPixel(seed=5, **{**NOISY, **params})
    block.input_path = path
    block.setup(RunInfo(duration_ns=round(duration_s * 1e9)))
    out = []
    for i in range(int(round(duration_s / window_s))):
        window = Window.from_seconds(i * window_s, (i + 1) * window_s, index=i)
        e = block.step(window, irradiance=video(window))["events"]
        out.append((e.t_ns, e.x, e.y, e.p, e.cause))
        lost = lost + e.n_loss if out[1:] else e.n_loss
    return [np.concatenate(parts) for parts in zip(*out)] + [lost]


def test_dense_input_is_recognised():
    window = Window.from_seconds(0, 0.01)
    irradiance = video(window)
    assert stamp_coverage(irradiance, np.arange(10)) >= DENSE_FRACTION
    sparse = Irradiance(FP, 550e-9, irradiance.t_ns, irradiance.background, irradiance.stamp_origin[:, 1:],
                        irradiance.stamp_flux[:, 1:, :5, :5])
    assert stamp_coverage(sparse, np.arange(10)) < DENSE_FRACTION


def test_dense_and_sparse_paths_give_identical_events(monkeypatch):
    sparse = events("sparse", 0.03)
    assert sparse[0].size > 1000                   # every pixel sees its noise cross a threshold now and then
    for path, window_s, threads in (("dense", 0.03, "1"), ("dense", 0.04, "2"), ("auto", 0.02, "2")):
        other = events(path, window_s, threads=threads, monkeypatch=monkeypatch)
        for a, b in zip(sparse, other):
            np.testing.assert_array_equal(a, b, err_msg=f"{path}, windows of {window_s} s, {threads} threads")


def test_dense_and_sparse_paths_agree_with_the_large_signal_filter(monkeypatch):
    # lowpass_form large_signal: the sweep's relaxation and bound in e^-L, against the sparse path, event for event.
    sparse = events("sparse", 0.03, lowpass_form="large_signal")
    assert sparse[0].size > 1000
    dense = events("dense", 0.04, threads="2", monkeypatch=monkeypatch, lowpass_form="large_signal")
    for a, b in zip(sparse, dense):
        np.testing.assert_array_equal(a, b)


def test_dense_path_reruns_tiles_that_run_out_of_room(monkeypatch):
    # Chunks of a few pixels with room for two events each: most tiles run out of room, are put
    # back as they were (state and events) and run again with more room; no event may change.
    from evsda.blocks.pixel import eventdriven

    sparse = events("sparse", 0.03)
    monkeypatch.setattr(eventdriven, "_FIRST_CAPACITY", 0)
    monkeypatch.setattr(eventdriven, "_DENSE_ROOM", 0.0)         # not the last window's events per pixel either
    monkeypatch.setattr(eventdriven, "_CHUNKS_PER_THREAD", 500)
    dense = events("dense", 0.04, threads="2", monkeypatch=monkeypatch)
    for a, b in zip(sparse, dense):
        np.testing.assert_array_equal(a, b)


def test_the_frames_of_a_video_are_the_sums_of_its_stamp_pixels():
    # dense_frames adds a video's one stamp a frame at a time: the same additions as np.add.at of the summed stamp
    # pixels (each summed from 0), bit for bit, also where a frame's stamp is all zero (no stamp pixels) and for
    # float32 stamps.
    from evsda.blocks.pixel.sampling import dense_frames, stamp_pixels, video_frames

    window = Window.from_seconds(0, 0.01)
    irradiance = video(window, spots=False)
    flux = irradiance.stamp_flux.copy()
    flux[3] = 0.0
    for stamps in (flux, flux.astype(np.float32)):
        given = Irradiance(FP, 550e-9, irradiance.t_ns, irradiance.background, irradiance.stamp_origin, stamps)
        samples = np.arange(1, 9)
        assert video_frames(given, samples) is not None
        expected = np.repeat(given.background[samples, None], FP.width_px * FP.height_px, axis=1)
        sparse = stamp_pixels(given, samples)
        np.add.at(expected, (sparse.sample, sparse.pixel), sparse.flux)
        np.testing.assert_array_equal(dense_frames(given, samples).view(np.int64), expected.view(np.int64))


def test_chunks_shrink_and_the_room_for_events_follows_the_last_window(monkeypatch):
    # The chunks shrink to the end (the threads end close together), and from the second window on the dense path's
    # chunks have room for the events the last window made per pixel: each chunk runs once, none again.
    from evsda.blocks.pixel import eventdriven

    for n, threads in ((89_960, 2), (5_000, 4), (7, 2), (1, 1)):
        sizes = np.diff(eventdriven.chunk_bounds(n, threads))
        assert sizes.sum() == n and np.all(sizes > 0) and np.all(np.diff(sizes) <= 0)
        assert sizes[-1] <= max(1, n // (4 * eventdriven._CHUNKS_PER_THREAD * threads))
    calls = []
    kernel = eventdriven.run_dense_chunk
    monkeypatch.setattr(eventdriven, "run_dense_chunk", lambda *args: calls.append(args[4].size) or kernel(*args))
    monkeypatch.setattr(eventdriven, "_FIRST_CAPACITY", 0)
    monkeypatch.setattr(eventdriven, "worker_threads", lambda: 2)
    block = DvsPixel(seed=5, **{**NOISY, "threshold_on": 0.01, "threshold_off": 0.01})   # ~5 events a pixel a window
    block.input_path = "dense"
    block.setup(RunInfo(duration_ns=120_000_000))
    chunks = len(eventdriven.chunk_bounds(FP.width_px * FP.height_px, 2)) - 1
    for i in range(3):
        window = Window.from_seconds(i * 0.04, (i + 1) * 0.04, index=i)
        calls.clear()
        events = block.step(window, irradiance=video(window))["events"]
        assert events.t_ns.size > 4 * FP.width_px * FP.height_px
        assert len(calls) > chunks if i == 0 else len(calls) == chunks
