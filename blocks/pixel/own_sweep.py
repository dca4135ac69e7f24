"""A window's input changes of the pixels under stamps, taken many pixels at a time (compiled, vectorised).

The pixels under the stamps change their input at most samples of a window (on the tracked pass ~12
changes a pixel, ~77 000 a window), and seldom fire between them. In the event-driven loop
(:func:`.pixel_loop.run_pixels`) each change costs the filter's advance to it and the bound that shows
no crossing before the next one (:func:`.crossing.band_bound`: ``a^j``, ``e^-D`` and a logarithm in
the large-signal form), one pixel's changes after the other's, as scalar code, and its row of input
(:func:`.drive_kernel.drive_rows`: two logarithms, made for every change before the loop). Here the pixels
of a chunk with at least ``MIN_SWEPT`` changes are swept together (own changes, or the background's: a pixel
due for a noise event takes the last kept change and the window's), change after change: in round
``r`` every pixel still in the sweep takes its ``r``-th change, in loops over the pixels that the compiler
vectorises (:mod:`.fastmath`'s functions give the same bits there), with the same arithmetic in the same
order as the event-driven loop:

* the change's drive (Eqs. 12-20) from its photon flux, :func:`.drive_kernel.drive_rows`' three loops;

* a pixel takes the change only where nothing is due before it (its comparator schedule, shot-noise
  trial or settling step): else it leaves the sweep there, the event-driven loop taking its events;
* the advance to the step before the change reuses the last bound's ``a^j`` (and in the large-signal
  form its relaxation) where it was taken over the same steps, as :func:`.pixel_loop.advanced` does;
  elsewhere (each pixel's first change) it is computed afresh;
* after the change the bound up to the last step the loop would act on (:func:`.pixel_loop._schedule_before`):
  where it holds the schedule is ``LATER``; where it fails the crossing is searched (one pixel at a
  time, as :func:`.pixel_loop._schedule_before` does), and a crossing before the next change ends the
  pixel's sweep; after the pixel's last change, with nothing due before the window's end, the schedule
  the loop makes there instead (``LATER`` where :func:`.pixel_loop.quiet_until` shows no crossing in the
  window, else the search: at the tile's end, the searches together, :func:`.crossing.batch_crossings`).

The event-driven loop then takes each pixel from the change the sweep stopped at (after its last: only
its events and the schedule it keeps), in the state the sweep left, with the rows of the changes left
driven then (only those: the sweep reads each change's flux, not a row of the state table's width): its
events are those it would have made alone (tested, and the events of the whole tracked pass:
``benchmarks/pixel_gil.py``'s digest). The sweep writes no events.
"""

from __future__ import annotations

import numba
import numpy as np

from .comparator import TOLERANCE
from .crossing import (J_LIMIT, NEVER, NO_STEP, UNSETTLED, band_bound, band_holds, batch_crossings, batched, power,
                       relaxed_at, search_crossing)
from .drive_kernel import SQUARE_LAW, drive_cutoff, drive_log, drive_rest, drive_rows
from .fastmath import wide_vectors
from .pixel_loop import (_AHEAD, ACCEPT, C_LEAK, C_PARA, CMP_NEXT, FLUX, L_, LATER, LOG_A, M_, NOISE_SCALE, OWED,
                         PARA, READY, SHOT_NEXT, STEP, TH_OFF, TH_ON, Y, _fetch_row, _settle_step, drifted,
                         next_crossing_known, quiet_until, relaxed_by)

TILE = 128                   # pixels swept together (ordered by their number of changes, so rounds shrink a tile)
MIN_SWEPT = 2                # pixels with fewer own changes are left to the event-driven loop (one change: nothing
#                              shared with the next, whose advance reuses the bound after the last)
# per-pixel fields of a tile (rows of the sweep's flattened tables, [field * TILE + lane]); N_*: the change's input
(F_FLUX, F_L, F_M, F_LEAK, F_PARA_C, F_Y, F_LOG_A, F_PARA, F_ACCEPT, F_TH_ON, F_TH_OFF, F_SCALE, F_KNOWN, F_RELAXED,
 N_FLUX, N_Y, N_LOG_A, N_PARA, N_ACCEPT, N_FLOAT) = range(20)
