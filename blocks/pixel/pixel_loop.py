"""The compiled per-pixel loop of the event-driven implementation (see :mod:`.eventdriven`).

Each pixel is taken on its own, from its last update through its input changes and its
events up to the end of the window; between them its state follows in closed form:

* low-pass filter at constant input (Eq. 16): ``L_j = Y + (L_0 - Y) a^j``, ``a = 1 - eps``, or in
  the large-signal form ``e^-L_j = e^-Y + (e^-L_0 - e^-Y) a^j`` (:func:`.crossing.relaxation`);
* memory drift by junction leak and parasitic photocurrent (Eqs. 18, 19): ``M`` falls by
  ``(R_leak + R_para) theta_ON dt`` per step;
* comparator (Eq. 17): the first step the input leaves its band (:mod:`.crossing`), not
  before the refractory period ends (Eq. 21); at most one event per step, the rest of
  ``Ne_total`` owed; at the first step the pixel may compare again the owed events that
  ``Ne_total`` no longer holds are lost (:mod:`.comparator`);
* shot noise (Eq. 20): trials arrive with the geometric waiting time of success
  probability ``q = 2 p_max`` per step (``p_max`` the largest probability per polarity over
  all inputs) and are accepted with ``p / p_max`` of the input at that step, the polarity
  from a fair coin (discrete-time thinning, Lewis & Shedler 1979): the reference's law. A
  shot event leaves the memory where it is (see :mod:`.noise`). Each pixel's leak and trial
  rates carry its own factor (``noise_scale``, hot pixels: :mod:`.initial`).

Within a step the comparator acts before the shot-noise trial, as in the reference. The
per-pixel state lives in two tables (see :data:`REAL`, :data:`COUNT`); random numbers are
counter-addressed per pixel (:mod:`.counter_rng`), so a pixel's events do not depend on
which other pixels are processed or on how the run is cut into windows.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from .comparator import ROUNDING_MARGIN, TOLERANCE
from .counter_rng import hash64_one, normal_one, uniform_open_one, unit_interval
from .crossing import (J_LIMIT, NEVER, NO_STEP, band_bound, first_crossing_known, large_weight, power, relaxation,
                       search_crossing)

# state table columns (keep in step with REAL and COUNT)
REAL = ("flux", "L", "M", "th_on", "th_off", "c_leak", "c_para",   # input, filter, memory, thresholds, causes
        "noise_scale",                                               # the pixel's leak and shot-noise rate factor
        "y", "log_a", "para", "accept")                              # derived from the input (Eqs. 14-16, 19-20)
COUNT = ("step", "ready", "shot_next", "shot_count", "cmp_next", "event_count",
         "owed")                                                     # signed events the comparator still owes
(FLUX, L_, M_, TH_ON, TH_OFF, C_LEAK, C_PARA, NOISE_SCALE, Y, LOG_A, PARA, ACCEPT) = range(len(REAL))
(STEP, READY, SHOT_NEXT, SHOT_COUNT, CMP_NEXT, EVENT_COUNT, OWED) = range(len(COUNT))
GAP, ACCEPT_STREAM, THRESHOLD = np.int64(1), np.int64(2), np.int64(3)    # counter-RNG streams (int64, not literals:
#                                                  one compile of the generator serves all three)
LATER = NEVER + np.int64(1)                      # "no comparator event before the pixel's next change or event"
SOON = -NEVER                                    # "no window's end shown quiet": the bound is checked in full
_LAZY, _EXACT = np.bool_(True), np.bool_(False)  # run_pixels may keep a bound as a schedule (typed bool, not literals)
SIGNAL, LEAK, PARASITIC, SHOT = 0, 1, 2, 3       # event causes (EventCause)

_AHEAD = 8                                       # pixels whose state rows are fetched ahead of their turn
WAKE_SPAN = np.int64(2**31 - 1)                  # wake steps kept in 32 bits from a first step, saturated there
jit = numba.njit(cache=True, error_model="numpy")
inline = numba.njit(cache=True, error_model="numpy", inline="always")    # so that loops over pixels vectorise


def _prefetch_item(context, builder, array_type, array, row, column):
    """LLVM's ``prefetch`` of ``array[row, column]`` (read, kept in every cache level, data)."""
    values = context.make_array(array_type)(context, builder, array)
    _prefetch_pointer(builder, cgutils.get_item_pointer(context, builder, array_type, values, [row, column],
                                                        wraparound=False))


