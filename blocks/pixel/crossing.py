"""First step at which a pixel's comparator input leaves its threshold band, in closed form.

Between events and input changes a pixel's comparator input ``dI = L - M`` (paper Eq. 17)
evolves deterministically: the low-pass output relaxes geometrically towards its target
(Eq. 16 at constant input: ``L_j - Y = (L_0 - Y) a^j`` with ``a = 1 - eps``) and the
memorised value drifts down linearly by the leak and parasitic currents (Eqs. 18, 19).
``j`` steps after the last update

    g(j) = C + D a^j + delta j,    C = Y - M_0,  D = L_0 - Y,  delta >= 0,

which is monotone when ``D <= 0`` and convex with a single minimum when ``D > 0``. The
first ``j >= j0`` with ``g(j) >= theta_ON`` or ``g(j) <= -theta_OFF`` is therefore found
without stepping: in closed form when ``g`` is linear, by Newton's method (settled on the
integers, bisection as the fallback) on a monotone stretch otherwise. Most searches end
sooner: ``D a^j`` lies between ``min(D, 0)`` and ``max(D, 0)`` and ``delta j`` between 0 and
``delta J``, so ``g`` stays within ``[C + min(D, 0), C + max(D, 0) + delta J]`` up to the horizon
``J``; when that range (widened far beyond the rounding of ``g``) stays inside the band there
is no crossing and nothing is solved. This is the
recursion the dense reference steps through, so the two agree to floating-point rounding.

The functions are compiled (Numba) scalar functions, called per pixel by the event-driven
loop (:mod:`.pixel_loop`); :func:`first_crossing` applies the search to arrays, and
:func:`batch_crossings` takes many searches together in vectorised loops (the same bits).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .fastmath import exp_, log_, wide_vectors

NEVER = np.int64(1) << np.int64(62)        # "no such step" [steps]
J_LIMIT = np.int64(1) << np.int64(52)      # longest look-ahead; beyond it a crossing counts as never [steps]
NO_STEP = np.int64(-1)                     # no step: a^j known for none (:func:`_g`)
UNSETTLED = np.int64(-2)                   # no step settled: left to the scalar search (:func:`batch_crossings`)
_NEWTON_STEPS = 12
_SETTLED = 0.25                            # Newton's step below which its iterate is settled [steps]
_ROUNDING = 1e-12                          # relative widening of the range of g against its rounding [1]
_UP, _DOWN = np.bool_(True), np.bool_(False)    # _root's direction typed bool, not a literal: one compile serves both

jit = numba.njit(cache=True, error_model="numpy")      # IEEE division (inf, nan) as in NumPy
inline = numba.njit(cache=True, error_model="numpy", inline="always")    # so that loops over pixels vectorise


@inline
def power(log_a, j):
    """``a^j`` as ``exp(j ln a)`` (``a = 0`` gives 0), flushed to 0 below 1e-307.

    The flush skips the range where the result underflows: the pixels' filters have long
    settled at the horizons searched, and 1e-307 of a log-current is far below the
    comparator's rounding tolerance. ``exp`` is :func:`.fastmath.exp_`, so that loops over
    pixels vectorise and give the same bits as scalar code.
    """
    x = j * log_a
    return exp_(x) if x > -707.0 else 0.0


@inline
def one_minus_power(x, decay):
    """``1 - a^j`` for ``x = j ln a <= 0`` and ``decay = a^j`` (:func:`power`), to a relative ~1e-11 also where
    ``a^j`` is near 1: the series of ``1 - e^x`` below ``|x| = 1e-5`` (error ``x^4/24``), ``1 - decay`` above."""
    series = -x * (1.0 + x * (0.5 + x * (1.0 / 6.0)))
    return series if x > -1e-5 else 1.0 - decay


@inline
def relaxation(d, e, x, decay, large):
    """The filter's ``L_j - Y`` after ``j`` steps at constant input from ``L_0 - Y = D`` (paper Eq. 16).

    ``x = j ln a``, ``decay = a^j`` (:func:`power`). Small-signal (Eq. 16 as printed, on ``L``):
    ``D a^j``. Large-signal (the same filter on ``w = e^-L``, the first-order logarithmic
    photoreceptor, :mod:`.lowpass`): ``w_j = w_inf + (w_0 - w_inf) a^j``, so
    ``L_j - Y = -ln(1 - a^j + e a^j)`` with ``e = e^-D`` (:func:`large_weight`); written with
    ``1 - a^j`` apart (:func:`one_minus_power`) so that it stays finite for any step.
    """
    if large:
        return -log_(one_minus_power(x, decay) + e * decay)
    return d * decay


@inline
def large_weight(d):
    """``e^-D``, the large-signal form's weight of the filter's start (:func:`relaxation`), clamped to ``e^+-700``."""
    return exp_(min(max(-d, -700.0), 700.0))


@inline
def relaxation_slope(d, e, log_a, x, decay, large):
    """``d/dj`` of :func:`relaxation` (Newton's method)."""
    if large:
        return -log_a * (e - 1.0) * decay / (one_minus_power(x, decay) + e * decay)
    return d * decay * log_a


@jit
def decay_reaching(target, d, large):
    """``a^j`` at which :func:`relaxation` equals ``target`` (the relaxation alone reaching a level), or NaN."""
    if large:
        return math.expm1(-target) / math.expm1(-d)
    return target / d


@jit
def comparator_input(j, c, d, log_a, delta, large=False):
    """``g(j) = C + relaxation(j) + delta j`` for ``j >= 1`` (small-signal: ``C + D a^j + delta j``)."""
    return c + relaxation(d, large_weight(d), j * log_a, power(log_a, j), large) + delta * j


@jit
def _reached(j, c, d, e, log_a, delta, level, upward, large):
    g = _g(j, c, d, e, log_a, delta, NO_STEP, 0.0, large)
    return g >= level if upward else g <= level


@inline
def _newton_step(x, lo_f, hi_f, c, d, e, log_a, delta, level, large):
    """One step of :func:`_root`'s Newton iteration on the continuous ``g`` from ``x``, kept in ``[lo_f, hi_f]``:
    ``(next x, step)`` (a step that is not finite counts as 0)."""
    decay = power(log_a, x)
    return _newton_move(x, c + relaxation(d, e, x * log_a, decay, large) + delta * x,
                        relaxation_slope(d, e, log_a, x * log_a, decay, large), delta, level, lo_f, hi_f)


@inline
def _newton_move(x, g, slope, delta, level, lo_f, hi_f):
    """:func:`_newton_step` given ``g`` and the relaxation's slope at ``x``."""
    dx = (level - g) / (slope + delta)
    dx = dx if math.isfinite(dx) else 0.0
    return min(max(x + dx, lo_f), hi_f), dx


@inline
def _candidate(x, lo, hi):
    """The integer step :func:`_root` checks after Newton's iteration ended at ``x``, in ``(lo, hi]``."""
    return min(max(np.int64(math.ceil(x - 1e-6)), lo + 1), hi)


@jit
def _root(lo, hi, c, d, e, log_a, delta, level, upward, x0, large):
    """Smallest ``j`` in ``(lo, hi]`` with ``g(j) >= level`` (``upward``) or ``<= level``.

    Requires the test false at ``lo``, true at ``hi`` and monotone in between. Newton's
    iteration on the continuous ``g`` from ``x0`` (``lo`` if not finite; ``g`` is convex or
    concave, so from a good start it converges in a few steps) gives the root; the integer
    after it is checked on ``g`` itself, and bisection finishes what Newton leaves unsettled.
    """
    lo_f, hi_f = float(lo), float(hi)
    x = min(max(x0, lo_f), hi_f) if math.isfinite(x0) else lo_f
    for _ in range(_NEWTON_STEPS):
        x, dx = _newton_step(x, lo_f, hi_f, c, d, e, log_a, delta, level, large)
        if abs(dx) < _SETTLED:
            break
    j = _candidate(x, lo, hi)
    if _reached(j, c, d, e, log_a, delta, level, upward, large) and (
            j - 1 <= lo or not _reached(j - 1, c, d, e, log_a, delta, level, upward, large)):
        return j
    while hi - lo > 1:
        mid = lo + (hi - lo) // 2
        if _reached(mid, c, d, e, log_a, delta, level, upward, large):
            hi = mid
        else:
            lo = mid
    return hi


@jit
def _ceil_steps(x):
    """``ceil(x)`` as steps, clipped to ``[0, J_LIMIT]`` (not finite -> limit)."""
    if not math.isfinite(x):
        return J_LIMIT
    return np.int64(min(max(math.ceil(x), 0.0), float(J_LIMIT)))


@inline
def stays_in_band(j_max, retention, c, d, log_a, delta, theta_on, theta_off, large=False):
    """Whether ``g`` stays strictly inside ``(-theta_off, theta_on)`` for ``0 <= j <= j_max``, from a bound.

    ``retention`` is ``a^j_max`` or less (0 will do). With ``0 <= a <= 1`` the relaxation
    (:func:`relaxation`, monotone in ``j`` in either form) lies between ``D`` and its value at
    ``j_max`` (0 for ``retention`` 0), and ``delta j`` between 0 and ``delta j_max``; the range
    is widened far beyond the rounding of ``g``. False means "not shown", not "crosses".
    """
    return band_holds(j_max, retention, relaxed_at(j_max, retention, d, log_a, large), c, d, log_a, delta, theta_on,
                      theta_off)


@inline
def relaxed_at(j_max, retention, d, log_a, large):
    """The relaxation :func:`stays_in_band` bounds ``g`` with: :func:`relaxation` at ``j_max`` (0 for ``retention`` 0)."""
    if large:
        return relaxation(d, large_weight(d), float(j_max) * log_a, retention, True) if retention > 0.0 else 0.0
    return d * retention


@inline
def band_holds(j_max, retention, relaxed, c, d, log_a, delta, theta_on, theta_off):
    """:func:`stays_in_band` given its relaxation ``relaxed`` (:func:`relaxed_at`)."""
    span = delta * float(j_max)
    margin = _ROUNDING * (abs(c) + abs(d) + span)
    return ((delta >= 0.0) & (log_a <= 0.0) & (retention >= 0.0) & (c + max(d, relaxed) + span + margin < theta_on)
            & (c + min(d, relaxed) - margin > -theta_off))


@jit
def first_crossing_one(j0, c, d, log_a, delta, theta_on, theta_off, horizon, large=False):
    """First ``j`` in ``[j0, horizon]`` at which ``g`` reaches ``theta_on`` (polarity +1) or ``-theta_off`` (-1).

    ``j0 >= 1``; ``horizon`` bounds the search where the answer stops mattering (the
    pixel's next input change; ``NEVER`` for none), except that ``j0`` itself is always
    tested. Returns ``(j, polarity)``, ``(NEVER, 0)`` where there is none. ``large``: the
    large-signal filter (:func:`relaxation`).
    """
    j, polarity, _, _, _ = first_crossing_known(j0, c, d, log_a, delta, theta_on, theta_off, horizon, large)
    return j, polarity


@jit
def first_crossing_known(j0, c, d, log_a, delta, theta_on, theta_off, horizon, large=False):
    """:func:`first_crossing_one`, also returning ``(j_max, a^j_max, relaxation)``, the retention and the
    relaxation its bound took (``j_max = max(min(horizon, J_LIMIT), j0)``; :func:`relaxed_at`): a caller
    that relaxes the pixel by ``j_max`` steps next takes them from there (the same bits)."""
    horizon = min(horizon, J_LIMIT)
    j_max = max(horizon, j0)
    holds, retention, relaxed = band_bound(j_max, c, d, log_a, delta, theta_on, theta_off, large)
    if holds:
        return NEVER, 0, j_max, retention, relaxed
    j, polarity = search_crossing(j0, c, d, log_a, delta, theta_on, theta_off, horizon, j_max, retention, large)
    return j, polarity, j_max, retention, relaxed


@jit
def band_bound(j_max, c, d, log_a, delta, theta_on, theta_off, large):
    """``(holds, a^j_max, relaxation)``: :func:`band_holds` at ``j_max`` with the retention and relaxation it
    takes (:func:`relaxed_at`), compiled once for its callers."""
    retention = power(log_a, j_max)
    relaxed = relaxed_at(j_max, retention, d, log_a, large)
    return band_holds(j_max, retention, relaxed, c, d, log_a, delta, theta_on, theta_off), retention, relaxed


@jit
def _g(j, c, d, e, log_a, delta, j_known, known, large):
    """:func:`comparator_input` at ``j``, taking ``a^j`` from ``known = a^j_known`` when ``j = j_known`` (same bits).

    Where the filter has settled (``a^j`` flushed to 0, :func:`power`) the large-signal relaxation is
    ``-ln(1 - 0 + e 0) = -ln 1 = -0`` exactly; it is taken as such, without the logarithm (the searches
    for a pixel's next leak event, seconds ahead, evaluate ``g`` there)."""
    x = j * log_a
    decay = known if j == j_known else power(log_a, j)
    if large and decay == 0.0 and x <= -707.0 and e == e:
        return c + -0.0 + delta * j
    return c + relaxation(d, e, x, decay, large) + delta * j


@jit
def search_crossing(j0, c, d, log_a, delta, theta_on, theta_off, horizon, j_known, known, large=False):
    """:func:`first_crossing_one` without its bound (``horizon <= J_LIMIT``): for callers that found the bound
    false already. ``known = power(log_a, j_known)``, which the bound took (``j_known``: ``max(horizon, j0)``),
    is not computed again."""
    e = large_weight(d) if large else 0.0
    g0 = _g(j0, c, d, e, log_a, delta, j_known, known, large)
    if g0 >= theta_on:
        return j0, 1
    if g0 <= -theta_off:
        return j0, -1
    if horizon <= j0:
        return NEVER, 0

    if d == 0.0 or log_a == 0.0 or log_a == -np.inf:     # linear: no relaxation left (a = 0 settles at once)
        if delta > 0.0:
            c_eff = c + d if log_a == 0.0 else c
            j = max(_ceil_steps((theta_on - c_eff) / delta), j0 + 1)
            # the closed form can be one step off through rounding: settle it on g itself
            if _g(j, c, d, e, log_a, delta, j_known, known, large) < theta_on:
                j += 1
            if j - 1 > j0 and _g(j - 1, c, d, e, log_a, delta, j_known, known, large) >= theta_on:
                j -= 1
            if j <= horizon and _g(j, c, d, e, log_a, delta, j_known, known, large) >= theta_on:
                return j, 1
        return NEVER, 0

    if d < 0.0:                                           # rising: after j0 only an ON crossing is possible
        if delta > 0.0:
            hi = _ceil_steps((theta_on - c - d) / delta) + 1              # g >= C + D + delta j
        elif c > theta_on:
            hi = _ceil_steps(math.log(decay_reaching(theta_on - c, d, large)) / log_a) + 1    # without drift
        else:
            hi = J_LIMIT
        hi = max(min(hi, horizon), j0 + 1)
        if _g(hi, c, d, e, log_a, delta, j_known, known, large) >= theta_on:
            # g is concave here: from any start Newton's first iterate lies at or below the root and the
            # next climb to it monotonically. The root without drift (drift only brings it forward) is
            # close above it when the relaxation alone reaches theta_ON; else the root of the drift alone
            # (relaxation only delays it), below the root; without drift, j0.
            ratio = decay_reaching(theta_on - c, d, large)
            start = math.log(ratio) / log_a if (ratio > 0.0) & (ratio < 1.0) else (
                (theta_on - c) / delta if delta > 0.0 else np.nan)
            return _root(j0, hi, c, d, e, log_a, delta, theta_on, _UP, start, large), 1
        return NEVER, 0

    # falling (D > 0): g convex, decreasing until j*, increasing after
    level_off = -theta_off
    if large:                                                      # slope -ln a (e - 1) a^j / (1 + (e - 1) a^j) = -delta
        j_star = math.log(delta / (log_a - delta) / math.expm1(-d)) / log_a if delta > 0.0 else np.inf
    else:
        j_star = math.log(delta / (-d * log_a)) / log_a if delta > 0.0 else np.inf    # a^{j*} = delta / (-D ln a)
    j_min = J_LIMIT if not math.isfinite(j_star) else np.int64(min(max(math.floor(j_star), 0.0), float(J_LIMIT)))
    j_min = min(max(j_min, j0), horizon)
    # OFF: on the decreasing stretch (j0, min(j_min + 1, horizon)]
    if delta > 0.0:
        hi = j_min
    elif c < level_off:
        hi = _ceil_steps(math.log(decay_reaching(level_off - c, d, large)) / log_a) + 1     # OFF without drift
    else:
        hi = J_LIMIT
    hi = max(min(hi, horizon), j0 + 1)
    if _g(hi, c, d, e, log_a, delta, j_known, known, large) > level_off:
        if delta > 0.0 and hi + 1 <= horizon and _g(hi + 1, c, d, e, log_a, delta, j_known, known, large) <= level_off:
            hi += 1
        else:
            hi = -1
    if hi > 0:
        ratio = decay_reaching(level_off - c, d, large)   # root without drift: drift only delays it
        start = math.log(ratio) / log_a if ratio > 0.0 else np.nan
        return _root(j0, hi, c, d, e, log_a, delta, level_off, _DOWN, start, large), -1
    # ON: after the minimum, where g increases (g(j_min) <= g(j0) < theta_ON)
    if delta > 0.0 and j_min < horizon:
        hi = max(min(_ceil_steps((theta_on - c) / delta) + 1, horizon), j_min + 1)   # g >= C + delta j
        if _g(hi, c, d, e, log_a, delta, j_known, known, large) >= theta_on:
            return _root(j_min, hi, c, d, e, log_a, delta, theta_on, _UP, float(hi), large), 1
    return NEVER, 0


@inline
def batched(j0, d, log_a, delta):
    """Whether :func:`batch_crossings` takes a search: :func:`search_crossing` of a falling filter (``D > 0``) with
    drift, ``0 < a < 1`` and ``j0`` below the look-ahead limit."""
    return (d > 0.0) & (delta > 0.0) & (log_a < 0.0) & (log_a > -np.inf) & (j0 < J_LIMIT)


@jit
def batch_crossings(j0, c, d, log_a, delta, theta_on, theta_off, large, out):
    """``out[k]``: :func:`search_crossing`'s ``j`` for ``(j0[k], c[k], .., horizon J_LIMIT, j_known J_LIMIT,
    known = a^J_LIMIT)`` where :func:`batched` holds, many searches at a time, where the crossing is at ``j0``,
    ON after the filter's OFF-ward minimum, or none; ``UNSETTLED`` where it is OFF before the minimum or where
    Newton's candidate is not the crossing (:func:`_root` bisects then): the caller searches those alone.

    The searches after a pixel's last change (:func:`.own_sweep._kept`) are nearly all of the first kind: the
    stamp has left the pixel, its filter falls, and the drift brings an ON event after its minimum (on the tracked
    pass 99.8 % of them, 0.03 % OFF first). The same arithmetic in the same order as :func:`search_crossing` and
    :func:`_root`: the brackets (the C library's ``expm1`` and ``log``) one search at a time; ``g`` at every step
    the scalar search tests and at Newton's iterates, with the relaxation's slope, in one loop over the searches
    that the compiler vectorises (:func:`_comparator_slopes`); Newton's iteration (:func:`_newton_move`) and the
    check of its candidate (:func:`_candidate`), the scalar search's branches taken as selections (tested against
    it). One kind of search and one compiled copy of ``g``: a first run compiles less."""
    n = j0.size
    lo, hi, e, x = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n), np.empty(4 * n)
    active, rooted = np.empty(n, np.bool_), np.empty(n, np.bool_)
    g, slope = np.empty(4 * n), np.empty(4 * n)
    for k in range(n):                # brackets, as search_crossing takes them: OFF on (j0, j_min (+1)], ON after
        first, c_k, d_k, log_a_k, delta_k = j0[k], c[k], d[k], log_a[k], delta[k]
        if large:
            j_star = math.log(delta_k / (log_a_k - delta_k) / math.expm1(-d_k)) / log_a_k
        else:
            j_star = math.log(delta_k / (-d_k * log_a_k)) / log_a_k
        j_min = J_LIMIT if not math.isfinite(j_star) else np.int64(min(max(math.floor(j_star), 0.0), float(J_LIMIT)))
        j_min = min(max(j_min, first), J_LIMIT)
        top = max(min(j_min, J_LIMIT), first + 1)
        after = max(min(_ceil_steps((theta_on[k] - c_k) / delta_k) + 1, J_LIMIT), j_min + 1)
        e[k] = large_weight(d_k) if large else 0.0
        lo[k], hi[k] = j_min, after
        x[k], x[n + k], x[2 * n + k], x[3 * n + k] = float(first), float(top), float(top + 1), float(after)
    _comparator_slopes(x, c, d, e, log_a, delta, large, g, slope)        # g at j0 and the brackets' ends
    for k in range(n):                # search_crossing's choice: an answer, or ON's root to settle in (j_min, after]
        g0, g_hi, g_next, g_after = g[k], g[n + k], g[2 * n + k], g[3 * n + k]
        on, level_off, top = theta_on[k], -theta_off[k], np.int64(x[n + k])
        at_first = (g0 >= on) | (g0 <= level_off)
        off_first = not g_hi > level_off or (top + 1 <= J_LIMIT and g_next <= level_off)
        rooted[k] = (not at_first) & (not off_first) & (lo[k] < J_LIMIT) & (g_after >= on)
        out[k] = j0[k] if at_first else (UNSETTLED if off_first else NEVER)
        active[k] = rooted[k]
        lo_f, hi_f, start = float(lo[k]), float(hi[k]), float(hi[k])
        x[k] = min(max(start, lo_f), hi_f) if math.isfinite(start) else lo_f
    for _ in range(_NEWTON_STEPS):    # _root's iteration, each search until its step settles
        _comparator_slopes(x[:n], c, d, e, log_a, delta, large, g, slope)
        moving = 0
        for k in range(n):
            moved, dx = _newton_move(x[k], g[k], slope[k], delta[k], theta_on[k], float(lo[k]), float(hi[k]))
            x[k] = moved if active[k] else x[k]
            active[k] = active[k] & (abs(dx) >= _SETTLED)
            moving += 1 if active[k] else 0
        if moving == 0:
            break
    for k in range(n):                # _root's candidate and the step before it
        j = _candidate(x[k], lo[k], hi[k])
        x[k], x[n + k] = float(j), float(j - 1)
    _comparator_slopes(x[:2 * n], c, d, e, log_a, delta, large, g, slope)
    for k in range(n):                # _root's check of its candidate (upward, to theta_ON)
        j = np.int64(x[k])
        root = j if (g[k] >= theta_on[k]) & ((j - 1 <= lo[k]) | (not g[n + k] >= theta_on[k])) else UNSETTLED
        out[k] = root if rooted[k] else out[k]


