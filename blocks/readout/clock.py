"""The readout clock: exact conversion between nanoseconds and integer clock ticks.

An arbiter works on the ticks ``k = 0, 1, 2, ...`` of a clock of ``f`` Hz started at
the run epoch; tick ``k`` falls at ``k / f`` seconds. Working in integer ticks keeps
every arbiter decision exact and independent of how the run is cut into windows.
Conversions split ``t = q * 1e9 + r`` so that no product overflows int64 for clocks
up to :data:`MAX_CLOCK_HZ`.
"""

from __future__ import annotations

import numpy as np

from evsda.graph import NS_PER_S

MAX_CLOCK_HZ = 5_000_000_000   # keeps r * f < 2**63 in the conversions below [Hz]


def ceil_tick(t_ns, clock_hz: int):
    """The first tick at or after ``t_ns`` [tick]: ``ceil(t_ns * f / 1e9)`` (scalar or array)."""
    t = np.asarray(t_ns, dtype=np.int64)
    if NS_PER_S % clock_hz == 0:                        # whole-nanosecond period
        return -(-t // np.int64(NS_PER_S // clock_hz))
    q, r = np.divmod(t, NS_PER_S)
    return q * np.int64(clock_hz) + (r * np.int64(clock_hz) + (NS_PER_S - 1)) // NS_PER_S


def tick_ns(k, clock_hz: int):
    """The time of tick ``k`` rounded down to whole nanoseconds [ns] (scalar or array)."""
    k = np.asarray(k, dtype=np.int64)
    if NS_PER_S % clock_hz == 0:
        return k * np.int64(NS_PER_S // clock_hz)
    q, r = np.divmod(k, np.int64(clock_hz))
    return q * NS_PER_S + (r * NS_PER_S) // np.int64(clock_hz)