def _prefetch_pointer(builder, pointer):
    """LLVM's ``prefetch`` of the item at ``pointer`` (read, kept in every cache level, data)."""
    byte_pointer, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
    signature_ir = ir.FunctionType(ir.VoidType(), [byte_pointer, i32, i32, i32])
    function = cgutils.get_or_insert_function(builder.module, signature_ir, "llvm.prefetch.p0i8")
    builder.call(function, [builder.bitcast(pointer, byte_pointer), i32(0), i32(3), i32(1)])


@intrinsic
def _prefetch(typingctx, array, row, column):
    """Ask the CPU to bring ``array[row, column]`` into its caches (LLVM's ``prefetch``; no effect on results)."""
    def codegen(context, builder, signature, args):
        _prefetch_item(context, builder, signature.args[0], args[0], args[1], args[2])
        return context.get_dummy_value()
    return types.void(array, row, column), codegen


@intrinsic
def _fetch_item(typingctx, array, index):
    """Ask the CPU to bring ``array[index]`` (one dimension) into its caches (no effect on results)."""
    def codegen(context, builder, signature, args):
        values = context.make_array(signature.args[0])(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, signature.args[0], values, [args[1]], wraparound=False)
        _prefetch_pointer(builder, pointer)
        return context.get_dummy_value()
    return types.void(array, index), codegen


_LINE_ITEMS = 8                                  # 8-byte items in a 64-byte cache line
_ROW_ITEMS = 32                                  # the widest state row fetched whole [items]


@intrinsic
def _fetch_row(typingctx, real, count, pixel):
    """Ask for a pixel's state rows (every cache line of ``real[pixel]`` and ``count[pixel]``: their first item,
    every ``_LINE_ITEMS``-th after it and their last) ahead of use (no effect on results): scattered rows wait on
    memory. A 96-byte row of ``real`` at a start 48 bytes into a line spans three lines; its first and last items
    alone left the middle one to a miss at its use. An intrinsic, so that no array is passed through a call
    (Numba counts an array's references up and down at each, atomically)."""
    def codegen(context, builder, signature, args):
        for array_type, array in zip(signature.args[:2], args[:2]):
            shape = cgutils.unpack_tuple(builder, context.make_array(array_type)(context, builder, array).shape, 2)
            last = builder.sub(shape[1], shape[1].type(1))
            _prefetch_item(context, builder, array_type, array, args[2], shape[1].type(0))
            for k in range(_LINE_ITEMS, _ROW_ITEMS, _LINE_ITEMS):     # the lines between (rows up to _ROW_ITEMS)
                column = shape[1].type(k)
                inside = builder.icmp_signed("<", column, last)
                with builder.if_then(inside, likely=True):
                    _prefetch_item(context, builder, array_type, array, args[2], column)
            _prefetch_item(context, builder, array_type, array, args[2], last)
        return context.get_dummy_value()
    return types.void(real, count, pixel), codegen


