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


def test_a_step_beside_another_pipelined_step_takes_no_helper_on_two_threads():
    # two steps running share the 2 cores: a helper would only make a third thread contend for them
    def threads_used():
        seen = set()
        threads.parallel_map(lambda x: (time.sleep(0.002), seen.add(threading.get_ident())), range(20), 2)
        return len(seen)

    with threads.running_step():
        assert threads_used() == 2                   # alone: the caller and a helper
        with threads.running_step():                 # another step running beside it
            assert threads_used() == 1


def test_a_helper_joins_a_loop_beside_another_step_once_that_step_ends():
    # the loop starts beside another pipelined step (no helper then); that step ends at the loop's 6th item and
    # the helper it lacked joins it for the items left; the results are the loop's, in order
    if not threads.LATE_HELPERS:
        pytest.skip("EVSDA_LATE_HELPERS=off")
    beside, ending = threading.Event(), threading.Event()

    def other_step():
        with threads.running_step():
            beside.set()
            ending.wait(5)

    other = threading.Thread(target=other_step)
    other.start()
    assert beside.wait(5)
    ran_on = {}

    def item(i):
        if i == 5:
            ending.set()
        time.sleep(0.005)
        ran_on[i] = threading.get_ident()
        return i * i

    with threads.running_step():
        results = threads.parallel_map(item, range(40), 2)
    other.join()
    assert results == [i * i for i in range(40)]
    assert {ran_on[i] for i in range(6)} == {threading.get_ident()}     # the caller alone while the step ran
    assert len(set(ran_on.values())) == 2                               # then a helper joined


def test_a_waiting_helper_leaves_when_the_loop_ends_or_fails():
    # beside a step that never ends, the lacking helper waits and leaves with the loop: no item runs twice or on
    # it, and the first failing item's error is raised as without it
    with threads.running_step():
        with threads.running_step():
            seen = []
            assert threads.parallel_map(lambda i: seen.append(threading.get_ident()) or i, range(10), 2) \
                == list(range(10))
            assert set(seen) == {threading.get_ident()}

            def failing(i):
                if i == 3:
                    raise ValueError(i)
                return i
            with pytest.raises(ValueError, match="3"):
                threads.parallel_map(failing, range(10), 2)
    assert threads.parallel_map(lambda i: i, range(4), 2) == list(range(4))
