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
from .crossing import J_LIMIT, NEVER, NO_STEP, band_bound, first_crossing_known, large_weight, power, relaxation

# state table columns (keep in step with REAL and COUNT)
REAL = ("flux", "L", "M", "th_on", "th_off", "c_leak", "c_para",   # input, filter, memory, thresholds, causes
        "noise_scale",                                               # the pixel's leak and shot-noise rate factor
        "y", "log_a", "para", "accept")                              # derived from the input (Eqs. 14-16, 19-20)
COUNT = ("step", "ready", "shot_next", "shot_count", "cmp_next", "event_count",
         "owed")                                                     # signed events the comparator still owes
(FLUX, L_, M_, TH_ON, TH_OFF, C_LEAK, C_PARA, NOISE_SCALE, Y, LOG_A, PARA, ACCEPT) = range(len(REAL))
(STEP, READY, SHOT_NEXT, SHOT_COUNT, CMP_NEXT, EVENT_COUNT, OWED) = range(len(COUNT))
GAP, ACCEPT_STREAM, THRESHOLD = 1, 2, 3          # counter-RNG streams
LATER = NEVER + np.int64(1)                      # "no comparator event before the pixel's next change or event"
SOON = -NEVER                                    # "no window's end shown quiet": the bound is checked in full
SIGNAL, LEAK, PARASITIC, SHOT = 0, 1, 2, 3       # event causes (EventCause)

_AHEAD = 8                                       # pixels whose state rows are fetched ahead of their turn
jit = numba.njit(cache=True, error_model="numpy")
inline = numba.njit(cache=True, error_model="numpy", inline="always")    # so that loops over pixels vectorise


@intrinsic
def _prefetch(typingctx, array, row, column):
    """Ask the CPU to bring ``array[row, column]`` into its caches (LLVM's ``prefetch``; no effect on results)."""
    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        pointer = cgutils.get_item_pointer(context, builder, array_type,
                                           context.make_array(array_type)(context, builder, args[0]),
                                           [args[1], args[2]], wraparound=False)
        byte_pointer, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        signature_ir = ir.FunctionType(ir.VoidType(), [byte_pointer, i32, i32, i32])
        function = cgutils.get_or_insert_function(builder.module, signature_ir, "llvm.prefetch.p0i8")
        builder.call(function, [builder.bitcast(pointer, byte_pointer), i32(0), i32(3), i32(1)])   # read, keep, data
        return context.get_dummy_value()
    return types.void(array, row, column), codegen


@inline
def _fetch_row(real, count, pixel):
    """Ask for a pixel's state rows ahead of use (no effect on results): scattered rows wait on memory."""
    _prefetch(real, pixel, 0)
    _prefetch(real, pixel, real.shape[1] - 1)
    _prefetch(count, pixel, 0)
    _prefetch(count, pixel, count.shape[1] - 1)


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
def start_pixels(real, count, next_step, filtered, memorised, th_on, th_off, credit, noise_scale, n_start, leak_hz,
                 dt, large, key, q):
    """Fill every pixel's state row (its input columns already set) from its initial state, at step ``n_start - 1``,
    and schedule its first shot-noise trial and comparator event: one pass over the tables."""
    for pixel in range(count.shape[0]):
        r, c = real[pixel], count[pixel]
        r[L_], r[M_], r[TH_ON], r[TH_OFF] = filtered[pixel], memorised[pixel], th_on[pixel], th_off[pixel]
        r[C_LEAK], r[C_PARA], r[NOISE_SCALE] = credit[0, pixel], credit[1, pixel], noise_scale[pixel]
        c[:] = 0
        c[STEP], c[READY] = n_start - 1, n_start
        c[SHOT_NEXT] = c[STEP] + shot_gap(key, pixel, c[SHOT_COUNT], q * real[pixel, NOISE_SCALE])
        c[CMP_NEXT], _, _, _ = _schedule(real[pixel], c, NEVER, leak_hz * dt, dt, large)
        next_step[pixel] = min(c[CMP_NEXT], c[SHOT_NEXT], _settle_step(c))


@inline
def _settle_step(c):
    """The step at which a pixel's owed events are settled: its first comparison after an event."""
    return c[READY] if c[OWED] != 0 else NEVER


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


@jit
def next_crossing_known(step, ready, y, memorised, filtered, log_a, para, th_on, th_off, noise_scale, t_change, leak_dt,
                        dt, large):
    """:func:`next_crossing`, also returning ``(j, a^j, relaxation)`` from its bound (:func:`.crossing.first_crossing_known`)."""
    drift = (leak_dt * noise_scale + para * dt) * th_on
    j0 = max(ready - step, np.int64(1))
    horizon = NEVER if t_change >= NEVER else t_change - 1 - step
    j, _, j_known, known, relaxed = first_crossing_known(j0, y - memorised, filtered - y, log_a, drift,
                                                         th_on - TOLERANCE, th_off - TOLERANCE, horizon, large)
    return (NEVER if j >= NEVER else step + j), j_known, known, relaxed