(I_STEP, I_READY, I_DUE, I_CMP, I_J_KNOWN, I_PTR, I_GO, I_CHANGE, I_NEXT, I_FRESH, I_SEARCH, N_INT) = range(12)
# the sweep's fields read from the state table, the first _CHANGED of them written back (loops: less to compile)
_STATE = ((F_FLUX, FLUX), (F_L, L_), (F_M, M_), (F_LEAK, C_LEAK), (F_PARA_C, C_PARA), (F_Y, Y), (F_LOG_A, LOG_A),
          (F_PARA, PARA), (F_ACCEPT, ACCEPT), (F_TH_ON, TH_ON), (F_TH_OFF, TH_OFF), (F_SCALE, NOISE_SCALE))
_CHANGED = 9
_SEARCH, _KEPT = 1, 2        # I_SEARCH: the bound failed; after the pixel's last change (run_pixels' lazy schedule)
(K_C, K_D, K_LOG_A, K_DELTA, K_ON, K_OFF, K_KNOWN, K_AT, K_RELAXED, K_FLOAT) = range(10)   # _kept's searches,
#                                                                                  [field * TILE + k]
(K_J0, K_LANE, K_OUT, K_INT) = range(4)
# a first run compiles each compiled function called from another again into the caller's code: the sweep and
# drive_left are inlined into deferred.take_and_run (Numba's IR, not compiled on their own there), and so are the
# small steps _enter and _search into the sweep; the vectorised loops stay functions (inlined, the sweep compiles
# slower: benchmarks/pixel_compile.py)
jit = numba.njit(cache=True, error_model="numpy")
inline = numba.njit(cache=True, error_model="numpy", inline="always")


def take_own(real, count, pixels, change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end,
             leak_hz, dt, large):
    """Take the own changes of ``pixels[i]`` (``change_lo[i]:change_hi[i]`` of ``change_step``, below ``n_own``:
    photon flux ``own_flux``, their rows of ``change_input`` not yet driven) that the event-driven loop would take
    before anything else happens to the pixel, and move ``change_lo[i]`` past them; then drive the rows of the
    own changes left (:func:`.drive_kernel.drive_rows`) for :func:`.pixel_loop.run_pixels`, which takes the pixels
    from there (with lazy schedules, as :func:`.deferred.take_and_run` runs it). Pixels with fewer than
    ``MIN_SWEPT`` own changes are left as they are.

    Updates the pixels' state rows as :func:`.pixel_loop.run_pixels` would (the comparator schedule ``LATER`` or
    the search's crossing; see the module). Returns the number of changes swept. Two compiled calls (``nogil``),
    which :func:`.deferred.take_and_run` makes itself (inlined there: a first run compiles them once, in it).
    """
    n = pixels.size
    total = sweep_own(real, count, pixels, change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k,
                      n_end, leak_hz, dt, large, np.empty(n, np.int64), np.empty(n), np.empty(n))
    drive_left(pixels, change_lo, change_hi, n_own, own_flux, drive_k, change_input)
    return total


@numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")
def drive_left(pixels, change_lo, change_hi, n_own, own_flux, drive_k, change_input):
    """The rows of ``change_input`` of the own changes (below ``n_own``) left to the pixels, driven from
    ``own_flux`` (:func:`.drive_kernel.drive_rows` of the fluxes gathered)."""
    n_left = 0
    for i in range(pixels.size):
        if change_hi[i] <= n_own:
            n_left += change_hi[i] - change_lo[i]
    flux = np.empty(n_left)
    rows = np.empty((n_left, change_input.shape[1]))
    k = 0
    for i in range(pixels.size):
        if change_hi[i] <= n_own:
            for ptr in range(change_lo[i], change_hi[i]):
                flux[k] = own_flux[ptr]
                k += 1
    drive_rows(flux, drive_k, rows)
    k = 0
    for i in range(pixels.size):
        if change_hi[i] <= n_own:
            for ptr in range(change_lo[i], change_hi[i]):
                change_input[ptr, FLUX], change_input[ptr, Y], change_input[ptr, LOG_A] = rows[k, FLUX], rows[k, Y], \
                    rows[k, LOG_A]
                change_input[ptr, PARA], change_input[ptr, ACCEPT] = rows[k, PARA], rows[k, ACCEPT]
                k += 1


@numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")
def sweep_own(real, count, pixels, change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end,
              leak_hz, dt, large, known_step, known_retention, known_relaxed):
    """:func:`take_own`'s sweep (see the module), the change's drive computed from its flux as it is taken (own
    changes: ``own_flux``; the background's, at and above ``n_own``: their rows' drive, or where a round's tile mixes
    both kinds, the ``FLUX`` of their rows driven again: the same bits). Sets ``known_step[i]``,
    ``known_retention[i]``, ``known_relaxed[i]`` to the ``j``, ``a^j`` and relaxation of the last bound taken by
    ``pixels[i]`` at the state it leaves it in (``NO_STEP``: none; :func:`.pixel_loop.run_pixels` starts from them)."""
    n = pixels.size
    for i in range(n):
        known_step[i] = NO_STEP
    # the pixels with changes to sweep, most first: a counting sort by their number
    most = 0
    for i in range(n):
        most = max(most, change_hi[i] - change_lo[i])
    if most < MIN_SWEPT:
        return 0
    starts = np.zeros(most + 2, np.int64)
    for i in range(n):
        k = change_hi[i] - change_lo[i]
        if k >= MIN_SWEPT:
            starts[most - k + 1] += 1
    for k in range(1, starts.size):
        starts[k] += starts[k - 1]
    order = np.empty(starts[-1], np.int64)
    for i in range(n):
        k = change_hi[i] - change_lo[i]
        if k >= MIN_SWEPT:
            order[starts[most - k]] = i
            starts[most - k] += 1
    fs = np.zeros(N_FLOAT * TILE)
    js = np.zeros(N_INT * TILE, np.int64)
    swept = np.empty(TILE, np.int64)                           # each pixel's number of changes to sweep
    kept_f, kept_j = np.empty(K_FLOAT * TILE), np.empty(K_INT * TILE, np.int64)     # _kept's searches
    leak_dt = leak_hz * dt
    total = 0
    for t0 in range(0, order.size, TILE):
        size = min(TILE, order.size - t0)
        for s in range(size):                         # the tile's pixels into the sweep's tables
            if s + _AHEAD < size:
                _fetch_row(real, count, pixels[order[t0 + s + _AHEAD]])
            i = order[t0 + s]
            p = pixels[i]
            swept[s] = change_hi[i] - change_lo[i]
            for field, column in _STATE:
                fs[field * TILE + s] = real[p, column]
            step, ready, shot_next = count[p, STEP], count[p, READY], count[p, SHOT_NEXT]
            due = min(shot_next, _settle_step(ready, count[p, OWED]))
            cmp_next = count[p, CMP_NEXT]
            if cmp_next < 0:          # a kept bound: the search where the crossing could come first (run_pixels')
                if -2 - cmp_next <= min(change_step[change_lo[i]] - 1, n_end - 1, due):
                    cmp_next = next_crossing_known(step, ready, real[p, Y], real[p, M_], real[p, L_], real[p, LOG_A],
                                                   real[p, PARA], real[p, TH_ON], real[p, TH_OFF],
                                                   real[p, NOISE_SCALE], NEVER, leak_dt, dt, large)[0]
                else:
                    cmp_next = LATER
            js[I_STEP * TILE + s], js[I_READY * TILE + s], js[I_DUE * TILE + s] = step, ready, due
            js[I_CMP * TILE + s], js[I_J_KNOWN * TILE + s], js[I_PTR * TILE + s] = cmp_next, NO_STEP, change_lo[i]
            js[I_GO * TILE + s] = 1
        m = size
        for r in range(swept[0]):
            while swept[m - 1] <= r:
                m -= 1                                # the pixels with an r-th change to sweep: a prefix
            own = False
            for s in range(m):                        # this round's change: its step, the next one's and its flux
                ptr = js[I_PTR * TILE + s]
                js[I_CHANGE * TILE + s] = change_step[ptr]
                js[I_NEXT * TILE + s] = change_step[ptr + 1] if r + 1 < swept[s] else NEVER     # none: its last
                if ptr < n_own:
                    fs[N_FLUX * TILE + s] = own_flux[ptr]
                    own = True
                else:                                 # the background's: its row's drive (drive_rows: the same bits)
                    fs[N_FLUX * TILE + s], fs[N_Y * TILE + s] = change_input[ptr, FLUX], change_input[ptr, Y]
                    fs[N_LOG_A * TILE + s], fs[N_PARA * TILE + s] = change_input[ptr, LOG_A], change_input[ptr, PARA]
                    fs[N_ACCEPT * TILE + s] = change_input[ptr, ACCEPT]
            if own:                                   # a tile of background changes alone (a few rows, many pixels
                _drive(fs, m, drive_k)                # due for a noise event) is not driven again
            n_fresh = _enter(fs, js, m, n_end, leak_hz, dt, large)
            if n_fresh:
                _fresh(fs, js, m, leak_hz, dt, large)
            if _bound(fs, js, m, n_end, leak_dt, dt, large):
                _search(fs, js, m, leak_dt, dt, large)
        _kept(fs, js, size, n_end, leak_dt, dt, large, kept_f, kept_j)
        for s in range(size):                         # back to the state tables, where changes were taken
            i = order[t0 + s]
            taken = js[I_PTR * TILE + s] - change_lo[i]
            if taken:
                p = pixels[i]
                for field, column in _STATE[:_CHANGED]:
                    real[p, column] = fs[field * TILE + s]
                count[p, STEP], count[p, CMP_NEXT] = js[I_STEP * TILE + s], js[I_CMP * TILE + s]
                known_step[i], known_retention[i] = js[I_J_KNOWN * TILE + s], fs[F_KNOWN * TILE + s]
                known_relaxed[i] = fs[F_RELAXED * TILE + s]
                change_lo[i] += taken
                total += taken
    return total


