"""Numba's first compiles on both cores: a block's compiled loops built ahead in a child process and in this one.

A run with an empty Numba cache (a user's first run after an install, CI, a new machine) compiles every
compiled loop before it first runs, and Numba compiles under one lock, so a process compiles on one core
while the other waits. :func:`start` hands a block's compile tasks (its cached loops, each with the argument types
a run calls it with) to a fresh interpreter, which compiles them in their order and writes them to the same on-disk
cache (``NUMBA_CACHE_DIR``, or Numba's folder beside the sources) while this process compiles the blocks that run
first. The block calls :meth:`Ahead.wait` before it first calls its loops: this process, done with its own compiles
by then, takes the tasks the child has not begun from the end of the list and compiles them itself (each task is
claimed once, by whichever process creates its file in a shared folder first), then waits for the child; Numba
loads the child's loops from the cache instead of compiling them. The compiled code, and so every result, is the
same whoever compiles a loop.

A child starts only when none of the named modules' cached loops has a signature cached for its current
source (reading their cache indexes takes milliseconds: later runs start no child), when the run may use
more than one thread (``EVSDA_THREADS``), and unless ``EVSDA_COMPILE_AHEAD=off``. One child at a time per
task list. A child that fails costs nothing but its time: the block then compiles what it needs itself.

Wherever the loops are compiled (the child, or this process when no child starts), :func:`quicker_inlining`
first takes out a copying cost of Numba's inliner (``inline="always"``, which the pixels' vectorised loops use):
the same compiled code, in less time (``EVSDA_QUICKER_INLINING=off``: Numba's own), and :func:`quicker_typing`
two costs of its typing that decide nothing (``EVSDA_QUICKER_TYPING=off``: Numba's own), and
:func:`quicker_llvm_calls` Numba's events around each call into LLVM (``EVSDA_QUICKER_LLVM_CALLS=off``: Numba's own),
and :func:`quicker_ir_walks` a call per leaf of Numba's walk for an IR statement's variables
(``EVSDA_QUICKER_IR_WALKS=off``: Numba's own), and :func:`inlinees_once` builds an inlined function's IR once per
compile context rather than at each of its call sites (``EVSDA_INLINEES_ONCE=off``: Numba's own), and
:func:`call_types_once` types a call of a function once per argument types (``EVSDA_CALL_TYPES_ONCE=off``: Numba's own).
"""

from __future__ import annotations

import atexit
import importlib
import inspect
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable

from .threads import usable_cores

log = logging.getLogger(__name__)

#: longest wait for a child before this process compiles on its own [s]
WAIT_LIMIT_S = 600.0

_CHILD = r"""
import json, os, sys, threading, time
parent, path, tasks, claims = json.loads(sys.argv[1])

def orphaned():                    # the run ended without stopping this child (killed): end with it
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(0)

threading.Thread(target=orphaned, daemon=True).start()
sys.path[:] = path
from evsda.graph.compile_ahead import compile_claimed, quicker_compiles
quicker_compiles()
compile_claimed(tasks, claims, range(len(tasks)))
"""

#: a compile task: ``("package.module:function", "argument types")``, the types as Numba spells them in a signature
#: (``"f8[:, ::1], i8, b1"``; one type with a trailing comma)
Task = tuple[str, str]

_started: dict[tuple[Task, ...], Ahead] = {}          # task list -> its child (one per list in this process)
_lock = threading.Lock()


class Ahead:
    """A child process compiling a block's tasks; :meth:`wait` takes the tasks it has not begun and returns once it
    has ended (at once if none)."""

    def __init__(self, process: subprocess.Popen | None, tasks: tuple[Task, ...] = (), claims: str | None = None):
        self.process = process
        self.started = process is not None
        self.tasks, self.claims = tasks, claims
        self._lock = threading.Lock()          # blocks that share the child wait for it together

    def wait(self) -> None:
        """Compile here the tasks the child has not claimed, last first, then wait for the child (the cached loops
        are then all written); kill it after ``WAIT_LIMIT_S``."""
        with self._lock:
            process, self.process = self.process, None
            if process is None:
                return
            if process.poll() is None:
                compile_claimed(self.tasks, self.claims, reversed(range(len(self.tasks))))
            try:
                process.wait(timeout=WAIT_LIMIT_S)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            if process.returncode:
                log.info("compiling ahead ended with status %s; the block compiles what it needs itself",
                         process.returncode)
            _remove(self.claims)