@inline
def _schedule(r, c, t_change, leak_dt, dt, large):
    """:func:`next_crossing_known` of the pixel with state rows ``r``, ``c``: ``(step, j, a^j, relaxation)``."""
    return next_crossing_known(c[STEP], c[READY], r[Y], r[M_], r[L_], r[LOG_A], r[PARA], r[TH_ON], r[TH_OFF],
                               r[NOISE_SCALE], t_change, leak_dt, dt, large)


@inline
def _schedule_before(r, c, t_change, last, leak_dt, dt, large):
    """:func:`_schedule` where only a crossing up to step ``last`` can be used: ``LATER`` without the search
    when the bound (:func:`.crossing.band_bound`) shows none up to ``last``.

    ``last`` is the last step at which :func:`run_pixel` would act on the crossing before something
    else happens to the pixel (its next input change, shot-noise trial, settling step or the window's
    end), after which it schedules the pixel again; a ``LATER`` left at the end of the call is replaced
    by :func:`_schedule`'s search with the same state, so the stored schedule and the events are the
    same. ``(j, a^j, relaxation)`` are the bound's, as in :func:`_schedule`.
    """
    step = c[STEP]
    j_max = max(last - step, c[READY] - step, np.int64(1))
    y, th_on = r[Y], r[TH_ON]
    drift = (leak_dt * r[NOISE_SCALE] + r[PARA] * dt) * th_on
    holds, retention, relaxed = band_bound(j_max, y - r[M_], r[L_] - y, r[LOG_A], drift, th_on - TOLERANCE,
                                           r[TH_OFF] - TOLERANCE, large)
    if holds:
        return LATER, j_max, retention, relaxed
    return _schedule(r, c, t_change, leak_dt, dt, large)


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
    """Move a pixel from its last step to step ``t`` at constant input (:func:`relaxed_by`)."""
    _advance_known(r, c, t, leak_hz, dt, large, NO_STEP, 0.0, 0.0)


@inline
def _advance_known(r, c, t, leak_hz, dt, large, j_known, known, relaxed):
    """:func:`_advance`, taking ``a^j`` from ``known = a^j_known`` and, in the large-signal form, ``L - Y`` from
    ``relaxed`` (the pixel's last schedule's bound, at its present input: :func:`.crossing.first_crossing_known`)
    when ``j = j_known``: the same bits, without their ``exp`` and ``log``."""
    j = t - c[STEP]
    if j > 0 and j == j_known and large and known > 0.0:
        r[L_] = r[Y] + relaxed
        r[M_], r[C_LEAK], r[C_PARA] = drifted(r[M_], r[C_LEAK], r[C_PARA], r[PARA], r[TH_ON], r[NOISE_SCALE], j,
                                              leak_hz, dt)
    elif j > 0:
        retention = known if j == j_known else power(r[LOG_A], j)
        r[L_], r[M_], r[C_LEAK], r[C_PARA] = relaxed_by(retention, r[L_], r[M_], r[C_LEAK], r[C_PARA], r[Y], r[LOG_A],
                                                        r[PARA], r[TH_ON], r[NOISE_SCALE], j, leak_hz, dt, large)
    c[STEP] = t


@inline
def _redraw(r, c, pixel, sign, key, th_mean_on, th_mean_off, th_sigma, th_floor):
    """IEBCS: a new threshold of the polarity that fired, addressed by the pixel's event count."""
    z = normal_one(key, THRESHOLD, pixel, c[EVENT_COUNT])
    if sign > 0:
        r[TH_ON] = max(th_mean_on + th_sigma * z, th_floor)
    else:
        r[TH_OFF] = max(th_mean_off + th_sigma * z, th_floor)
    c[EVENT_COUNT] += 1


@inline
def _fire(r, c):
    """Comparator event (Eq. 17) of a pixel whose state is at the event step.

    Returns ``(polarity, cause, total)``: the cause is the contribution to ``L - M``
    pushing hardest in the event's direction (see :mod:`.comparator`), which gives up one
    threshold; ``total`` is ``|Ne_total|``, the events the comparator could emit now.
    """
    delta = r[L_] - r[M_]
    sign = 1 if delta >= 0.0 else -1
    theta = r[TH_ON] if sign > 0 else r[TH_OFF]
    total = max(math.trunc((abs(delta) + TOLERANCE) / theta), 1.0)
    signal = delta - (r[C_LEAK] + r[C_PARA])
    cause, best = SIGNAL, sign * signal
    for k, column in ((LEAK, C_LEAK), (PARASITIC, C_PARA)):
        if sign * r[column] > best:
            cause, best = k, sign * r[column]
    moved = sign * theta
    if cause != SIGNAL:
        r[C_LEAK + cause - 1] -= moved
    r[M_] += moved
    return sign, cause, total