@jit
def _drive(fs, m, drive_k):
    """The drive (``N_Y`` .. ``N_ACCEPT``) of the flux ``N_FLUX`` of the tile's pixels ``0 .. m - 1``
    (:func:`.drive_kernel.drive_rows`' three loops: the same bits)."""
    wide_vectors()
    square_law = drive_k[SQUARE_LAW] != 0.0
    for s in range(m):
        fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s] = drive_log(fs[N_FLUX * TILE + s], drive_k)         # x, ln x
    for s in range(m):
        fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s] = drive_cutoff(fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s], drive_k,
                                                                  square_law)                          # Y, w
    for s in range(m):
        fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s], fs[N_PARA * TILE + s], fs[N_ACCEPT * TILE + s] = drive_rest(
            fs[N_FLUX * TILE + s], fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s], drive_k)


@inline
def _enter(fs, js, m, n_end, leak_hz, dt, large):
    """Which of the tile's pixels ``0 .. m - 1`` take their change (``I_GO``: nothing due before it), and their
    advance to the step before it where the last bound's ``a^j`` serves (:func:`.pixel_loop.advanced`'s cases
    without ``exp`` or ``log``); the others are marked ``I_FRESH``. Returns how many are."""
    n_fresh = 0
    for s in range(m):                # loads first, no branches: every pixel computes, those that take it keep it
        go = js[I_GO * TILE + s] != 0
        step, cmp_next, due = js[I_STEP * TILE + s], js[I_CMP * TILE + s], js[I_DUE * TILE + s]
        t_change, j_known = js[I_CHANGE * TILE + s], js[I_J_KNOWN * TILE + s]
        filtered, memorised = fs[F_L * TILE + s], fs[F_M * TILE + s]
        c_leak, c_para = fs[F_LEAK * TILE + s], fs[F_PARA_C * TILE + s]
        y, log_a, para, th_on, scale = fs[F_Y * TILE + s], fs[F_LOG_A * TILE + s], fs[F_PARA * TILE + s], \
            fs[F_TH_ON * TILE + s], fs[F_SCALE * TILE + s]
        known, relaxed = fs[F_KNOWN * TILE + s], fs[F_RELAXED * TILE + s]
        t_event = min(cmp_next, due)
        go = go & ((t_event >= t_change) | (t_event >= n_end))      # run_pixels: no event before the change
        j = t_change - 1 - step
        moved = j > 0
        # advanced(): a^j known (j = j_known): large-signal L - Y is the bound's relaxation (known > 0), small-signal
        # L - Y = (L - Y) a^j
        reuse = moved & (j == j_known) & ((known > 0.0) | (not large))
        fresh = go & moved & (not reuse)
        moved_m, moved_leak, moved_para = drifted(memorised, c_leak, c_para, para, th_on, scale, j, leak_hz, dt)
        moved_l = y + relaxed if large else y + (filtered - y) * known
        keep = go & reuse
        fs[F_L * TILE + s] = moved_l if keep else filtered
        fs[F_M * TILE + s] = moved_m if keep else memorised
        fs[F_LEAK * TILE + s] = moved_leak if keep else c_leak
        fs[F_PARA_C * TILE + s] = moved_para if keep else c_para
        js[I_GO * TILE + s] = 1 if go else 0
        js[I_FRESH * TILE + s] = 1 if fresh else 0
        n_fresh += 1 if fresh else 0
    return n_fresh


