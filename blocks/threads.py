"""How many threads a block's compiled or GIL-free work may use."""

from __future__ import annotations

from evsda.graph.threads import usable_cores


def worker_threads() -> int:
    """``EVSDA_THREADS`` if set, else every core this process may use (sweep workers set it to share the cores):
    :func:`evsda.graph.threads.usable_cores`."""
    return usable_cores()