@inline
def _record(r, c, pixel, t, sign, cause, k_refr, ev_step, ev_pixel, ev_pol, ev_cause, n_events,
            redraw, key, th_mean_on, th_mean_off, th_sigma, th_floor):
    """Write an event of ``pixel`` at step ``t``, start its refractory period (Eq. 21), redraw (IEBCS).

    Returns the number of events written.
    """
    c[READY] = t + k_refr
    ev_step[n_events], ev_pixel[n_events], ev_pol[n_events], ev_cause[n_events] = t, pixel, sign, cause
    if redraw:
        _redraw(r, c, pixel, sign, key, th_mean_on, th_mean_off, th_sigma, th_floor)
    return n_events + 1


@inline
def run_pixel(r, c, pixel, lo, hi, stop, change_step, change_input, n_end, leak_hz, dt, large, k_refr, q, key, redraw,
              th_mean_on, th_mean_off, th_sigma, th_floor, ev_step, ev_pixel, ev_pol, ev_cause, n_events, lost,
              saved_r, saved_c):
    """Every event of one pixel (state rows ``r``, ``c``) before step ``n_end``, through its input changes ``lo:hi``.

    From ``change_step[k]`` on the pixel's input is row ``k`` of ``change_input`` (columns
    ``FLUX`` and ``Y`` to ``ACCEPT`` of :data:`REAL`). With ``stop <= hi`` the pixel stops
    after the change ``stop - 1`` and its comparator's schedule (up to the next change), its
    later events and changes left for another call. Events go to the ``ev_*`` buffers from
    position ``n_events``; ``lost`` accumulates the events lost. Returns ``(n_events, lost,
    done)``: a pixel whose events would overflow the buffers is put back as it was
    (``saved_r``, ``saved_c`` are scratch rows) and ``done`` is False.
    """
    capacity = ev_step.size
    leak_dt = leak_hz * dt
    saved_r[:], saved_c[:] = r, c
    first_event, lost_before = n_events, lost
    ptr, end = lo, hi
    t_change = change_step[ptr] if ptr < end else NEVER
    cmp_next = c[CMP_NEXT]              # the first crossing at the present input: valid up to any change
    j_known, known, relaxed = NO_STEP, 0.0, 0.0          # what its schedule's bound took (none: from the state)
    while True:
        t_settle = _settle_step(c)
        t_event = min(cmp_next, c[SHOT_NEXT], t_settle)
        if t_event < t_change and t_event < n_end:
            if n_events + 2 > capacity:                       # no room: undo this pixel
                r[:], c[:] = saved_r, saved_c
                return first_event, lost_before, False
            _advance(r, c, t_event, leak_hz, dt, large)
            awake = c[READY] <= t_event
            fires = cmp_next == t_event
            sign, cause, total = 0, SIGNAL, 0.0
            if fires:
                sign, cause, total = _fire(r, c)
            if t_settle == t_event:                           # first comparison after an event (Eq. 17)
                owed = c[OWED]
                kept = min(float(abs(owed)), total) if (owed > 0) == (sign > 0) else 0.0
                lost += abs(owed) - kept
                c[OWED] = 0
            if fires:
                c[OWED] = sign * np.int64(total - 1.0)
                n_events = _record(r, c, pixel, t_event, sign, cause, k_refr, ev_step, ev_pixel, ev_pol, ev_cause,
                                   n_events, redraw, key, th_mean_on, th_mean_off, th_sigma, th_floor)
                awake = False
            if c[SHOT_NEXT] == t_event:                       # shot noise (Eq. 20)
                bits = hash64_one(key, ACCEPT_STREAM, pixel, c[SHOT_COUNT])
                if unit_interval(bits) < r[ACCEPT]:
                    if awake:
                        sign = 1 if (bits & np.uint64(1)) == 1 else -1
                        n_events = _record(r, c, pixel, t_event, sign, SHOT, k_refr, ev_step, ev_pixel, ev_pol,
                                           ev_cause, n_events, redraw, key, th_mean_on, th_mean_off, th_sigma,
                                           th_floor)
                    else:
                        lost += 1.0
                c[SHOT_COUNT] += 1
                c[SHOT_NEXT] = t_event + shot_gap(key, pixel, c[SHOT_COUNT], q * r[NOISE_SCALE])
        elif ptr < end:                                       # the next input takes over
            _advance_known(r, c, t_change - 1, leak_hz, dt, large, j_known, known, relaxed)
            row = change_input[ptr]
            r[FLUX], r[Y], r[LOG_A], r[PARA], r[ACCEPT] = row[FLUX], row[Y], row[LOG_A], row[PARA], row[ACCEPT]
            ptr += 1
            t_change = change_step[ptr] if ptr < end else NEVER
        else:
            break
        last = min(t_change - 1, n_end - 1, c[SHOT_NEXT], _settle_step(c))
        cmp_next, j_known, known, relaxed = _schedule_before(r, c, t_change, last, leak_dt, dt, large)
        if ptr == stop:
            break
    if cmp_next == LATER:               # the stored schedule is the search's (the pixel's next call starts from it)
        cmp_next = _schedule(r, c, t_change, leak_dt, dt, large)[0]
    c[CMP_NEXT] = cmp_next
    return n_events, lost, True