@jit
def _fresh(fs, js, m, leak_hz, dt, large):
    """The advance of the tile's pixels marked ``I_FRESH`` (:func:`.pixel_loop.advanced` without a known ``a^j``,
    ``j > 0``: :func:`.pixel_loop.relaxed_by` of :func:`.crossing.power`; the same bits, as a known ``a^j`` was taken
    by the same :func:`.crossing.power`), computed by every pixel in a loop the compiler vectorises (most are, in
    the first round; later rounds seldom have any)."""
    wide_vectors()
    for s in range(m):
        fresh = js[I_FRESH * TILE + s] != 0
        filtered, memorised = fs[F_L * TILE + s], fs[F_M * TILE + s]
        c_leak, c_para = fs[F_LEAK * TILE + s], fs[F_PARA_C * TILE + s]
        j = js[I_CHANGE * TILE + s] - 1 - js[I_STEP * TILE + s]
        log_a = fs[F_LOG_A * TILE + s]
        moved_l, moved_m, moved_leak, moved_para = relaxed_by(
            power(log_a, j), filtered, memorised, c_leak, c_para, fs[F_Y * TILE + s], log_a, fs[F_PARA * TILE + s],
            fs[F_TH_ON * TILE + s], fs[F_SCALE * TILE + s], j, leak_hz, dt, large)
        fs[F_L * TILE + s] = moved_l if fresh else filtered
        fs[F_M * TILE + s] = moved_m if fresh else memorised
        fs[F_LEAK * TILE + s] = moved_leak if fresh else c_leak
        fs[F_PARA_C * TILE + s] = moved_para if fresh else c_para


@jit
def _bound(fs, js, m, n_end, leak_dt, dt, large):
    """The change's new input for the pixels that take it, and the bound up to the last step the event-driven loop
    would act on (:func:`.pixel_loop._schedule_before` with :func:`.crossing.band_bound`): ``LATER`` where it holds,
    else ``I_SEARCH``. Returns the number of searches left."""
    wide_vectors()
    n_search = 0
    for s in range(m):
        go = js[I_GO * TILE + s] != 0
        t_change, t_next = js[I_CHANGE * TILE + s], js[I_NEXT * TILE + s]
        ready, due, old_step = js[I_READY * TILE + s], js[I_DUE * TILE + s], js[I_STEP * TILE + s]
        filtered, memorised = fs[F_L * TILE + s], fs[F_M * TILE + s]
        y, log_a, para = fs[N_Y * TILE + s], fs[N_LOG_A * TILE + s], fs[N_PARA * TILE + s]
        th_on, th_off, scale = fs[F_TH_ON * TILE + s], fs[F_TH_OFF * TILE + s], fs[F_SCALE * TILE + s]
        step = t_change - 1
        last = min(t_next - 1, n_end - 1, due)
        j0 = max(ready - step, np.int64(1))
        j_max = max(last - step, j0)
        drift = (leak_dt * scale + para * dt) * th_on
        c, d, on, off = y - memorised, filtered - y, th_on - TOLERANCE, th_off - TOLERANCE
        retention = power(log_a, j_max)                                          # band_bound
        relaxed = relaxed_at(j_max, retention, d, log_a, large)
        holds = band_holds(j_max, retention, relaxed, c, d, log_a, drift, on, off)
        fs[F_FLUX * TILE + s] = fs[N_FLUX * TILE + s] if go else fs[F_FLUX * TILE + s]
        fs[F_Y * TILE + s] = y if go else fs[F_Y * TILE + s]
        fs[F_LOG_A * TILE + s] = log_a if go else fs[F_LOG_A * TILE + s]
        fs[F_PARA * TILE + s] = para if go else fs[F_PARA * TILE + s]
        fs[F_ACCEPT * TILE + s] = fs[N_ACCEPT * TILE + s] if go else fs[F_ACCEPT * TILE + s]
        fs[F_KNOWN * TILE + s] = retention if go else fs[F_KNOWN * TILE + s]
        fs[F_RELAXED * TILE + s] = relaxed if go else fs[F_RELAXED * TILE + s]
        js[I_STEP * TILE + s] = step if go else old_step
        js[I_J_KNOWN * TILE + s] = j_max if go else js[I_J_KNOWN * TILE + s]
        js[I_CMP * TILE + s] = LATER if go else js[I_CMP * TILE + s]
        js[I_PTR * TILE + s] += 1 if go else 0
        # after its last change, with nothing due before the window's end, the loop keeps a bound instead
        # (run_pixels with lazy schedules, as take_and_run runs it): _search
        kept = go & (t_next >= NEVER) & (last == n_end - 1)
        search = go & ((not holds) | kept)
        js[I_SEARCH * TILE + s] = (_KEPT if kept else _SEARCH) if search else 0
        n_search += 1 if search else 0
    return n_search