@jit
def shot_gap(key, pixel, count, q):
    """Steps to the next shot-noise trial: geometric with success probability ``q`` per step."""
    if q <= 0.0:
        return NEVER
    if q >= 1.0:
        return np.int64(1)
    u = uniform_open_one(key, GAP, pixel, count)
    return np.int64(min(math.floor(math.log(u) / math.log1p(-q)) + 1.0, float(NEVER // 2)))


@jit
def start_pixels(real, count, next_step, inverse, rows, settled, parasitic_hz, th_on, th_off, phase, noise_scale, n_start,
                 leak_hz, dt, large, key, q):
    """Fill every pixel's state row from its start, at step ``n_start - 1``, and schedule its first shot-noise trial
    and comparator event: one pass over the tables, which it writes first.

    Pixel ``p``'s input columns are row ``inverse[p]`` of ``rows`` (:func:`.drive_kernel.drive_rows` of the distinct
    fluxes) and its settled filter and parasitic rate entry ``inverse[p]`` of ``settled`` and ``parasitic_hz``
    (:meth:`.model.PixelModel.distinct_drive`); ``th_on``, ``th_off``, ``phase`` and ``noise_scale`` are its draws
    (:func:`.initial.initial_draws`). The filter starts settled and the memory a head start ``phase theta_ON`` below
    it, charged to the leak and parasitic contributions in proportion to their rates: :func:`.initial.initial_pixels`'
    arithmetic, pixel by pixel (the same bits, tested), without its arrays of the whole sensor (~120 MB on a 1280 x
    720 sensor, each page first touched).

    The comparator's schedule is the one a turn's end keeps (:func:`kept_schedule`): where :func:`quiet_until`
    bounds the first crossing (almost every pixel: its first leak event seconds ahead), that bound, the search
    left for the turn at which its crossing could be used (most pixels take a background change or a noise event
    first, after which it is searched again anyway); the same events as the search here (it was ~150 ms of CPU
    on a 1280 x 720 sensor, the filter settled a rounding off its target)."""
    for pixel in range(count.shape[0]):
        k = inverse[pixel]
        for column in (FLUX, Y, LOG_A, PARA, ACCEPT):
            real[pixel, column] = rows[k, column]
        filtered, rate = settled[k], leak_hz + parasitic_hz[k]
        head = phase[pixel] * th_on[pixel] if rate > 0.0 else 0.0
        share = leak_hz / rate if rate > 0.0 else 0.0
        c_leak = head * share
        memorised = filtered - head
        real[pixel, L_], real[pixel, M_] = filtered, memorised
        real[pixel, TH_ON], real[pixel, TH_OFF] = th_on[pixel], th_off[pixel]
        real[pixel, C_LEAK], real[pixel, C_PARA], real[pixel, NOISE_SCALE] = c_leak, head - c_leak, noise_scale[pixel]
        for column in range(count.shape[1]):
            count[pixel, column] = 0
        step, ready = n_start - 1, n_start
        count[pixel, STEP], count[pixel, READY] = step, ready
        shot_next = step + shot_gap(key, pixel, np.int64(0), q * noise_scale[pixel])
        count[pixel, SHOT_NEXT] = shot_next
        cmp_next = kept_schedule(step, ready, real[pixel, Y], memorised, filtered, real[pixel, LOG_A],
                                 real[pixel, PARA], th_on[pixel], th_off[pixel], noise_scale[pixel], leak_hz * dt, dt,
                                 large)
        count[pixel, CMP_NEXT] = cmp_next
        next_step[pixel] = min(schedule_bound(cmp_next), shot_next, NEVER)       # owes nothing: no settling step


@inline
def _settle_step(ready, owed):
    """The step at which a pixel's owed events are settled: its first comparison after an event."""
    return ready if owed != 0 else NEVER


@jit
def next_crossing(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, t_change, leak_dt, dt,
                  large):
    """Step of a pixel's next comparator event before its next input change ``t_change`` (``NEVER``: none).

    The pixel is at ``step`` with the given state and input and may fire from ``ready`` on;
    ``large``: the large-signal filter.
    """
    t, _, _, _ = next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale,
                                  t_change, leak_dt, dt, large)
    return t


@inline
def _search_span(step, ready, t_change):
    """``(j0, horizon)`` of :func:`next_crossing_known`'s search from ``step`` [steps]: the first step a crossing
    may be taken at (the refractory period's ``ready``, at least the next step) and the last before the next change
    ``t_change`` (at most ``J_LIMIT``). Its bound covers ``max(horizon, j0)`` steps
    (:func:`.crossing.first_crossing_known`)."""
    return max(ready - step, np.int64(1)), min(NEVER if t_change >= NEVER else t_change - 1 - step, J_LIMIT)


@jit
def next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, t_change, leak_dt,
                        dt, large):
    """:func:`next_crossing`, also returning ``(j, a^j, relaxation)`` from its bound (:func:`.crossing.first_crossing_known`)."""
    drift = (leak_dt * noise_scale + para * dt) * th_on
    j0, horizon = _search_span(step, ready, t_change)
    j, _, j_known, known, relaxed = first_crossing_known(j0, y - memorised, filtered - y, log_a, drift,
                                                         th_on - TOLERANCE, th_off - TOLERANCE, horizon, large)
    return (NEVER if j >= NEVER else step + j), j_known, known, relaxed


@inline
def _schedule_before(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, t_change, last,
                     leak_dt, dt, large):
    """:func:`next_crossing_known` where only a crossing up to step ``last`` can be used: ``LATER`` without the
    search when the bound (:func:`.crossing.band_bound`) shows none up to ``last``.

    ``last`` is the last step at which :func:`run_pixels` would act on the crossing before something
    else happens to the pixel (its next input change, shot-noise trial, settling step or the window's
    end), after which it schedules the pixel again; a ``LATER`` left at the end of the pixel's turn is
    replaced by the search with the same state, so the stored schedule and the events are the same.
    Returns ``(step, j, a^j, relaxation)``, the last three the bound's, as :func:`next_crossing_known`'s.
    Where the search's own bound would be this one (``last`` is the step before the next change, the usual
    case), the search starts from it (:func:`.crossing.search_crossing`) instead of taking it again.
    """
    j0, horizon = _search_span(step, ready, t_change)                   # next_crossing_known's
    j_max = max(last - step, j0)
    drift = (leak_dt * noise_scale + para * dt) * th_on
    c, d, on, off = y - memorised, filtered - y, th_on - TOLERANCE, th_off - TOLERANCE
    holds, retention, relaxed = band_bound(j_max, c, d, log_a, drift, on, off, large)
    if holds:
        return LATER, j_max, retention, relaxed
    if max(horizon, j0) != j_max:
        return next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale,
                                   t_change, leak_dt, dt, large)
    j, _ = search_crossing(j0, c, d, log_a, drift, on, off, horizon, j_max, retention, large)
    return (NEVER if j >= NEVER else step + j), j_max, retention, relaxed


