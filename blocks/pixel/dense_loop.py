"""The compiled loop of the dense input path: pixels walk their samples straight from the frames, many at a time.

Video frames, or noise added upstream, change nearly every pixel at every sample. Instead
of listing (pixel, change) pairs, the pixels of a tile read their photon flux at each sample
of the window off the frame-major input (``background[k] + stamps[k, pixel]``: the additions,
in the same order, that the sparse path makes; the frames two samples ahead are prefetched)
and take the input change as the event-driven loop (:func:`.pixel_loop.run_pixels`) would, in
two loops over the tile that the compiler vectorises, the first for the new drive
(:func:`.drive_kernel.drive_one`), the second for the rest:

* a change is *quiet* when the pixel has no event due before it and the next sample
  changes its flux again: the pixel then relaxes to the change (:func:`.pixel_loop.relaxed_by`),
  takes its new drive and, in the common case where the comparator input provably stays
  inside its band until the next sample (:func:`.crossing.stays_in_band`), has no crossing
  to solve; otherwise the crossing is solved exactly (:func:`.crossing.search_crossing`,
  past the bound), as ``run_pixels`` does;
* a change with an event due before it is taken by ``run_pixels`` for that sample (its
  events, then the change, with the drive and the retention the sweep computed), and the
  pixel rejoins the sweep;
* a pixel whose flux stops changing from sample to sample (the next sample holds it) leaves
  the sweep there, and ``run_pixels`` takes it from there, through its remaining samples and
  events, as it does every pixel with an event due after its last change.

Every step is the arithmetic ``run_pixels`` performs, in the same order, with the same
functions (:mod:`.fastmath` vectorises to the same bits), so the events are those of the
sparse path (tested). Nothing of size pixels x samples is allocated.
"""

from __future__ import annotations

import numba
import numpy as np

from .crossing import J_LIMIT, NEVER, first_crossing_one, power, search_crossing, stays_in_band
from .comparator import TOLERANCE
from .drive_kernel import SQUARE_LAW, drive_cutoff, drive_into, drive_log, drive_rest
from .pixel_loop import (ACCEPT, C_LEAK, C_PARA, CMP_NEXT, FLUX, L_, LOG_A, M_, NOISE_SCALE, OWED, PARA, READY,
                         SHOT_NEXT, STEP, TH_OFF, TH_ON, Y, _EXACT, _prefetch, _settle_step, relaxed_by, run_pixels)

TILE = 128                   # pixels swept together (64: ~5 % more CPU, 256: the same)
_SOLVE = np.int64(-1)        # "crossing to be solved" mark in the sweep
_STEPPED = np.int64(2)       # "run_pixels takes this sample" mark in the sweep
_FIRST, _ONE = np.int64(0), np.int64(1)     # run_pixels' counts typed int64, not literals: one compile serves all
# per-pixel fields of a tile (rows of the sweep's tables)
(F_FLUX, F_L, F_M, F_LEAK, F_PARA_C, F_Y, F_LOG_A, F_PARA, F_ACCEPT, F_TH_ON, F_TH_OFF, F_SCALE, F_RETAIN, F_NOW,
 F_NEXT, F_NEW_Y, F_NEW_LOG_A, F_NEW_PARA, F_NEW_ACCEPT, N_FLOAT) = range(20)     # F_NEW_*: the drive of F_NOW
(I_STEP, I_READY, I_DUE, I_CMP, I_ACTIVE, I_LEAVE, I_SPAN, I_OPEN, N_INT) = range(9)
jit = numba.njit(cache=True, error_model="numpy")
inline = numba.njit(cache=True, error_model="numpy", inline="always")


@jit
def _sweep(fs, js, n, t_now, t_next, last, leak_hz, dt, large, drive_k):
    """:func:`_drive_law` then :func:`_sweep_law`, each with its constant (the cutoff law's ``square_law``, the
    filter's form ``large``, typed ``Literal[bool]``: a compiled loop for each value, as constant as when inlined).

    Compiled apart, not inlined: four inlined copies of the whole sweep took 4x the compile time (same loops)."""
    if drive_k[SQUARE_LAW] != 0.0:
        _drive_law(fs, n, drive_k, True)
    else:
        _drive_law(fs, n, drive_k, False)
    if large:
        return _sweep_law(fs, js, n, t_now, t_next, last, leak_hz, dt, True)
    return _sweep_law(fs, js, n, t_now, t_next, last, leak_hz, dt, False)


