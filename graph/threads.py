"""One BLAS thread per process, for the command line and the Python API alike; few malloc arenas.

The blocks' linear algebra is many small products: several BLAS threads per process spin
and contend (up to 50x slower on a loaded machine) and take the cores that sweep workers
and the pixel loop's own threads need. ``EVSDA_BLAS_THREADS`` changes the limit.

glibc gives each thread that allocates its own malloc arena (up to 8 per core), and each arena
keeps the memory freed into it: with the pipelined windows' threads the tracked 4 s pass peaked at
770-795 MB against 664 MB one step at a time. Four arenas bring it to 627 MB at the same speed (two:
600 MB but slower; benchmarks/framework_pipeline.py, docs/speed.md). ``MALLOC_ARENA_MAX``, if set,
is left to glibc.
"""

from __future__ import annotations

import ctypes
import os

from threadpoolctl import threadpool_limits

from .errors import UserError


def blas_threads() -> int:
    """The BLAS thread limit: ``EVSDA_BLAS_THREADS`` (default 1)."""
    text = os.environ.get("EVSDA_BLAS_THREADS", "1")
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise UserError(f"EVSDA_BLAS_THREADS must be a whole number of at least 1, got {text!r}")
    return value


def limit_blas():
    """A context manager holding every BLAS library loaded in this process to :func:`blas_threads`."""
    return threadpool_limits(limits=blas_threads(), user_api="blas")


#: malloc arenas a run's threads share (glibc's ``M_ARENA_MAX``)
MALLOC_ARENAS = 4
_M_ARENA_MAX = -8          # glibc's malloc.h


def limit_malloc_arenas() -> None:
    """Hold glibc to :data:`MALLOC_ARENAS` malloc arenas for threads that have none yet (no-op elsewhere, or
    where ``MALLOC_ARENA_MAX`` is set)."""
    if os.environ.get("MALLOC_ARENA_MAX"):
        return
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):       # not glibc (macOS, Windows)
        return
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt(_M_ARENA_MAX, MALLOC_ARENAS)
