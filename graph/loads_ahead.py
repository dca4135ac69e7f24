"""A run's first cached compiled loads made ahead, on a thread, from the list its blocks' last run left (issue 13).

A run of the tracked pass loads ~28 compiled functions from Numba's cache, most of them in window 0 (the optics'
screens, stamps and propagation, then the pixels' loops, then the metrics), each where a step first calls it: ~1.2
ms of CPU a load, about half of it in LLVM's calls (object code added and finalised, symbols resolved), which
release the interpreter lock, on the run's critical path (the optics' first step, then the pixels'). The graph's
load before it runs on one core (the libraries' imports), the other core idle.

:class:`LoadsAhead` replays them sooner: once the graph's blocks are built (their modules imported, the graph's load
not yet over: networkx's import, the checks, the run's set-up and window 0's scene steps follow), it starts a thread
(``evsda-loads-ahead``) that loads, in the recorded order, each function with each argument types that the last run
of the same block types loaded, as Numba's ``Dispatcher.compile`` does on a cache hit (under its compiler lock;
nothing is ever compiled there: a function whose types are not in the cache is left to its first call). The loads'
LLVM calls run on the second core meanwhile; a step that calls a function already loaded finds its machine code at
once, one whose load is still to come loads it itself as before. The same machine code is loaded, so every result
is the same.

The list is the run's own record: every load from Numba's cache during the run (:func:`.numba_loads.record_loads`,
the replayed ones with them), in order, kept at the end of a run that returned (rewritten only when it differs) in
a file named by the graph's block types, in the folder where Numba caches this module's own functions (its
locators: ``NUMBA_CACHE_DIR``, else beside the sources, else the user's cache). A first run, or another set of
block types, replays nothing and leaves its list; an entry that no longer loads (code edited, so its cache entry is
stale; a function gone) is dropped from the next list; one that loads but is no longer called costs its load on
the second core until its source changes. A list that cannot be read is ignored. Only where :func:`.numba_loads.
lazy_registries` applies (a load then needs no compiler set-up), only on the Numba versions checked, and only where
``Dispatcher.compile``'s cache branch is as checked.

The thread takes the interpreter lock from the main thread for the loads' Python (about half of them), and while
it waits for it each of the main thread's lock releases (its imports' file calls) becomes a hand-over or a
wake-up across cores: it pays only where a core is free, and lost on the shared 2-core host of the twentieth
session (docs/speed.md: "The start's compiled loads replayed ahead, tried"). So it is off unless
``EVSDA_LOADS_AHEAD`` says otherwise: ``on`` replays only where the machine had at least :data:`FREE_CORES` idle on
average over the graph's load until its blocks were built (``/proc/stat``; where that cannot be read, it replays),
``always`` whatever the idle cores; both keep the list; ``off`` (the default) replays and keeps nothing. Blocks
stepped in worker processes load there (``EVSDA_WORKERS``): a list kept without workers then loads some functions
in the run's process that it does not call.
"""

from __future__ import annotations

import hashlib
import logging
import os
import sys
import threading
from collections.abc import Iterable
from pathlib import Path

from .compile_ahead import switched_off
from .numba_loads import lazy_registries, record_loads

log = logging.getLogger(__name__)

#: the Numba versions whose ``Dispatcher.compile`` cache branch was checked
_CHECKED = ("0.68.1",)

#: ``Dispatcher.compile``'s lines on a cache hit in the versions checked (what :func:`_load` does)
_NUMBAS_HIT = '''                cres = self._cache.load_overload(sig, self.targetctx)
                if cres is not None:
                    self._cache_hits[sig] += 1
                    # XXX fold this in add_overload()? (also see compiler.py)
                    if not cres.objectmode:
                        self.targetctx.insert_user_function(cres.entry_point,
                                                            cres.fndesc,
                                                            [cres.library])
                    self.add_overload(cres)
                    return cres.entry_point
'''