@jit
def _drive_law(fs, n, drive_k, square_law):
    """The drive (``F_NEW_*``) of the flux ``F_NOW`` of pixels ``0 .. n - 1`` of a tile, in three loops (short loops
    overlap more pixels' work)."""
    for i in range(n):
        fs[F_NEW_Y * TILE + i], fs[F_NEW_LOG_A * TILE + i] = drive_log(fs[F_NOW * TILE + i], drive_k)    # x, ln x
    for i in range(n):
        fs[F_NEW_Y * TILE + i], fs[F_NEW_LOG_A * TILE + i] = drive_cutoff(
            fs[F_NEW_Y * TILE + i], fs[F_NEW_LOG_A * TILE + i], drive_k, square_law)                  # Y, w
    for i in range(n):
        new_y, new_log_a, new_para, new_accept = drive_rest(fs[F_NOW * TILE + i], fs[F_NEW_Y * TILE + i],
                                                            fs[F_NEW_LOG_A * TILE + i], drive_k)
        fs[F_NEW_Y * TILE + i], fs[F_NEW_LOG_A * TILE + i] = new_y, new_log_a
        fs[F_NEW_PARA * TILE + i], fs[F_NEW_ACCEPT * TILE + i] = new_para, new_accept


@jit
def _sweep_law(fs, js, n, t_now, t_next, last, leak_hz, dt, large):
    """Take the sample at ``t_now`` for the active pixels ``0 .. n - 1`` of a tile, where it is quiet.

    ``fs``/``js``: the tile's float and integer tables (flattened ``[field, TILE]``);
    ``F_NOW``/``F_NEXT`` hold this and the next sample's flux (``last``: there is none),
    ``F_NEW_*`` the drive of ``F_NOW`` (:func:`_drive_law`).
    ``F_RETAIN`` is the filter's retention ``a^j`` over the ``I_SPAN = j`` steps from the
    pixel's last step to this sample. A pixel whose flux holds still while its comparator
    is scheduled without a horizon (``I_OPEN``) waits; one with an event due before its
    change is marked ``_STEPPED`` in ``I_ACTIVE`` (:func:`.pixel_loop.run_pixels` takes the sample); one
    whose next sample does not change it leaves (``I_LEAVE``). Returns the numbers of pixels
    whose crossing is left to solve (``_SOLVE`` in ``I_CMP``) and of pixels stepped.
    """
    leak_dt = leak_hz * dt
    n_solve = n_stepped = 0
    step = t_now - 1
    for i in range(n):      # all loads first, then no branches: every pixel computes, the quiet ones keep the result
        flux, held, following = fs[F_NOW * TILE + i], fs[F_FLUX * TILE + i], fs[F_NEXT * TILE + i]
        filtered, memorised = fs[F_L * TILE + i], fs[F_M * TILE + i]
        c_leak, c_para = fs[F_LEAK * TILE + i], fs[F_PARA_C * TILE + i]
        y, log_a, para, accept = fs[F_Y * TILE + i], fs[F_LOG_A * TILE + i], fs[F_PARA * TILE + i], \
            fs[F_ACCEPT * TILE + i]
        th_on, th_off, scale, retain = fs[F_TH_ON * TILE + i], fs[F_TH_OFF * TILE + i], fs[F_SCALE * TILE + i], \
            fs[F_RETAIN * TILE + i]
        last_step, ready, cmp_next = js[I_STEP * TILE + i], js[I_READY * TILE + i], js[I_CMP * TILE + i]
        due, active, leave = js[I_DUE * TILE + i], js[I_ACTIVE * TILE + i] != 0, js[I_LEAVE * TILE + i]
        span, is_open = js[I_SPAN * TILE + i], js[I_OPEN * TILE + i] != 0

        j = step - last_step
        waits = active & (flux == held) & is_open
        quiet = (active & (flux != held) & (min(cmp_next, due) >= t_now) & (last | (following != flux))
                 & ((j <= 0) | (j == span)))
        moved_l, moved_m, moved_leak, moved_para = relaxed_by(retain, filtered, memorised, c_leak, c_para, y, log_a,
                                                              para, th_on, scale, j, leak_hz, dt, large)
        moved = j > 0                         # run_pixels' advance moves only forward
        new_l = moved_l if moved else filtered
        new_m = moved_m if moved else memorised
        new_y, new_log_a, new_para, new_accept = fs[F_NEW_Y * TILE + i], fs[F_NEW_LOG_A * TILE + i], \
            fs[F_NEW_PARA * TILE + i], fs[F_NEW_ACCEPT * TILE + i]
        # a change with an event due first: run_pixels takes this sample (the pixel ends at its step) and it stays
        stepped = active & (flux != held) & (last | (following != flux)) & (quiet == False)   # noqa: E712
        takes = quiet | stepped                                             # the new input from this sample on
        # the retention to the next sample, for the bound of first_crossing_one now and the relaxation then
        horizon = J_LIMIT if last else min(t_next - 1 - step, J_LIMIT)
        next_span = horizon if takes else t_next - 1 - last_step           # waiting: from its last step
        next_retain = power(new_log_a if takes else log_a, next_span)
        j0 = max(ready - step, np.int64(1))
        inside = stays_in_band(max(horizon, j0), next_retain if j0 <= horizon else 0.0, new_y - new_m,
                               new_l - new_y, new_log_a, (leak_dt * scale + new_para * dt) * th_on,
                               th_on - TOLERANCE, th_off - TOLERANCE, large)

        fs[F_FLUX * TILE + i] = flux if quiet else held
        fs[F_L * TILE + i] = new_l if quiet else filtered
        fs[F_M * TILE + i] = new_m if quiet else memorised
        fs[F_LEAK * TILE + i] = (moved_leak if moved else c_leak) if quiet else c_leak
        fs[F_PARA_C * TILE + i] = (moved_para if moved else c_para) if quiet else c_para
        fs[F_Y * TILE + i] = new_y if quiet else y
        fs[F_LOG_A * TILE + i] = new_log_a if quiet else log_a
        fs[F_PARA * TILE + i] = new_para if quiet else para
        fs[F_ACCEPT * TILE + i] = new_accept if quiet else accept
        fs[F_RETAIN * TILE + i] = next_retain if takes | waits else retain
        js[I_SPAN * TILE + i] = next_span if takes | waits else span
        js[I_STEP * TILE + i] = step if quiet else last_step
        js[I_CMP * TILE + i] = (NEVER if inside else _SOLVE) if quiet else cmp_next
        js[I_OPEN * TILE + i] = (1 if last else 0) if quiet else js[I_OPEN * TILE + i]
        stays = quiet | waits | stepped
        js[I_LEAVE * TILE + i] = t_now if active != stays else leave        # those that stay are active
        js[I_ACTIVE * TILE + i] = _STEPPED if stepped else (1 if stays else 0)
        n_solve += 1 if quiet != (quiet & inside) else 0
        n_stepped += 1 if stepped else 0
    return n_solve, n_stepped


