"""Compiling ahead (evsda.graph.compile_ahead): a child process fills the Numba cache that this process then loads."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

MODULE = textwrap.dedent("""
    import os, signal, time
    import numba

    if os.environ.get("EVSDA_COMPILE_AHEAD") == "off":          # in the child compiling ahead only
        if os.environ.get("AHEAD_KILLED"):
            os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(float(os.environ.get("AHEAD_SLOW", "0")))        # its first task takes that long

    @numba.njit(cache=True)
    def twice(x):
        return 2 * x

    @numba.njit(cache=True)
    def thrice(x):
        return 3 * x

    @numba.njit(cache=True)
    def broken(x):
        return x.no_such_attribute
""")

#: twice(4) after the tasks: compiled by the child (or this process), loaded from the cache here
TASKS = [["ahead_kernels:twice", "i8,"], ["ahead_kernels:thrice", "i8,"], ["ahead_kernels:twice", "f8,"]]

PARENT = textwrap.dedent("""
    import json, os, sys, time
    import ahead_kernels
    from evsda.graph import compile_ahead
    tasks, when = json.loads(sys.argv[1]), sys.argv[2]
    ahead = compile_ahead.start(tasks, ("ahead_kernels",))
    if ahead.process is not None and when == "late":          # the child has ended: nothing left to take here
        ahead.process.wait()
    if ahead.process is not None and when == "begun":         # the child has claimed its first task
        while not os.path.exists(os.path.join(ahead.claims, "0")):
            time.sleep(0.01)
    ahead.wait()
    value = ahead_kernels.twice(4)
    stats = [ahead_kernels.twice.stats, ahead_kernels.thrice.stats]
    print(json.dumps({"started": ahead.started, "value": value, "loaded": sum(sum(s.cache_hits.values()) for s in stats),
                      "compiled": sum(sum(s.cache_misses.values()) for s in stats), "inliner": compile_ahead._inliner,
                      "typing": compile_ahead._typing, "llvm": compile_ahead._llvm_calls,
                      "walks": compile_ahead._ir_walks, "inlinees": compile_ahead._inlinees,
                      "call_types": compile_ahead._call_types_edit,
                      "claims_left": ahead.claims is not None and os.path.exists(ahead.claims)}))