@inline
def relaxed_by(retention, filtered, memorised, c_leak, c_para, y, log_a, para, th_on, noise_scale, j, leak_hz, dt,
               large):
    """``(L, M, c_leak, c_para)`` after ``j > 0`` steps at constant input (Eqs. 16, 18, 19), the filter's
    ``retention = a^j`` given (``power(log_a, j)``)."""
    if large:
        d = filtered - y
        filtered = y + relaxation(d, large_weight(d), j * log_a, retention, True)
    else:
        filtered = y + (filtered - y) * retention
    return (filtered,) + drifted(memorised, c_leak, c_para, para, th_on, noise_scale, j, leak_hz, dt)


@inline
def drifted(memorised, c_leak, c_para, para, th_on, noise_scale, j, leak_hz, dt):
    """``(M, c_leak, c_para)`` after ``j`` steps of leak and parasitic drift (Eqs. 18, 19; :func:`relaxed_by`)."""
    scale = th_on * j * dt
    leak = leak_hz * noise_scale * scale
    para = para * scale
    return memorised - (leak + para), c_leak + leak, c_para + para


@inline
def _advance(r, c, t, leak_hz, dt, large):
    """Move a pixel with state rows ``r``, ``c`` from its last step to step ``t`` at constant input
    (:func:`advanced`)."""
    r[L_], r[M_], r[C_LEAK], r[C_PARA] = advanced(t - c[STEP], NO_STEP, 0.0, 0.0, r[L_], r[M_], r[C_LEAK], r[C_PARA],
                                                  r[Y], r[LOG_A], r[PARA], r[TH_ON], r[NOISE_SCALE], leak_hz, dt, large)
    c[STEP] = t


@inline
def advanced(j, j_known, known, relaxed, filtered, memorised, c_leak, c_para, y, log_a, para, th_on, noise_scale,
             leak_hz, dt, large):
    """``(L, M, c_leak, c_para)`` of a pixel ``j`` steps on at constant input (:func:`relaxed_by`; none for
    ``j <= 0``), taking ``a^j`` from ``known = a^j_known`` and, in the large-signal form, ``L - Y`` from
    ``relaxed`` (the pixel's last schedule's bound, at its present input: :func:`.crossing.first_crossing_known`)
    when ``j = j_known``: the same bits, without their ``exp`` and ``log`` (``j_known = NO_STEP``: none known)."""
    if j > 0 and j == j_known and large and known > 0.0:
        memorised, c_leak, c_para = drifted(memorised, c_leak, c_para, para, th_on, noise_scale, j, leak_hz, dt)
        return y + relaxed, memorised, c_leak, c_para
    if j > 0:
        retention = known if j == j_known else power(log_a, j)
        return relaxed_by(retention, filtered, memorised, c_leak, c_para, y, log_a, para, th_on, noise_scale, j,
                          leak_hz, dt, large)
    return filtered, memorised, c_leak, c_para