@jit
def _solve(fs, js, n, t_next, last, leak_hz, dt, large):
    """The exact next crossing (:func:`.pixel_loop.next_crossing`) of the tile's pixels marked ``_SOLVE``.

    Their bound in the sweep was :func:`.crossing.first_crossing_one`'s own (same arguments)
    where the pixel may fire before the next sample (``j0 <= horizon``), and it failed: the
    search starts past it there, with the bound's ``a^horizon`` (``F_RETAIN``).
    """
    leak_dt = leak_hz * dt
    for i in range(n):
        if js[I_CMP * TILE + i] == _SOLVE:
            step, ready, y = js[I_STEP * TILE + i], js[I_READY * TILE + i], fs[F_Y * TILE + i]
            drift = (leak_dt * fs[F_SCALE * TILE + i] + fs[F_PARA * TILE + i] * dt) * fs[F_TH_ON * TILE + i]
            j0 = max(ready - step, np.int64(1))
            horizon = J_LIMIT if last else min(t_next - 1 - step, J_LIMIT)
            args = (j0, y - fs[F_M * TILE + i], fs[F_L * TILE + i] - y, fs[F_LOG_A * TILE + i], drift,
                    fs[F_TH_ON * TILE + i] - TOLERANCE, fs[F_TH_OFF * TILE + i] - TOLERANCE, horizon)
            j, _ = search_crossing(*args, horizon, fs[F_RETAIN * TILE + i], large) if j0 <= horizon else \
                first_crossing_one(*args, large)                # F_RETAIN: the bound's a^horizon
            js[I_CMP * TILE + i] = NEVER if j >= NEVER else step + j


