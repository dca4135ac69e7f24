"""A run's cached compiled loads replayed ahead on a thread (evsda.graph.loads_ahead): the same results, loaded
before the first call, robust to a cold cache, a stale or unreadable list, another set of blocks, and the switch."""

import textwrap
from pathlib import Path

MODULE = textwrap.dedent("""
    import numpy as np
    import numba

    class Sensor:                          # a block type: the list's file is named by the graph's block types
        pass

    class Telescope:
        pass

    @numba.njit(cache=True)
    def allocates(n):                      # NRT: a new array
        return np.arange(n) * 0.5

    @numba.njit(cache=True)
    def hashes(s, k):
        return hash(s) ^ hash((k, 2.5))

    @numba.njit(cache=True)
    def never_called(x):
        return x + 1
""")

SCRIPT = textwrap.dedent("""
    import json, os, pickle, sys
    import ahead_kernels as k
    from evsda.graph import loads_ahead
    blocks = [getattr(k, name) for name in os.environ.get("BLOCKS", "Sensor").split(",")]
    stale = os.environ.get("STALE")
    if stale:                              # a list written by hand before the run: stale entries, or unreadable
        from numba import types
        path = loads_ahead._list_file(blocks)
        entries = [("ahead_kernels", "gone", (types.int64,)), ("not_imported", "f", (types.int64,)),
                   ("ahead_kernels", "never_called", (types.float64,)),        # a signature not in the cache
                   ("ahead_kernels", "allocates", (types.int64,))]
        path.write_bytes(b"not a pickle" if stale == "unreadable" else
                         pickle.dumps({"format": 1, "entries": entries}))
    ahead = loads_ahead.LoadsAhead()
    ahead.start(blocks)
    if ahead.thread is not None:
        ahead.thread.join()
    functions = (k.allocates, k.hashes, k.never_called)
    before = [len(f.overloads) for f in functions]           # loaded ahead, before any call
    values = [k.allocates(5).tolist(), k.hashes("abc", 7)]   # the run's calls
    ahead.keep()
    path = loads_ahead._list_file(blocks)
    kept = [e[1] for e in pickle.loads(path.read_bytes())["entries"]] if path.exists() else None
    print(json.dumps({"before": before, "values": values, "kept": kept, "replayed": ahead.thread is not None,
                      "loaded": [sum(f.stats.cache_hits.values()) for f in functions],
                      "compiled": [sum(f.stats.cache_misses.values()) for f in functions]}))
""")


def runner(fresh_numba):
    """The script's runs, replaying wherever there is a list (``always``: whatever the machine's idle cores)."""
    run = fresh_numba(SCRIPT, "EVSDA_LOADS_AHEAD")
    return lambda **env: run(**{"EVSDA_LOADS_AHEAD": "always", **env})


def test_a_run_replays_the_loads_of_the_last_run_of_its_blocks(fresh_numba, tmp_path):
    run = runner(fresh_numba)
    (tmp_path / "ahead_kernels.py").write_text(MODULE)
    cold = run()                                # an empty cache: compiled at the calls, so no load to keep
    recorded = run()                            # loaded at the calls, and kept
    ahead = run()                               # loaded ahead from the list, before the calls
    off = run(EVSDA_LOADS_AHEAD="off")
    default = fresh_numba(SCRIPT, "EVSDA_LOADS_AHEAD")()        # the switch unset: off
    assert cold["compiled"] == [1, 1, 0] and cold["kept"] is None and not cold["replayed"]
    assert recorded["before"] == [0, 0, 0] and recorded["kept"] == ["allocates", "hashes"]
    assert ahead["replayed"] and ahead["before"] == [1, 1, 0] and ahead["loaded"] == [1, 1, 0]
    assert ahead["compiled"] == recorded["compiled"] == off["compiled"] == [0, 0, 0]
    assert ahead["kept"] == ["allocates", "hashes"]
    for unswitched in (off, default):           # nothing replayed (the list left as it was)
        assert unswitched["before"] == [0, 0, 0] and not unswitched["replayed"] and unswitched["loaded"] == [1, 1, 0]
    assert cold["values"] == recorded["values"] == ahead["values"] == off["values"] == default["values"]


def test_another_set_of_blocks_has_a_list_of_its_own(fresh_numba, tmp_path):
    run = runner(fresh_numba)
    (tmp_path / "ahead_kernels.py").write_text(MODULE)
    run(), run()                                # compiled, then a list for [Sensor]
    other = run(BLOCKS="Sensor,Telescope")      # no list for these types yet: nothing replayed, its own kept
    assert not other["replayed"] and other["before"] == [0, 0, 0] and other["kept"] == ["allocates", "hashes"]
    lists = sorted(p.name for p in Path(tmp_path / "numba").rglob("evsda-loads-*.pickle"))
    assert len(lists) == 2


def test_a_stale_or_unreadable_list_loads_what_it_can_and_compiles_nothing(fresh_numba, tmp_path):
    run = runner(fresh_numba)
    (tmp_path / "ahead_kernels.py").write_text(MODULE)
    run()                                       # compiled: allocates and hashes cached
    stale = run(STALE="entries")                # a function gone, a module not imported, types not cached
    assert stale["replayed"] and stale["before"] == [1, 0, 0]     # only allocates(int64) loads
    assert stale["compiled"] == [0, 0, 0]       # never_called(float64) is not compiled ahead
    assert stale["kept"] == ["allocates", "hashes"]               # the stale entries dropped
    unreadable = run(STALE="unreadable")
    assert not unreadable["replayed"] and unreadable["kept"] == ["allocates", "hashes"]
    assert stale["values"] == unreadable["values"]


def test_the_graph_load_names_its_block_classes_once_they_are_built(tmp_path):
    from evsda.graph.graphfile import load_graph

    examples = Path(__file__).parents[2] / "examples"
    built = []
    graph = load_graph(examples / "iss_pass.yaml", blocks_built=built.append)
    assert len(built) == 1
    assert sorted(c.__qualname__ for c in built[0]) == sorted(type(n.block).__qualname__ for n in graph.nodes.values())


def test_nothing_is_replayed_where_the_other_cores_were_busy(monkeypatch):
    from evsda.graph import loads_ahead

    monkeypatch.setattr(loads_ahead.os, "cpu_count", lambda: 2)
    ticks = iter([(1000, 4000), (1050, 4100)])                  # 100 ticks, 50 of them idle: one core free
    monkeypatch.setattr(loads_ahead, "_idle_ticks", lambda: next(ticks))
    assert loads_ahead._free_cores(loads_ahead._idle_ticks()) == 1.0
    ticks = iter([(1000, 4000), (1010, 4100)])                  # 10 idle of 100: 0.2 cores, below FREE_CORES
    assert loads_ahead._free_cores(next(ticks)) == 0.2 < loads_ahead.FREE_CORES
    ticks = iter([(1000, 4000), (1000, 4004)])                  # too few ticks between to tell: every core
    assert loads_ahead._free_cores(next(ticks)) == 2.0
    monkeypatch.setattr(loads_ahead, "_idle_ticks", lambda: None)       # no /proc/stat: every core
    assert loads_ahead._free_cores(None) == 2.0