@jit
def _redrawn(th_on, th_off, event_count, pixel, sign, key, th_mean_on, th_mean_off, th_sigma, th_floor):
    """IEBCS: ``(theta_ON, theta_OFF, event count)`` with a new threshold of the polarity that fired, addressed by
    the pixel's event count."""
    z = normal_one(key, THRESHOLD, pixel, event_count)
    if sign > 0:
        th_on = max(th_mean_on + th_sigma * z, th_floor)
    else:
        th_off = max(th_mean_off + th_sigma * z, th_floor)
    return th_on, th_off, event_count + 1


@jit
def _fire(filtered, memorised, th_on, th_off, c_leak, c_para):
    """Comparator event (Eq. 17) of a pixel whose state is at the event step.

    Returns ``(polarity, cause, total, M, c_leak, c_para)``: the cause is the contribution to ``L - M``
    pushing hardest in the event's direction (see :mod:`.comparator`), which gives up one
    threshold; ``total`` is ``|Ne_total|``, the events the comparator could emit now.
    """
    delta = filtered - memorised
    sign = 1 if delta >= 0.0 else -1
    theta = th_on if sign > 0 else th_off
    total = max(math.trunc((abs(delta) + TOLERANCE) / theta), 1.0)
    signal = delta - (c_leak + c_para)
    cause, best = SIGNAL, sign * signal
    if sign * c_leak > best:
        cause, best = LEAK, sign * c_leak
    if sign * c_para > best:
        cause, best = PARASITIC, sign * c_para
    moved = sign * theta
    if cause == LEAK:
        c_leak -= moved
    elif cause == PARASITIC:
        c_para -= moved
    return sign, cause, total, memorised + moved, c_leak, c_para


@jit
def quiet_until(filtered, y, memorised, th_on, th_off, noise_scale, para, step, y_high, y_low, para_high, leak_dt,
                dt):
    """The last window end ``n_end`` before which a pixel (its state at ``step``) provably cannot fire under
    background changes whose ``Y`` lie in ``[y_low, y_high]`` and parasitic rates below ``para_high`` (the
    envelope), taken or not; ``SOON`` where none is shown.

    :func:`.deferred._cannot_fire`'s bound with the envelope in place of the pending changes' extremes,
    the same expressions in the same order: each is monotone in those extremes and in the steps ``n_end - 1
    - step`` (rounding is monotone), so wherever the envelope holds the pending changes and ``n_end`` is at
    most the result, that bound holds too, and the pixel need not be read (:func:`.deferred.select_pixels`).
    """
    if not min(filtered, y, y_low) - memorised > -(th_off - TOLERANCE) + ROUNDING_MARGIN:
        return SOON
    rise = max(filtered, y, y_high) - memorised
    limit = th_on - TOLERANCE - ROUNDING_MARGIN
    drift = (leak_dt * noise_scale + max(para, para_high) * dt) * th_on
    if not rise < limit or not drift >= 0.0:
        return SOON
    if drift == 0.0:
        return NEVER
    steps = np.int64(min((limit - rise) / drift, float(J_LIMIT)))
    if not rise + drift * steps < limit:          # rounding: bisect between 0 steps (quiet) and these (not)
        quiet = np.int64(0)
        while steps - quiet > 1:
            middle = quiet + (steps - quiet) // 2
            if rise + drift * middle < limit:
                quiet = middle
            else:
                steps = middle
        steps = quiet
    return step + 1 + steps


@inline
def wake_code(step, wake_from):
    """A wake step as :func:`.deferred.select_pixels` keeps it: ``step - wake_from`` in 32 bits, saturated at
    ``+-WAKE_SPAN`` (half the bytes to scan each window). A code saturated high stands for a step at least
    ``wake_from + WAKE_SPAN``, one saturated low for a step before ``wake_from - WAKE_SPAN``: compared with a
    window's end within ``WAKE_SPAN`` of ``wake_from`` both give the answer the step would."""
    return np.int32(max(min(step - wake_from, WAKE_SPAN), -WAKE_SPAN))