@inline
def _search(fs, js, m, leak_dt, dt, large):
    """The crossing up to the next change of the pixels marked ``_SEARCH`` (:func:`.pixel_loop._schedule_before`
    where its bound failed); those marked ``_KEPT`` wait for the tile's end (:func:`_kept`)."""
    for s in range(m):
        if js[I_SEARCH * TILE + s] == _SEARCH:
            step, ready, t_next, j_max = js[I_STEP * TILE + s], js[I_READY * TILE + s], js[I_NEXT * TILE + s], \
                js[I_J_KNOWN * TILE + s]
            y, memorised, filtered = fs[F_Y * TILE + s], fs[F_M * TILE + s], fs[F_L * TILE + s]
            log_a, para, th_on, th_off, scale = fs[F_LOG_A * TILE + s], fs[F_PARA * TILE + s], \
                fs[F_TH_ON * TILE + s], fs[F_TH_OFF * TILE + s], fs[F_SCALE * TILE + s]
            j0 = max(ready - step, np.int64(1))
            horizon = min(t_next - 1 - step, J_LIMIT)
            if max(horizon, j0) != j_max:
                cmp_next, j_known, known, relaxed = next_crossing_known(step, ready, y, memorised, filtered, log_a,
                                                                        para, th_on, th_off, scale, t_next, leak_dt,
                                                                        dt, large)
                js[I_J_KNOWN * TILE + s], fs[F_KNOWN * TILE + s], fs[F_RELAXED * TILE + s] = j_known, known, relaxed
            else:
                drift = (leak_dt * scale + para * dt) * th_on
                j, _ = search_crossing(j0, y - memorised, filtered - y, log_a, drift, th_on - TOLERANCE,
                                       th_off - TOLERANCE, horizon, j_max, fs[F_KNOWN * TILE + s], large)
                cmp_next = NEVER if j >= NEVER else step + j
            js[I_CMP * TILE + s] = cmp_next


