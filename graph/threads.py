"""One BLAS thread per process, for the command line and the Python API alike.

The blocks' linear algebra is many small products: several BLAS threads per process spin
and contend (up to 50x slower on a loaded machine) and take the cores that sweep workers
and the pixel loop's own threads need. ``EVSDA_BLAS_THREADS`` changes the limit.
"""

from __future__ import annotations

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