@jit
def kept_schedule(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, leak_dt, dt, large):
    """The comparator schedule a pixel keeps at the end of its turn, with no input change ahead: the search's
    crossing (:func:`next_crossing_known`, no horizon), or where :func:`quiet_until` bounds it, that bound
    ``R`` kept instead as ``-2 - R`` (:func:`schedule_bound`), the search left for when it can be used.

    At the pixel's next turn its state is the one the bound was taken at until its first input change
    (:mod:`.deferred`: changes taken quietly all lie before ``R``), so the search made then, only where
    the crossing could come before anything else, gives the crossing the search here would have
    (:func:`run_pixels`); until then ``R`` is the pixel's next comparator step for the choice of pixels.
    Most turns end with the crossing seconds ahead (leak), past the next background change, after which it
    is searched again: the search is most of a noise event's cost.
    """
    bound = quiet_until(filtered, y, memorised, th_on, th_off, noise_scale, para, step, -np.inf, np.inf, 0.0,
                        leak_dt, dt)
    if bound != SOON:
        return -2 - bound
    return next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, NEVER,
                               leak_dt, dt, large)[0]


@inline
def schedule_bound(cmp_next):
    """The earliest step a kept schedule (:func:`kept_schedule`) allows the comparator's next event at."""
    return cmp_next if cmp_next >= 0 else -2 - cmp_next


@jit
def resolve_schedules(real, count, next_step, leak_hz, dt, large):
    """Every pixel's kept schedule made the search's crossing (:func:`kept_schedule`), and ``next_step`` with it:
    for the dense path, which reads them as such (:mod:`.dense_loop`)."""
    leak_dt = leak_hz * dt
    for pixel in range(count.shape[0]):
        if count[pixel, CMP_NEXT] < 0:
            cmp_next = next_crossing_known(count[pixel, STEP], count[pixel, READY], real[pixel, Y], real[pixel, M_],
                                           real[pixel, L_], real[pixel, LOG_A], real[pixel, PARA], real[pixel, TH_ON],
                                           real[pixel, TH_OFF], real[pixel, NOISE_SCALE], NEVER, leak_dt, dt,
                                           large)[0]
            count[pixel, CMP_NEXT] = cmp_next
            next_step[pixel] = min(cmp_next, count[pixel, SHOT_NEXT], _settle_step(count[pixel, READY],
                                                                                    count[pixel, OWED]))


