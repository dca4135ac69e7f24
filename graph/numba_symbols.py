"""The symbols of Numba's cached compiled code read in one pass (issue 13: a run's start).

When Numba loads a cached function (``CPUCodeLibrary._unserialize``), it records the names that the library's
shared bitcode defines in ``JitEngine._load_defined_symbols``: every function and global variable of the module,
each one's name and whether it is a declaration read by its own llvmlite call. Each such call takes llvmlite's
LLVM lock, and Numba fires two of its events (``numba:llvm_lock``) at each take, so the walk costs ~4 llvmlite
calls and ~8 events a symbol, ~1 600 symbols over the optics' loads: interpreter-held Python at every run's start.

:func:`one_pass_symbols` makes ``_load_defined_symbols`` take the lock once for a module and call the same
LLVM functions of llvmlite's library (``LLVMPY_ModuleFunctionsIter``, ``LLVMPY_FunctionsIterNext``,
``LLVMPY_IsDeclaration``, ``LLVMPY_GetValueName``, and the globals' alike) directly: the same names, so the same
set, and nothing else changes. It applies only on the Numba and llvmlite versions checked, only where
``_load_defined_symbols``'s source is Numba's as checked; ``EVSDA_ONE_PASS_SYMBOLS=off`` leaves Numba as it is.
"""

from __future__ import annotations

import inspect
import sys

from .compile_ahead import attempted_edit, switched_off

#: the Numba and llvmlite versions whose ``JitEngine._load_defined_symbols`` and iterators were checked
_CHECKED = (("0.68.1", "0.50.0"),)

#: ``JitEngine._load_defined_symbols``'s source in the versions checked
_NUMBAS_WALK = '''    def _load_defined_symbols(self, mod):
        """Extract symbols from the module
        """
        for gsets in (mod.functions, mod.global_variables):
            self._defined_symbols |= {gv.name for gv in gsets
                                      if not gv.is_declaration}
'''

_one_pass: bool | None = None       # None: not tried; True: one pass a module; False: Numba's walk


def one_pass_symbols() -> bool:
    """Make Numba read a loaded module's defined symbols in one pass (see the module docstring); whether it now does.

    Nothing is done (nor imported) while Numba is not imported."""
    global _one_pass
    if _one_pass is None and "numba" in sys.modules:
        _one_pass = attempted_edit(_edit_walk, "Numba's symbol walk left as it is")
    return bool(_one_pass)


def defined_names(module) -> set[str]:
    """The names of the functions and global variables that the llvmlite ``module`` defines (not declares)."""
    from llvmlite.binding import ffi

    lib = ffi.lib
    walks = ((lib.LLVMPY_ModuleFunctionsIter, lib.LLVMPY_FunctionsIterNext, lib.LLVMPY_DisposeFunctionsIter),
             (lib.LLVMPY_ModuleGlobalsIter, lib.LLVMPY_GlobalsIterNext, lib.LLVMPY_DisposeGlobalsIter))
    declared, name_of = lib.LLVMPY_IsDeclaration._cfn, lib.LLVMPY_GetValueName._cfn
    names = set()
    with lib._lock:                              # llvmlite's LLVM lock, taken once for the module
        for start, step, dispose in walks:
            values = start._cfn(module)
            try:
                value = step._cfn(values)
                while value:
                    if not declared(value):
                        names.add(name_of(value).decode("utf-8"))
                    value = step._cfn(values)
            finally:
                dispose._cfn(values)
    return names


def _edit_walk() -> bool:
    import llvmlite
    import numba
    from numba.core.codegen import JitEngine

    if (numba.__version__, llvmlite.__version__) not in _CHECKED or switched_off("EVSDA_ONE_PASS_SYMBOLS"):
        return False
    numbas = JitEngine._load_defined_symbols
    if inspect.getsource(numbas) != _NUMBAS_WALK:
        return False

    def _load_defined_symbols(self, mod):
        self._defined_symbols |= defined_names(mod)

    _load_defined_symbols.__doc__ = numbas.__doc__
    _load_defined_symbols.__qualname__ = numbas.__qualname__
    JitEngine._load_defined_symbols = _load_defined_symbols
    return True
