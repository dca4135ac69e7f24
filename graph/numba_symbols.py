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

Before that walk, ``_unserialize`` parses the library's shared bitcode (``llvmlite.binding.parse_bitcode``, ~6 ms
a library, ~0.1 s CPU over a run's loads). A cached run needs only its names: the module itself is read again only
to link the library into a new compile (``CPUCodeLibrary._get_module_for_linking``). :func:`kept_symbols` makes
``_unserialize`` keep the names in a small file beside Numba's cache files, named by a digest of the bitcode (and
llvmlite's version), the first time it loads a library, and read them from there afterwards instead of parsing; the
bitcode is then parsed at the first link, if any. The same names, read from the same module, go to the same set,
and the same object code is loaded. It applies only to loads through :mod:`.numba_loads`' ``load_overload`` (which
says where the cache is), on the versions checked, where ``_unserialize``'s source is Numba's as checked;
``EVSDA_KEPT_SYMBOLS=off`` leaves Numba as it is.
"""

from __future__ import annotations

import contextlib
import hashlib
import inspect
import json
import os
import sys
import tempfile
import threading

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

#: ``CPUCodeLibrary._unserialize``'s source in the versions checked
_NUMBAS_UNSERIALIZE = '''    @classmethod
    def _unserialize(cls, codegen, state):
        name, kind, data = state
        self = codegen.create_library(name)
        assert isinstance(self, cls)
        if kind == 'bitcode':
            # No need to re-run optimizations, just make the module ready
            self._final_module = ll.parse_bitcode(data)
            self._finalize_final_module()
            return self
        elif kind == 'object':
            object_code, shared_bitcode = data
            self.enable_object_caching()
            self._set_compiled_object(object_code)
            self._shared_module = ll.parse_bitcode(shared_bitcode)
            self._finalize_final_module()
            # Load symbols from cache
            self._codegen._engine._load_defined_symbols(self._shared_module)
            return self
        else:
            raise ValueError("unsupported serialization kind %r" % (kind,))
'''

#: the lines by which ``CPUCodeLibrary._get_module_for_linking`` returns the shared module, in the versions checked
_NUMBAS_LINKING = ("        if self._shared_module is not None:\n            return self._shared_module\n")

_one_pass: bool | None = None       # None: not tried; True: one pass a module; False: Numba's walk
_kept: bool | None = None           # None: not tried; True: names kept beside the cache; False: Numba's parse
_beside = threading.local()         # .folder: the cache folder of the load under way on this thread (or None)


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


def kept_symbols() -> bool:
    """Make Numba's cached loads keep each library's defined names beside its cache and parse its bitcode only to
    link it (see the module docstring); whether they now do. Nothing is done (nor imported) while Numba is not
    imported."""
    global _kept
    if _kept is None and "numba" in sys.modules:
        _kept = attempted_edit(_edit_unserialize, "Numba's loads parse their bitcode as they are")
    return bool(_kept)


@contextlib.contextmanager
def names_beside(folder: str):
    """Keep the names of the libraries loaded on this thread within the block in ``folder`` (a cache folder)."""
    before = getattr(_beside, "folder", None)
    _beside.folder = folder
    try:
        yield
    finally:
        _beside.folder = before


def names_file(folder: str, bitcode: bytes) -> str:
    """Where the defined names of a library with this shared ``bitcode`` are kept in ``folder``: named by a digest of
    the bitcode and of llvmlite's version."""
    import llvmlite

    digest = hashlib.blake2b(llvmlite.__version__.encode(), digest_size=20)
    digest.update(bitcode)
    return os.path.join(folder, f"defined-{digest.hexdigest()}.json")


def read_names(path: str) -> set[str] | None:
    """The names kept at ``path``; None where there are none (or they cannot be read)."""
    try:
        with open(path, "rb") as file:
            names = json.loads(file.read())
    except (OSError, ValueError):
        return None
    return set(names) if isinstance(names, list) and all(isinstance(n, str) for n in names) else None


def keep_names(path: str, names: set[str]) -> None:
    """Write ``names`` to ``path`` whole or not at all (a temporary file renamed); nothing where that fails."""
    try:
        handle, temporary = tempfile.mkstemp(dir=os.path.dirname(path), prefix=".defined-", suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(handle, "w") as file:
            json.dump(sorted(names), file)
        os.replace(temporary, path)
    except OSError:
        with contextlib.suppress(OSError):
            os.unlink(temporary)


def _edit_unserialize() -> bool:
    import llvmlite
    import numba
    from numba.core import codegen
    from numba.core.codegen import CPUCodeLibrary

    if (numba.__version__, llvmlite.__version__) not in _CHECKED or switched_off("EVSDA_KEPT_SYMBOLS"):
        return False
    numbas, linking = CPUCodeLibrary._unserialize, CPUCodeLibrary._get_module_for_linking
    if inspect.getsource(numbas) != _NUMBAS_UNSERIALIZE or _NUMBAS_LINKING not in inspect.getsource(linking):
        return False

    def _unserialize(cls, codegen_, state):
        folder = getattr(_beside, "folder", None)
        name, kind, data = state
        if kind != "object" or folder is None:
            return numbas.__func__(cls, codegen_, state)
        object_code, shared_bitcode = data
        self = codegen_.create_library(name)
        assert isinstance(self, cls)
        self.enable_object_caching()
        self._set_compiled_object(object_code)
        path = names_file(folder, shared_bitcode)
        names = read_names(path)
        if names is None:
            self._shared_module = codegen.ll.parse_bitcode(shared_bitcode)
        else:
            self._unparsed_bitcode = shared_bitcode         # parsed at the first link (_get_module_for_linking)
        self._finalize_final_module()
        if names is None:
            self._codegen._engine._load_defined_symbols(self._shared_module)
            keep_names(path, defined_names(self._shared_module))
        else:
            self._codegen._engine._defined_symbols |= names
        return self

    def _get_module_for_linking(self):
        bitcode = self.__dict__.pop("_unparsed_bitcode", None)
        if bitcode is not None:
            self._shared_module = codegen.ll.parse_bitcode(bitcode)
        return linking(self)

    _unserialize.__doc__, _unserialize.__qualname__ = numbas.__doc__, numbas.__qualname__
    _get_module_for_linking.__doc__, _get_module_for_linking.__qualname__ = linking.__doc__, linking.__qualname__
    CPUCodeLibrary._unserialize = classmethod(_unserialize)
    CPUCodeLibrary._get_module_for_linking = _get_module_for_linking
    return True