""")


def parent(tmp_path, tasks=TASKS, when="late", **env) -> dict:
    """Run PARENT in a fresh interpreter with the kernels' module on its path and its own Numba cache folder,
    ``when`` it waits for the child ("late": after the child ended, "begun": once it claimed its first task); what
    it printed, and that it printed nothing else."""
    environ = {name: value for name, value in os.environ.items()
               if name not in ("EVSDA_COMPILE_AHEAD", "EVSDA_QUICKER_INLINING", "EVSDA_QUICKER_TYPING",
                               "EVSDA_QUICKER_LLVM_CALLS", "EVSDA_QUICKER_IR_WALKS", "EVSDA_INLINEES_ONCE",
                               "EVSDA_CALL_TYPES_ONCE")}
    environ.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), EVSDA_THREADS="2",
                   PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    environ.update(env)
    out = subprocess.run([sys.executable, "-c", PARENT, json.dumps(tasks), when], env=environ, capture_output=True,
                         text=True, check=True)
    assert out.stderr == "" and len(out.stdout.splitlines()) == 1
    return json.loads(out.stdout)


@pytest.fixture
def kernels(tmp_path):
    (tmp_path / "ahead_kernels.py").write_text(MODULE)
    return tmp_path


EDITED = {"inliner": True, "typing": True, "llvm": True, "walks": True, "inlinees": True, "call_types": True,
          "claims_left": False}


def test_the_child_compiles_and_this_process_loads_then_no_child_once_cached(kernels):
    first = parent(kernels)
    assert first == {"started": True, "value": 8, "loaded": 1, "compiled": 0, **EDITED}
    again = parent(kernels)
    assert again == {"started": False, "value": 8, "loaded": 1, "compiled": 0, "inliner": None,
                     "typing": None, "llvm": None, "walks": None, "inlinees": None, "call_types": None,
                     "claims_left": False}                                                  # nothing compiles


def test_this_process_compiles_the_tasks_the_child_has_not_begun_from_the_last(kernels):
    """The child is on its first task (twice for integers, 2 s): this process takes the other two, the last first;
    twice(4) then loads what the child cached."""
    assert parent(kernels, when="begun", AHEAD_SLOW="2") == {"started": True, "value": 8, "loaded": 1, "compiled": 2,
                                                            **EDITED}


def test_a_task_that_fails_leaves_the_others_compiled(kernels):
    assert parent(kernels, [["ahead_kernels:broken", "i8,"], *TASKS]) == {"started": True, "value": 8, "loaded": 1,
                                                                        "compiled": 0, **EDITED}


@pytest.mark.parametrize("env", [{"EVSDA_THREADS": "1"}, {"EVSDA_COMPILE_AHEAD": "off"}])
def test_one_thread_or_switched_off_compiles_here(kernels, env):
    assert parent(kernels, **env) == {"started": False, "value": 8, "loaded": 0, "compiled": 1, **EDITED}


def test_a_child_that_is_killed_costs_only_its_time(kernels):
    assert parent(kernels, AHEAD_KILLED="1") == {"started": True, "value": 8, "loaded": 0, "compiled": 1, **EDITED}


INLINED_KERNELS = textwrap.dedent("""
    import numba

    @numba.njit(inline="always")
    def relax(a, y, j):
        r = 1.0
        for _ in range(j):
            r *= a
        return y + (1.0 - r) * (a - y) if j > 0 else y

    @numba.njit(inline="always")
    def step(x, a, y, j):
        if x > y:
            return relax(a, y, j) - relax(x, a, j + 1)
        return relax(x, y, j)

    @numba.njit
    def sweep(xs, a, y, j):
        total = 0.0
        for i in range(xs.size):
            xs[i] = step(xs[i], a, y, j)
            total += xs[i]
        return total
""")

ASSEMBLY = textwrap.dedent(r"""
    import json, re, sys
    from evsda.graph import compile_ahead

    def numbered_names_aside(code):          # the symbols' numbered names, and the lengths of strings holding them
        code = re.sub(r"_ZN\S+|\b\w*\$\d+\w*", "SYMBOL", code)
        return "\n".join(line for line in code.splitlines() if "missing Environment" not in line)
""")

INLINED = ASSEMBLY + textwrap.dedent(r"""
    import numpy as np

    def compiled():
        kernels = {}
        exec(sys.argv[1], kernels)              # new dispatchers: compiled again
        xs = np.linspace(0.0, 2.0, 101)
        total = kernels["sweep"](xs, 0.9, 0.7, 3)
        code = kernels["sweep"].inspect_asm(kernels["sweep"].signatures[0])
        return total, xs.tolist(), numbered_names_aside(code)

    numbas = compiled()
    edited = getattr(compile_ahead, sys.argv[2])()
    print(json.dumps({"edited": edited, "same": compiled() == numbas}))
""")


PIXEL_FUNCTION = ASSEMBLY + textwrap.dedent(r"""
    import numba
    from numba import types
    from evsda.blocks.pixel import drive_kernel

    def compiled():
        kernel = numba.jit(**drive_kernel.drive_rows.targetoptions)(drive_kernel.drive_rows.py_func)    # uncached
        signature = (types.float64[::1], types.float64[::1], types.float64[:, ::1])
        kernel.compile(signature)
        return numbered_names_aside(kernel.inspect_asm(signature))

    numbas = compiled()
    edited = getattr(compile_ahead, sys.argv[2])()
    print(json.dumps({"edited": edited, "same": compiled() == numbas}))