_STATE = ((F_FLUX, FLUX), (F_L, L_), (F_M, M_), (F_LEAK, C_LEAK), (F_PARA_C, C_PARA), (F_Y, Y), (F_LOG_A, LOG_A),
          (F_PARA, PARA), (F_ACCEPT, ACCEPT), (F_TH_ON, TH_ON), (F_TH_OFF, TH_OFF), (F_SCALE, NOISE_SCALE))
_CHANGED = 9                 # the sweep writes the first _CHANGED of _STATE's fields (the others it only reads)


@inline
def _to_state(fs, js, i, real, count, pixel):
    """The sweep's fields of tile pixel ``i`` back into the state rows of ``pixel``.

    Inlined, the tables indexed in place: a compiled call, or a row's view, counts the arrays' references up and
    down (atomically) at each pixel."""
    for field, column in _STATE[:_CHANGED]:
        real[pixel, column] = fs[field * TILE + i]
    count[pixel, STEP], count[pixel, CMP_NEXT] = js[I_STEP * TILE + i], js[I_CMP * TILE + i]


@inline
def _from_state(fs, js, i, real, count, pixel, t_next):
    """Tile pixel ``i`` from the state rows of ``pixel``, active, its comparator scheduled up to ``t_next``
    (``NEVER``: open); inlined as :func:`_to_state`.

    Its filter's retention to its next sample (``F_RETAIN`` over ``I_SPAN`` steps) is the caller's to set.
    """
    for field, column in _STATE:
        fs[field * TILE + i] = real[pixel, column]
    ready = count[pixel, READY]
    js[I_STEP * TILE + i], js[I_READY * TILE + i], js[I_CMP * TILE + i] = count[pixel, STEP], ready, \
        count[pixel, CMP_NEXT]
    js[I_DUE * TILE + i] = min(count[pixel, SHOT_NEXT], _settle_step(ready, count[pixel, OWED]))
    js[I_ACTIVE * TILE + i], js[I_LEAVE * TILE + i], js[I_OPEN * TILE + i] = 1, NEVER, 1 if t_next >= NEVER else 0