@inline
def quiet_until(real, count, p, y_high, y_low, para_high, leak_dt, dt):
    """The last window end ``n_end`` before which pixel ``p`` provably cannot fire under background changes whose
    ``Y`` lie in ``[y_low, y_high]`` and parasitic rates below ``para_high`` (the envelope), taken or not; ``SOON``
    where none is shown.

    :func:`.deferred._cannot_fire`'s bound with the envelope in place of the pending changes' extremes,
    the same expressions in the same order: each is monotone in those extremes and in the steps ``n_end - 1
    - step`` (rounding is monotone), so wherever the envelope holds the pending changes and ``n_end`` is at
    most the result, that bound holds too, and the pixel need not be read (:func:`.deferred.select_pixels`).
    """
    filtered, y, memorised, th_on = real[p, L_], real[p, Y], real[p, M_], real[p, TH_ON]
    if not min(filtered, y, y_low) - memorised > -(real[p, TH_OFF] - TOLERANCE) + ROUNDING_MARGIN:
        return SOON
    rise = max(filtered, y, y_high) - memorised
    limit = th_on - TOLERANCE - ROUNDING_MARGIN
    drift = (leak_dt * real[p, NOISE_SCALE] + max(real[p, PARA], para_high) * dt) * th_on
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
    return count[p, STEP] + 1 + steps


#: :func:`run_pixel` compiled apart, for the dense path (:mod:`.dense_loop`): one compile serves its calls. The
#: helpers taking a pixel's state rows and :func:`run_pixel` are inlined where they are called: a call passing
#: arrays costs each array's reference count up and down again (atomic), about a third of the loop's time
run_pixel_apart = jit(run_pixel.py_func)


@numba.njit(cache=True, error_model="numpy", nogil=True)     # chunks run in threads (see .eventdriven)
def run_chunk(real, count, next_step, wake, envelope, pixels, change_lo, change_hi, change_step, change_input, n_end,
              leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on, th_mean_off, th_sigma, th_floor,
              ev_step, ev_pixel, ev_pol, ev_cause):
    """:func:`run_pixel` for each of ``pixels``, one after the other; pixel ``pixels[i]`` has the changes
    ``change_lo[i]:change_hi[i]`` (rows of ``change_input`` may be shared by many pixels).

    Updates the state tables, ``next_step`` (each pixel's next event) and ``wake`` (the earlier of
    it and :func:`quiet_until` under ``envelope = (y_high, y_low, para_high)``) in place and writes
    the events (step, pixel, polarity, cause) into the ``ev_*`` buffers. Returns ``(events
    written, pixels done, events lost in the pixels)``: the chunk stops before a pixel whose
    events would overflow the buffers.
    """
    n_events = np.int64(0)                     # int64, not Literal[int](0): one compile of run_pixel serves all
    lost = 0.0
    saved_r = np.empty(real.shape[1])
    saved_c = np.empty(count.shape[1], np.int64)
    for i in range(pixels.size):
        if i + _AHEAD < pixels.size:
            _fetch_row(real, count, pixels[i + _AHEAD])
        pixel = pixels[i]
        r, c = real[pixel], count[pixel]
        n_events, lost, done = run_pixel(r, c, pixel, change_lo[i], change_hi[i], change_hi[i] + 1, change_step,
                                         change_input, n_end, leak_hz, dt, large, k_refr, q, key, redraw, th_mean_on,
                                         th_mean_off, th_sigma, th_floor, ev_step, ev_pixel, ev_pol, ev_cause,
                                         n_events, lost, saved_r, saved_c)
        if not done:
            return n_events, i, lost
        next_step[pixel] = min(c[CMP_NEXT], c[SHOT_NEXT], _settle_step(c))
        wake[pixel] = min(next_step[pixel], quiet_until(real, count, pixel, envelope[0], envelope[1], envelope[2],
                                                        leak_hz * dt, dt))
    return n_events, pixels.size, lost
