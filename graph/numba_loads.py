"""Numba's cached compiled code loaded without setting up its compiler first (issue 13: a run's start).

Numba loads a cached compiled function in ``numba.core.caching.Cache.load_overload``, which first calls
``target_context.refresh()``. That imports about a hundred of Numba's modules (its implementations of NumPy, the
typed containers, jitclass, ...) and installs their typing and lowering registries: ~0.25 s CPU at a process's
first load, paid by every run on the interpreter lock before its first compiled call. A cached function needs
none of it: its machine code is made, and the registries are read only to type and lower new code, which every
compile refreshes first itself (``numba.core.compiler.CompilerBase.__init__``; lowering also at its first lookup,
``BaseContext.get_function``). What a load does need is Numba's runtime (NRT, whose allocation functions the code
calls: ``rtsys.initialize``) and the symbols that modules add to LLVM's symbol table when they are imported; of
the modules ``refresh`` imports in Numba 0.68.1 only ``numba.cpython.hashing`` does (the interpreter's hash
secret).

:func:`lazy_registries` makes ``load_overload`` take just those two and then load as Numba does: the same machine
code runs, so every result is the same. Its loads name their cache folder to :mod:`.numba_symbols`, which keeps each
library's defined names there (:func:`.numba_symbols.kept_symbols`). It applies only on the Numba versions checked,
only where ``load_overload``'s source is Numba's as checked, and only for Numba's CPU target;
``EVSDA_LAZY_REGISTRIES=off`` leaves Numba as it is.
"""

from __future__ import annotations

import inspect
import sys

from .compile_ahead import attempted_edit, switched_off
from .numba_symbols import kept_symbols, names_beside, one_pass_symbols

#: the Numba versions whose ``Cache.load_overload`` and ``refresh`` were checked
_CHECKED = ("0.68.1",)

#: ``Cache.load_overload``'s source in the versions checked
_NUMBAS_LOAD = '''    def load_overload(self, sig, target_context):
        """
        Load and recreate the cached object for the given signature,
        using the *target_context*.
        """
        # Refresh the context to ensure it is initialized
        target_context.refresh()
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
        # None returned if the `with` block swallows an exception
'''

_lazy: bool | None = None           # None: not tried; True: loads refresh nothing; False: Numba's loads


def lazy_registries() -> bool:
    """Make Numba's cached loads skip the compiler's registries (see the module docstring); whether they now do.

    Nothing is done (nor imported) while Numba is not imported: a process whose blocks do not use it does not
    import it here."""
    global _lazy
    if _lazy is None and "numba" in sys.modules:
        _lazy = attempted_edit(_edit_load, "Numba's cached loads left as they are")
        one_pass_symbols()                          # and read each loaded module's symbols in one pass
        kept_symbols()                              # or keep them beside the cache, the bitcode parsed to link
    return bool(_lazy)


def _edit_load() -> bool:
    import numba
    from numba.core import caching
    from numba.core.cpu import CPUContext

    if numba.__version__ not in _CHECKED or switched_off("EVSDA_LAZY_REGISTRIES"):
        return False
    numbas = caching.Cache.load_overload
    if inspect.getsource(numbas) != _NUMBAS_LOAD:
        return False

    def load_overload(self, sig, target_context):
        if type(target_context) is not CPUContext:
            return numbas(self, sig, target_context)
        _runtime(target_context)
        with self._guard_against_spurious_io_errors(), names_beside(self._cache_path):
            return self._load_overload(sig, target_context)

    load_overload.__doc__ = numbas.__doc__
    load_overload.__qualname__ = numbas.__qualname__
    caching.Cache.load_overload = load_overload
    return True


def _runtime(target_context) -> None:
    """What cached machine code needs of Numba: its runtime, and the hash secret's symbols."""
    import numba.cpython.hashing  # noqa: F401 -- adds the interpreter's hash secret to LLVM's symbols
    from numba.core.runtime import nrt

    nrt.rtsys.initialize(target_context)
