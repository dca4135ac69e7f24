"""First step at which a pixel's comparator input leaves its threshold band, in closed form.

Between events and input changes a pixel's comparator input ``dI = L - M`` (paper Eq. 17)
evolves deterministically: the low-pass output relaxes geometrically towards its target
(Eq. 16 at constant input: ``L_j - Y = (L_0 - Y) a^j`` with ``a = 1 - eps``) and the
memorised value drifts down linearly by the leak and parasitic currents (Eqs. 18, 19).
``j`` steps after the last update

    g(j) = C + D a^j + delta j,    C = Y - M_0,  D = L_0 - Y,  delta >= 0,

which is monotone when ``D <= 0`` and convex with a single minimum when ``D > 0``. The
first ``j >= j0`` with ``g(j) >= theta_ON`` or ``g(j) <= -theta_OFF`` is therefore found
without stepping: in closed form when ``g`` is linear, by bisection on a monotone stretch
otherwise. This is the recursion the dense reference steps through, so the two agree to
floating-point rounding.
"""

from __future__ import annotations

import numpy as np

NEVER = np.int64(1) << np.int64(62)        # "no such step" [steps]
J_LIMIT = np.int64(1) << np.int64(52)      # longest look-ahead; beyond it a crossing counts as never [steps]
_NEWTON_STEPS = 12


def comparator_input(j, c, d, log_a, delta):
    """``g(j) = C + D a^j + delta j`` for ``j >= 1`` (``a^j`` as ``exp(j ln a)``; ``a = 0`` gives 0)."""
    return c + d * np.exp(j * log_a) + delta * j


def _bisect(lo, hi, c, d, log_a, delta, level, upward: bool, x0=None):
    """Smallest ``j`` in ``(lo, hi]`` with ``g(j) >= level`` (``upward``) or ``<= level``.

    Requires the test false at ``lo``, true at ``hi`` and monotone in between. Newton's
    iteration on the continuous ``g`` from ``x0`` (default ``lo``; ``g`` is convex or concave,
    so from a good start it converges in a few steps) gives the root; the integer after it
    is checked on ``g`` itself, and the rare item Newton leaves unsettled is finished by
    bisection.
    """
    lo_f, hi_f = lo.astype(float), hi.astype(float)
    x = lo_f if x0 is None else np.minimum(np.maximum(np.where(np.isfinite(x0), x0, lo_f), lo_f), hi_f)
    for _ in range(_NEWTON_STEPS):
        decay = np.exp(x * log_a)
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (level - (c + d * decay + delta * x)) / (d * decay * log_a + delta)
        dx = np.where(np.isfinite(dx), dx, 0.0)
        x = np.minimum(np.maximum(x + dx, lo_f), hi_f)
        if np.abs(dx).max() < 0.25:
            break
    j = np.minimum(np.maximum(np.ceil(x - 1e-6).astype(np.int64), lo + 1), hi)

    def test(j):
        g = comparator_input(j, c, d, log_a, delta)
        return g >= level if upward else g <= level

    settled = test(j) & ((j - 1 <= lo) | ~test(j - 1))
    if settled.all():
        return j
    k = np.flatnonzero(~settled)
    lo_k, hi_k = lo[k].copy(), hi[k].copy()
    ck, dk, lk, deltak, levk = c[k], d[k], log_a[k], delta[k], level[k]
    while True:
        open_ = hi_k - lo_k > 1
        if not open_.any():
            break
        mid = lo_k + (hi_k - lo_k) // 2
        g = comparator_input(mid, ck, dk, lk, deltak)
        ok = g >= levk if upward else g <= levk
        hi_k = np.where(open_ & ok, mid, hi_k)
        lo_k = np.where(open_ & ~ok, mid, lo_k)
    j[k] = hi_k
    return j


def _ceil_steps(x):
    """``ceil(x)`` as steps, clipped to ``[0, J_LIMIT]`` (NaN -> limit)."""
    x = np.where(np.isfinite(x), x, float(J_LIMIT))
    return np.minimum(np.maximum(np.ceil(x), 0.0), float(J_LIMIT)).astype(np.int64)