#: the idle cores (the machine's, on average over the graph's load until its blocks are built) below which nothing is
#: replayed: a thread beside the main one then takes the interpreter lock from it on a shared core
FREE_CORES = 0.5

#: a recorded load: the function's module, its qualified name, its argument types (Numba's types)
Entry = tuple[str, str, tuple]

#: the list file's format; a list of another is ignored
_FORMAT = 1


class LoadsAhead:
    """One run's loads ahead: :meth:`start` once its blocks are built, :meth:`keep` once it has returned."""

    def __init__(self):
        self.mode = _mode()
        self.idle_since = _idle_ticks() if self.mode == "on" else None   # the machine's idle and all CPU ticks
        self.path: Path | None = None           # the list file of the graph's block types
        self.previous: list[Entry] = []         # the list read from it
        self.loads: list | None = None          # this run's loads: (function, argument types), in order
        self.thread: threading.Thread | None = None

    def start(self, block_types: Iterable[type]) -> None:
        """Record the run's loads, and replay the list of ``block_types`` (the graph's block classes, their modules
        imported) on a thread (:func:`_mode`). Nothing where Numba is not imported, off, or not as checked."""
        mode = self.mode
        if mode == "off" or "numba" not in sys.modules or not _numba_checked():
            return
        if not lazy_registries():
            return
        self.path = _list_file(block_types)
        if self.path is None:
            return
        self.previous = _read(self.path)
        self.loads = record_loads()
        if self.previous and (mode == "always" or _free_cores(self.idle_since) >= FREE_CORES):
            self.thread = threading.Thread(target=_replay, args=(self.previous,), name="evsda-loads-ahead")
            self.thread.start()

    def keep(self) -> None:
        """After a run that returned: stop recording; write its loads as the list where they differ from it."""
        if self.loads is None:
            return
        record_loads(False)
        entries = _entries(self.loads)
        self.loads = None
        if entries and entries != self.previous:
            _write(self.path, entries)


def _mode() -> str:
    """``EVSDA_LOADS_AHEAD``: ``off`` (unset, or any word for off), ``on`` (where a core is idle) or ``always``."""
    value = os.environ.get("EVSDA_LOADS_AHEAD", "").strip().lower()
    if value in ("on", "always"):
        return value
    if value and not switched_off("EVSDA_LOADS_AHEAD"):
        log.warning("EVSDA_LOADS_AHEAD must be 'off', 'on' or 'always', got %r: off", value)
    return "off"


def _numba_checked() -> bool:
    """Whether Numba is a version checked and its ``Dispatcher.compile`` loads from the cache as :func:`_load`."""
    import inspect

    import numba
    from numba.core.dispatcher import Dispatcher

    try:
        return numba.__version__ in _CHECKED and _NUMBAS_HIT in inspect.getsource(Dispatcher.compile)
    except (OSError, TypeError):                # no source to check
        return False


def _idle_ticks() -> tuple[int, int] | None:
    """The machine's CPU ticks idle (idle and waiting for I/O) and all its ticks since it started (``/proc/stat``'s
    first line), or None where there is none."""
    try:
        with open("/proc/stat", "rb") as file:
            ticks = [int(field) for field in file.readline().split()[1:]]
        return ticks[3] + ticks[4], sum(ticks)
    except (OSError, ValueError, IndexError):
        return None


def _free_cores(since: tuple[int, int] | None) -> float:
    """The machine's idle cores on average from ``since`` (:func:`_idle_ticks`) to now; every core where that is
    unknown (no ``/proc/stat``, or less than a few ticks between: a quick load, nothing seen to share)."""
    cores = os.cpu_count() or 1
    now = _idle_ticks()
    if since is None or now is None or now[1] - since[1] < 4 * cores:
        return float(cores)
    return cores * (now[0] - since[0]) / (now[1] - since[1])


