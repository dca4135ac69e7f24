"""SciPy's array-API layer imported without what a run never reads (issue 13: import only what a run needs).

A run of the tracked pass imports SciPy with its blocks (the optics' ``scipy.fft``, ``scipy.special`` and
``scipy.linalg``, the pixels' ``scipy.constants``), and with any of them, on SciPy 1.17, its array-API layer
``scipy._lib._array_api``. Two parts of it are ~15 % of the instructions of the command line's import and the
graph's load together (callgrind, docs/speed.md):

* ``scipy._lib.array_api_compat.numpy`` clones NumPy's namespace (``from numpy import *`` and every name of
  ``dir(numpy)``), and NumPy 2 lists its lazily loaded submodules there, so the clone imports ``numpy.f2py``,
  ``numpy.testing``, ``numpy.ma``, ``numpy.char``, ... (and with them ``unittest``, ``difflib``,
  ``charset_normalizer``): ~6 %;
* ``xp_capabilities``, the decorator with which SciPy states each function's array backends, parses every decorated
  function's docstring (numpydoc's scraper) to add a table of them to it: ~95 functions at ``scipy.special``'s
  import, ~9 %.

:func:`lean_array_api` (the ``evsda`` command calls it before it loads a graph, a worker process before it imports
its block) has the first import of ``scipy._lib._array_api``, whenever something imports SciPy, made with those
submodules left out of NumPy's ``__all__`` and ``dir`` for that import only (the clone's namespace then lacks
``f2py``, ``testing``, ``ma``, ..., which are no array-API names; NumPy's own namespace is as before), and
``xp_capabilities`` then recording each function's capabilities as SciPy does, without rewriting its docstring. No
number changes: SciPy's functions are the same. Only on SciPy 1.17 and NumPy 2, only where SciPy's array-API layer
is not imported yet; ``EVSDA_LEAN_SCIPY=off`` leaves SciPy's import as it is. A process that imports no SciPy pays
nothing (the finder waits for the import).
"""

from __future__ import annotations

import importlib.machinery
import logging
import sys

from .compile_ahead import switched_off

log = logging.getLogger(__name__)

#: the SciPy versions whose array-API layer was checked (``array_api_compat.numpy``'s clone, ``xp_capabilities``)
_CHECKED = ("1.17.",)
#: NumPy's lazily loaded submodules that its ``__all__`` and ``dir`` name and no array-API code reads
LEFT_OUT = ("f2py", "testing", "ma", "char", "rec", "matlib", "ctypeslib", "polynomial", "typing", "strings", "core")
ARRAY_API = "scipy._lib._array_api"


def lean_array_api() -> bool:
    """Have SciPy's array-API layer imported lean (the module docstring) when it is first imported; whether it
    will be."""
    if switched_off("EVSDA_LEAN_SCIPY") or ARRAY_API in sys.modules or any(
            isinstance(finder, _LeanArrayApi) for finder in sys.meta_path):
        return False
    import numpy as np
    scipy_version = installed_version("scipy")
    if scipy_version is None or not scipy_version.startswith(_CHECKED) or not np.__version__.startswith("2."):
        return False
    sys.meta_path.insert(0, _LeanArrayApi())
    return True


def installed_version(distribution: str) -> str | None:
    """The installed version of ``distribution`` (its metadata's ``Version`` field), or None where it is not installed.

    ``importlib.metadata.version`` parses the whole metadata file with the e-mail parser: SciPy's is 62 KB with its
    long description, 2.8-3.0 ms of CPU at every start; the field is in the header (the lines before the first blank
    one, core metadata's RFC 822 form), which is all that is read here: 0.5-0.9 ms."""
    from importlib.metadata import PackageNotFoundError, distribution as installed

    try:
        found = installed(distribution)
    except PackageNotFoundError:
        return None
    text = found.read_text("METADATA") or found.read_text("PKG-INFO") or ""
    for line in text.split("\n\n", 1)[0].splitlines():
        field, _, value = line.partition(":")
        if field.strip().lower() == "version":
            return value.strip()
    return None


class _LeanArrayApi:
    """An import finder that hands ``scipy._lib._array_api`` to :class:`_LeanLoader`, once."""

    def find_spec(self, name, path, target=None):
        if name != ARRAY_API:
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _LeanLoader(spec.loader)
        return spec


class _LeanLoader:
    """SciPy's loader of its array-API layer, run with NumPy's lazy submodules out of sight, then
    ``xp_capabilities`` recording without docstrings."""

    def __init__(self, loader):
        self.loader = loader

    def __getattr__(self, name):            # get_source, get_filename, ...: SciPy's loader's
        return getattr(self.loader, name)

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        import numpy as np
        names, listing = np.__all__, np.__dir__
        hidden = {name for name in LEFT_OUT if f"numpy.{name}" not in sys.modules}
        np.__all__ = [name for name in names if name not in hidden]
        np.__dir__ = lambda: [name for name in listing() if name not in hidden]
        try:
            self.loader.exec_module(module)
        finally:
            np.__all__, np.__dir__ = names, listing
        module.xp_capabilities = _recording_only(module.xp_capabilities)


def _recording_only(xp_capabilities):
    """``xp_capabilities`` that records a function's capabilities in SciPy's table as SciPy does (the same
    dictionary) and leaves its docstring; SciPy's own where its decorator is not as checked."""
    def decorator_factory(**options):
        decorate = xp_capabilities(**options)
        cells = dict(zip(decorate.__code__.co_freevars, decorate.__closure__ or ()))
        if "capabilities" not in cells or "capabilities_table" not in cells:
            return decorate
        capabilities, table = cells["capabilities"].cell_contents, cells["capabilities_table"].cell_contents

        def record(f):
            table[f] = capabilities
            return f
        return record
    decorator_factory.__doc__ = xp_capabilities.__doc__
    return decorator_factory
