"""Numba's first compiles on the second core: a block's compiled loops built ahead in a child process.

A run with an empty Numba cache (a user's first run after an install, CI, a new machine) compiles every
compiled loop before it first runs, and Numba compiles under one lock, so a process compiles on one core
while the other waits. :func:`start` runs a block's own small warm-up (a function that calls the block's
loops with the argument types a run gives them) in a fresh interpreter, which compiles them and writes
them to the same on-disk cache (``NUMBA_CACHE_DIR``, or Numba's folder beside the sources) while this
process compiles the blocks that run first. The block calls :meth:`Ahead.wait` before it first calls its
loops, and Numba then loads them from the cache instead of compiling them: the compiled code, and so every
result, is the same.

A child starts only when none of the named modules' cached loops has a signature cached for its current
source (reading their cache indexes takes milliseconds: later runs start no child), when the run may use
more than one thread (``EVSDA_THREADS``), and unless ``EVSDA_COMPILE_AHEAD=off``. One child at a time per
warm-up. A child that fails costs nothing but its time: the block then compiles what it needs itself.
"""

from __future__ import annotations

import atexit
import importlib
import json
import logging
import os
import subprocess
import sys
import threading

from .threads import usable_cores

log = logging.getLogger(__name__)

#: longest wait for a child before this process compiles on its own [s]
WAIT_LIMIT_S = 600.0

_CHILD = r"""
import json, os, sys, threading, time
parent, path, target, args = json.loads(sys.argv[1])

def orphaned():                    # the run ended without stopping this child (killed): end with it
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(0)

threading.Thread(target=orphaned, daemon=True).start()
sys.path[:] = path
module, name = target.split(":")
getattr(__import__(module, fromlist=[name]), name)(*args)
"""

_started: dict[str, Ahead] = {}          # warm-up target -> its child (this process starts one per target)
_lock = threading.Lock()


class Ahead:
    """A child process compiling a block's loops; :meth:`wait` returns once it has ended (at once if none)."""

    def __init__(self, process: subprocess.Popen | None):
        self.process = process
        self.started = process is not None
        self._lock = threading.Lock()          # blocks that share the child wait for it together

    def wait(self) -> None:
        """Wait for the child (the cached loops are then all written); kill it after ``WAIT_LIMIT_S``."""
        with self._lock:
            process, self.process = self.process, None
            if process is None:
                return
            try:
                process.wait(timeout=WAIT_LIMIT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            if process.returncode:
                log.info("compiling ahead ended with status %s; the block compiles what it needs itself",
                         process.returncode)


def start(target: str, modules: tuple[str, ...], *args) -> Ahead:
    """Run ``target`` (``"package.module:function"``, called with ``args``, JSON values) in a child process
    when none of ``modules``' cached loops is in the Numba cache; an :class:`Ahead` to wait on either way."""
    with _lock:
        if target in _started or not _wanted() or _cached(modules):
            return _started.get(target) or Ahead(None)
        env = dict(os.environ, EVSDA_COMPILE_AHEAD="off", EVSDA_THREADS="1", OPENBLAS_NUM_THREADS="1")
        try:
            process = subprocess.Popen([sys.executable, "-c", _CHILD, json.dumps([os.getpid(), sys.path, target, list(args)])],
                                       env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL, close_fds=True)
        except OSError as error:
            log.info("cannot compile ahead (%s)", error)
            return Ahead(None)
        atexit.register(_end, process)
        _started[target] = ahead = Ahead(process)
        return ahead


def _wanted() -> bool:
    if os.environ.get("EVSDA_COMPILE_AHEAD", "").strip().lower() in ("off", "0", "no", "false"):
        return False
    try:
        return usable_cores() > 1
    except ValueError:
        return False


def _cached(modules: tuple[str, ...]) -> bool:
    """Whether any cached compiled function of ``modules`` has a signature in the cache for its current source
    (also True when that cannot be read: then no child starts)."""
    for name in modules:
        for value in vars(importlib.import_module(name)).values():
            cache = getattr(value, "_cache", None)
            index = getattr(cache, "_cache_file", None)
            if index is None or getattr(value, "targetoptions", {}).get("inline") == "always":
                continue
            try:
                if index._load_index():          # Numba's index of this function's cached signatures
                    return True
            except Exception:                    # noqa: BLE001 -- unreadable here: this process compiles
                return True
    return False


def _end(process: subprocess.Popen) -> None:
    """At exit: a child still compiling is stopped (a half-written cache entry is never visible: Numba
    writes each file whole and renames it)."""
    if process.poll() is None:
        process.kill()
        process.wait()
