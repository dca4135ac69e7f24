"""One BLAS thread per process, for the command line and the Python API alike; few malloc arenas that keep
what is freed (:func:`keep_freed_memory`); one pool of worker threads that the blocks' parallel loops share (:func:`parallel_map`).

The blocks' linear algebra is many small products: several BLAS threads per process spin
and contend (up to 50x slower on a loaded machine) and take the cores that sweep workers
and the pixel loop's own threads need. ``EVSDA_BLAS_THREADS`` changes the limit.

glibc gives each thread that allocates its own malloc arena (up to 8 per core), and each arena
keeps the memory freed into it: with the pipelined windows' threads the tracked 4 s pass peaked at
770-795 MB against 664 MB one step at a time. Four arenas bring it to 627 MB at the same speed (two:
600 MB but slower; benchmarks/framework_pipeline.py, docs/speed.md). ``MALLOC_ARENA_MAX``, if set,
is left to glibc.

The blocks' parallel loops (sources rendered side by side, probe pairs, pixel chunks) ran each on a
``ThreadPoolExecutor`` of their own, made and joined at every call: new threads every window (and new
per-thread buffers, first touched again), and, with pipelined windows, the optics' and the pixels'
pools side by side on top of the pipeline's threads. :func:`parallel_map` runs them on the calling
thread plus helpers from one pool the process keeps: ``threads - 1`` helpers serve every caller, so a
window's threads are the pipeline's steps plus that many.
"""

from __future__ import annotations

import ctypes
import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

from .errors import UserError


def usable_cores() -> int:
    """The threads a run's blocks may use: ``EVSDA_THREADS`` if set (sweep workers set it to share the cores), else
    every core this process may run on."""
    value = os.environ.get("EVSDA_THREADS", "").strip()
    if value:
        if not value.isdigit():
            raise ValueError(f"EVSDA_THREADS must be a whole number of threads, got {value!r}")
        return max(1, int(value))
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                 # no affinity masks (macOS, Windows)
        return os.cpu_count() or 1


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


#: freed memory glibc keeps for reuse at the top of a heap before it gives it back (``M_TRIM_THRESHOLD``) [byte]
TRIM_THRESHOLD_BYTES = 512 << 20
#: blocks up to this size come from the heaps, not from a mapping of their own (``M_MMAP_THRESHOLD``; glibc's
#: largest on 64 bits) [byte]
MMAP_THRESHOLD_BYTES = 32 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3     # glibc's malloc.h


def _mallopt():
    """glibc's ``mallopt``, or None (not glibc: macOS, Windows)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return mallopt


def keep_freed_memory() -> None:
    """Reuse freed memory rather than give it back and fault it in, zeroed, again.

    A window's large arrays (stamps, screens, the pixels' buffers) are freed and made again every window.
    glibc maps each block above its (moving) mmap threshold on its own and unmaps it when freed, and gives
    back what is free at a heap's top above its trim threshold; NumPy asks for 2 MB pages on arrays of 4 MB
    and more. Each new array then meets fresh pages, which the kernel zeroes, 2 MB at a time: ~4 % of a run's
    CPU (`clear_page_erms` in `perf`). Blocks up to :data:`MMAP_THRESHOLD_BYTES` now come from the heaps, a
    heap keeps up to :data:`TRIM_THRESHOLD_BYTES` free, and NumPy takes ordinary pages: on 3 s of the tracked
    pass the system time fell 0.54-0.92 -> 0.25-0.36 s on one thread and 0.73-0.97 -> 0.39-0.43 s on two, and on
    the 10 s pass 2.0 -> 0.6-0.9 s on two, for 18 MB more peak memory (748 -> 766 MB; docs/speed.md).
    ``MALLOC_TRIM_THRESHOLD_`` or ``MALLOC_MMAP_THRESHOLD_``, if set, are left to glibc, and
    ``NUMPY_MADVISE_HUGEPAGE`` to NumPy.
    """
    mallopt = _mallopt()
    if mallopt is not None:
        if not os.environ.get("MALLOC_TRIM_THRESHOLD_"):
            mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
        if not os.environ.get("MALLOC_MMAP_THRESHOLD_"):
            mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    if "NUMPY_MADVISE_HUGEPAGE" not in os.environ:
        import numpy as np
        core = getattr(np, "_core", None) or np.core
        setter = getattr(core.multiarray, "_set_madvise_hugepage", None)
        if setter is not None:
            setter(False)


def limit_malloc_arenas() -> None:
    """Hold glibc to :data:`MALLOC_ARENAS` malloc arenas for threads that have none yet (no-op elsewhere, or
    where ``MALLOC_ARENA_MAX`` is set)."""
    mallopt = _mallopt()
    if mallopt is not None and not os.environ.get("MALLOC_ARENA_MAX"):
        mallopt(_M_ARENA_MAX, MALLOC_ARENAS)


T = TypeVar("T")

_helpers: ThreadPoolExecutor | None = None      # the process's helper threads, made on first use
_helper_count = 0
_helpers_lock = threading.Lock()


def _helper_pool(count: int) -> ThreadPoolExecutor:
    """The process's pool of at least ``count`` helper threads (a larger one replaces a smaller one)."""
    global _helpers, _helper_count
    with _helpers_lock:
        if _helpers is None or _helper_count < count:
            old, _helpers, _helper_count = _helpers, ThreadPoolExecutor(count, thread_name_prefix="evsda-worker"), count
            if old is not None:
                old.shutdown(wait=False)          # its threads end once their tasks are done
        return _helpers


