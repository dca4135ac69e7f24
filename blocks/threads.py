"""How many threads a block's compiled or GIL-free work may use."""

from __future__ import annotations

import os


def worker_threads() -> int:
    """``EVSDA_THREADS`` if set, else every core this process may use (sweep workers set it to share the cores)."""
    value = os.environ.get("EVSDA_THREADS", "").strip()
    if value:
        if not value.isdigit():
            raise ValueError(f"EVSDA_THREADS must be a whole number of threads, got {value!r}")
        return max(1, int(value))
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                 # no affinity masks (macOS, Windows)
        return os.cpu_count() or 1
