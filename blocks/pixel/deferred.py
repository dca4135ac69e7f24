"""Changes of the uniform background, applied to each pixel only when they can matter.

A background that drifts (the sky brightening as a tracking mount climbs, sampled every
``cadence_s``) changes the input of every pixel away from the stamps at once. Taking each
change to every pixel costs sensor pixels x changes, although almost no pixel can fire
because of a change of a few 1e-4 of the log-intensity. Instead the changes are kept, in
order, in a history (:class:`SharedChanges`) and each pixel records how many of them it
has taken (``applied``). A pixel that is due for nothing before the window's end (its next
comparator, shot-noise or settling step lies beyond it) and whose comparator provably
cannot reach a threshold before then under the changes it has not taken
(:func:`select_pixels`) is left alone; the next time it is processed for any reason it takes
its pending changes first, at their own steps, through the same compiled loop
(:mod:`.pixel_loop`). Because a pixel's state is only ever advanced at its own events and
input changes, in order, the events are the same bytes as when every change is taken at
once (the property that makes the events independent of the window length; tested). Most pixels are
passed over on their wake step alone (:func:`.pixel_loop.quiet_until`, under an envelope of the changes),
without reading their state.

The bound (paper Eqs. 16-19 at piecewise constant input): between updates the filtered
log-intensity ``L`` relaxes geometrically towards the input's ``Y`` (in the large-signal form
``e^-L`` does, towards ``e^-Y``: ``L`` is monotone in ``e^-L``), so in either form it stays within
the hull of its value at the last update and every ``Y`` it is given; the memorised ``M`` only
falls, by at most the largest drift ``(R_leak + R_para) theta_ON dt`` per step. So
``L - M`` stays below ``max(L_0, Y_i) - M_0 + drift_max (n_end - 1 - step_0)`` and above
``min(L_0, Y_i) - M_0``; if that band lies inside the comparator's thresholds (less their
rounding tolerance and a margin for floating-point rounding), the pixel cannot fire.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.cpython.unsafe.numbers import trailing_zeros
from numba.extending import intrinsic

from .comparator import ROUNDING_MARGIN, TOLERANCE
from .crossing import power
from .fastmath import _float_to_bits, wide_vectors
from .own_sweep import drive_left, sweep_own
from .pixel_loop import (_AHEAD, _LAZY, ACCEPT, C_LEAK, C_PARA, FLUX, L_, LOG_A, M_, NEVER, NOISE_SCALE, PARA,
                         STEP, TH_OFF, TH_ON, WAKE_SPAN, Y, _advance, _fetch_item, _fetch_row, drifted, quiet_until,
                         relaxed_by, run_pixels, wake_code)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _cannot_fire(filtered, y, memorised, th_on, th_off, noise_scale, para, step, y_high, y_low, para_high, n_end,
                 leak_dt, dt):
    """Whether a pixel (its state at ``step``) provably cannot fire before ``n_end`` under its pending changes,
    whose largest and smallest ``Y`` are ``y_high``, ``y_low`` and largest parasitic rate ``para_high`` (see the
    module's bound).

    Takes the pixel's fields, read in place by the caller (a row view per pixel costs two atomic reference
    counts, for every pixel of the sensor each window)."""
    high = max(filtered, y, y_high)
    low = min(filtered, y, y_low)
    drift = (leak_dt * noise_scale + max(para, para_high) * dt) * th_on
    rise = high - memorised + drift * max(n_end - 1 - step, 0)
    fall = low - memorised
    return rise < th_on - TOLERANCE - ROUNDING_MARGIN and fall > -(th_off - TOLERANCE) + ROUNDING_MARGIN


_LOOK_BLOCK = 1024            # pixels scanned for those to look at before their rows are read
_LANES = 16                   # wake codes compared at once (:func:`_awake_mask`)


@intrinsic
def _awake_mask(typingctx, wake, start, limit):
    """Bit ``b`` set where ``wake[start + b] < limit``, for ``b < 16`` (``wake`` 32-bit codes, ``limit`` within their
    range): one vector load and compare (AVX-512: one ``vpcmpd`` into a mask register), not sixteen branches."""
    def codegen(context, builder, signature, args):
        values = context.make_array(signature.args[0])(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, signature.args[0], values, [args[1]], wraparound=False)
        lanes = ir.VectorType(ir.IntType(32), _LANES)
        loaded = builder.load(builder.bitcast(pointer, lanes.as_pointer()), align=4)
        undefined = ir.Constant(lanes, ir.Undefined)
        one = builder.insert_element(undefined, builder.trunc(args[2], ir.IntType(32)), ir.Constant(ir.IntType(32), 0))
        limits = builder.shuffle_vector(one, undefined, ir.Constant(ir.VectorType(ir.IntType(32), _LANES),
                                                                    [0] * _LANES))
        below = builder.icmp_signed("<", loaded, limits)
        return builder.zext(builder.bitcast(below, ir.IntType(_LANES)), ir.IntType(64))
    return types.uint64(wake, start, limit), codegen


@numba.njit(cache=True, error_model="numpy", nogil=True)     # runs beside other blocks' steps (pipelined windows)
def select_pixels(real, count, next_step, wake, applied, touched, changed, n_end, base, end, y_high, y_low, para_high,
                  envelope, leak_dt, dt, defer, refresh, kept, offset, n_kept, change_first, change_counts, quiet_from,
                  first, stop):
    """The pixels a window must process, in order, and the changes each takes.

    A pixel is processed when it is due before ``n_end`` (``next_step``), has its own input
    changes (``changed``, sorted), or lies away from the stamps (not in ``touched``, sorted)
    with background changes it has not taken (``applied < end``) that could make it fire
    (:func:`_cannot_fire`; ``y_high``, ``y_low``, ``para_high``: :meth:`SharedChanges.suffix_bounds`).
    ``defer`` False takes every change to every pixel at once (the reference the tests compare with).
    Returns ``(pixels, lo, hi, quiet_lo)``, the changes :func:`take_and_run` gives each: a pixel away from the
    stamps with pending changes takes its :meth:`SharedChanges.quiet_ranges` of the ``n_kept`` kept changes
    placed at ``offset`` (the first ``kept`` from before this window), marked taken (``applied`` set to ``end``:
    it takes them all in this window's run); ``changed[k]`` its own changes ``change_first[k]:change_first[k] +
    change_counts[k]``, after the kept changes ``quiet_from[k]`` (-1: none) to the last but one taken quietly; the
    others none. The ranges are made as each pixel is chosen, its ``applied`` read once (they were a second pass,
    ``take_ranges``, reading it again scattered over the sensor).

    ``wake[p]`` is the earlier of ``next_step[p]`` and :func:`.pixel_loop.quiet_until` under
    ``envelope = (y_high, y_low, para_high, wake_from)``, which holds every kept and later change, kept as
    :func:`.pixel_loop.wake_code` from ``wake_from``: a pixel whose wake step is ``n_end`` or later and has no
    own change is neither due nor able to fire, and only ``wake`` is read of it (4 bytes, not its state rows),
    sixteen codes compared at once (:func:`_awake_mask`). ``refresh`` sets ``wake`` of every pixel (a new
    envelope) and reads them all, as does a window ending ``WAKE_SPAN`` or more after ``wake_from`` (the caller
    renews the envelope first). The pixels to look at are listed a block at a time, so that their rows are asked
    for ahead of use. Only the pixels ``first .. stop - 1`` are looked at (ranges apart can run in threads).
    """
    n = min(stop, next_step.size)
    pixels = np.empty(max(n - first, 0), np.int64)
    lo, hi, quiet_lo = np.empty_like(pixels), np.empty_like(pixels), np.empty_like(pixels)
    look = np.empty(_LOOK_BLOCK, np.int64)
    m, it, ic = 0, 0, 0
    while it < touched.size and touched[it] < first:
        it += 1
    while ic < changed.size and changed[ic] < first:
        ic += 1
    ic_scan = ic
    y_env_high, y_env_low, para_env_high, wake_from = envelope[0], envelope[1], envelope[2], np.int64(envelope[3])
    limit = n_end - wake_from                         # a wake code below it: awake before n_end
    skip = defer and not refresh and abs(limit) < WAKE_SPAN
    for p0 in range(first, n, _LOOK_BLOCK):
        # the block's pixels to look at: those awake before n_end or with an own change (every pixel without skip)
        p1, k = min(n, p0 + _LOOK_BLOCK), 0
        if not skip:
            for p in range(p0, p1):
                look[k] = p
                k += 1
        q = p0
        while skip and q < p1:            # _LANES pixels at a time: those awake and those with an own change
            width = min(_LANES, p1 - q)
            mask = np.uint64(0)
            if width == _LANES:
                mask = _awake_mask(wake, q, limit)
            else:
                for b in range(width):
                    if wake[q + b] < limit:
                        mask |= np.uint64(1) << np.uint64(b)
            while ic_scan < changed.size and changed[ic_scan] < q + width:
                mask |= np.uint64(1) << np.uint64(changed[ic_scan] - q)
                ic_scan += 1
            while mask != 0:              # in order, each once
                look[k] = q + np.int64(trailing_zeros(mask))
                k += 1
                mask &= mask - np.uint64(1)
            q += width
        for i in range(k):                # their rows asked for ahead (scattered: each waits on memory)
            if i + _AHEAD < k:
                ahead = look[i + _AHEAD]
                _fetch_row(real, count, ahead)
                _fetch_item(next_step, ahead)
                _fetch_item(applied, ahead)
            p = look[i]
            while it < touched.size and touched[it] < p:
                it += 1
            under = it < touched.size and touched[it] == p
            while ic < changed.size and changed[ic] < p:
                ic += 1
            own = ic < changed.size and changed[ic] == p
            if refresh:
                wake[p] = wake_code(min(next_step[p], quiet_until(real[p, L_], real[p, Y], real[p, M_], real[p, TH_ON],
                                                                  real[p, TH_OFF], real[p, NOISE_SCALE], real[p, PARA],
                                                                  count[p, STEP], y_env_high, y_env_low, para_env_high,
                                                                  leak_dt, dt)), wake_from)
            busy = own or next_step[p] < n_end
            behind = (not under) and applied[p] < end
            if behind and not busy:
                j = applied[p] - base
                busy = not defer or not _cannot_fire(real[p, L_], real[p, Y], real[p, M_], real[p, TH_ON],
                                                     real[p, TH_OFF], real[p, NOISE_SCALE], real[p, PARA],
                                                     count[p, STEP], y_high[j], y_low[j], para_high[j], n_end,
                                                     leak_dt, dt)
            if busy:
                pixels[m], lo[m], hi[m], quiet_lo[m] = p, 0, 0, -1
                if behind:
                    pending = applied[p] - base
                    if pending < kept - 1:        # quietly up to the last but one kept change
                        lo[m], quiet_lo[m] = offset + kept - 1, pending
                    else:
                        lo[m] = offset + pending
                    hi[m] = offset + n_kept
                    applied[p] = end
                if own:
                    lo[m], hi[m], quiet_lo[m] = change_first[ic], change_first[ic] + change_counts[ic], quiet_from[ic]
                m += 1
    return pixels[:m].copy(), lo[:m].copy(), hi[:m].copy(), quiet_lo[:m].copy()


@numba.njit(cache=True, error_model="numpy", nogil=True)
def take_quietly_reference(real, count, pixels, lo, end, steps, inputs, leak_hz, dt, large):
    """Give ``pixels[i]`` the changes ``lo[i] .. end - 1`` (``steps``, ``inputs`` rows) without looking
    for comparator events between them: the compiled loop's own updates (:func:`.pixel_loop._advance`
    to the step before each change, then the new input), less its search for the next crossing after
    each, which finds none where the deferral bound held past the next change. One pixel after the
    other: the reference of :func:`take_quietly` (tested)."""
    for i in range(pixels.size):
        r, c = real[pixels[i]], count[pixels[i]]
        for k in range(lo[i], end):
            _advance(r, c, steps[k] - 1, leak_hz, dt, large)
            row = inputs[k]
            r[FLUX], r[Y], r[LOG_A], r[PARA], r[ACCEPT] = row[FLUX], row[Y], row[LOG_A], row[PARA], row[ACCEPT]


@numba.njit(cache=True, error_model="numpy", nogil=True)     # chunks run in threads (see .eventdriven)
def take_and_run(real, count, next_step, wake, envelope, pixels, quiet_lo, quiet_end, shared_step, shared_input,
                 change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end, leak_hz, dt, large,
                 k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma, th_floor, ev_step, ev_pixel, ev_pol,
                 ev_cause):
    """:func:`take_quietly` of the ``pixels`` with ``quiet_lo >= 0`` (their changes ``quiet_lo .. quiet_end - 1``
    of ``shared_step``, ``shared_input``), then :func:`.pixel_loop.run_pixels` of them all: one chunk's pixels
    while their rows are in cache, in the chunks' threads. Per pixel the same arithmetic in the same order as
    taking every pixel's quiet changes first (tested)."""
    quiet = quiet_lo >= 0
    if quiet.any():
        take_quietly(real, count, pixels[quiet], quiet_lo[quiet], quiet_end, shared_step, shared_input, leak_hz, dt,
                     large)
    known_step, known_retention, known_relaxed = np.empty(pixels.size, np.int64), np.empty(pixels.size), \
        np.empty(pixels.size)          # the sweep's last bound of each pixel, for run_pixels' first advance
    sweep_own(real, count, pixels, change_lo, change_hi, change_step, change_input, n_own, own_flux, drive_k, n_end,
              leak_hz, dt, large, known_step, known_retention, known_relaxed)   # own_sweep.take_own: the sweep
    drive_left(pixels, change_lo, change_hi, n_own, own_flux, drive_k, change_input)        # the rows left
    return run_pixels(real, count, next_step, wake, envelope, pixels, change_lo, change_hi, NEVER, change_step,
                      change_input, n_end, leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma,
                      th_floor, ev_step, ev_pixel, ev_pol, ev_cause, np.int64(0), 0.0, _LAZY, known_step,
                      known_retention, known_relaxed)