def first_crossing(j0, c, d, log_a, delta, theta_on, theta_off, horizon=None):
    """First ``j`` in ``[j0, horizon]`` at which ``g`` reaches ``theta_on`` (polarity +1) or ``-theta_off`` (-1).

    All arguments are arrays of one length, ``j0 >= 1``; ``horizon`` (default: no limit)
    bounds the search where the answer stops mattering (the pixel's next input change).
    Returns ``(j, polarity)`` with ``j = NEVER``, polarity 0, where there is none.
    """
    n = j0.shape[0]
    j0 = j0.astype(np.int64)
    horizon = np.full(n, J_LIMIT) if horizon is None else np.minimum(horizon.astype(np.int64), J_LIMIT)
    out = np.full(n, NEVER, dtype=np.int64)
    pol = np.zeros(n, dtype=np.int8)

    g0 = comparator_input(j0, c, d, log_a, delta)
    on0, off0 = g0 >= theta_on, g0 <= -theta_off
    off0 &= ~on0
    out[on0], pol[on0] = j0[on0], 1
    out[off0], pol[off0] = j0[off0], -1
    todo = ~(on0 | off0) & (horizon > j0)

    # -- linear: no relaxation left (D = 0, a = 1, or a = 0 which leaves L = Y after one step)
    linear = (d == 0) | (log_a == 0) | np.isneginf(log_a)
    idx = np.flatnonzero(todo & linear & (delta > 0))
    if idx.size:
        ci, di, la, dl, th = c[idx], d[idx], log_a[idx], delta[idx], theta_on[idx]
        c_eff = ci + np.where(la == 0, di, 0.0)
        j = np.maximum(_ceil_steps((th - c_eff) / dl), j0[idx] + 1)
        # the closed form can be one step off through rounding: settle it on g itself
        j = np.where(comparator_input(j, ci, di, la, dl) >= th, j, j + 1)
        back = (j - 1 > j0[idx]) & (comparator_input(j - 1, ci, di, la, dl) >= th)
        j = np.where(back, j - 1, j)
        good = (j <= horizon[idx]) & (comparator_input(j, ci, di, la, dl) >= th)
        out[idx[good]], pol[idx[good]] = j[good], 1

    # -- rising (D < 0): g increases, so after j0 only an ON crossing is possible
    idx = np.flatnonzero(todo & ~linear & (d < 0))
    if idx.size:
        ci, di, la, dl, th = c[idx], d[idx], log_a[idx], delta[idx], theta_on[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            hi_drift = _ceil_steps((th - ci - di) / dl) + 1          # g >= C + D + delta j
            hi_relax = _ceil_steps(np.log((th - ci) / di) / la) + 1  # without drift
        hi = np.where(dl > 0, hi_drift, np.where(ci > th, hi_relax, J_LIMIT))
        hi = np.maximum(np.minimum(hi, horizon[idx]), j0[idx] + 1)
        ok = comparator_input(hi, ci, di, la, dl) >= th
        if ok.any():
            k = np.flatnonzero(ok)
            with np.errstate(divide="ignore", invalid="ignore"):
                start = np.log((th[k] - ci[k]) / di[k]) / la[k]   # root without drift: drift only brings it forward
            j = _bisect(j0[idx[k]], hi[k], ci[k], di[k], la[k], dl[k], th[k], upward=True, x0=start)
            out[idx[k]], pol[idx[k]] = j, 1

    # -- falling (D > 0): g convex, decreasing until j*, increasing after
    idx = np.flatnonzero(todo & ~linear & (d > 0))
    if idx.size:
        ci, di, la, dl = c[idx], d[idx], log_a[idx], delta[idx]
        jlo, hz = j0[idx], horizon[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            j_star = np.where(dl > 0, np.log(dl / (-di * la)) / la, np.inf)   # a^{j*} = delta / (-D ln a)
            tf = -theta_off[idx]
            hi_relax = _ceil_steps(np.log((tf - ci) / di) / la) + 1          # OFF without drift
        j_min = np.minimum(np.maximum(np.floor(np.where(np.isfinite(j_star), j_star, float(J_LIMIT))), 0), float(J_LIMIT))
        j_min = np.minimum(np.maximum(j_min.astype(np.int64), jlo), hz)
        # OFF: on the decreasing stretch (j0, min(j_min + 1, horizon)]
        hi = np.where(dl > 0, j_min, np.where(ci < tf, hi_relax, J_LIMIT))
        hi = np.maximum(np.minimum(hi, hz), jlo + 1)
        hi = np.where(comparator_input(hi, ci, di, la, dl) <= tf, hi,
                      np.where((dl > 0) & (hi + 1 <= hz) & (comparator_input(hi + 1, ci, di, la, dl) <= tf),
                               hi + 1, -1))
        off = hi > 0
        if off.any():
            k = np.flatnonzero(off)
            with np.errstate(divide="ignore", invalid="ignore"):
                start = np.log((tf[k] - ci[k]) / di[k]) / la[k]   # root without drift: drift only delays it
            j = _bisect(jlo[k], hi[k], ci[k], di[k], la[k], dl[k], tf[k], upward=False, x0=start)
            out[idx[k]], pol[idx[k]] = j, -1
        # ON: after the minimum, where g increases (g(j_min) <= g(j0) < theta_ON)
        on = ~off & (dl > 0) & (j_min < hz)
        if on.any():
            k = np.flatnonzero(on)
            th = theta_on[idx[k]]
            lo = j_min[k]
            hi = np.minimum(_ceil_steps((th - ci[k]) / dl[k]) + 1, hz[k])      # g >= C + delta j
            hi = np.maximum(hi, lo + 1)
            ok = comparator_input(hi, ci[k], di[k], la[k], dl[k]) >= th
            if ok.any():
                k, lo, hi, th = k[ok], lo[ok], hi[ok], th[ok]
                j = _bisect(lo, hi, ci[k], di[k], la[k], dl[k], th, upward=True, x0=hi.astype(float))
                out[idx[k]], pol[idx[k]] = j, 1
    return out, pol

