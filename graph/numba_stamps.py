"""Numba's cache stamped by a package's sources, not by one file's (issue 13: stale compiled code).

Numba keeps a cached compiled function while the file that defines it is unchanged: the stamp in its cache index is
a hash of that file's bytes (``numba.core.caching._SourceFileBackedLocatorMixin.get_source_stamp``), and the
index key a hash of the function's own bytecode. What the machine code also holds is not looked at: the functions
it calls or inlines from other files, and the constants it imports from them. A development checkout that changes
only ``blocks/pixel/own_sweep.py`` or ``crossing.py`` kept running the old sweep that ``deferred.take_and_run``
compiled into its own code, silently.

:func:`stamp_packages` puts :class:`PackageStamped` first in Numba's cache locators
(``numba.core.caching.CacheImpl._locator_classes``) for the functions of the packages named: the same cache folder
and file names as Numba's own locator, but the stamp is :func:`folder_digest` of the folder that holds the
function's file, a hash of every ``.py`` file in it. Any change to a file of the package compiles its cached
functions again at their next call; an unchanged tree (an installed package, a later run) loads them from the
cache as before, since the digest is of the files' bytes, not their times. The compiled code of each of evsda's
packages reads only its own folder's code and constants (``tests/framework/test_framework_numba_stamps.py``
checks that every compiled function's global names come from its own folder or from outside evsda).

It applies only on the Numba versions checked, where ``CacheImpl.__init__`` takes the locators from that list (and
``NUMBA_CACHE_LOCATOR_CLASSES`` is not set), and for functions in a plain folder (not a zip file, not a frozen
application); ``EVSDA_PACKAGE_STAMPS=off`` leaves Numba's stamps (the cached functions then compile once, as after
any change of stamp, and again when it is switched back on).
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.util
import linecache
import os
import sys
import threading

from .compile_ahead import attempted_edit, switched_off

#: the Numba versions whose cache locators and their use in ``CacheImpl.__init__`` were checked
_CHECKED = ("0.68.1",)

#: Numba's locators in the versions checked, in their order
_NUMBAS = ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator", "IPythonCacheLocator",
           "ZipCacheLocator")

#: the lines of ``CacheImpl.__init__`` that choose a locator from the list, in the versions checked
_NUMBAS_CHOICE = ("            locator_classes = self._locator_classes\n",
                  "            locator = cls.from_function(py_func, source_path)\n")

#: Numba's locators that read the function's own file (the ones :class:`PackageStamped` wraps)
_FILE_BACKED = ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator")

_packages: set[str] = set()          # the packages whose functions are stamped by their folder
_stamped: bool | None = None         # None: not tried; True: Numba's cache uses PackageStamped; False: Numba's own
_lock = threading.Lock()


def stamp_packages(*packages: str) -> None:
    """Stamp the cached compiled functions of ``packages`` (and of their sub-packages) by their folder's sources.

    Numba is not imported here: where it is not imported yet, the locator goes in as soon as it is (before any
    function of the packages is decorated, as long as this is called before they are imported)."""
    with _lock:
        _packages.update(packages)
        if _stamped is None and "numba" in sys.modules:
            _install()
        elif _stamped is None and not any(isinstance(finder, _AfterNumba) for finder in sys.meta_path):
            sys.meta_path.insert(0, _AfterNumba())


def stamped() -> bool:
    """Whether Numba's cache stamps the packages' functions by their folder (False: not yet, or Numba's own stamps)."""
    return bool(_stamped)


def _install() -> None:
    global _stamped
    _stamped = attempted_edit(_edit_locators, "Numba's cache stamps left as they are")


def _edit_locators() -> bool:
    import numba
    from numba.core import caching, config

    if numba.__version__ not in _CHECKED or switched_off("EVSDA_PACKAGE_STAMPS") or config.CACHE_LOCATOR_CLASSES:
        return False
    numbas = caching.CacheImpl._locator_classes
    choice = _source(caching.CacheImpl.__init__)
    if [locator.__name__ for locator in numbas] != list(_NUMBAS) or any(choice.count(line) != 1 for line in _NUMBAS_CHOICE):
        return False
    PackageStamped.wrapped = tuple(locator for locator in numbas if locator.__name__ in _FILE_BACKED)
    caching.CacheImpl._locator_classes = [PackageStamped, *numbas]
    return True


def _source(function) -> str:
    """``function``'s lines in its file (what ``inspect.getsource`` reads, without its search of the modules)."""
    code = function.__code__
    last = max(line for _, _, line in code.co_lines() if line is not None)
    return "".join(linecache.getlines(code.co_filename)[code.co_firstlineno - 1:last])


class _AfterNumba(importlib.abc.MetaPathFinder):
    """Puts the locator in once Numba's package has been imported (then leaves ``sys.meta_path``)."""

    def find_spec(self, name, path, target=None):
        if name != "numba":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        numbas_exec = spec.loader.exec_module

        def exec_module(module):
            numbas_exec(module)
            with _lock:
                if _stamped is None:
                    _install()

        try:
            spec.loader.exec_module = exec_module
        except AttributeError:                       # a loader that takes no attribute: stamp_packages' next call
            pass
        return spec


class PackageStamped:
    """A Numba cache locator: Numba's own (the same cache folder and names) whose stamp is :func:`folder_digest` of
    the folder that holds the function's file; for the functions of the packages given to :func:`stamp_packages`."""

    wrapped: tuple = ()              # Numba's file-backed locators, in Numba's order

    def __init__(self, numbas, folder: str, spec):
        self._numbas = numbas
        self._folder = folder
        self._spec = spec                        # the module's import (its listing of the folder is shared)
        self._py_file = numbas._py_file          # read by Numba's warning on a function it cannot cache

    @classmethod
    def from_function(cls, py_func, py_file):
        """The locator for ``py_func`` (defined in ``py_file``), or None: Numba's own locators then choose."""
        module = getattr(py_func, "__module__", None) or ""
        if getattr(sys, "frozen", False) or not any(module == p or module.startswith(p + ".") for p in _packages):
            return None
        folder = os.path.dirname(os.path.abspath(py_file))
        if not os.path.isdir(folder):
            return None
        for numbas in cls.wrapped:
            locator = _numbas_locator(numbas, py_func, py_file)
            if locator is not None:
                return cls(locator, folder, py_func.__globals__.get("__spec__"))
        return None

    def ensure_cache_path(self):
        self._numbas.ensure_cache_path()

    def get_cache_path(self):
        return self._numbas.get_cache_path()

    def get_disambiguator(self):
        return self._numbas.get_disambiguator()

    def get_source_stamp(self):
        """``("package", digest)`` of the folder's sources; Numba's stamp of the file where the folder cannot be read."""
        try:
            return ("package", _import_digest(self._folder, self._spec))
        except OSError:
            return self._numbas.get_source_stamp()


_checked: dict[tuple[type, str], str] = {}          # (Numba's locator, source file) -> the cache folder it checked


def _numbas_locator(numbas: type, py_func, py_file: str):
    """``numbas.from_function(py_func, py_file)``: Numba's locator for the function, or None.

    Numba checks for every function that its cache folder can be written (the folder made, and a temporary file
    created and dropped in it: ~0.1 ms on a virtual machine's file system, ~15 ms over the 163 compiled functions
    a run of the tracked pass decorates). A module's functions share their file and so their folder: the check is
    made for the file's first function, and its others are located in the folder it checked (still checked again
    where Numba saves: ``ensure_cache_path``)."""
    checked = _checked.get((numbas, py_file))
    if checked is not None:
        locator = numbas(py_func, py_file)
        if locator.get_cache_path() == checked:
            return locator
    locator = numbas.from_function(py_func, py_file)
    if locator is not None:
        _checked[numbas, py_file] = locator.get_cache_path()
    return locator


_imports: dict[str, tuple[object, str]] = {}         # folder -> (the last module import to read it, its digest)


def _import_digest(folder: str, spec) -> str:
    """:func:`folder_digest`, read once per import of a module (a module's functions are decorated one after the
    other; a reload or the next module reads the folder again)."""
    known = _imports.get(folder)
    if spec is not None and known is not None and known[0] is spec:
        return known[1]
    digest = folder_digest(folder)
    _imports[folder] = spec, digest
    return digest


_digests: dict[str, tuple[tuple, str]] = {}         # folder -> (its .py files' names, times and sizes; their digest)


def folder_digest(folder: str) -> str:
    """SHA-256 (hex) of the names and bytes of every ``.py`` file in ``folder`` (not its sub-folders).

    The files are read again only when one's name, modification time or size differs from the last call's (one
    listing of the folder a call)."""
    with os.scandir(folder) as entries:
        key = sorted([(entry.name, stat.st_mtime_ns, stat.st_size) for entry in entries
                      if entry.name.endswith(".py") and entry.is_file() and (stat := entry.stat())])
    known = _digests.get(folder)
    if known is not None and known[0] == key:
        return known[1]
    digest = hashlib.sha256()
    for name, _, _ in key:
        with open(os.path.join(folder, name), "rb") as source:
            digest.update(name.encode() + b"\0" + hashlib.sha256(source.read()).digest())
    _digests[folder] = key, digest.hexdigest()
    return digest.hexdigest()