@inline
def _hand_over(fs, js, n, real, count, first_pixel, columns, t_now, t_next, last, hand, none, model, buffers,
               n_events, lost):
    """The sample at ``t_now`` of the tile's pixels marked ``_STEPPED`` (an event due before it), taken by
    :func:`.pixel_loop.run_pixels`: their events, then the change, with the drive and the retention the sweep
    computed; the pixels rejoin the sweep. Returns ``(events written, lost, done)``; not done: the buffers ran
    out of room (the tile is put back by the caller).

    One call for all of them, in the tile's order (the events' order, as one call a pixel would write them):
    each call counts its 17 arrays' references up and down, atomically. Inlined into the chunk's loop, as
    :func:`_to_state` and :func:`_from_state` are. ``hand``: room for the call's pixels, their changes' ranges,
    steps and rows; ``none``: empty arrays (no schedule kept, no wake steps); ``model``: ``run_pixels``' arguments
    from ``n_end`` to ``th_floor``, ``buffers`` its events' (a function inlined takes at most 30 arguments).
    """
    pixels, lo, hi, change_step, change_input = hand
    unkept, no_wake, no_envelope = none
    m = 0
    for i in range(n):
        if js[I_ACTIVE * TILE + i] == _STEPPED:
            pixel = first_pixel + columns[i]
            _to_state(fs, js, i, real, count, pixel)
            pixels[m], lo[m], hi[m] = pixel, 2 * m, 2 * m + (1 if last else 2)     # this change and the next
            change_step[2 * m], change_step[2 * m + 1] = t_now, t_next
            row = 2 * m                                        # the sweep's drive of this sample
            change_input[row, FLUX], change_input[row, Y] = fs[F_NOW * TILE + i], fs[F_NEW_Y * TILE + i]
            change_input[row, LOG_A], change_input[row, PARA] = fs[F_NEW_LOG_A * TILE + i], fs[F_NEW_PARA * TILE + i]
            change_input[row, ACCEPT] = fs[F_NEW_ACCEPT * TILE + i]
            m += 1
    n_events, n_done, lost = run_pixels(real, count, unkept, no_wake, no_envelope, pixels[:m], lo[:m], hi[:m], _ONE,
                                        change_step, change_input, *model, *buffers, n_events, lost, _EXACT, unkept,
                                        no_envelope, no_envelope)
    if n_done < m:
        return n_events, lost, False
    for i in range(n):
        if js[I_ACTIVE * TILE + i] == _STEPPED:           # at step t_now - 1: the sweep's retention
            _from_state(fs, js, i, real, count, first_pixel + columns[i], t_next)
    return n_events, lost, True