# fields of the pixels swept together by take_quietly (rows of its table), then their own input before their first
# change (its last rows)
(S_L, S_M, S_LEAK, S_PARA_C, S_TH_ON, S_SCALE, N_SWEPT) = range(7)
(S_Y, S_LOG_A, S_PARA) = range(N_SWEPT, N_SWEPT + 3)
N_OWN = 3


@numba.njit(cache=True, error_model="numpy", nogil=True)
def take_quietly(real, count, pixels, lo, end, steps, inputs, leak_hz, dt, large):
    """:func:`take_quietly_reference`, change by change over every pixel that takes it.

    A pixel's first change relaxes it from its own step at its own input; every later one from
    the step before the change before it, at that change's input: the same ``j`` and ``a^j`` for
    every pixel taking it. So after each pixel's first change (its own ``j`` and input, the pixels' fields
    gathered into contiguous rows first, so that this loop too is vectorised) the pixels taking change
    ``k`` (those with ``lo < k``, a prefix once ordered by ``lo``) take it together, ``a^j`` computed
    once, in loops over their fields gathered into contiguous rows: the filter's relaxation once for each
    run of pixels with the same ``L`` bits (:func:`_relax_runs`: runs only merge), the drift vectorised.
    Each pixel goes through the same arithmetic in the same order (:func:`.pixel_loop.relaxed_by`;
    :mod:`.fastmath`'s functions give the same bits in vectorised loops), so its state is the
    reference's bit for bit (tested).
    """
    wide_vectors()
    n = pixels.size
    if n == 0:
        return
    first = lo[0]
    for i in range(1, n):
        first = min(first, lo[i])
    # pixels ordered by lo (a counting sort): rank[i] is pixel i's place. Loops, not NumPy's cumsum, min and slice
    # assignment: each of those is compiled apart on a first run (the assignment's shape check with its message, ~1 s)
    starts = np.zeros(end - first + 1, np.int64)
    for i in range(n):
        starts[lo[i] - first + 1] += 1
    for k in range(1, starts.size):
        starts[k] += starts[k - 1]
    rank = np.empty(n, np.int64)
    for i in range(n):
        rank[i] = starts[lo[i] - first]
        starts[lo[i] - first] += 1
    for k in range(starts.size - 1, 0, -1):
        starts[k] = starts[k - 1]
    starts[0] = 0
    f = np.empty((N_SWEPT + N_OWN, n))
    j_first = np.empty(n, np.int64)
    for i in range(n):                                 # in the pixels' order: the state tables' order
        if i + _AHEAD < n:
            _fetch_row(real, count, pixels[i + _AHEAD])
        p, s = pixels[i], rank[i]                      # its fields, gathered
        f[S_L, s], f[S_M, s], f[S_LEAK, s], f[S_PARA_C, s] = real[p, L_], real[p, M_], real[p, C_LEAK], real[p, C_PARA]
        f[S_TH_ON, s], f[S_SCALE, s] = real[p, TH_ON], real[p, NOISE_SCALE]
        f[S_Y, s], f[S_LOG_A, s], f[S_PARA, s] = real[p, Y], real[p, LOG_A], real[p, PARA]
        j_first[s] = steps[lo[i]] - 1 - count[p, STEP]
    _first_sweep(f[S_L], f[S_M], f[S_LEAK], f[S_PARA_C], f[S_TH_ON], f[S_SCALE], f[S_Y], f[S_LOG_A], f[S_PARA],
                 j_first, leak_hz, dt, large)         # each pixel's first change, from its own step and input
    # their L as runs of equal bits: the pixels with lo = k - 1 join the runs at change k (the same step as those
    # before them: one run where the bits are the same), the runs' L relaxed change by change
    at, value, moved = np.empty(n + 1, np.int64), np.empty(n), np.empty(n)
    n_at, m = 0, 0
    for k in range(first + 1, end):
        for s in range(m, starts[k - first]):
            if n_at == 0 or _float_to_bits(f[S_L, s]) != _float_to_bits(value[n_at - 1]):
                at[n_at], value[n_at] = s, f[S_L, s]
                n_at += 1
        m = starts[k - first]                          # the pixels with lo < k
        j = steps[k] - steps[k - 1]                    # from the step before change k - 1 to the one before k
        if j > 0:
            row = inputs[k - 1]
            n_at = _relax_runs(at, value, moved, n_at, power(row[LOG_A], j), row[Y], row[LOG_A], row[PARA], j, leak_hz,
                               dt, large)
            _drift(f[S_M, :m], f[S_LEAK, :m], f[S_PARA_C, :m], f[S_TH_ON, :m], f[S_SCALE, :m], row[PARA], j, leak_hz,
                   dt)
    at[n_at] = m
    for r in range(n_at):                              # the runs' L back to their pixels
        for s in range(at[r], at[r + 1]):
            f[S_L, s] = value[r]
    last = inputs[end - 1]
    for i in range(n):
        if i + _AHEAD < n:
            _fetch_row(real, count, pixels[i + _AHEAD])
        p, s = pixels[i], rank[i]
        real[p, L_], real[p, M_], real[p, C_LEAK], real[p, C_PARA] = f[S_L, s], f[S_M, s], f[S_LEAK, s], f[S_PARA_C, s]
        real[p, FLUX], real[p, Y], real[p, LOG_A], real[p, PARA], real[p, ACCEPT] = last[FLUX], last[Y], last[LOG_A], \
            last[PARA], last[ACCEPT]
        count[p, STEP] = steps[end - 1] - 1