def start(tasks: tuple[Task, ...], modules: tuple[str, ...]) -> Ahead:
    """Compile ``tasks`` in a child process (and in this one at :meth:`Ahead.wait`) when none of ``modules``'
    cached loops is in the Numba cache; an :class:`Ahead` to wait on either way."""
    tasks = tuple(map(tuple, tasks))
    with _lock:
        if tasks in _started:
            return _started[tasks]
        if _cached(modules):
            return Ahead(None)
        quicker_compiles()                       # this process compiles too (some, or all of them without a child)
        if not _wanted():
            return Ahead(None)
        env = dict(os.environ, EVSDA_COMPILE_AHEAD="off", EVSDA_THREADS="1", OPENBLAS_NUM_THREADS="1")
        claims = tempfile.mkdtemp(prefix="evsda-claims-")
        try:
            process = subprocess.Popen([sys.executable, "-c", _CHILD,
                                        json.dumps([os.getpid(), sys.path, tasks, claims])],
                                       env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL, close_fds=True)
        except OSError as error:
            log.info("cannot compile ahead (%s)", error)
            _remove(claims)
            return Ahead(None)
        atexit.register(_end, process, claims)
        _started[tasks] = ahead = Ahead(process, tasks, claims)
        return ahead


def quicker_compiles() -> None:
    """Numba's compiles without the costs that decide nothing (each edit below, where it is not switched off)."""
    quicker_inlining()
    quicker_typing()
    quicker_llvm_calls()
    quicker_ir_walks()
    inlinees_once()
    call_types_once()


def compile_claimed(tasks: tuple[Task, ...], claims: str, order) -> None:
    """Compile each task of ``tasks``, in ``order`` (indexes), that this process claims first in the folder
    ``claims``; a task that fails is left to the block's own call."""
    for index in order:
        if not _claimed(claims, index):
            continue
        function, types = tasks[index]
        try:
            _compile(function, types)
        except Exception as error:                 # noqa: BLE001 -- the block compiles it itself when it calls it
            log.info("compiling %s ahead failed (%s)", function, error)


