"""Background changes left out of pixels they cannot make fire (blocks/pixel/deferred.py) change no event.

A uniform background that drifts changes every pixel's input at each of its samples. The fast
implementation gives such a change only to the pixels it could make fire before the window's end
(a bound on the comparator input) and lets the others take it later, in order. The reference gives
every change to every pixel at once. Events, lost-event counts and the pixels' final state must be
identical, whatever the windows and the threads, also when the background jumps far enough to make
pixels fire by itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.pixel.eventdriven import EventDrivenPixels
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window

FP = FocalPlane(64, 48, 10e-6, 0.5)
NOISY = dict(leak_rate_hz=2.0, shot_noise_rate_hz=2.0, parasitic_rate_per_lux_hz=1e-3)


def sky(t_ns: np.ndarray) -> np.ndarray:
    """A sky brightening by 3e-4 every 10 ms sample, with a 30 % jump at 0.13 s and a 20 % drop at 0.21 s."""
    step = np.floor(t_ns / 1e7)
    return 2e5 * (1 + 3e-4 * step) * np.where(t_ns >= 130_000_000, 1.3, 1.0) * np.where(t_ns >= 210_000_000, 0.8, 1.0)


def irradiance(window: Window) -> Irradiance:
    """Sky samples every 10 ms, a 5 x 5 stamp crossing the field at 1 kHz."""
    t = np.arange(-(-window.start_ns // 10**6) * 10**6, window.stop_ns, 10**6, dtype=np.int64)
    x = 5 + 150 * t * 1e-9
    origin = np.stack([np.round(x).astype(np.int32), np.full(t.size, 20, np.int32)], axis=-1)[:, None]
    stamp = np.full((t.size, 1, 5, 5), 3e6)
    return Irradiance(FP, 550e-9, t, sky(t), origin, stamp)


def run(window_s: float, defer: bool, monkeypatch, threads: str = "1", duration_s: float = 0.3,
        form: str = "small_signal", room: int = 1024):
    from evsda.blocks.pixel import eventdriven

    monkeypatch.setenv("EVSDA_THREADS", threads)
    monkeypatch.setattr(eventdriven, "_FIRST_CAPACITY", room)     # 0: chunks run again with more room
    monkeypatch.setattr(EventDrivenPixels, "defer_background", defer)
    block = DvsPixel(seed=11, lowpass_form=form, **NOISY)
    block.setup(RunInfo(duration_ns=round(duration_s * 1e9)))
    out, lost, left_behind = [], 0, 0
    for i in range(int(round(duration_s / window_s))):
        window = Window.from_seconds(i * window_s, (i + 1) * window_s, index=i)
        e = block.step(window, irradiance=irradiance(window))["events"]
        out.append((e.t_ns, e.x, e.y, e.p, e.cause))
        lost += e.n_loss
        applied = block.pixels["applied"]
        left_behind = max(left_behind, int(np.sum(applied < applied.max())))
    state = {name: block.pixel_field(name) for name in ("flux", "filtered", "memorised", "theta_on", "step", "ready")}
    return [np.concatenate(parts) for parts in zip(*out)], lost, left_behind, state


@pytest.mark.parametrize("window_s, threads, form, room", [(0.02, "1", "small_signal", 1024),
                                                           (0.05, "2", "small_signal", 0),
                                                           (0.05, "2", "large_signal", 1024)])
def test_left_out_background_changes_change_no_event(monkeypatch, window_s, threads, form, room):
    # large_signal: e^-L relaxes linearly towards e^-Y, so L stays in the hull of its start and its targets: the
    # deferral bound holds unchanged; room 0: chunks that run out of room for events run again (the changes they
    # took quietly first are taken once)
    reference, lost, behind, _ = run(0.03, False, monkeypatch, form=form)
    assert behind == 0
    events, lost_fast, behind_fast, _ = run(window_s, True, monkeypatch, threads, form=form, room=room)
    assert behind_fast > FP.width_px * FP.height_px // 2          # most pixels left the drift for later
    t, x, y, p, cause = reference
    jump = (t >= 130_000_000) & (t < 131_000_000)
    assert np.sum(jump & (p > 0)) > 100                           # the jump itself makes many pixels fire
    for a, b in zip(reference, events):
        np.testing.assert_array_equal(a, b)
    assert lost == lost_fast


def test_pixels_read_the_same_state(monkeypatch):
    *_, reference = run(0.03, False, monkeypatch, duration_s=0.12)
    *_, fast = run(0.04, True, monkeypatch, duration_s=0.12)      # pixel_field gives them their pending changes
    for key in reference:
        np.testing.assert_array_equal(reference[key], fast[key])


@pytest.mark.parametrize("form", ["small_signal", "large_signal"])
def test_pixels_read_only_by_their_wake_step_are_those_the_bound_leaves_out(monkeypatch, form):
    # select_pixels reads only the wake step of a pixel shown quiet under the envelope of the background changes
    # (pixel_loop.quiet_until); reading every pixel's bound instead (refresh) must choose the same pixels, window
    # by window, through the sky's drift and its jumps (which renew the envelope)
    from evsda.blocks.pixel import eventdriven

    select = eventdriven.select_pixels
    seen = {"windows": 0, "renewed": 0, "quiet": 0}

    def checked(real, count, next_step, wake, applied, touched, changed, n_end, *rest):
        *bounds, defer, refresh, kept, offset, n_kept, change_first, change_counts, quiet_from, first, stop = rest
        if refresh:
            seen["renewed"] += 1
        else:
            seen["windows"] += 1
            wake_from = int(bounds[5][3])                                   # the envelope's: wake codes from it
            seen["quiet"] = max(seen["quiet"], int(np.sum(wake[first:stop].astype(np.int64) + wake_from >= n_end)))
            full = select(real, count, next_step, wake.copy(), applied.copy(), touched, changed, n_end, *bounds, defer,
                          True, kept, offset, n_kept, change_first, change_counts, quiet_from, first, stop)
        out = select(real, count, next_step, wake, applied, touched, changed, n_end, *rest)
        if not refresh:
            for a, b in zip(full, out):
                np.testing.assert_array_equal(a, b)
        return out

    monkeypatch.setattr(eventdriven, "select_pixels", checked)
    run(0.02, True, monkeypatch, form=form)
    assert seen["windows"] >= 5 and seen["renewed"] >= 3         # both kinds of window seen
    assert seen["quiet"] > FP.width_px * FP.height_px // 2        # most pixels read by their wake step alone


@pytest.mark.parametrize("large", [False, True])
@pytest.mark.parametrize("shared_l", [False, True])
def test_changes_taken_together_are_those_taken_one_pixel_at_a_time(large, shared_l):
    # take_quietly sweeps the pixels change by change (vectorised); its reference takes one pixel's changes after
    # the other: the same state bit for bit, also for pixels already at or past a change's step (no relaxation),
    # and where runs of pixels share their L (the sweep relaxes L once a run: shared_l, with +0.0 and -0.0 apart)
    from evsda.blocks.pixel.deferred import take_quietly, take_quietly_reference
    from evsda.blocks.pixel.pixel_loop import COUNT, L_, LOG_A, M_, NOISE_SCALE, PARA, REAL, STEP, TH_ON, Y

    rng = np.random.default_rng(5)
    n, k = 3000, 40
    real = rng.normal(size=(n, len(REAL)))
    real[:, L_], real[:, M_], real[:, Y] = rng.normal(-2, 3, n), rng.normal(-2, 3, n), rng.normal(-2, 3, n)
    if shared_l:
        real[:, L_] = rng.choice([0.0, -0.0, -2.5, 1.0], n, p=[0.3, 0.3, 0.3, 0.1])
    real[:, LOG_A] = -10.0 ** rng.uniform(-9, 1, n)
    real[:, PARA], real[:, TH_ON], real[:, NOISE_SCALE] = rng.uniform(0, 5, n), rng.uniform(0.05, 0.5, n), 1.0
    count = rng.integers(0, 100, size=(n, len(COUNT)))
    steps = np.cumsum(rng.integers(1, 3000, k)) + 50
    inputs = rng.normal(size=(k, len(REAL)))
    inputs[:, LOG_A] = -10.0 ** rng.uniform(-9, 1, k)
    inputs[:, PARA] = rng.uniform(0, 5, k)
    count[:, STEP] = steps[0] + rng.integers(-60, 400, n)           # some at or past the first changes' steps
    pixels = np.sort(rng.choice(n, 2000, replace=False))
    lo = rng.integers(0, k - 1, pixels.size)
    end = np.int64(k - 1)
    fast_real, fast_count = real.copy(), count.copy()
    take_quietly(fast_real, fast_count, pixels, lo, end, steps, inputs, 0.3, 1e-6, large)
    take_quietly_reference(real, count, pixels, lo, end, steps, inputs, 0.3, 1e-6, large)
    np.testing.assert_array_equal(fast_real.view(np.int64), real.view(np.int64))
    np.testing.assert_array_equal(fast_count, count)



def test_wake_codes_saturate_and_sixteen_compare_as_one_at_a_time():
    # select_pixels keeps wake steps as 32-bit codes from a first step (pixel_loop.wake_code), saturated, and compares
    # sixteen at once (deferred._awake_mask): the same answers as the steps themselves within the codes' span
    import numba

    from evsda.blocks.pixel.crossing import NEVER
    from evsda.blocks.pixel.deferred import _awake_mask
    from evsda.blocks.pixel.pixel_loop import WAKE_SPAN, wake_code

    @numba.njit
    def codes(steps, wake_from):
        out = np.empty(steps.size, np.int32)
        for i in range(steps.size):
            out[i] = wake_code(steps[i], wake_from)
        return out

    @numba.njit
    def masks(wake, limit):
        out = np.empty(wake.size // 16, np.uint64)
        for i in range(out.size):
            out[i] = _awake_mask(wake, 16 * i, limit)
        return out

    rng = np.random.default_rng(3)
    wake_from = np.int64(5_000_000_000)
    steps = np.concatenate([wake_from + rng.integers(-2**33, 2**33, 4000), [NEVER, -NEVER, wake_from,
                                                                           wake_from + WAKE_SPAN + 1]])
    steps = np.concatenate([steps, wake_from + rng.integers(-50, 50, 4000)])[:8000]
    wake = codes(steps, wake_from)
    assert wake.max() == WAKE_SPAN and wake.min() == -WAKE_SPAN
    for n_end in wake_from + np.array([-2**30, -7, 0, 3, 2**30, WAKE_SPAN - 1]):
        awake = steps < n_end                                      # the steps' own answer
        limit = n_end - wake_from
        np.testing.assert_array_equal(wake.astype(np.int64) < limit, awake)
        bits = masks(wake, limit)
        expected = (awake.reshape(-1, 16) * (1 << np.arange(16))).sum(axis=1).astype(np.uint64)
        np.testing.assert_array_equal(bits, expected)


def test_state_tables_start_on_a_cache_line_and_a_restored_state_steps_alike(monkeypatch):
    # eventdriven._line_aligned: the tables start on a cache line; a state whose tables do not (a restored one) is
    # copied to tables that do when an engine takes it, and steps to the same events
    monkeypatch.setenv("EVSDA_THREADS", "1")
    blocks = [DvsPixel(seed=11, **NOISY) for _ in range(2)]
    windows = [Window.from_seconds(i * 0.03, (i + 1) * 0.03, index=i) for i in range(6)]
    for block in blocks:
        block.setup(RunInfo(duration_ns=round(0.18 * 1e9)))
        for window in windows[:3]:
            block.step(window, irradiance=irradiance(window))
    assert all(block.pixels[key].ctypes.data % 64 == 0 for block in blocks for key in ("real", "count"))
    for key in ("real", "count"):                                 # 8 bytes past a line, as a restored state may be
        table = blocks[1].pixels[key]
        raw = np.empty(table.nbytes + 72, np.uint8)
        start = -raw.ctypes.data % 64 + 8
        moved = raw[start:start + table.nbytes].view(table.dtype).reshape(table.shape)
        moved[...] = table
        blocks[1].pixels[key] = moved
    blocks[1].set_state(blocks[1].get_state())
    for window in windows[3:]:
        first, second = (block.step(window, irradiance=irradiance(window))["events"] for block in blocks)
        for name in ("t_ns", "x", "y", "p", "cause"):
            np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    assert all(blocks[1].pixels[key].ctypes.data % 64 == 0 for key in ("real", "count"))
