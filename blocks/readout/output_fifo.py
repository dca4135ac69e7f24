"""The output FIFO and bus of a readout: a first-in first-out queue of finite depth
drained by a bus that carries one event every ``service`` clock ticks.

An event that reaches the FIFO at tick ``a`` is accepted if fewer than ``depth``
accepted events are still waiting for the bus (granted later than ``a``); otherwise it
is dropped (the saturation of paper Sec. 2.5: "when saturated the arbiter will fail to
record, skipping events"). An accepted event is granted the bus at

    g_i = max(a_i, g_{i-1} + service)                                     (Lindley)

which is the D/1/K queue of queueing theory with deterministic service. Without drops
the recursion has the closed form ``g_i = i*s + max(g_{-1} + s, max_{j<=i}(a_j - j*s))``
(a running maximum), which is evaluated with numpy; only stretches where the FIFO is
full fall back to an event-by-event loop, and that loop jumps over the arrivals that a
full FIFO refuses, so its cost grows with the accepted events, not the flood.
"""

from __future__ import annotations

from collections import deque
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
    i = 0
    while i < n:
        # fast path: assume every arrival from i on is accepted, find the first overflow
        seg = a[i:]
        j = np.arange(seg.size, dtype=np.int64)
        j *= service
        g = seg - j
        np.maximum.accumulate(g, out=g)
        np.maximum(g, last_grant + service, out=g)
        g += j
        full = _overflows(seg, g, prior, service, depth)
        if full is None and i == 0:                   # nothing dropped: no copies
            return FifoResult(np.ones(n, dtype=bool), g, int(g[-1]))
        m = seg.size if full is None else full
        accepted[i:i + m] = True
        grant[i:i + m] = g[:m]
        if m:
            last_grant = int(g[m - 1])
        if full is None:
            break
        # slow path from the first overflow, until the FIFO is empty again
        queue = deque(int(x) for x in prior[prior > seg[m]])
        queue.extend(int(x) for x in g[:m][g[:m] > seg[m]])
        i += m
        while i < n:
            t = int(a[i])
            while queue and queue[0] <= t:
                queue.popleft()
            if not queue:
                break                     # back to the fast path with an empty FIFO
            if len(queue) >= depth:       # full: refuse everything until a slot frees
                i = max(i + 1, int(np.searchsorted(a, queue[0], side="left")))
                continue
            last_grant = max(t, last_grant + service)
            queue.append(last_grant)
            accepted[i] = True
            grant[i] = last_grant
            i += 1
        prior = np.asarray(queue, dtype=np.int64)
    return FifoResult(accepted, grant, last_grant)


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
    if prior.size:
        candidates = np.union1d(candidates, np.arange(np.searchsorted(a, prior[-1], side="left")))
    if candidates.size == 0:
        return None
    at = a[candidates]
    left_before = np.minimum(np.searchsorted(g, at, side="right"), candidates)
    occupancy = (candidates - left_before) + (prior.size - np.searchsorted(prior, at, side="right"))
    full = np.flatnonzero(occupancy >= depth)
    return int(candidates[full[0]]) if full.size else None