@numba.njit(cache=True, error_model="numpy", inline="always")
def _first_sweep(filtered, memorised, c_leak, c_para, th_on, noise_scale, y, log_a, para, j, leak_hz, dt, large):
    """Every pixel of the rows ``j[i]`` steps on at its own input ``y[i], log_a[i], para[i]`` (none for
    ``j[i] <= 0``; :func:`.pixel_loop.advanced` with no ``a^j`` known, as one pixel alone: :func:`.pixel_loop.relaxed_by`
    of :func:`.crossing.power`), computed by every pixel, kept by those that move (a loop that vectorises)."""
    for i in range(filtered.size):
        moved_l, moved_m, moved_leak, moved_para = relaxed_by(
            power(log_a[i], j[i]), filtered[i], memorised[i], c_leak[i], c_para[i], y[i], log_a[i], para[i], th_on[i],
            noise_scale[i], j[i], leak_hz, dt, large)
        moves = j[i] > 0
        filtered[i] = moved_l if moves else filtered[i]
        memorised[i] = moved_m if moves else memorised[i]
        c_leak[i] = moved_leak if moves else c_leak[i]
        c_para[i] = moved_para if moves else c_para[i]


@numba.njit(cache=True, error_model="numpy", inline="always")
def _relax_runs(at, value, moved, n_at, retention, y, log_a, para, j, leak_hz, dt, large):
    """The ``L`` of the runs ``value[:n_at]`` (first pixels ``at``) ``j > 0`` steps on at the input ``y, log_a, para``
    (:func:`.pixel_loop.relaxed_by`, ``retention = a^j``), neighbours left with the same bits merged into one run.
    Returns the runs' number. The new ``L`` depends on a pixel only through its ``L``, so a run's pixels keep
    one ``L``: on the tracked pass ~650 000 (pixel, change) pairs a window take ~15 000 relaxations, each run's
    computed in a vectorised loop first (:func:`_relaxed_runs`, into the scratch ``moved``), then merged."""
    _relaxed_runs(moved, value, n_at, retention, y, log_a, para, j, leak_hz, dt, large)
    w, last, relaxed = 0, np.int64(0), 0.0
    for r in range(n_at):
        bits = _float_to_bits(value[r])
        if w > 0 and bits == last:
            continue                                   # the run before had these bits: the same L after
        last = bits
        if w > 0 and _float_to_bits(moved[r]) == _float_to_bits(relaxed):
            continue                                   # the run before ends with the same bits: one run
        at[w], value[w], relaxed = at[r], moved[r], moved[r]
        w += 1
    return w


