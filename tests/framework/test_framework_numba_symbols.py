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
    walked = {"EVSDA_KEPT_SYMBOLS": "off"}      # every load parses its bitcode and walks its symbols
    compiled = run(**walked)                    # an empty cache: compiled here
    loaded = run(**walked)                      # then loaded, the symbols read in one pass
    numbas = run(EVSDA_ONE_PASS_SYMBOLS="off", **walked)  # loaded as Numba does
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


KEPT = textwrap.dedent("""
    import json
    import numba                           # imported first: kept_symbols waits for it
    import numpy as np
    from numba.core import codegen
    from evsda.graph import numba_loads, numba_symbols
    numba_loads.lazy_registries()          # installs the kept names too
    kept = numba_symbols.kept_symbols()
    parsed = []
    parse = codegen.ll.parse_bitcode
    def counted(bitcode):
        parsed.append(len(bitcode))
        return parse(bitcode)
    codegen.ll.parse_bitcode = counted
    import loads_kernels as k
    values = [k.allocates(5).tolist(), k.calls(4)]
    try:
        k.raises(-1.0)
    except ValueError as error:
        values.append(str(error))
    loads = len(parsed)
    engine = k.allocates.targetctx.codegen()._engine
    names = sorted(engine._defined_symbols)

    @numba.njit
    def links(n):                          # a new compile that links a loaded library (its bitcode parsed now)
        return k.allocates(n).sum() * 2.0

    values.append(links(6))
    loaded = sum(sum(f.stats.cache_hits.values()) for f in (k.allocates, k.calls, k.raises))
    print(json.dumps({"kept": kept, "values": values, "names": names, "loads": loads, "parsed": len(parsed),
                      "loaded": loaded}))
""")


def test_kept_names_are_the_parsed_ones_and_the_bitcode_is_parsed_to_link(fresh_numba, tmp_path):
    run = fresh_numba(KEPT, "EVSDA_KEPT_SYMBOLS")
    (tmp_path / "loads_kernels.py").write_text(MODULE)
    compiled = run()                            # an empty cache: compiled here
    numbas = run(EVSDA_KEPT_SYMBOLS="off")      # loaded as Numba does: every library's bitcode parsed
    first = run()                               # loaded, parsed, and the names kept beside the cache
    kept = run()                                # loaded with the kept names: parsed only to link
    assert compiled["loaded"] == 0 and numbas["loaded"] == first["loaded"] == kept["loaded"] == 3
    assert compiled["values"] == numbas["values"] == first["values"] == kept["values"]
    assert compiled["values"][2] == "negative" and compiled["values"][3] == 15.0
    assert not numbas["kept"] and first["kept"] and kept["kept"]
    assert numbas["loads"] == first["loads"] == 3 and kept["loads"] == 0 and kept["parsed"] >= 1
    assert numbas["names"] == first["names"] == kept["names"]
    assert len(list((tmp_path / "numba").rglob("defined-*.json"))) == 3


def test_kept_names_round_trip_and_unreadable_ones_are_none(tmp_path):
    from evsda.graph import numba_symbols

    path = numba_symbols.names_file(str(tmp_path), b"BC\xc0\xde bitcode")
    assert path != numba_symbols.names_file(str(tmp_path), b"BC\xc0\xde other")
    assert numba_symbols.read_names(path) is None
    numba_symbols.keep_names(path, {"b", "a", "\u00e9\nx"})
    assert numba_symbols.read_names(path) == {"a", "b", "\u00e9\nx"}
    (tmp_path / "broken.json").write_text("[\"a\", ")
    assert numba_symbols.read_names(str(tmp_path / "broken.json")) is None
    numba_symbols.keep_names(str(tmp_path / "missing" / "x.json"), {"a"})       # no folder: nothing written
    assert not (tmp_path / "missing").exists()


def test_unserialize_is_left_as_numbas_where_its_source_differs(monkeypatch):
    pytest.importorskip("numba")
    from numba.core.codegen import CPUCodeLibrary

    from evsda.graph import numba_symbols

    numbas = CPUCodeLibrary.__dict__["_unserialize"]
    monkeypatch.setattr(numba_symbols, "_kept", None)
    monkeypatch.setattr(numba_symbols, "_NUMBAS_UNSERIALIZE", numba_symbols._NUMBAS_UNSERIALIZE.replace("data", "x"))
    assert not numba_symbols.kept_symbols()
    assert CPUCodeLibrary.__dict__["_unserialize"] is numbas