def _replay(entries: list[Entry]) -> None:
    """Load each entry's function from Numba's cache, in order, while the run's main thread lives."""
    main = threading.main_thread()
    for module, qualname, sig in entries:
        if not main.is_alive():                 # the command ended (an error, say): the exit waits for no more
            return
        dispatcher = _dispatcher(module, qualname)
        if dispatcher is not None:
            try:
                _load(dispatcher, sig)
            except Exception as error:          # noqa: BLE001 -- not loaded here: its first call loads or compiles it
                log.debug("not loaded ahead: %s.%s%s (%s)", module, qualname, sig, error)


def _dispatcher(module: str, qualname: str):
    """The compiled function ``module.qualname`` if its module is imported (none is imported here), else None."""
    from numba.core.dispatcher import Dispatcher

    value = sys.modules.get(module)
    for name in qualname.split("."):
        value = getattr(value, name, None)
    return value if isinstance(value, Dispatcher) else None


def _load(dispatcher, sig: tuple) -> None:
    """Numba's ``Dispatcher.compile`` on a cache hit (:data:`_NUMBAS_HIT`), under its compiler lock; nothing where
    ``sig`` is loaded already or not in the cache (no compile)."""
    from numba.core import sigutils
    from numba.core.compiler_lock import global_compiler_lock

    with global_compiler_lock, dispatcher._compiling_counter:
        args, _ = sigutils.normalize_signature(sig)
        if tuple(args) in dispatcher.overloads:
            return
        cres = dispatcher._cache.load_overload(sig, dispatcher.targetctx)
        if cres is None:
            return
        dispatcher._cache_hits[sig] += 1
        if not cres.objectmode:
            dispatcher.targetctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
        dispatcher.add_overload(cres)


def _entries(loads: list) -> list[Entry]:
    """The run's loads as list entries, each once, in order (functions reachable by module and name only)."""
    entries, seen = [], set()
    for function, sig in loads:
        entry = (function.__module__, function.__qualname__, tuple(sig))
        if "<" not in entry[1] and entry not in seen:       # not a local function: <locals>, <lambda>
            seen.add(entry)
            entries.append(entry)
    return entries


def _list_file(block_types: Iterable[type]) -> Path | None:
    """The list file of these block types, in the folder where Numba caches this module's functions; None where
    there is none to write."""
    names = sorted({f"{cls.__module__}.{cls.__qualname__}" for cls in block_types})
    digest = hashlib.sha256("\n".join(names).encode()).hexdigest()[:16]
    folder = _cache_folder()
    return None if folder is None else folder / f"evsda-loads-{digest}.pickle"


def _cache_folder() -> Path | None:
    """The folder Numba's own locators choose for a function of this file (the first that can be written)."""
    from numba.core import caching

    for locator in (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator, caching.UserWideCacheLocator):
        found = locator.from_function(_cache_folder, __file__)
        if found is not None:
            return Path(found.get_cache_path())
    return None


def _read(path: Path) -> list[Entry]:
    """The list in ``path``; empty where there is none or it cannot be read."""
    import pickle

    try:
        with open(path, "rb") as file:
            kept = pickle.load(file)            # Numba's own cache files are pickles in the same folder
        if kept["format"] == _FORMAT:
            return [tuple(entry) for entry in kept["entries"]]
    except FileNotFoundError:
        pass
    except Exception as error:                  # noqa: BLE001 -- unreadable (another Numba's types, say): none
        log.debug("list of loads ahead not read: %s (%s)", path, error)
    return []


def _write(path: Path, entries: list[Entry]) -> None:
    """Write the list to ``path`` at once (a temporary file renamed over it); nothing where that fails."""
    import pickle
    import tempfile

    written = None
    try:
        with tempfile.NamedTemporaryFile("wb", dir=path.parent, prefix=path.name, delete=False) as file:
            written = file.name
            pickle.dump({"format": _FORMAT, "entries": entries}, file, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(written, path)
    except OSError as error:
        log.debug("list of loads ahead not kept: %s (%s)", path, error)
        if written is not None:
            Path(written).unlink(missing_ok=True)