def _forget_helpers() -> None:
    """In a forked child: the parent's helper threads do not exist there (nor its late helpers at work, and its
    condition may have been held by one of its threads)."""
    global _helpers, _helper_count, _late_working, _cores
    _helpers, _helper_count, _late_working, _cores = None, 0, 0, threading.Condition()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_helpers)


_steps_running = 0                              # pipelined block steps running now (:func:`running_step`)
_late_working = 0                               # helpers at work that joined their loop late
_cores = threading.Condition()                  # guards the two counts; notified when either falls or a loop ends
#: a loop that starts beside another step gets the helpers it lacks once a core comes free (``EVSDA_LATE_HELPERS=off``:
#: only those free when it starts)
LATE_HELPERS = os.environ.get("EVSDA_LATE_HELPERS", "on").strip().lower() != "off"


@contextmanager
def running_step():
    """Count a pipelined block step as running while in this context: :func:`parallel_map` gives such a step
    one helper fewer for every other step running beside it (they share the cores), until that step ends."""
    global _steps_running
    with _cores:
        _steps_running += 1
    try:
        yield
    finally:
        with _cores:
            _steps_running -= 1
            _cores.notify_all()


def parallel_map(fn: Callable[[Any], T], items: Iterable, threads: int) -> list[T]:
    """``[fn(item) for item in items]``, on up to ``threads`` threads: the calling thread and ``threads - 1``
    helpers of the pool the process shares, each taking the next item not yet taken.

    The caller never waits for a busy helper: it works through the items itself, and a helper that starts
    late finds none left (so nested and concurrent calls cannot deadlock). If ``fn`` raises, no further item
    is started, the items already started finish, and the error of the first failing item (in the items'
    order) is raised, the one the loop above would raise. Which thread runs an item is not fixed, so ``fn``
    must give the same result on any thread.

    Pipelined, a loop gets one helper fewer for each other step running beside it when it starts, so the
    threads at work stay within the cores; the helpers it lacks wait and join it once a core comes free (a step
    beside it ends) while items are left. On the tracked pass the optics' loop starts beside the pixels' step in
    nearly every window: without them its ~6 items ran on its own thread to the end while the pixels' core
    idled once their step was done (docs/speed.md).
    """
    items = list(items)
    wanted = min(threads, len(items)) - 1
    helpers = min(threads - max(_steps_running - 1, 0), len(items)) - 1
    late = wanted - max(helpers, 0) if LATE_HELPERS else 0
    if helpers < 1 and late < 1:
        return [fn(item) for item in items]
    results: list[Any] = [None] * len(items)
    errors: dict[int, BaseException] = {}
    taken = [0]
    lock = threading.Lock()

    def work() -> None:
        while True:
            with lock:
                i = taken[0]
                if i >= len(items) or errors:
                    return
                taken[0] += 1
            try:
                results[i] = fn(items[i])
            except BaseException as exc:          # noqa: BLE001 -- re-raised below, in the items' order
                with lock:
                    errors[i] = exc

    def left() -> bool:
        return taken[0] < len(items) and not errors

    def join_late() -> None:
        """A helper the loop lacked at its start: it waits for a free core, then takes items as the others do."""
        global _late_working
        with _cores:
            while left() and _steps_running + _late_working >= threads:
                _cores.wait()
            if not left():
                return
            _late_working += 1
        try:
            work()
        finally:
            with _cores:
                _late_working -= 1
                _cores.notify_all()

    pool = _helper_pool(wanted)
    started = [pool.submit(work) for _ in range(max(helpers, 0))]
    started += [pool.submit(join_late) for _ in range(late)]
    try:
        work()
    finally:
        if late:
            with _cores:
                _cores.notify_all()               # waiting helpers leave
        for future in started:
            if not future.cancel():               # running: it finishes the item it took
                future.result()
    if errors:
        raise errors[min(errors)]
    return results
