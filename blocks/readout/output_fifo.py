"""The output FIFO and bus of a readout: a first-in first-out queue of finite depth
drained by a bus that carries one event every ``service`` clock ticks.

An event that reaches the FIFO at tick ``a`` is accepted if fewer than ``depth``
accepted events are still waiting for the bus (granted later than ``a``); otherwise it
is dropped (the saturation of paper Sec. 2.5: "when saturated the arbiter will fail to
record, skipping events"). An accepted event is granted the bus at

    g_i = max(a_i, g_{i-1} + service)                                     (Lindley)

which is the D/1/K queue of queueing theory with deterministic service. Without drops
the recursion has the closed form ``g_i = i*s + max(g_{-1} + s, max_{j<=i}(a_j - j*s))``
(a running maximum), which is evaluated with numpy; a busy period that starts with a full FIFO has a closed
form too (a running minimum, see :func:`_busy_period`), so floods cost no Python loop
per event.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEVER = np.iinfo(np.int64).min // 4   # "the bus was never granted" [tick]


@dataclass
class FifoResult:
    accepted: np.ndarray     # bool [n]
    grant: np.ndarray        # int64 [n] tick the bus takes the event (undefined where dropped)
    last_grant: int          # tick of the last accepted grant [tick]


def run_fifo(arrival: np.ndarray, service: int, depth: int, waiting: np.ndarray,
             last_grant: int) -> FifoResult:
    """Push ``arrival`` (sorted ticks) through the FIFO and bus.

    ``waiting`` holds the (sorted) grant ticks of events accepted earlier, and
    ``last_grant`` the last grant tick, so that a run cut into pieces gives the same
    answer as one call.
    """
    a = np.asarray(arrival, dtype=np.int64)
    n = a.size
    accepted = np.zeros(n, dtype=bool)
    grant = np.zeros(n, dtype=np.int64)
    prior = np.asarray(waiting, dtype=np.int64)
    i, batch = 0, n
    while i < n:
        # no FIFO overflow: the closed form of the Lindley recursion, up to the first overflow
        seg = a[i:i + batch]
        j = np.arange(seg.size, dtype=np.int64)
        j *= service
        g = seg - j
        np.maximum.accumulate(g, out=g)
        np.maximum(g, last_grant + service, out=g)
        g += j
        full = _overflows(seg, g, prior, service, depth)
        if full is None and seg.size == n:            # nothing dropped: no copies
            return FifoResult(np.ones(n, dtype=bool), g, int(g[-1]))
        m = seg.size if full is None else full
        accepted[i:i + m] = True
        grant[i:i + m] = g[:m]
        if m:
            last_grant = int(g[m - 1])
        i += m
        if full is None:                              # the batch went through: carry its waiting grants
            prior = np.concatenate([prior, g])
            prior = prior[prior > a[i]] if i < n else prior[:0]
            batch *= 2
            continue
        # a full FIFO: serve the busy period that follows until the FIFO empties
        waits = np.concatenate([prior[prior > a[i]], g[:m][g[:m] > a[i]]])
        i, last_grant = _busy_period(a, i, int(waits[0]), waits.size, service, depth, last_grant, accepted, grant)
        prior, batch = np.zeros(0, np.int64), 1024
    return FifoResult(accepted, grant, last_grant)


def _busy_period(a: np.ndarray, i: int, head: int, waiting: int, service: int, depth: int, last_grant: int,
                 accepted: np.ndarray, grant: np.ndarray) -> tuple[int, int]:
    """Serve arrivals from ``i`` while the bus stays busy; returns ``(first arrival that finds the
    FIFO empty, last grant)``.

    While the bus is busy its grants follow back to back: the ``waiting`` events wait for
    ``head, head + s, ...`` and the ``r``-th event accepted after them gets
    ``last_grant + r s``. By an arrival at ``a`` the grants up to it have freed
    ``F(a) = max(0, floor((a - head) / s) + 1)`` slots, so it finds
    ``waiting + r - F(a)`` events waiting and is accepted iff ``r < c = depth - waiting + F(a)``.
    With ``c`` non-decreasing the count of accepted events obeys
    ``r_{k+1} = min(r_k + 1, c_k)``, whose solution is ``r_{k+1} = k + min(1, min_{j<=k}(c_j - j))``
    (a running minimum): the whole busy period is evaluated with numpy.
    """
    n, taken, batch = a.size, 0, 256
    while i < n:
        seg = a[i:i + batch]
        k = np.arange(seg.size, dtype=np.int64)
        freed = np.maximum(0, (seg - head) // service + 1)
        c = depth - waiting - taken + freed
        after = k + np.minimum(1, np.minimum.accumulate(c - k))    # accepted after each arrival
        before = np.concatenate([[0], after[:-1]])
        empty = np.flatnonzero(freed >= waiting + taken + before)  # every grant passed: FIFO empty
        stop = seg.size if empty.size == 0 else int(empty[0])
        took = np.flatnonzero(after[:stop] > before[:stop])
        accepted[i + took] = True
        grant[i + took] = last_grant + service * (taken + after[took])
        taken += int(after[stop - 1]) if stop else 0
        if stop < seg.size:
            return i + stop, last_grant + taken * service
        i += seg.size
        batch *= 2
    return n, last_grant + taken * service


def _overflows(a: np.ndarray, g: np.ndarray, prior: np.ndarray, service: int, depth: int) -> int | None:
    """Index of the first arrival that finds ``depth`` events waiting, if every arrival before it
    is accepted with the grants ``g``; ``None`` if there is none.

    Waiting at arrival ``j``: earlier grants later than ``a_j``, from ``g`` and ``prior``.
    Grants are at least ``service`` apart, so ``depth`` of them can wait only where the
    previous grant is at least ``(depth - 1) * service + 1`` after the arrival: the exact
    count is needed only there (and where ``prior`` grants may still wait).
    """
    lag = np.empty(a.size, dtype=np.int64)
    lag[0] = np.iinfo(np.int64).min
    np.subtract(g[:-1], a[1:], out=lag[1:])
    candidates = np.flatnonzero(lag > (depth - 1) * service)
    if prior.size:                                  # arrivals before the last prior grant, too
        head = int(np.searchsorted(a, prior[-1], side="left"))
        candidates = np.concatenate([np.arange(head), candidates[candidates >= head]])
    lo, block = 0, 1024                             # look at the candidates in growing blocks,
    while lo < candidates.size:                     # as the first overflow is often early
        cand = candidates[lo:lo + block]
        at = a[cand]
        left_before = np.minimum(np.searchsorted(g, at, side="right"), cand)
        occupancy = (cand - left_before) + (prior.size - np.searchsorted(prior, at, side="right"))
        full = np.flatnonzero(occupancy >= depth)
        if full.size:
            return int(cand[full[0]])
        lo += block
        block *= 4
    return None
