"""The blocks' shared worker threads (graph/threads.py ``parallel_map``): the results and the error of the plain
loop, on the caller plus the process's helpers, never waiting on a busy pool."""

import threading
import time

import pytest

from evsda.graph import threads


def test_results_in_order_and_on_several_threads():
    seen = set()

    def square(x):
        seen.add(threading.get_ident())
        time.sleep(0.002)                # long enough for a helper to take items too
        return x * x

    assert threads.parallel_map(square, range(40), 3) == [x * x for x in range(40)]
    assert threading.get_ident() in seen and len(seen) > 1


def test_one_thread_runs_on_the_caller_only():
    seen = set()
    assert threads.parallel_map(lambda x: seen.add(threading.get_ident()) or x, range(5), 1) == list(range(5))
    assert seen == {threading.get_ident()}


def test_the_first_failing_item_in_order_is_raised_and_no_later_item_starts():
    started = []

    def fail_at_3_and_5(x):
        started.append(x)
        if x == 5:
            raise KeyError(x)            # may run before item 3 fails; item 3's error is still the one raised
        if x == 3:
            time.sleep(0.01)
            raise ValueError(x)
        return x

    with pytest.raises(ValueError, match="3"):
        threads.parallel_map(fail_at_3_and_5, range(100), 2)
    assert len(started) < 100            # nothing new starts after a failure


def test_helpers_are_kept_between_calls():
    helpers = set()
    for _ in range(5):
        helpers |= set(threads.parallel_map(lambda x: (time.sleep(0.002), threading.get_ident())[1], range(20), 2))
    helpers.discard(threading.get_ident())
    assert 1 <= len(helpers) <= threads._helper_count < 5      # a pool per call would have made 5 threads or more


def test_nested_and_concurrent_calls_finish_while_the_helpers_are_busy():
    # every helper blocked in an outer item: the inner calls run on their callers instead of waiting
    def outer(x):
        return sum(threads.parallel_map(lambda y: y, range(x), 2))

    results = {}

    def caller(name):
        results[name] = threads.parallel_map(outer, range(30), 2)

    workers = [threading.Thread(target=caller, args=(n,)) for n in range(3)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(timeout=30)
    assert all(not w.is_alive() for w in workers)
    assert all(r == [x * (x - 1) // 2 for x in range(30)] for r in results.values())


FAULTS = r"""
import resource, sys
import numpy as np
from evsda.graph import threads
if sys.argv[1] == "keep":
    threads.keep_freed_memory()
def window():                                # ~100 MB of arrays of ~8 MB made and freed, as a window does
    held = [np.ones(1_000_000 + 1000 * i) for i in range(12)]
    del held
window()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    window()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def test_freed_arrays_are_reused_without_new_page_faults():
    # glibc's defaults give the freed heap top back (and map big blocks on their own), so every window's arrays
    # meet fresh pages that the kernel zeroes; kept, the next window's arrays reuse them
    import os
    import subprocess
    import sys
    env = {k: v for k, v in os.environ.items()
           if k not in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_", "NUMPY_MADVISE_HUGEPAGE")}
    faults = {mode: int(subprocess.run([sys.executable, "-c", FAULTS, mode], capture_output=True, text=True,
                                       check=True, env=env).stdout)
              for mode in ("default", "keep")}
    if faults["default"] < 1000:
        pytest.skip(f"this C library keeps freed memory by itself ({faults})")
    assert faults["keep"] < faults["default"] / 10, faults


def _step_in_thread(urgency=()):
    """A pipelined step holding a core in a thread of its own until the returned event is set."""
    running, end = threading.Event(), threading.Event()

    def step():
        with threads.running_step(urgency):
            running.set()
            end.wait(30)

    thread = threading.Thread(target=step)
    thread.start()
    running.wait(30)
    return end, thread


def test_a_loop_beside_another_step_runs_on_its_caller_until_that_step_ends_then_a_helper_joins():
    # two steps running share the 2 cores: a helper would only make a third thread contend for them; once the
    # other step ends, a core is free and a helper takes the loop's next items
    end, other = _step_in_thread()
    ran = []

    def item(x):
        if x == 10:
            end.set()
            other.join()
        time.sleep(0.003)
        ran.append((x, threading.get_ident()))

    with threads.running_step():
        threads.parallel_map(item, range(60), 2)
    caller = threading.get_ident()
    assert all(tid == caller for x, tid in ran if x <= 10)
    assert any(tid != caller for x, tid in ran if x > 10)


def test_a_freed_core_goes_to_the_most_urgent_waiting_loop():
    # steps of windows 1 and 2 each run a loop while a third step holds the last core; when it ends, the helper of
    # the newer window's loop takes the core, and the older one's helper only once that loop has no items left
    end, holder = _step_in_thread((0, 0))
    times = {}
    started = threading.Barrier(3)

    def loop(name, urgency):
        def item(x):
            times.setdefault(name, []).append((time.perf_counter(), threading.get_ident(), x))
            time.sleep(0.003)
        with threads.running_step(urgency):
            callers[name] = threading.get_ident()
            started.wait(30)
            threads.parallel_map(item, range(40), 3)

    callers = {}
    loops = [threading.Thread(target=loop, args=(n, u)) for n, u in (("old", (1, 0)), ("new", (2, 0)))]
    for thread in loops:
        thread.start()
    started.wait(30)
    time.sleep(0.02)                      # both loops under way, their helpers waiting for a core
    end.set()
    holder.join()
    for thread in loops:
        thread.join(30)
    helped = {name: [t for t, tid, _ in rows if tid != callers[name]] for name, rows in times.items()}
    new_last = max(t for t, _, _ in times["new"])
    assert helped["new"]
    assert all(t >= min(helped["new"]) for t in helped["old"])
    assert not [t for t in helped["old"] if t < new_last - 0.004]   # the old loop's helper came after the new's items
