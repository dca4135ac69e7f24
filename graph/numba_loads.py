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

Each loaded function also brings the environments of the Numba implementations compiled into it (``np.sum``'s in
``numba.np.arraymath``, ...), rebuilt by ``numba.core.environment._rebuild_env`` with their module's globals: it
imports the module, and a run's loads import six of Numba's not imported otherwise (``numba.np.arraymath``,
``arrayobj``, ``linalg``, ``npyimpl``, ``numba.cpython.numbers``, ``numba.misc.literal``: 24 modules with what they
import, ~0.1 s CPU on the interpreter lock at the first load). Nopython code never reads an environment's globals
(only object mode's lowering does; its constants are the environment's ``consts``), and none of these modules adds a
symbol that machine code calls. :func:`lazy_registries` therefore gives the environment of a Numba module not yet
imported a stand-in namespace holding its name (what ``Environment.__reduce__`` and ``can_cache`` read) instead of
importing it: the same machine code and constants. A later compile in the process imports the modules itself (its
refresh). Only on the Numba versions checked and where ``_rebuild_env``'s source is Numba's as checked;
``EVSDA_LAZY_ENVIRONMENTS=off`` imports them as Numba does.

What a lazy load does need first, Numba's runtime, :func:`lazy_registries` starts setting up at once on a thread of
its own (:func:`_runtime_ahead`): that set-up compiles the runtime's functions with LLVM (~17 ms CPU, three quarters
of it in llvmlite's calls, which release the interpreter lock), at the first compiled call otherwise, in window 0
on the run's critical path. Started with the run (``run_graph``), it runs beside the run's set-up and first steps,
on the other core; the first load waits for it (Numba's compiler lock, which the set-up holds) or, where it failed,
sets the runtime up itself and meets the error. ``EVSDA_RUNTIME_AHEAD=off`` leaves it to the first load.

A load makes ~40 calls into LLVM's C API (the runtime's set-up ~270), each wrapped by Numba in two
``numba:llvm_lock`` events that only time compiles: :func:`lazy_registries` takes them off as compiles do
(:func:`.compile_ahead.quicker_llvm_calls`; ``EVSDA_QUICKER_LLVM_CALLS=off`` keeps them).
"""

from __future__ import annotations

import inspect
import sys
import threading

from .compile_ahead import attempted_edit, quicker_llvm_calls, switched_off
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

#: ``numba.core.environment._rebuild_env``'s source in the versions checked
_NUMBAS_REBUILD_ENV = '''def _rebuild_env(modname, consts, env_name):
    env = lookup_environment(env_name)
    if env is not None:
        return env

    mod = importlib.import_module(modname)
    env = Environment(mod.__dict__)
    env.consts[:] = consts
    env.env_name = env_name
    # Cache loaded object
    Environment._memo[env_name] = env
    return env
'''

_lazy: bool | None = None           # None: not tried; True: loads refresh nothing; False: Numba's loads


def lazy_registries() -> bool:
    """Make Numba's cached loads skip the compiler's registries (see the module docstring); whether they now do.

    Nothing is done (nor imported) while Numba is not imported: a process whose blocks do not use it does not
    import it here."""
    global _lazy
    if _lazy is None and "numba" in sys.modules:
        _lazy = attempted_edit(_edit_load, "Numba's cached loads left as they are")
        attempted_edit(_edit_environments, "Numba's environments rebuilt as Numba does")
        one_pass_symbols()                          # and read each loaded module's symbols in one pass
        kept_symbols()                              # or keep them beside the cache, the bitcode parsed to link
        quicker_llvm_calls()                        # and make each of its LLVM calls without Numba's two events
        if _lazy and not switched_off("EVSDA_RUNTIME_AHEAD"):
            _runtime_ahead()
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


def _edit_environments() -> bool:
    """Rebuild a loaded environment of a Numba module not yet imported without importing it (module docstring)."""
    import numba
    from numba.core import environment

    if numba.__version__ not in _CHECKED or switched_off("EVSDA_LAZY_ENVIRONMENTS"):
        return False
    numbas = environment._rebuild_env
    if inspect.getsource(numbas) != _NUMBAS_REBUILD_ENV:
        return False

    def _rebuild_env(modname, consts, env_name):
        if modname in sys.modules or not modname.startswith("numba."):
            return numbas(modname, consts, env_name)
        env = environment.lookup_environment(env_name)
        if env is not None:
            return env
        env = environment.Environment({"__name__": modname})       # the stand-in for the module's globals
        env.consts[:] = consts
        env.env_name = env_name
        environment.Environment._memo[env_name] = env
        return env

    # pickled by reference as Numba's (an environment's reducer names it): a cache written here loads anywhere as
    # Numba's own would, through whichever function is installed there
    _rebuild_env.__module__, _rebuild_env.__qualname__ = numbas.__module__, numbas.__qualname__
    environment._rebuild_env = _rebuild_env
    return True


def _runtime_ahead() -> None:
    """Set Numba's runtime up on a thread of its own (the module docstring). Not a daemon: the interpreter's exit
    waits for it rather than unloading LLVM under a call."""

    def set_up():
        try:
            from numba.core.registry import cpu_target

            _runtime(cpu_target.target_context)
        except Exception:       # noqa: BLE001 -- not set up: the first load sets it up itself and meets the error
            pass

    threading.Thread(target=set_up, name="evsda-numba-runtime").start()


def _runtime(target_context) -> None:
    """What cached machine code needs of Numba: its runtime, and the hash secret's symbols."""
    import numba.cpython.hashing  # noqa: F401 -- adds the interpreter's hash secret to LLVM's symbols
    from numba.core.runtime import nrt

    nrt.rtsys.initialize(target_context)