@inline
def _kept(fs, js, size, n_end, leak_dt, dt, large, kept_f, kept_j):
    """After the tile's rounds, the schedule :func:`.pixel_loop.run_pixels` makes after the last change of the
    pixels marked ``_KEPT`` (the round's state is theirs: later rounds leave them): ``LATER`` where
    :func:`.pixel_loop.quiet_until` shows the window quiet, else :func:`.pixel_loop.next_crossing_known`'s crossing
    (no horizon), the searches :func:`.crossing.batched` takes all at once (:func:`.crossing.batch_crossings`:
    on the pass nearly every one, most an event in the window), the others and those it leaves one at a time. A
    crossing found together carries its ``a^j`` and relaxation (:func:`_at_crossings`) as the pixel's last bound
    would: :func:`.pixel_loop.run_pixels`' advance to that event takes them (the same bits)."""
    n = 0
    for s in range(size):
        if js[I_SEARCH * TILE + s] == _KEPT:
            step, ready = js[I_STEP * TILE + s], js[I_READY * TILE + s]
            y, memorised, filtered = fs[F_Y * TILE + s], fs[F_M * TILE + s], fs[F_L * TILE + s]
            log_a, para, th_on, th_off, scale = fs[F_LOG_A * TILE + s], fs[F_PARA * TILE + s], \
                fs[F_TH_ON * TILE + s], fs[F_TH_OFF * TILE + s], fs[F_SCALE * TILE + s]
            cmp_next = LATER
            if not quiet_until(filtered, y, memorised, th_on, th_off, scale, para, step, -np.inf, np.inf, 0.0,
                               leak_dt, dt) >= n_end:
                # next_crossing_known without a horizon: first_crossing_known's bound, then search_crossing
                drift = (leak_dt * scale + para * dt) * th_on
                j0 = max(ready - step, np.int64(1))
                c, d, on, off = y - memorised, filtered - y, th_on - TOLERANCE, th_off - TOLERANCE
                holds, known, _ = band_bound(max(J_LIMIT, j0), c, d, log_a, drift, on, off, large)
                if holds:
                    cmp_next = NEVER
                elif batched(j0, d, log_a, drift):
                    for field, value in ((K_C, c), (K_D, d), (K_LOG_A, log_a), (K_DELTA, drift), (K_ON, on),
                                         (K_OFF, off), (K_KNOWN, known)):
                        kept_f[field * TILE + n] = value
                    kept_j[K_J0 * TILE + n], kept_j[K_LANE * TILE + n] = j0, s
                    n += 1
                    continue
                else:
                    cmp_next = next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off,
                                                   scale, NEVER, leak_dt, dt, large)[0]
            js[I_CMP * TILE + s] = cmp_next
    if n == 0:
        return
    batch_crossings(kept_j[K_J0 * TILE:K_J0 * TILE + n], kept_f[K_C * TILE:K_C * TILE + n],
                    kept_f[K_D * TILE:K_D * TILE + n], kept_f[K_LOG_A * TILE:K_LOG_A * TILE + n],
                    kept_f[K_DELTA * TILE:K_DELTA * TILE + n], kept_f[K_ON * TILE:K_ON * TILE + n],
                    kept_f[K_OFF * TILE:K_OFF * TILE + n], large, kept_j[K_OUT * TILE:K_OUT * TILE + n])
    for k in range(n):
        if kept_j[K_OUT * TILE + k] == UNSETTLED:     # Newton's candidate not the crossing: search_crossing bisects
            kept_j[K_OUT * TILE + k] = search_crossing(
                kept_j[K_J0 * TILE + k], kept_f[K_C * TILE + k], kept_f[K_D * TILE + k], kept_f[K_LOG_A * TILE + k],
                kept_f[K_DELTA * TILE + k], kept_f[K_ON * TILE + k], kept_f[K_OFF * TILE + k], J_LIMIT, J_LIMIT,
                kept_f[K_KNOWN * TILE + k], large)[0]
    _at_crossings(kept_f, kept_j, n, large)
    for k in range(n):
        s, j = kept_j[K_LANE * TILE + k], kept_j[K_OUT * TILE + k]
        if j >= NEVER:
            js[I_CMP * TILE + s] = NEVER
        else:                                 # run_pixels' advance to the crossing takes its a^j and relaxation
            js[I_CMP * TILE + s] = js[I_STEP * TILE + s] + j
            js[I_J_KNOWN * TILE + s], fs[F_KNOWN * TILE + s] = j, kept_f[K_AT * TILE + k]
            fs[F_RELAXED * TILE + s] = kept_f[K_RELAXED * TILE + k]


@jit
def _at_crossings(kept_f, kept_j, n, large):
    """``a^j`` and the relaxation (:func:`.crossing.relaxed_at`, as a bound takes them) at the crossing ``j`` of each of
    :func:`_kept`'s ``n`` batched searches (none found: at ``J_LIMIT``, unused), in a loop the compiler vectorises."""
    wide_vectors()
    for k in range(n):
        j = min(kept_j[K_OUT * TILE + k], J_LIMIT)
        log_a, d = kept_f[K_LOG_A * TILE + k], kept_f[K_D * TILE + k]
        retention = power(log_a, j)
        kept_f[K_AT * TILE + k] = retention
        kept_f[K_RELAXED * TILE + k] = relaxed_at(j, retention, d, log_a, large)