""")


@pytest.mark.parametrize("edit", ["quicker_inlining", "quicker_typing", "quicker_llvm_calls", "quicker_ir_walks",
                                  "inlinees_once", "call_types_once"])
@pytest.mark.parametrize("script", [INLINED, PIXEL_FUNCTION], ids=["nested inlined functions", "drive_rows"])
def test_numbas_inliner_typing_or_llvm_calls_edited_compile_the_same_machine_code(tmp_path, script, edit):
    environ = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    environ.pop("EVSDA_QUICKER_INLINING", None)
    environ.pop("EVSDA_QUICKER_TYPING", None)
    environ.pop("EVSDA_QUICKER_LLVM_CALLS", None)
    environ.pop("EVSDA_QUICKER_IR_WALKS", None)
    environ.pop("EVSDA_INLINEES_ONCE", None)
    environ.pop("EVSDA_CALL_TYPES_ONCE", None)
    out = subprocess.run([sys.executable, "-c", script, INLINED_KERNELS, edit], env=environ, capture_output=True,
                         text=True, check=True)
    assert json.loads(out.stdout) == {"edited": True, "same": True}


def test_numbas_inliner_left_as_it_is_when_switched_off(kernels):
    assert parent(kernels, EVSDA_QUICKER_INLINING="off")["inliner"] is False


FLAGS = textwrap.dedent(r"""
    import json, sys
    from numba.core import errors
    from numba.core.compiler import Flags
    from evsda.graph import compile_ahead

    def flags():
        plain, nrt, copied, wrapped, explicit = Flags(), Flags(), None, Flags(), Flags()
        nrt.nrt = True
        copied = Flags(nrt)
        wrapped.nrt, wrapped.no_cpython_wrapper = True, True
        explicit.nrt = False                  # set to its default: equal to plain, with other options set
        return [plain, nrt, copied, wrapped, explicit]

    def seen(all_flags):          # each one's values (in order) and hash, and which equal which
        return ([[list(f.values().items()), hash(f)] for f in all_flags]
                + [[a == b for b in all_flags] + [a == 3] for a in all_flags])

    all_flags = flags()
    numbas = seen(all_flags)
    edited = compile_ahead.quicker_typing()
    print(json.dumps({"edited": edited, "same": seen(all_flags) == numbas == seen(flags()),
                      "message": errors.termcolor().errmsg("no match")}))
""")


def test_numbas_typing_edited_reads_the_same_flags_and_plain_messages():
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_QUICKER_TYPING"}
    out = subprocess.run([sys.executable, "-c", FLAGS], env=environ, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == {"edited": True, "same": True, "message": "no match"}


def test_numbas_typing_left_as_it_is_when_switched_off(kernels):
    assert parent(kernels, EVSDA_QUICKER_TYPING="off")["typing"] is False


LOCK_EVENTS = textwrap.dedent(r"""
    import json
    import numba
    from numba.core import event
    from evsda.graph import compile_ahead

    def lock_events():             # the numba:llvm_lock events a compile broadcasts
        heard = event.RecordingListener()
        with event.install_listener("numba:llvm_lock", heard):
            numba.njit(lambda x: x + 1)(2)
        return len(heard.buffer)

    numbas = lock_events()
    edited = compile_ahead.quicker_llvm_calls()
    print(json.dumps({"edited": edited, "numbas": numbas > 0, "after": lock_events()}))
""")


def test_numbas_llvm_lock_events_taken_off():
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_QUICKER_LLVM_CALLS"}
    out = subprocess.run([sys.executable, "-c", LOCK_EVENTS], env=environ, capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == {"edited": True, "numbas": True, "after": 0}


def test_numbas_llvm_lock_events_left_on_when_switched_off(kernels):
    assert parent(kernels, EVSDA_QUICKER_LLVM_CALLS="off")["llvm"] is False


IR_VARIABLES = textwrap.dedent(r"""
    import json
    import numpy as np
    from numba.core import compiler
    from evsda.blocks.pixel import crossing, own_sweep
    from evsda.graph import compile_ahead

    def variables():              # each statement's variables, in order, of two pixel functions' IR (and of the
        found = []                # statements' own parts: expressions, lists, dicts)
        for function in (own_sweep.sweep_own.py_func, crossing.batch_crossings.py_func):
            for block in compiler.run_frontend(function).blocks.values():
                for statement in block.body:
                    found.append([v.name for v in statement.list_vars()])
                    value = getattr(statement, "value", None)
                    if hasattr(value, "list_vars"):
                        found.append([v.name for v in value.list_vars()])
        return found

    numbas = variables()
    edited = compile_ahead.quicker_ir_walks()
    print(json.dumps({"edited": edited, "same": variables() == numbas, "statements": len(numbas)}))