@jit
def _comparator_slopes(x, c, d, e, log_a, delta, large, g, slope):
    """``g[s * n + k]``: ``g`` at the step ``x[s * n + k]`` of the search ``k`` (``n`` searches; a whole step, or
    Newton's iterate), and ``slope[s * n + k]`` its relaxation's slope there (:func:`relaxation_slope`), in a loop
    the compiler vectorises: :func:`_newton_step`'s arithmetic, also :func:`_g`'s at a whole step ``j = x`` (the
    same bits: ``x`` is exact, ``a^j`` is taken as :func:`power` takes it, and the large-signal relaxation
    where ``a^j`` is flushed to 0 is ``-ln 1 = -0``, that function's shortcut, for any ``e`` :func:`large_weight`
    gives)."""
    wide_vectors()
    n = c.size
    for slot in range(x.size // n):
        for k in range(n):
            at = x[slot * n + k]
            decay = power(log_a[k], at)
            g[slot * n + k] = c[k] + relaxation(d[k], e[k], at * log_a[k], decay, large) + delta[k] * at
            slope[slot * n + k] = relaxation_slope(d[k], e[k], log_a[k], at * log_a[k], decay, large)


@jit
def first_crossing(j0, c, d, log_a, delta, theta_on, theta_off, horizon, large=False):
    """:func:`first_crossing_one` over arrays of one length; returns ``(j, polarity)`` arrays."""
    n = j0.shape[0]
    out = np.empty(n, np.int64)
    pol = np.empty(n, np.int8)
    for k in range(n):
        out[k], pol[k] = first_crossing_one(np.int64(j0[k]), c[k], d[k], log_a[k], delta[k], theta_on[k],
                                            theta_off[k], np.int64(horizon[k]), large)
    return out, pol