def _claimed(claims: str, index: int) -> bool:
    """Whether this process is the first to claim task ``index`` (its file created in ``claims``)."""
    try:
        os.close(os.open(os.path.join(claims, str(index)), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except OSError:                                # claimed by the other process (or the folder is gone)
        return False
    return True


def _compile(function: str, types: str) -> None:
    """Compile (or load from the cache) the dispatcher ``function`` for the argument types ``types``: what its
    first call with arguments of those types compiles, under the same cache key."""
    from numba.core.sigutils import normalize_signature
    module, name = function.split(":")
    dispatcher = getattr(importlib.import_module(module), name)
    arguments, _ = normalize_signature(types)
    dispatcher.compile(tuple(arguments))


def _remove(claims: str | None) -> None:
    if claims is not None:
        shutil.rmtree(claims, ignore_errors=True)


def _wanted() -> bool:
    if switched_off("EVSDA_COMPILE_AHEAD"):
        return False
    try:
        return usable_cores() > 1
    except ValueError:
        return False


def switched_off(variable: str) -> bool:
    """Whether the environment variable ``variable`` says off (``off``, ``0``, ``no``, ``false``)."""
    return os.environ.get(variable, "").strip().lower() in ("off", "0", "no", "false")


def attempted_edit(edit: Callable[[], bool], unedited: str) -> bool:
    """What ``edit`` of Numba returns, or False (logged with ``unedited``) where it fails: Numba then stays as it is."""
    try:
        return edit()
    except Exception as error:                     # noqa: BLE001 -- Numba's own code stays
        log.info("%s (%s)", unedited, error)
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


def _end(process: subprocess.Popen, claims: str) -> None:
    """At exit: a child still compiling is stopped (a half-written cache entry is never visible: Numba
    writes each file whole and renames it), and its claims' folder removed."""
    if process.poll() is None:
        process.kill()
        process.wait()
    _remove(claims)


# -- Numba's inliner, copying less ---------------------------------------------------------------------------

#: the Numba versions whose inliner :func:`quicker_inlining` was checked on (the same machine code); others keep theirs
_INLINER_CHECKED = ("0.68.1",)

#: the edits of ``InlineWorker.inline_ir``'s source: (Numba's lines, ours)
_INLINER_EDITS = (
    ("""            for block_label, block in the_ir.blocks.items():
                new_block = copy.deepcopy(the_ir.blocks[block_label])
""", """            memo = {}
            for block_label, block in the_ir.blocks.items():
                new_block = copy.deepcopy(the_ir.blocks[block_label], memo)
"""),
    ("""        callee_ir_original = copy_ir(callee_ir)
""", """        callee_ir_original = callee_ir
"""),
)

_inliner: bool | None = None           # None: not tried; True: Numba's inliner edited; False: left as it is


def quicker_inlining() -> bool:
    """Make Numba's inliner copy a callee's IR once per inlined call, not once per block and then again; whether
    it now does (False: this Numba's inliner is not the one checked, and it is left as it is).

    Each call of an ``inline="always"`` function is replaced by a copy of the callee's IR
    (``numba.core.inline_closurecall.InlineWorker.inline_ir``). Numba 0.68 deep-copies the IR block by block, each
    block with its own ``copy.deepcopy`` memo, so that every block copies the callee's whole variable scope (all its
    variables, those of its own inlined callees included: blocks x variables), and then copies the result again
    as an unchanged copy to return, which both of Numba's callers drop (``untyped_passes.InlineInlinables``,
    ``typed_passes.InlineOverloads``; numba#8989, numba-cuda#688). Here the blocks are copied with one memo (the
    scope once; the copy's blocks share it, as the callee's own blocks do) and the copy is returned. The inlined
    IR is the same, and so is the compiled code: each of the 35 machine-code objects a pixel block caches
    disassembles to the same instructions (symbol numbering aside). The pixels' first compile takes ~6 s less
    CPU (docs/speed.md). The method is rebuilt from its own source with the edits, only on the Numba versions
    checked and where each of Numba's lines is found once as it is; it stays so for the process.
    ``EVSDA_QUICKER_INLINING=off`` leaves Numba's inliner as it is.
    """
    global _inliner
    if _inliner is None:
        _inliner = attempted_edit(_edit_inliner, "Numba's inliner left as it is")
    return _inliner


def _edit_inliner() -> bool:
    import numba
    from numba.core import inline_closurecall
    from numba.core.compiler_lock import global_compiler_lock

    if numba.__version__ not in _INLINER_CHECKED or switched_off("EVSDA_QUICKER_INLINING"):
        return False
    method = inline_closurecall.InlineWorker.inline_ir
    source = inspect.getsource(method)
    for numbas, ours in _INLINER_EDITS:
        if source.count(numbas) != 1:
            return False
        source = source.replace(numbas, ours)
    indent = len(source) - len(source.lstrip())       # the method's source as a module-level function
    source = "".join(line[indent:] for line in source.splitlines(keepends=True))
    namespace = dict(vars(inline_closurecall))
    exec(compile(source, inspect.getsourcefile(method), "exec"), namespace)       # noqa: S102
    edited = namespace[method.__name__]
    edited.__qualname__ = method.__qualname__
    with global_compiler_lock:
        inline_closurecall.InlineWorker.inline_ir = edited
    return True


# -- Numba's typing, without its idle work -------------------------------------------------------------------

#: the Numba versions whose typing :func:`quicker_typing` was checked on (the same machine code); others keep theirs
_TYPING_CHECKED = ("0.68.1",)

_typing: bool | None = None            # None: not tried; True: Numba's typing edited; False: left as it is


def quicker_typing() -> bool:
    """Take two costs out of Numba's typing that decide nothing; whether they are now out (False: this Numba is not
    the one checked, and it is left as it is).

    * The compiler flags (``numba.core.targetconfig.TargetConfig``) are part of the key of every overload's cache of
      implementations (``typing.templates._OverloadFunctionTemplate._get_impl``): each call site typed hashes them and
      compares them with the keys found, and both read each of the 22 options through its property into a dict
      (``values``; ~300 000 times in the main job's first run, ~1.5 s of CPU). The dict is now read straight from the
      set values and a per-class tuple of the defaults; the hash, ``hash(tuple(sorted(values())))``, sorts the dict's
      keys, the option names, so it is the same for every instance of a class and is computed once per class; and a
      flags object equals itself without reading its values. Same dicts, same hashes, same equalities: the same
      overloads are found.
    * Each failed match of a call against a typing template formats its error message (kept, in case no template
      matches), and with ``colorama`` installed Numba highlights it, re-initialising ``colorama`` (which wraps
      ``sys.stdout`` and ``sys.stderr`` again) per message part (~60 000 in that run, ~0.5 s). The messages are now
      left plain, as ``NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING`` makes them (Numba's default colour scheme
      only makes them bold).

    Only on the Numba versions checked; it stays so for the process. ``EVSDA_QUICKER_TYPING=off`` leaves Numba as it is.
    """
    global _typing
    if _typing is None:
        _typing = attempted_edit(_edit_typing, "Numba's typing left as it is")
    return _typing


def _edit_typing() -> bool:
    import numba
    from numba.core import errors, targetconfig
    from numba.core.compiler_lock import global_compiler_lock

    if numba.__version__ not in _TYPING_CHECKED or switched_off("EVSDA_QUICKER_TYPING"):
        return False
    global _TargetConfig
    _TargetConfig = config = targetconfig.TargetConfig
    with global_compiler_lock:
        config.values, config.__hash__, config.__eq__ = _flag_values, _flags_hash, _flags_equal
        errors._termcolor_inst = _plain_messages(errors._DummyColorScheme)()       # what errors.termcolor() returns
    return True


_TargetConfig: type | None = None                  # numba.core.targetconfig.TargetConfig, once edited


_option_defaults: dict[type, tuple] = {}           # TargetConfig subclass -> ((option name, default), ...)
_options_hash: dict[type, int] = {}                # TargetConfig subclass -> the hash of each of its instances


def _flag_values(self) -> dict:
    """``TargetConfig.values``: each option's value, the default where unset, in the options' order."""
    defaults = _option_defaults.get(type(self))
    if defaults is None:
        defaults = _option_defaults[type(self)] = tuple((name, option.default) for name, option in self.options.items())
    get = self._values.get
    return {name: get(name, default) for name, default in defaults}


def _flags_hash(self) -> int:
    """``TargetConfig.__hash__``: Numba's ``hash(tuple(sorted(self.values())))``, the sorted option names' hash."""
    value = _options_hash.get(type(self))
    if value is None:
        value = _options_hash[type(self)] = hash(tuple(sorted(self.values())))
    return value


def _flags_equal(self, other):
    """``TargetConfig.__eq__``: equal values (itself at once; two of a class with the same options set: their set
    values, the rest being the class's defaults in both)."""
    if self is other:
        return True
    if isinstance(other, _TargetConfig):
        mine, theirs = self._values, other._values
        if type(self) is type(other) and mine.keys() == theirs.keys():
            return mine == theirs
        return self.values() == other.values()
    return NotImplemented


def _plain_messages(scheme: type) -> type:
    """A colour scheme of Numba's error messages that leaves them as they are."""
    def plain(self, msg):
        return msg

    return type("PlainMessages", (scheme,), {name: plain for name in
                                              ("code", "errmsg", "filename", "indicate", "highlight", "reset")})


# -- LLVM's calls without Numba's events ---------------------------------------------------------------------

#: the Numba versions whose LLVM lock events :func:`quicker_llvm_calls` was checked on; others keep theirs
_LLVM_CALLS_CHECKED = ("0.68.1",)

_llvm_calls: bool | None = None        # None: not tried; True: Numba's lock events taken off; False: left as they are


def quicker_llvm_calls() -> bool:
    """Take Numba's events off the lock of LLVM's C API; whether they are now off (False: this Numba is not the one
    checked, or its callbacks are not found, and it is left as it is).

    Each call into LLVM's C API (``llvmlite.binding.ffi``) takes llvmlite's lock, and Numba registers callbacks on
    it (``numba.core.base._initialize_llvm_lock_event``) that broadcast a ``numba:llvm_lock`` start and end event to
    each listener, only to add the time the lock was held to a compile's metadata (``timers``, which no part of
    evsda reads). Compiling the main job makes ~120 000 such calls, each ~3x dearer with the two events (~12 against
    ~4 µs at load 5). The callbacks are taken off: the calls, and the code they build, are the same; a compile's
    metadata has no ``llvm_lock`` time and listeners to that event hear none. It stays so for the process.
    ``EVSDA_QUICKER_LLVM_CALLS=off`` leaves Numba's callbacks on.
    """
    global _llvm_calls
    if _llvm_calls is None:
        _llvm_calls = attempted_edit(_take_off_lock_events, "Numba's LLVM lock events left as they are")
    return _llvm_calls


def _take_off_lock_events() -> bool:
    import numba
    from llvmlite.binding import ffi
    from numba.core import base

    if numba.__version__ not in _LLVM_CALLS_CHECKED or switched_off("EVSDA_QUICKER_LLVM_CALLS"):
        return False
    numbas = [(enter, leave) for enter, leave in ffi.lib._lock._cblist
              if enter.__qualname__.startswith(base._initialize_llvm_lock_event.__qualname__ + ".")]
    if len(numbas) != 1:
        return False
    ffi.unregister_lock_callback(*numbas[0])
    return True


# -- Numba's IR walks, a call less per leaf ------------------------------------------------------------------

#: the Numba versions whose ``Inst._rec_list_vars`` :func:`quicker_ir_walks` was checked on; others keep theirs
_IR_WALKS_CHECKED = ("0.68.1",)

#: ``numba.core.ir.Inst._rec_list_vars``'s source in the versions checked
_NUMBAS_REC_LIST_VARS = '''    def _rec_list_vars(self, val):
        """
        A recursive helper used to implement list_vars() in subclasses.
        """
        if isinstance(val, Var):
            return [val]
        elif isinstance(val, Inst):
            return val.list_vars()
        elif isinstance(val, (list, tuple)):
            lst = []
            for v in val:
                lst.extend(self._rec_list_vars(v))
            return lst
        elif isinstance(val, dict):
            lst = []
            for v in val.values():
                lst.extend(self._rec_list_vars(v))
            return lst
        else:
            return []
'''

_ir_walks: bool | None = None          # None: not tried; True: Numba's walk edited; False: left as it is


def quicker_ir_walks() -> bool:
    """Make Numba's walk for the variables of an IR statement call itself only for what can hold variables; whether
    it now does (False: this Numba's walk is not the one checked, and it is left as it is).

    Each analysis of a function's IR lists the variables each statement reads and writes (``Inst.list_vars``, by
    ``analysis.compute_use_defs`` at each post-processing, ``postproc``'s deletions, the interpreter, SSA): Numba's
    ``Inst._rec_list_vars`` walks the statement's attributes and calls itself for each one, leaves included (its
    location, names, constants: ~2.5 million calls, ~2/3 of them leaves, in the pixels' warm-up compile). The edit
    appends a variable found in a list, tuple or dict and skips what can hold none, without the call: the same list,
    in the same order, so the same analyses and the same compiled code. Only on the Numba versions checked and where
    the method's source is Numba's as checked; it stays so for the process. ``EVSDA_QUICKER_IR_WALKS=off`` leaves
    Numba's walk as it is.
    """
    global _ir_walks
    if _ir_walks is None:
        _ir_walks = attempted_edit(_edit_ir_walks, "Numba's IR walk left as it is")
    return _ir_walks


def _edit_ir_walks() -> bool:
    import numba
    from numba.core import ir
    from numba.core.compiler_lock import global_compiler_lock

    if numba.__version__ not in _IR_WALKS_CHECKED or switched_off("EVSDA_QUICKER_IR_WALKS"):
        return False
    if inspect.getsource(ir.Inst._rec_list_vars) != _NUMBAS_REC_LIST_VARS:
        return False
    variable, instruction, holders = ir.Var, ir.Inst, (ir.Inst, list, tuple, dict)

    def _rec_list_vars(self, val):
        if isinstance(val, variable):
            return [val]
        if isinstance(val, instruction):
            return val.list_vars()
        if isinstance(val, dict):
            val = val.values()
        elif not isinstance(val, (list, tuple)):
            return []
        found = []
        for item in val:
            if isinstance(item, variable):
                found.append(item)
            elif isinstance(item, holders):
                found.extend(self._rec_list_vars(item))
        return found

    _rec_list_vars.__doc__ = ir.Inst._rec_list_vars.__doc__
    _rec_list_vars.__qualname__ = ir.Inst._rec_list_vars.__qualname__
    with global_compiler_lock:
        ir.Inst._rec_list_vars = _rec_list_vars
    return True


# -- an inlined function's IR built once ---------------------------------------------------------------------

#: the Numba versions whose ``InlineWorker.inline_function`` :func:`inlinees_once` was checked on; others keep theirs
_INLINEES_CHECKED = ("0.68.1",)

#: the lines of ``InlineWorker.inline_function`` and ``run_untyped_passes`` that the edit relies on
_NUMBAS_INLINE_FUNCTION = "        callee_ir = self.run_untyped_passes(function)\n"
_NUMBAS_UNTYPED_FLAGS = "        state.flags.enable_ssa = enable_ssa\n"

_inlinees: bool | None = None          # None: not tried; True: Numba's inlining edited; False: left as it is
_untyped: dict = {}                    # inlined function -> [(its compile context, its IR after the untyped passes)]


def inlinees_once() -> bool:
    """Make Numba build an inlined function's IR once per compile context, not again at each call site inlined;
    whether it now does (False: this Numba's inlining is not the one checked, and it is left as it is).

    Each call of an ``inline="always"`` function is inlined by ``InlineWorker.inline_function``, which first runs the
    untyped half of the compiler over the callee (``run_untyped_passes``: its bytecode, IR, rewrites, its own
    inlined callees) and then inlines a copy of that IR (``inline_ir``, which copies it before any change). The
    pixels' warm-up compile inlines 121 times, 31 functions (``exp_`` 19 times, ``log_`` 13, ...). The edit keeps
    each function's IR with the context it was built in (the typing context, the target context's and the pipeline's
    classes, the caller's flags but ``release_gil`` and its local types, compared by value) and inlines a copy of it
    wherever the same function is inlined in the same context; the caller's flags are set as Numba's ``run_untyped_passes`` sets them (no SSA). Only on the
    Numba versions checked and where Numba's lines are found as they are; it stays so for the process.
    ``EVSDA_INLINEES_ONCE=off`` leaves Numba's inlining as it is.
    """
    global _inlinees
    if _inlinees is None:
        _inlinees = attempted_edit(_edit_inlinees, "Numba's inlining left as it is")
    return _inlinees


def _edit_inlinees() -> bool:
    import numba
    from numba.core import inline_closurecall
    from numba.core.compiler_lock import global_compiler_lock

    if numba.__version__ not in _INLINEES_CHECKED or switched_off("EVSDA_INLINEES_ONCE"):
        return False
    worker = inline_closurecall.InlineWorker
    if (inspect.getsource(worker.inline_function).count(_NUMBAS_INLINE_FUNCTION) != 1
            or inspect.getsource(worker.run_untyped_passes).count(_NUMBAS_UNTYPED_FLAGS) != 1):
        return False
    numbas = worker.inline_function

    def inline_function(self, caller_ir, block, i, function, arg_typs=None):
        callee_ir = _untyped_ir(self, function)
        return self.inline_ir(caller_ir, block, i, callee_ir, function.__code__.co_freevars, arg_typs=arg_typs)

    inline_function.__doc__ = numbas.__doc__
    inline_function.__qualname__ = numbas.__qualname__
    with global_compiler_lock:
        worker.inline_function = inline_function
    return True


def _untyped_ir(worker, function):
    """``function``'s IR after the untyped passes in ``worker``'s context: built once per context (``inline_ir``
    copies it before it changes anything)."""
    worker.flags.enable_ssa = False                  # as run_untyped_passes sets the caller's flags
    context = (worker.typingctx, type(worker.targetctx), type(worker.pipeline), _untyped_flags(worker.flags),
               dict(worker.locals))
    built = _untyped.setdefault(function, [])
    for known, callee_ir in built:
        if known == context:
            return callee_ir
    callee_ir = worker.run_untyped_passes(function)
    built.append((context, callee_ir))
    return callee_ir


def _untyped_flags(flags) -> dict:
    """The compiler flags the untyped passes may read: all but ``release_gil`` (read only when the wrapper that
    calls the compiled function from Python is made, and in object mode). The target context a compile uses is made
    from its base and these flags (``compiler._make_subtarget``): the same flags, the same context."""
    values = flags.values()
    del values["release_gil"]
    return values


# -- a call's type once per function, arguments and context ---------------------------------------------------

#: the Numba versions, and the digest of ``BaseFunction.get_call_type``'s source, :func:`call_types_once` was checked on
_CALL_TYPES_CHECKED = ("0.68.1",)
_NUMBAS_GET_CALL_TYPE = "6559c167bfc0ad36ab4af049ed2f2b9ddc28ce1eedbc2e3462b69b62079e850e"

_call_types_edit: bool | None = None   # None: not tried; True: Numba's call typing edited; False: left as it is
_call_types: dict = {}                 # (function type, context, target, flags, arguments, keywords) -> (signature, impl key)
_memoisable: dict = {}                 # function type -> whether none of its templates inlines an overload
_numbas_get_call_type = None           # Numba's BaseFunction.get_call_type, once edited


def call_types_once() -> bool:
    """Make Numba type a call of a function (an operator, a NumPy function, an ``@overload``) once per function type,
    argument types and typing context; whether it now does (False: this Numba's call typing is not the one checked,
    and it is left as it is).

    ``BaseFunction.get_call_type`` tries the function's typing templates in order for each call site and each time
    type inference comes back to it: the pixels' compile types ~15 600 calls of ~890 distinct kinds (``mul``,
    ``getitem``, ``add``, ... of the same types, again and again), each time from the first template. A template's
    answer depends on those and on the compile's flags (an overload's implementation is compiled for them, and
    Numba keeps it under them: the same flags object is part of the key here); the one side effect, the
    implementation key recorded for the signature's argument types (``_impl_keys``, which lowering reads), is set
    again from the first answer at each call, as Numba would set it. Functions with an overload inlined at typing
    (``@overload(inline=...)``, whose typing builds fresh IR for the inliner each time) are typed as Numba does.
    Failed typings are not kept. Only on the Numba versions checked and where ``get_call_type``'s source is Numba's
    as checked; it stays so for the process. ``EVSDA_CALL_TYPES_ONCE=off`` leaves Numba's typing as it is.
    """
    global _call_types_edit
    if _call_types_edit is None:
        _call_types_edit = attempted_edit(_edit_call_types, "Numba's call typing left as it is")
    return _call_types_edit


def _edit_call_types() -> bool:
    import hashlib

    import numba
    from numba.core.compiler_lock import global_compiler_lock
    from numba.core.target_extension import get_local_target
    from numba.core.targetconfig import ConfigStack
    from numba.core.types.functions import BaseFunction

    if numba.__version__ not in _CALL_TYPES_CHECKED or switched_off("EVSDA_CALL_TYPES_ONCE"):
        return False
    numbas = BaseFunction.get_call_type
    if hashlib.sha256(inspect.getsource(numbas).encode()).hexdigest() != _NUMBAS_GET_CALL_TYPE:
        return False
    global _numbas_get_call_type
    _numbas_get_call_type = numbas

    def get_call_type(self, context, args, kws):
        key = (self, context, get_local_target(context), ConfigStack.top_or_none(), tuple(args), tuple(kws.items()))
        try:
            signature, impl_key = _call_types[key]
        except KeyError:
            pass
        except TypeError:                            # an argument type that cannot be hashed: typed as Numba does
            return numbas(self, context, args, kws)
        else:
            self._impl_keys[signature.args] = impl_key
            return signature
        signature = numbas(self, context, args, kws)
        if signature is not None and _typed_alike(self):
            _call_types[key] = signature, self._impl_keys[signature.args]
        return signature

    get_call_type.__doc__ = numbas.__doc__
    get_call_type.__qualname__ = numbas.__qualname__
    with global_compiler_lock:
        BaseFunction.get_call_type = get_call_type
    return True


def _typed_alike(function) -> bool:
    """Whether each typing of ``function``'s calls gives the same answer and leaves the same state: none of its
    templates is an overload inlined at typing (which keeps fresh IR for the inliner at each typing)."""
    known = _memoisable.get(function)
    if known is None:
        known = _memoisable[function] = all(getattr(getattr(template, "_inline", None), "is_never_inline", True)
                                            for template in function.templates)
    return known

