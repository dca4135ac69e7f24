"""Refractory period of the reset circuit (paper Eq. 21).

After an event the pixel holds its reset for ``T_refr``; Eq. 21 adds the step ``dt`` to
the hold time after every step and releases the pixel once the hold time reaches
``T_refr``. A pixel that fires at step ``n`` is therefore blind at steps
``n + 1 ... n + k - 1`` and may fire again at ``n + k`` with ``k = max(1, ceil(T_refr/dt))``:
the minimum of one step is the comparator's "one event per pixel per step" (Eq. 17).
"""

from __future__ import annotations


def refractory_steps(refractory_ns: int, dt_ns: int) -> int:
    """Steps ``k`` between an event and the next step at which the pixel may fire [1]."""
    return max(1, -(-int(refractory_ns) // int(dt_ns)))