@numba.njit(cache=True, error_model="numpy", inline="always")
def _drift(memorised, c_leak, c_para, th_on, noise_scale, para, j, leak_hz, dt):
    """Every pixel's ``M`` and causes ``j`` steps on at the parasitic rate ``para`` (:func:`.pixel_loop.drifted`), in a
    loop the compiler vectorises."""
    for i in range(memorised.size):
        memorised[i], c_leak[i], c_para[i] = drifted(memorised[i], c_leak[i], c_para[i], para, th_on[i],
                                                     noise_scale[i], j, leak_hz, dt)


@numba.njit(cache=True, error_model="numpy")
def _relaxed_runs(moved, value, n_at, retention, y, log_a, para, j, leak_hz, dt, large):
    """``moved[r]``: the filter's ``L`` of :func:`.pixel_loop.relaxed_by` from ``value[r]``, for ``r < n_at``, in a loop
    the compiler vectorises (:mod:`.fastmath`'s ``exp`` and ``log``: the same bits as one at a time; a call of its own,
    not inlined, as a scalar loop over the runs took ~1 s more of the first compile with them inlined)."""
    wide_vectors()
    for r in range(n_at):
        moved[r] = relaxed_by(retention, value[r], 0.0, 0.0, 0.0, y, log_a, para, 0.0, 0.0, j, leak_hz, dt, large)[0]


