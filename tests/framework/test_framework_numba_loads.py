"""Numba's cached loads without the compiler's registries (evsda.graph.numba_loads): the same results, less set-up."""

import textwrap

MODULE = textwrap.dedent("""
    import numpy as np
    import numba

    @numba.njit(cache=True)
    def allocates(n):                      # NRT: a new array
        return np.arange(n) * 0.5

    @numba.njit(cache=True)
    def hashes(s, k):                      # the interpreter's hash secret (numba.cpython.hashing's symbols)
        return hash(s) ^ hash((k, 2.5))

    @numba.njit(cache=True)
    def raises(x):
        if x < 0:
            raise ValueError("negative")
        return x
""")

SCRIPT = textwrap.dedent("""
    import json, sys
    import loads_kernels as k              # imports Numba, which lazy_registries waits for
    from evsda.graph import numba_loads
    lazy = numba_loads.lazy_registries()
    values = [k.allocates(5).tolist(), k.hashes("abc", 7)]
    try:
        k.raises(-1.0)
    except ValueError as error:
        values.append(str(error))
    refreshed = "numba.np.arraymath" in sys.modules          # imported by the registries' refresh
    import numba
    import numpy as np

    @numba.njit
    def fresh(x):                          # a compile after lazy loads: the compiler refreshes itself
        return np.sum(np.sqrt(x))

    values.append(fresh(np.arange(4.0)))
    loaded = sum(sum(f.stats.cache_hits.values()) for f in (k.allocates, k.hashes, k.raises))
    print(json.dumps({"lazy": lazy, "values": values, "refreshed": refreshed, "loaded": loaded}))
""")


def test_cached_loads_skip_the_registries_and_give_the_same_results(fresh_numba, tmp_path):
    run = fresh_numba(SCRIPT, "EVSDA_LAZY_REGISTRIES")
    (tmp_path / "loads_kernels.py").write_text(MODULE)
    compiled = run()                            # an empty cache: compiled (and refreshed) here
    loaded = run()                              # then loaded from the cache without a refresh
    numbas = run(EVSDA_LAZY_REGISTRIES="off")   # loaded as Numba does
    assert compiled["loaded"] == 0 and loaded["loaded"] == numbas["loaded"] == 3
    assert compiled["values"] == loaded["values"] == numbas["values"]
    assert compiled["values"][0] == [0.0, 0.5, 1.0, 1.5, 2.0] and compiled["values"][2] == "negative"
    assert loaded["lazy"] and not numbas["lazy"]
    assert not loaded["refreshed"] and numbas["refreshed"]


ENVIRONMENTS = textwrap.dedent("""
    import numpy as np
    import numba

    @numba.njit(cache=True, nogil=True)
    def fills(n):                          # environments of numba.np.arrayobj (np.empty), arraymath (sum, any)
        out = np.empty((n, 2))
        for i in range(n):
            out[i, 0] = 0.5 * i
            out[i, 1] = 0.0
        return out.sum() + np.any(out > 1.0)
""")

ENVIRONMENTS_SCRIPT = textwrap.dedent("""
    import json, sys
    import environment_kernels as k
    from evsda.graph import numba_loads
    numba_loads.lazy_registries()
    import numpy as np
    values = [k.fills(5)]
    imported = "numba.np.arrayobj" in sys.modules      # by the environments' rebuild
    import numba

    @numba.njit
    def fresh(x):                          # a compile after the stand-in environments: its refresh imports them
        return np.mean(x) + np.sum(x)

    values += [fresh(np.arange(4.0)), k.fills(7)]
    print(json.dumps({"values": values, "imported": imported, "loaded": sum(k.fills.stats.cache_hits.values())}))
""")


def test_loaded_environments_of_numba_modules_import_none_and_give_the_same_results(fresh_numba, tmp_path):
    run = fresh_numba(ENVIRONMENTS_SCRIPT, "EVSDA_LAZY_ENVIRONMENTS")
    (tmp_path / "environment_kernels.py").write_text(ENVIRONMENTS)
    compiled = run()                            # an empty cache: compiled here (its compile imports the modules)
    loaded = run()                              # loaded: arrayobj's environments rebuilt without importing it
    numbas = run(EVSDA_LAZY_ENVIRONMENTS="off")  # loaded as Numba does
    assert compiled["loaded"] == 0 and loaded["loaded"] == numbas["loaded"] == 1
    assert compiled["values"] == loaded["values"] == numbas["values"] == [6.0, 7.5, 11.5]
    assert compiled["imported"] and not loaded["imported"] and numbas["imported"]


RUNTIME_SCRIPT = textwrap.dedent("""
    import json, threading
    import loads_kernels as k
    from numba.core.runtime import nrt
    from evsda.graph import numba_loads
    numba_loads.lazy_registries()
    ahead = [t for t in threading.enumerate() if t.name == "evsda-numba-runtime"]
    for thread in ahead:
        thread.join()
    set_up = nrt.rtsys._init                   # before any compiled call
    values = [k.allocates(5).tolist(), k.hashes("abc", 7)]
    print(json.dumps({"ahead": len(ahead), "set_up": set_up, "values": values,
                      "loaded": sum(sum(f.stats.cache_hits.values()) for f in (k.allocates, k.hashes))}))
""")


def test_the_runtime_is_set_up_ahead_of_the_first_load(fresh_numba, tmp_path):
    run = fresh_numba(RUNTIME_SCRIPT, "EVSDA_RUNTIME_AHEAD")
    (tmp_path / "loads_kernels.py").write_text(MODULE)
    compiled = run()                            # an empty cache: compiled here
    ahead = run()                               # loaded, the runtime set up on its own thread first
    at_first_load = run(EVSDA_RUNTIME_AHEAD="off")
    assert ahead["ahead"] == 1 and ahead["set_up"]
    assert at_first_load["ahead"] == 0 and not at_first_load["set_up"]
    assert ahead["loaded"] == at_first_load["loaded"] == 2
    assert compiled["values"] == ahead["values"] == at_first_load["values"]


LOCK_EVENTS_SCRIPT = textwrap.dedent("""
    import json
    import loads_kernels as k
    from numba.core import event
    from evsda.graph import numba_loads
    numba_loads.lazy_registries()
    heard = event.RecordingListener()
    with event.install_listener("numba:llvm_lock", heard):     # the events of each LLVM call a load makes
        values = [k.allocates(5).tolist()]
    print(json.dumps({"events": len(heard.buffer), "values": values, "loaded": sum(k.allocates.stats.cache_hits.values())}))
""")


def test_loads_make_their_llvm_calls_without_numbas_lock_events(fresh_numba, tmp_path):
    run = fresh_numba(LOCK_EVENTS_SCRIPT, "EVSDA_QUICKER_LLVM_CALLS")
    (tmp_path / "loads_kernels.py").write_text(MODULE)
    run()                                       # an empty cache: compiled here
    quicker, numbas = run(), run(EVSDA_QUICKER_LLVM_CALLS="off")
    assert quicker["loaded"] == numbas["loaded"] == 1 and quicker["values"] == numbas["values"]
    assert quicker["events"] == 0 and numbas["events"] > 0