@numba.njit(cache=True, error_model="numpy", nogil=True)     # chunks run in threads (see .eventdriven)
def run_pixels(real, count, next_step, wake, envelope, pixels, change_lo, change_hi, stop_after, change_step,
               change_input, n_end, leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma,
               th_floor, ev_step, ev_pixel, ev_pol, ev_cause, n_events, lost, lazy, known_step, known_retention,
               known_relaxed):
    """Every event before step ``n_end`` of each of ``pixels``, one after the other, pixel ``pixels[i]`` through
    its input changes ``change_lo[i]:change_hi[i]``: from ``change_step[k]`` on its input is row ``k`` of
    ``change_input`` (columns ``FLUX`` and ``Y`` to ``ACCEPT`` of :data:`REAL`; rows may be shared by many
    pixels).

    A pixel stops after its change ``change_lo[i] + stop_after - 1`` and its comparator's schedule (up to
    the next change), its later events and changes left for another call (``stop_after`` beyond its
    changes: none left). Updates the state tables in place, ``next_step`` (each pixel's next event) and
    ``wake`` (the earlier of it and :func:`quiet_until` under ``envelope = (y_high, y_low, para_high,
    wake_from)``, as :func:`wake_code` from ``wake_from``) where they are not empty, and writes the events (step, pixel, polarity, cause) into the ``ev_*``
    buffers from position ``n_events``; ``lost`` accumulates the events lost. Returns ``(events
    written, pixels done, lost)``: it stops before a pixel whose events would overflow the buffers,
    that pixel untouched.

    ``lazy``: a pixel with no input change left keeps a bound as its comparator schedule where one is shown
    (:func:`kept_schedule`; ``next_step`` holds the bound), and the search is made at the turn at which the
    crossing could be used; else (and where ``stop_after`` stops the pixel) the search's crossing is kept.

    ``known_step[i]``, ``known_retention[i]``, ``known_relaxed[i]`` (empty: none): the ``j``, ``a^j`` and relaxation
    the last bound of ``pixels[i]`` took at its present state (:func:`.own_sweep.sweep_own`'s, ``NO_STEP``: none),
    which its first advance by ``j`` steps takes instead of their ``exp`` and ``log`` (:func:`advanced`: the same
    bits), as after a bound taken here; an event at the step the bound reached (a shot-noise trial or a settling
    step: most noise events) takes them too.

    A pixel's state is read into local variables at its turn and written back at its end: no array is
    passed through a call in the loops (Numba counts an array's references up and down at each, atomically:
    about a third of this loop's time when the helpers took the pixel's state rows).
    """
    capacity = ev_step.size
    leak_dt = leak_hz * dt
    for i in range(pixels.size):
        if i + _AHEAD < pixels.size:
            _fetch_row(real, count, pixels[i + _AHEAD])
        pixel = pixels[i]
        flux, filtered, memorised = real[pixel, FLUX], real[pixel, L_], real[pixel, M_]
        th_on, th_off = real[pixel, TH_ON], real[pixel, TH_OFF]
        c_leak, c_para = real[pixel, C_LEAK], real[pixel, C_PARA]
        noise_scale, y, log_a = real[pixel, NOISE_SCALE], real[pixel, Y], real[pixel, LOG_A]
        para, accept = real[pixel, PARA], real[pixel, ACCEPT]
        step, ready, shot_next, shot_count = count[pixel, STEP], count[pixel, READY], count[pixel, SHOT_NEXT], \
            count[pixel, SHOT_COUNT]
        cmp_next = count[pixel, CMP_NEXT]   # the first crossing at the present input: valid up to any change
        event_count, owed = count[pixel, EVENT_COUNT], count[pixel, OWED]
        first_event, lost_before = n_events, lost
        ptr, end = change_lo[i], change_hi[i]
        stop = ptr + stop_after
        t_change = change_step[ptr] if ptr < end else NEVER
        j_known, known, relaxed = NO_STEP, 0.0, 0.0          # what its schedule's bound took (none: from the state)
        shown = NO_STEP                 # the j up to which _schedule_before's bound showed no crossing (LATER)
        if known_step.size:
            j_known, known, relaxed = known_step[i], known_retention[i], known_relaxed[i]
        quiet = SOON                    # quiet_until of the present state where the lazy schedule took it
        if cmp_next < 0:                # a kept bound: the search, where the crossing could come first (the state
            # is still the one the bound was taken at: kept_schedule); elsewhere none comes before what does
            if -2 - cmp_next <= min(t_change - 1, n_end - 1, shot_next, _settle_step(ready, owed)):
                cmp_next = next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off,
                                               noise_scale, NEVER, leak_dt, dt, large)[0]
            else:
                cmp_next = LATER
        while True:
            t_settle = _settle_step(ready, owed)
            t_event = min(cmp_next, shot_next, t_settle)
            event = t_event < t_change and t_event < n_end
            if event:                                         # an event first (at the bound's j: its a^j)
                if n_events + 2 > capacity:                   # no room: this pixel as it was, without its events
                    return first_event, i, lost_before
                t, j_at = t_event, j_known
            elif ptr < end:                                   # the next input takes over
                t, j_at = t_change - 1, j_known
            else:
                break
            # one place that advances the pixel: each inlined copy of it costs ~1 s of the first compile
            filtered, memorised, c_leak, c_para = advanced(t - step, j_at, known, relaxed, filtered, memorised,
                                                           c_leak, c_para, y, log_a, para, th_on, noise_scale, leak_hz,
                                                           dt, large)
            step = t
            if event:
                awake = ready <= t_event
                fires = cmp_next == t_event
                sign, cause, total = 0, SIGNAL, 0.0
                if fires:
                    sign, cause, total, memorised, c_leak, c_para = _fire(filtered, memorised, th_on, th_off, c_leak,
                                                                          c_para)
                if t_settle == t_event:                       # first comparison after an event (Eq. 17)
                    kept = min(float(abs(owed)), total) if (owed > 0) == (sign > 0) else 0.0
                    lost += abs(owed) - kept
                    owed = 0
                if fires:                                     # the event; the refractory period (Eq. 21)
                    owed = sign * np.int64(total - 1.0)
                    ready = t_event + k_refr
                    ev_step[n_events], ev_pixel[n_events], ev_pol[n_events], ev_cause[n_events] = t_event, pixel, \
                        sign, cause
                    n_events += 1
                    if redraw:
                        th_on, th_off, event_count = _redrawn(th_on, th_off, event_count, pixel, sign, key, th_mean_on,
                                                              th_mean_off, th_sigma, th_floor)
                    awake = False
                if shot_next == t_event:                      # shot noise (Eq. 20)
                    bits = hash64_one(key, ACCEPT_STREAM, pixel, shot_count)
                    if unit_interval(bits) < accept:
                        if awake:
                            sign = 1 if (bits & np.uint64(1)) == 1 else -1
                            ready = t_event + k_refr
                            ev_step[n_events], ev_pixel[n_events], ev_pol[n_events], ev_cause[n_events] = t_event, \
                                pixel, sign, SHOT
                            n_events += 1
                            if redraw:
                                th_on, th_off, event_count = _redrawn(th_on, th_off, event_count, pixel, sign, key,
                                                                      th_mean_on, th_mean_off, th_sigma, th_floor)
                        else:
                            lost += 1.0
                    shot_count += 1
                    shot_next = t_event + shot_gap(key, pixel, shot_count, q * noise_scale)
            else:
                flux, y, log_a = change_input[ptr, FLUX], change_input[ptr, Y], change_input[ptr, LOG_A]
                para, accept = change_input[ptr, PARA], change_input[ptr, ACCEPT]
                ptr += 1
                t_change = change_step[ptr] if ptr < end else NEVER
            last = min(t_change - 1, n_end - 1, shot_next, _settle_step(ready, owed))
            if lazy and t_change >= NEVER and last == n_end - 1:      # nothing else before the window's end
                cmp_next, j_known, shown = LATER, NO_STEP, NO_STEP    # kept_schedule at the turn's end, or now:
                quiet = quiet_until(filtered, y, memorised, th_on, th_off, noise_scale, para, step, -np.inf, np.inf,
                                    0.0, leak_dt, dt)
                if not quiet >= n_end:
                    cmp_next = next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off,
                                                   noise_scale, NEVER, leak_dt, dt, large)[0]
            else:
                cmp_next, j_known, known, relaxed = _schedule_before(step, ready, y, memorised, filtered, log_a,
                                                                     para, th_on, th_off, noise_scale, t_change,
                                                                     last, leak_dt, dt, large)
                quiet, shown = SOON, j_known
            if ptr == stop:
                break
        if cmp_next == LATER:           # the stored schedule is the search's or a bound of it (kept_schedule)
            if lazy and t_change >= NEVER and quiet != SOON:      # kept_schedule's bound, taken above (same state)
                cmp_next = -2 - quiet
            elif lazy and t_change >= NEVER:
                cmp_next = kept_schedule(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale,
                                         leak_dt, dt, large)
            elif shown == max(_search_span(step, ready, t_change)):
                cmp_next = NEVER        # the bound that held was the search's own (first_crossing_known): none
            else:
                cmp_next = next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off,
                                               noise_scale, t_change, leak_dt, dt, large)[0]
        real[pixel, FLUX], real[pixel, L_], real[pixel, M_] = flux, filtered, memorised
        real[pixel, TH_ON], real[pixel, TH_OFF] = th_on, th_off
        real[pixel, C_LEAK], real[pixel, C_PARA] = c_leak, c_para
        real[pixel, Y], real[pixel, LOG_A], real[pixel, PARA], real[pixel, ACCEPT] = y, log_a, para, accept
        count[pixel, STEP], count[pixel, READY], count[pixel, SHOT_NEXT] = step, ready, shot_next
        count[pixel, SHOT_COUNT], count[pixel, CMP_NEXT] = shot_count, cmp_next
        count[pixel, EVENT_COUNT], count[pixel, OWED] = event_count, owed
        if next_step.size:
            next_step[pixel] = min(schedule_bound(cmp_next), shot_next, _settle_step(ready, owed))
            if wake.size:
                wake[pixel] = wake_code(min(next_step[pixel], quiet_until(filtered, y, memorised, th_on, th_off,
                                                                          noise_scale, para, step, envelope[0],
                                                                          envelope[1], envelope[2], leak_dt, dt)),
                                        np.int64(envelope[3]))
    return n_events, pixels.size, lost
