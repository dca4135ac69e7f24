"""Numba's loaded symbols read in one pass (evsda.graph.numba_symbols): the same symbols and results, or Numba's walk."""

import textwrap

import pytest

MODULE = textwrap.dedent("""
    import numpy as np
    import numba

    @numba.njit(cache=True)
    def allocates(n):                      # NRT: a new array
        return np.arange(n) * 0.5

    @numba.njit(cache=True)
    def calls(n):                          # a cached function that calls another (its symbols in the same library)
        return allocates(n).sum() + hash(n)

    @numba.njit(cache=True)
    def raises(x):
        if x < 0:
            raise ValueError("negative")
        return x
""")

SCRIPT = textwrap.dedent("""
    import json
    import numba                           # imported first: one_pass_symbols waits for it
    from numba.core.codegen import JitEngine
    from evsda.graph import numba_loads, numba_symbols
    numbas = JitEngine._load_defined_symbols
    numba_loads.lazy_registries()          # installs the one-pass walk too
    one_pass = numba_symbols.one_pass_symbols()
    modules = []
    walk = JitEngine._load_defined_symbols
    def recording(self, mod):
        modules.append(mod)
        return walk(self, mod)
    JitEngine._load_defined_symbols = recording
    import loads_kernels as k
    values = [k.allocates(5).tolist(), k.calls(4)]
    try:
        k.raises(-1.0)
    except ValueError as error:
        values.append(str(error))
    same = []
    for mod in modules:                    # each module's symbols by Numba's walk and by the one pass
        class Engine:
            _defined_symbols = set()
        numbas(Engine, mod)
        same.append(Engine._defined_symbols == numba_symbols.defined_names(mod))
    symbols = sum(len(numba_symbols.defined_names(mod)) for mod in modules)
    loaded = sum(sum(f.stats.cache_hits.values()) for f in (k.allocates, k.calls, k.raises))
    print(json.dumps({"one_pass": one_pass, "values": values, "same": same, "symbols": symbols, "loaded": loaded}))
""")


def test_loaded_symbols_in_one_pass_are_numbas_and_give_the_same_results(fresh_numba, tmp_path):
    run = fresh_numba(SCRIPT, "EVSDA_ONE_PASS_SYMBOLS")
    (tmp_path / "loads_kernels.py").write_text(MODULE)
    compiled = run()                            # an empty cache: compiled here
    loaded = run()                              # then loaded, the symbols read in one pass
    numbas = run(EVSDA_ONE_PASS_SYMBOLS="off")  # loaded as Numba does
    assert compiled["loaded"] == 0 and loaded["loaded"] == numbas["loaded"] == 3
    assert compiled["values"] == loaded["values"] == numbas["values"]
    assert compiled["values"][2] == "negative"
    assert loaded["one_pass"] and not numbas["one_pass"]
    assert loaded["same"] and all(loaded["same"]) and loaded["symbols"] > 0
    assert all(numbas["same"]) and numbas["symbols"] == loaded["symbols"]


def test_the_walk_is_left_as_numbas_where_its_source_differs(monkeypatch):
    pytest.importorskip("numba")
    from numba.core.codegen import JitEngine

    from evsda.graph import numba_symbols

    numbas = JitEngine._load_defined_symbols
    monkeypatch.setattr(numba_symbols, "_one_pass", None)
    monkeypatch.setattr(numba_symbols, "_NUMBAS_WALK", numba_symbols._NUMBAS_WALK.replace("gsets", "values"))
    assert not numba_symbols.one_pass_symbols()
    assert JitEngine._load_defined_symbols is numbas