class SharedChanges:
    """The background's input changes not yet taken by every pixel, kept in the pixel state dict.

    State entries: ``shared_step`` (k,) [steps], ``shared_input`` (k, columns) rows of the state
    table's input columns, ``shared_base`` the global index of the first kept change, and
    ``applied`` (pixels,) the global count of changes each pixel has taken.
    """

    def __init__(self, state: dict, columns: int):
        n = state["real"].shape[0]
        if "applied" not in state:                 # a state from before deferral: every pixel up to date
            state["applied"] = np.zeros(n, np.int64)
            state["shared_step"] = np.zeros(0, np.int64)
            state["shared_input"] = np.zeros((0, columns))
            state["shared_base"] = 0
        self.s = state

    @property
    def end(self) -> int:
        """Global count of changes so far."""
        return int(self.s["shared_base"]) + self.s["shared_step"].size

    def append(self, steps: np.ndarray, rows: np.ndarray) -> None:
        self.s["shared_step"] = np.concatenate([self.s["shared_step"], np.asarray(steps, np.int64)])
        self.s["shared_input"] = np.concatenate([self.s["shared_input"], rows])

    def behind(self, pixels: np.ndarray) -> np.ndarray:
        """Those of ``pixels`` (sorted) with changes not yet taken."""
        return pixels[self.s["applied"][pixels] < self.end]

    def ranges(self, pixels: np.ndarray, offset: int) -> tuple[np.ndarray, np.ndarray]:
        """Each pixel's pending changes as ``lo, hi`` rows of the kept changes placed at ``offset``."""
        lo = offset + self.s["applied"][pixels] - int(self.s["shared_base"])
        return lo, np.full(pixels.size, offset + self.s["shared_step"].size, np.int64)

    def suffix_bounds(self, y: int, para: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Largest and smallest ``Y`` and largest parasitic rate of the kept changes from each index on
        (columns ``y``, ``para`` of their rows); one more entry for none pending (neutral values)."""
        rows = self.s["shared_input"]
        y_high = np.r_[np.maximum.accumulate(rows[::-1, y])[::-1], -np.inf]
        y_low = np.r_[np.minimum.accumulate(rows[::-1, y])[::-1], np.inf]
        para_high = np.r_[np.maximum.accumulate(rows[::-1, para])[::-1], -np.inf]
        return y_high, y_low, para_high

    def quiet_ranges(self, pixels: np.ndarray, kept: int, offset: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`ranges`, split: ``quiet_lo`` (-1: none) is each pixel's first pending change of those it takes
        without the crossing searches (:func:`take_quietly`, from there to the last but one of the first ``kept``
        kept changes), ``lo:hi`` the rows left to the compiled loop (:func:`take_and_run` does both).

        Exact because every one of the quiet changes was left out of the pixel in a window after it, where
        the bound showed no event before that window's end, which is past the last of them; the last is
        left to the compiled loop, which looks for the pixel's next event after it.
        """
        lo = self.s["applied"][pixels] - int(self.s["shared_base"])
        quiet = lo < kept - 1
        return (offset + np.where(quiet, kept - 1, lo), np.full(pixels.size, offset + self.s["shared_step"].size, np.int64),
                np.where(quiet, lo, -1))

    def taken(self, pixels: np.ndarray) -> None:
        """``pixels`` have taken every kept change."""
        self.s["applied"][pixels] = self.end

    def prune(self) -> None:
        """Forget the changes every pixel has taken."""
        first = int(self.s["applied"].min()) if self.s["applied"].size else self.end
        drop = first - int(self.s["shared_base"])
        if drop > 0:
            self.s["shared_step"] = self.s["shared_step"][drop:].copy()
            self.s["shared_input"] = self.s["shared_input"][drop:].copy()
            self.s["shared_base"] = first
