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
otherwise. This is the same recursion the dense reference steps through, so the two agree
to floating-point rounding.
"""

from __future__ import annotations

import numpy as np

NEVER = np.int64(1) << np.int64(62)        # "no such step" [steps]
_J_LIMIT = np.int64(1) << np.int64(52)     # longest look-ahead; beyond it a crossing counts as never [steps]


def comparator_input(j, c, d, log_a, delta):
    """``g(j) = C + D a^j + delta j`` (``a^j`` as ``exp(j ln a)``; ``a = 0`` gives 0 for ``j >= 1``)."""
    with np.errstate(invalid="ignore", over="ignore"):
        decay = np.exp(np.where(j > 0, j * log_a, 0.0))
    return c + d * decay + delta * j


def _first_true(lo, hi, pred):
    """Smallest ``j`` in ``(lo, hi]`` with ``pred(j)``, given ``pred`` false at ``lo``, true at ``hi``, monotone between."""
    lo, hi = lo.copy(), hi.copy()
    open_ = hi - lo > 1
    while open_.any():
        idx = np.flatnonzero(open_)
        mid = lo[idx] + (hi[idx] - lo[idx]) // 2
        ok = pred(idx, mid)
        hi[idx] = np.where(ok, mid, hi[idx])
        lo[idx] = np.where(ok, lo[idx], mid)
        open_[idx] = hi[idx] - lo[idx] > 1
    return hi


def _ceil_steps(x):
    """``ceil(x)`` as steps, clipped to ``[0, _J_LIMIT]`` (NaN -> limit)."""
    x = np.where(np.isfinite(x), x, float(_J_LIMIT))
    return np.clip(np.ceil(x), 0, float(_J_LIMIT)).astype(np.int64)


def first_crossing(j0, c, d, log_a, delta, theta_on, theta_off):
    """First ``j >= j0`` at which ``g`` reaches ``theta_on`` (polarity +1) or ``-theta_off`` (-1).

    All arguments are arrays of one length (``j0 >= 1``). Returns ``(j, polarity)`` with
    ``j = NEVER`` and polarity 0 where the input never leaves the band.
    """
    n = j0.shape[0]
    j0 = j0.astype(np.int64)
    out = np.full(n, NEVER, dtype=np.int64)
    pol = np.zeros(n, dtype=np.int8)

    def g(idx, j):
        return comparator_input(j, c[idx], d[idx], log_a[idx], delta[idx])

    everyone = np.arange(n)
    g0 = g(everyone, j0)
    on0, off0 = g0 >= theta_on, g0 <= -theta_off
    out[on0], pol[on0] = j0[on0], 1
    off0 &= ~on0
    out[off0], pol[off0] = j0[off0], -1
    todo = ~(on0 | off0)

    # -- linear: no relaxation left (D = 0, a = 1, or a = 0 which leaves L = Y after one step)
    linear = todo & ((d == 0) | (log_a == 0) | np.isneginf(log_a))
    idx = np.flatnonzero(linear & (delta > 0))
    if idx.size:
        c_eff = c[idx] + np.where(log_a[idx] == 0, d[idx], 0.0)
        j = np.maximum(_ceil_steps((theta_on[idx] - c_eff) / delta[idx]), j0[idx])
        # the closed form can be one step off through rounding: settle it on g itself
        j = np.where(g(idx, j) >= theta_on[idx], j, j + 1)
        j = np.where((j - 1 > j0[idx]) & (g(idx, j - 1) >= theta_on[idx]), j - 1, j)
        good = (j < _J_LIMIT) & (g(idx, j) >= theta_on[idx])
        out[idx[good]], pol[idx[good]] = j[good], 1

    # -- rising (D < 0): g increases; only an ON crossing is possible after j0
    idx = np.flatnonzero(todo & ~linear & (d < 0))
    if idx.size:
        dl, cl, la, th = delta[idx], c[idx], log_a[idx], theta_on[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            hi_drift = _ceil_steps((th - cl - d[idx]) / dl) + 1
            hi_relax = _ceil_steps(np.log((th - cl) / d[idx]) / la) + 1
        hi = np.where(dl > 0, hi_drift, np.where(cl > th, hi_relax, _J_LIMIT))
        hi = np.maximum(np.minimum(hi, _J_LIMIT), j0[idx] + 1)
        ok = g(idx, hi) >= th
        sel = idx[ok]
        if sel.size:
            j = _first_true(j0[sel], hi[ok], lambda k, m: g(sel[k], m) >= theta_on[sel[k]])
            out[sel], pol[sel] = j, 1

    # -- falling (D > 0): g convex, decreasing until j*, increasing after
    idx = np.flatnonzero(todo & ~linear & (d > 0))
    if idx.size:
        dl, cl, la, dd = delta[idx], c[idx], log_a[idx], d[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = dl / (-dd * la)                        # a^{j*} at the minimum
            j_star = np.where(dl > 0, np.log(ratio) / la, np.inf)
        j_min = np.clip(np.floor(np.where(np.isfinite(j_star), j_star, float(_J_LIMIT))), 0, float(_J_LIMIT))
        j_min = np.maximum(j_min.astype(np.int64), j0[idx])
        # OFF: on the decreasing stretch (j0, j_min + 1]
        tf = -theta_off[idx]
        with np.errstate(divide="ignore", invalid="ignore"):
            hi_relax = _ceil_steps(np.log((tf - cl) / dd) / la) + 1
        hi_off = np.where(dl > 0, j_min, np.where(cl < tf, hi_relax, _J_LIMIT))
        hi_off = np.maximum(np.minimum(hi_off, _J_LIMIT), j0[idx] + 1)
        hi_off = np.where(g(idx, hi_off) <= tf, hi_off,
                          np.where((dl > 0) & (g(idx, hi_off + 1) <= tf), hi_off + 1, -1))
        has_off = hi_off > 0
        sel = idx[has_off]
        if sel.size:
            j = _first_true(j0[sel], hi_off[has_off], lambda k, m: g(sel[k], m) <= -theta_off[sel[k]])
            out[sel], pol[sel] = j, -1
        # ON: after the minimum, where g increases
        rest = ~has_off & (dl > 0)
        sel = idx[rest]
        if sel.size:
            lo = np.maximum(j_min[rest], j0[sel])
            hi = np.maximum(np.minimum(_ceil_steps((theta_on[sel] - c[sel]) / delta[sel]) + 1, _J_LIMIT), lo + 1)
            ok = g(sel, hi) >= theta_on[sel]
            sel, lo, hi = sel[ok], lo[ok], hi[ok]
            if sel.size:   # g(lo) <= g(j0) < theta_on, as g decreases from j0 to j_min
                out[sel] = _first_true(lo, hi, lambda k, m: g(sel[k], m) >= theta_on[sel[k]])
                pol[sel] = 1
    return out, pol