""")


def test_numbas_ir_walk_edited_lists_the_same_variables():
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_QUICKER_IR_WALKS"}
    out = json.loads(subprocess.run([sys.executable, "-c", IR_VARIABLES], env=environ, capture_output=True, text=True,
                                    check=True).stdout)
    assert out["edited"] and out["same"] and out["statements"] > 100


def test_numbas_ir_walk_left_as_it_is_when_switched_off(kernels):
    assert parent(kernels, EVSDA_QUICKER_IR_WALKS="off")["walks"] is False


INLINEES = textwrap.dedent(r"""
    import json, sys
    import numpy as np
    from evsda.graph import compile_ahead

    edited = compile_ahead.inlinees_once()
    kernels = {}
    exec(sys.argv[1], kernels)
    kernels["sweep"](np.linspace(0.0, 2.0, 11), 0.9, 0.7, 3)
    built = {f.__name__: len(contexts) for f, contexts in compile_ahead._untyped.items()}
    print(json.dumps({"edited": edited, "built": built}))
""")


def test_an_inlined_functions_ir_is_built_once_per_context():
    """``relax`` is inlined three times in ``step``: its IR is built once, and ``step``'s once."""
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_INLINEES_ONCE"}
    out = subprocess.run([sys.executable, "-c", INLINEES, INLINED_KERNELS], env=environ, capture_output=True,
                         text=True, check=True)
    assert json.loads(out.stdout) == {"edited": True, "built": {"relax": 1, "step": 1}}


def test_numbas_inlining_left_as_it_is_when_switched_off(kernels):
    assert parent(kernels, EVSDA_INLINEES_ONCE="off")["inlinees"] is False


CALL_TYPES = textwrap.dedent(r"""
    import json, sys
    import numpy as np
    from evsda.graph import compile_ahead
    from evsda.blocks.pixel import drive_kernel

    edited = compile_ahead.call_types_once()
    kernels = {}
    exec(sys.argv[1], kernels)
    kernels["sweep"](np.linspace(0.0, 2.0, 11), 0.9, 0.7, 3)
    import numba                                     # a pixel loop typed too (compiled, uncached, not run)
    numba.njit(drive_kernel.drive_rows.py_func).compile((numba.float64[::1], numba.float64[::1], numba.float64[:, ::1]))
    from numba.core.targetconfig import ConfigStack
    same = []
    for (function, context, target, flags, args, kws), (signature, impl_key) in compile_ahead._call_types.items():
        with ConfigStack().enter(flags):                  # typed again as Numba types it, in the same compile flags
            again = compile_ahead._numbas_get_call_type(function, context, args, dict(kws))
        same.append(again == signature and function._impl_keys[again.args] == impl_key)
    print(json.dumps({"edited": edited, "kept": len(same), "same": all(same)}))
""")


def test_a_call_typed_once_has_numbas_signature_and_implementation():
    """Every call type kept (a sweep of nested inlined functions, the pixels' drive_rows) is Numba's own: typed again
    by Numba's get_call_type, the same signature and the same implementation key."""
    environ = {name: value for name, value in os.environ.items() if name != "EVSDA_CALL_TYPES_ONCE"}
    out = subprocess.run([sys.executable, "-c", CALL_TYPES, INLINED_KERNELS], env=environ, capture_output=True,
                         text=True, check=True)
    result = json.loads(out.stdout)
    assert result["edited"] and result["same"] and result["kept"] > 20


def test_numbas_call_typing_left_as_it_is_when_switched_off(kernels):
    assert parent(kernels, EVSDA_CALL_TYPES_ONCE="off")["call_types"] is False