@numba.njit(cache=True, error_model="numpy", nogil=True)     # chunks run in threads (see .eventdriven)
def run_dense_chunk(real, count, next_step, first_pixel, columns, stamps, background, steps, drive_k, n_end,
                    leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma, th_floor,
                    ev_step, ev_pixel, ev_pol, ev_cause, off_background):
    """Every event before step ``n_end`` of the pixels ``first_pixel + columns[i]``, their inputs read off the frames.

    ``stamps[k, column]`` is the summed stamp flux of sample ``k`` and ``background[k]`` its
    uniform flux [photon s^-1]; sample ``k`` holds from step ``steps[k]``. Sets
    ``off_background[column]`` where the pixel's last flux differs from the last
    background. Returns ``(events written, pixels done, events lost)`` as
    :func:`.pixel_loop.run_pixels` does: a tile whose events overflow the buffers is put
    back as it was, with its events, and the chunk stops before it.
    """
    n_samples = steps.size
    n_real, n_count = real.shape[1], count.shape[1]
    fs = np.zeros(N_FLOAT * TILE)
    js = np.zeros(N_INT * TILE, np.int64)
    start_r = np.empty((TILE, n_real))
    start_c = np.empty((TILE, n_count), np.int64)
    change_step = np.empty(max(n_samples, 2), np.int64)
    change_input = np.empty((max(n_samples, 2), n_real))
    one_pixel, no_change, changes = np.empty(1, np.int64), np.zeros(1, np.int64), np.empty(1, np.int64)
    unkept, no_envelope = np.empty(0, np.int64), np.empty(0)     # run_pixels keeps no schedule here (see below)
    no_wake = np.empty(0, np.int32)
    #                                                            and is given no bound taken before
    hand = (np.empty(TILE, np.int64), np.empty(TILE, np.int64), np.empty(TILE, np.int64), np.empty(2 * TILE, np.int64),
            np.empty((2 * TILE, n_real)))                     # _hand_over's call: pixels, changes' ranges, steps, rows
    none = (unkept, no_wake, no_envelope)
    model = (n_end, leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma, th_floor)
    buffers = (ev_step, ev_pixel, ev_pol, ev_cause)
    n_events = _FIRST                                         # int64, not Literal[int](0): see _FIRST
    lost = 0.0
    for t0 in range(0, columns.size, TILE):
        n = min(TILE, columns.size - t0)
        tile_events, tile_lost = n_events, lost
        for i in range(n):                                    # the tile's state into the sweep's tables
            pixel = first_pixel + columns[t0 + i]
            start_r[i], start_c[i] = real[pixel], count[pixel]
            _from_state(fs, js, i, real, count, pixel, NEVER)   # scheduled without a horizon at a window's end
            js[I_SPAN * TILE + i] = steps[0] - 1 - count[pixel, STEP]
            fs[F_RETAIN * TILE + i] = power(real[pixel, LOG_A], steps[0] - 1 - count[pixel, STEP])
        done = True
        c0 = columns[t0]                                      # the tile's columns, if they are c0, c0 + 1, ...
        contiguous = True
        for i in range(n):
            contiguous &= columns[t0 + i] == c0 + i
        for i in range(n):
            fs[F_NEXT * TILE + i] = background[0] + stamps[0, columns[t0 + i]]
        for k in range(n_samples):
            last = k + 1 == n_samples
            following = min(k + 1, n_samples - 1)             # this sample's flux: the last one's next
            if contiguous:
                for i in range(n):
                    fs[F_NOW * TILE + i] = fs[F_NEXT * TILE + i]
                    fs[F_NEXT * TILE + i] = background[following] + stamps[following, c0 + i]
            else:
                for i in range(n):
                    fs[F_NOW * TILE + i] = fs[F_NEXT * TILE + i]
                    fs[F_NEXT * TILE + i] = background[following] + stamps[following, columns[t0 + i]]
            if k + 2 < n_samples:                             # frames lie a frame apart in memory: fetch ahead
                for i in range(0, n, 8):                      # a cache line holds 8 samples
                    _prefetch(stamps, k + 2, columns[t0 + i])
                _prefetch(stamps, k + 2, columns[t0 + n - 1])
            t_next = NEVER if last else steps[k + 1]
            n_solve, n_stepped = _sweep(fs, js, n, steps[k], t_next, last, leak_hz, dt, large, drive_k)
            if n_solve:
                _solve(fs, js, n, t_next, last, leak_hz, dt, large)
            if n_stepped:                                     # run_pixels takes this sample: events, the change
                n_events, lost, done = _hand_over(fs, js, n, real, count, first_pixel, columns[t0:t0 + n], steps[k],
                                                  t_next, last, hand, none, model, buffers, n_events, lost)
                if not done:
                    break
        for i in range(n if done else 0):                     # back to the state tables; the rest by run_pixels
            column = columns[t0 + i]
            pixel = first_pixel + column
            _to_state(fs, js, i, real, count, pixel)
            c = count[pixel]
            leave = js[I_LEAVE * TILE + i]
            held = real[pixel, FLUX]
            n_changes = _FIRST                        # int64 from the start: one compile of run_pixels
            if leave < NEVER:                                 # its samples from the one it left the sweep at
                for k in range(n_samples):
                    if steps[k] >= leave:
                        flux = background[k] + stamps[k, column]
                        if flux != held:
                            change_step[n_changes] = steps[k]
                            drive_into(change_input[n_changes], flux, drive_k)
                            n_changes += 1
                            held = flux
            if leave < NEVER or min(c[CMP_NEXT], c[SHOT_NEXT], _settle_step(c[READY], c[OWED])) < n_end:
                one_pixel[0], changes[0] = pixel, n_changes
                n_events, n_done, lost = run_pixels(real, count, unkept, no_wake, no_envelope, one_pixel, no_change,
                                                    changes, NEVER, change_step, change_input, n_end, leak_hz, dt,
                                                    large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma,
                                                    th_floor, ev_step, ev_pixel, ev_pol, ev_cause, n_events, lost,
                                                    _EXACT, unkept, no_envelope, no_envelope)
                done = n_done == 1
                if not done:
                    break
            off_background[column] = held != background[n_samples - 1]
            next_step[pixel] = min(c[CMP_NEXT], c[SHOT_NEXT], _settle_step(c[READY], c[OWED]))
        if not done:                                          # no room: the tile as it was, without its events
            for i in range(n):
                pixel = first_pixel + columns[t0 + i]
                real[pixel], count[pixel] = start_r[i], start_c[i]
            return tile_events, t0, tile_lost
    return n_events, columns.size, lost
