"""The stamp pixels' own input changes swept many pixels at a time (blocks/pixel/own_sweep.py) change no event.

The event-driven loop takes a pixel's input changes one after the other, pixel after pixel. The sweep
takes the pixels under stamps together, change after change, as long as nothing is due before a change,
and leaves the rest (each pixel's last change, its events and what follows them) to the loop. Events,
lost-event counts and the pixels' final state must be those of the loop alone, bit for bit, whatever the
windows, the threads and the room for events, in both forms of the filter; the scene makes the stamp
flicker (every pixel under it changes at every sample), so that pixels fire in the middle of their
changes and leave the sweep there.
"""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import RunInfo, Window

FP = FocalPlane(64, 48, 10e-6, 0.5)
NOISY = dict(leak_rate_hz=2.0, shot_noise_rate_hz=5.0, parasitic_rate_per_lux_hz=1e-3, refractory_period_s=2e-4)


def irradiance(window: Window) -> Irradiance:
    """A sky drifting by 3e-4 every 10 ms and, at 1 kHz, a 7 x 7 stamp crossing the field whose flux flickers by
    ~10 % from sample to sample (every pixel under it changes at every sample)."""
    t = np.arange(-(-window.start_ns // 10**6) * 10**6, window.stop_ns, 10**6, dtype=np.int64)
    sky = 2e5 * (1 + 3e-4 * np.floor(t / 1e7))
    x = 5 + 150 * t * 1e-9
    origin = np.stack([np.round(x).astype(np.int32), np.full(t.size, 20, np.int32)], axis=-1)[:, None]
    flicker = 1.0 + 0.1 * np.sin(t * 1e-6 * 2.1)[:, None, None, None] * np.cos(np.arange(7) * 0.7)[None, None, :, None]
    stamp = 3e6 * flicker * np.ones((t.size, 1, 7, 7))
    return Irradiance(FP, 550e-9, t, sky, origin, stamp)


def loop_alone(real, count, next_step, wake, envelope, pixels, quiet_lo, quiet_end, shared_step, shared_input,
               change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end, *rest):
    """:func:`.deferred.take_and_run` without the sweep: the own rows driven at once, every change by the loop."""
    from evsda.blocks.pixel.deferred import take_quietly
    from evsda.blocks.pixel.drive_kernel import drive_rows
    from evsda.blocks.pixel.pixel_loop import _LAZY, NEVER, run_pixels

    drive_rows(own_flux, drive_k, change_input[:n_own])
    quiet = quiet_lo >= 0
    leak_hz, dt, large = rest[:3]
    if quiet.any():
        take_quietly(real, count, pixels[quiet], quiet_lo[quiet], quiet_end, shared_step, shared_input, leak_hz, dt,
                     large)
    return run_pixels(real, count, next_step, wake, envelope, pixels, change_lo, change_hi, NEVER, change_step,
                      change_input, n_end, *rest, np.int64(0), 0.0, _LAZY, np.empty(0, np.int64), np.empty(0),
                      np.empty(0))


def run(monkeypatch, window_s: float, sweep: bool, form: str, threads: str = "1", room: int = 1024,
        duration_s: float = 0.12):
    from evsda.blocks.pixel import eventdriven, own_sweep

    monkeypatch.setenv("EVSDA_THREADS", threads)
    monkeypatch.setattr(eventdriven, "_FIRST_CAPACITY", room)     # 0: chunks run again with more room
    counted = {"swept": 0, "sweepable": 0}
    if sweep:
        take_and_run = eventdriven.take_and_run

        def counting(real, count, next_step, wake, envelope, pixels, quiet_lo, quiet_end, shared_step, shared_input,
                     change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end, leak_hz, dt,
                     large, *rest):
            own = change_hi - change_lo >= own_sweep.MIN_SWEPT                          # the changes swept,
            swept = own_sweep.take_own(real.copy(), count.copy(), pixels, change_lo.copy(), change_hi, change_step,
                                       change_input.copy(), n_own, own_flux, drive_k, n_end, leak_hz, dt, large)
            counted["sweepable"] += int(np.sum((change_hi - change_lo)[own]))                # counted on copies (the
            counted["swept"] += swept                     # sum after the call, which lets the other threads run)
            return take_and_run(real, count, next_step, wake, envelope, pixels, quiet_lo, quiet_end, shared_step,
                                shared_input, change_lo, change_hi, change_step, change_input, n_own, own_flux,
                                drive_k, n_end, leak_hz, dt, large, *rest)

        monkeypatch.setattr(eventdriven, "take_and_run", counting)
    else:
        monkeypatch.setattr(eventdriven, "take_and_run", loop_alone)
    block = DvsPixel(seed=7, lowpass_form=form, **NOISY)
    block.setup(RunInfo(duration_ns=round(duration_s * 1e9)))
    out, lost = [], 0
    for i in range(int(round(duration_s / window_s))):
        window = Window.from_seconds(i * window_s, (i + 1) * window_s, index=i)
        e = block.step(window, irradiance=irradiance(window))["events"]
        out.append((e.t_ns, e.x, e.y, e.p, e.cause))
        lost += e.n_loss
    state = {name: block.pixel_field(name) for name in ("flux", "filtered", "memorised", "theta_on", "step", "ready")}
    return [np.concatenate(parts) for parts in zip(*out)], lost, state, counted


@pytest.mark.parametrize("window_s, threads, form, room", [(0.02, "1", "large_signal", 1024),
                                                           (0.04, "2", "large_signal", 0),
                                                           (0.03, "2", "small_signal", 1024)])
def test_swept_changes_make_the_events_of_the_loop_alone(monkeypatch, window_s, threads, form, room):
    reference, lost, state, _ = run(monkeypatch, 0.03, False, form)
    events, lost_swept, state_swept, counted = run(monkeypatch, window_s, True, form, threads, room)
    # thousands of stamp changes swept; pixels that fire between their changes leave the sweep there
    assert 2_000 < counted["swept"] < counted["sweepable"]
    t, x, y, p, cause = reference
    under = (np.abs(x.astype(float) - (5 + 150 * t * 1e-9)) < 5) & (np.abs(y.astype(float) - 23) < 5)
    assert np.sum(under & (cause == 0)) > 100                     # the flicker makes the stamp's pixels fire
    for a, b in zip(reference, events):
        np.testing.assert_array_equal(a, b)
    assert lost == lost_swept
    for key in state:
        np.testing.assert_array_equal(state[key], state_swept[key])


@pytest.mark.parametrize("large", [False, True])
def test_batch_crossings_are_the_scalar_searches(large):
    """crossing.batch_crossings, the sweep's searches after a pixel's last change taken many at a time, gives
    search_crossing's step for every search it settles (the others are left to it), over falling filters (the
    searches it takes: crossed.batched), drifts and starts drawn on both sides of the thresholds: crossings at j0,
    soon, seconds ahead, ON after an OFF-ward minimum, or never; it leaves OFF crossings after j0 (rising filters,
    which it does not take, are drawn too, and not taken)."""
    from evsda.blocks.pixel.crossing import (J_LIMIT, NEVER, UNSETTLED, band_bound, batch_crossings, batched,
                                             search_crossing)

    rng = np.random.default_rng(7)
    n = 40000
    log_a = np.log1p(-10 ** rng.uniform(-7, -0.3, n))
    d = 10 ** rng.uniform(-6, 0.7, n) * rng.choice([-1.0, 1.0], n)
    on, off = rng.uniform(0.05, 0.6, n), rng.uniform(0.05, 0.6, n)
    c = rng.uniform(-1.2, 1.2, n) * np.where(d < 0, on, off) - d * rng.uniform(-0.2, 1.2, n)
    delta = 10 ** rng.uniform(-18, -1, n)
    j0 = np.where(rng.random(n) < 0.5, 1, rng.integers(1, 10**6, n)).astype(np.int64)
    known = np.array([band_bound(J_LIMIT, c[k], d[k], log_a[k], delta[k], on[k], off[k], large)[1] for k in range(n)])
    taken = np.array([batched(j0[k], d[k], log_a[k], delta[k]) for k in range(n)])
    np.testing.assert_array_equal(taken, d > 0)
    j0, c, d, log_a, delta, on, off, known = (v[taken] for v in (j0, c, d, log_a, delta, on, off, known))
    out = np.empty(j0.size, np.int64)
    batch_crossings(j0, c, d, log_a, delta, on, off, large, out)
    searched = [search_crossing(j0[k], c[k], d[k], log_a[k], delta[k], on[k], off[k], J_LIMIT, J_LIMIT, known[k],
                                large) for k in range(j0.size)]
    expected, polarity = np.array([j for j, _ in searched]), np.array([p for _, p in searched])
    off_later = (polarity < 0) & (expected != j0)
    settled = out != UNSETTLED
    assert not (settled & off_later).any()
    assert settled[~off_later].mean() > 0.99
    np.testing.assert_array_equal(out[settled], expected[settled])
    on_later = settled & (polarity > 0) & (expected != j0) & (expected < NEVER)
    assert len(set(expected[on_later])) > 5000      # ON after the minimum at many steps, at j0, and never
    assert (settled & (expected == j0)).sum() > 5000 and (settled & (expected == NEVER)).any()


@pytest.mark.parametrize("large", [False, True])
def test_comparator_slopes_at_whole_steps_are_g(large):
    """crossing._comparator_slopes, batch_crossings' one compiled g, gives crossing._g's bits at whole steps (which
    batch_crossings tests there), also where the filter has settled (a^j flushed to 0, _g's shortcut) and at
    J_LIMIT with a^J_LIMIT known (the searches' bound)."""
    from evsda.blocks.pixel.crossing import J_LIMIT, NO_STEP, _comparator_slopes, _g, large_weight, power

    rng = np.random.default_rng(11)
    n = 20000
    log_a = np.log1p(-10 ** rng.uniform(-7, -0.3, n))
    d = 10 ** rng.uniform(-6, 0.7, n) * rng.choice([-1.0, 1.0], n)
    c, delta = rng.uniform(-1.0, 1.0, n), 10 ** rng.uniform(-18, -1, n)
    steps = np.concatenate([rng.integers(1, 10**7, n), np.full(n, J_LIMIT)])
    e = np.array([large_weight(v) for v in d]) if large else np.zeros(n)
    g, slope = np.empty(2 * n), np.empty(2 * n)
    _comparator_slopes(steps.astype(float), c, d, e, log_a, delta, large, g, slope)
    expected = [_g(steps[i], c[i % n], d[i % n], e[i % n], log_a[i % n], delta[i % n], NO_STEP, 0.0, large)
                for i in range(n)]
    expected += [_g(J_LIMIT, c[k], d[k], e[k], log_a[k], delta[k], J_LIMIT, power(log_a[k], J_LIMIT), large)
                 for k in range(n)]
    assert (steps[:n] * log_a <= -707.0).mean() > 0.1             # settled filters among them
    np.testing.assert_array_equal(g.view(np.int64), np.array(expected).view(np.int64))
