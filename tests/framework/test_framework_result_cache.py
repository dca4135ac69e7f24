"""Results kept on disk across runs (evsda.graph.result_cache): exact values, misses on any other key or code,
never an error that stops a run, safe with concurrent writers, bounded, and switched off by EVSDA_CACHE=off."""

import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from evsda.graph import UserError
from evsda.graph.result_cache import ResultCache, cache_root, code_digest

#: floats JSON must carry exactly: a tenth's rounding, the smallest subnormal, the largest float, signed zero,
#: infinities and NaN
FLOATS = [0.1 + 0.2, 5e-324, 1.7976931348623157e308, -0.0, math.inf, -math.inf, math.nan, 1 / 3]


@pytest.fixture
def cache(monkeypatch, tmp_path) -> ResultCache:
    monkeypatch.setenv("EVSDA_CACHE", "on")
    monkeypatch.setenv("EVSDA_CACHE_DIR", str(tmp_path / "cache"))
    return ResultCache("test", [Path(__file__)])


def counted(cache, key, value=1.0):
    """(value, whether it was computed) of ``cache.remember(key, ...)``."""
    calls = []
    got = cache.remember(key, lambda: calls.append(1) or value)
    return got, bool(calls)


def test_values_come_back_bit_for_bit_and_other_keys_miss(cache):
    assert counted(cache, {"a": 1, "x": 0.1}, FLOATS) == (FLOATS, True)
    got, computed = counted(cache, {"x": 0.1, "a": 1}, None)                   # the same key, any order
    assert not computed
    assert repr(got) == repr(FLOATS)                                           # -0.0 and NaN too
    assert counted(cache, {"a": 1, "x": 0.10000000000000002}, 2.0) == (2.0, True)   # the next float
    assert counted(cache, {"a": 1.0, "x": 0.1}, 3.0) == (3.0, True)             # 1.0 is not 1
    assert counted(cache, {"a": [1, 2]}, 4.0) == (4.0, True)
    assert counted(cache, {"a": [2, 1]}, 5.0) == (5.0, True)


def test_a_change_of_the_code_misses(monkeypatch, tmp_path, cache):
    source = tmp_path / "code.py"
    source.write_text("x = 1\n")
    first = ResultCache("test", [source])
    assert counted(first, "key") == (1.0, True)
    assert counted(ResultCache("test", [source]), "key") == (1.0, False)
    source.write_text("x = 2\n")
    code_digest.cache_clear()
    assert counted(ResultCache("test", [source]), "key", 2.0) == (2.0, True)
    assert counted(ResultCache("test", [tmp_path / "missing.py"]), "key", 3.0) == (3.0, True)   # unreadable:
    assert not list((tmp_path / "cache").rglob("*missing*"))                                      # not cached


def test_unreadable_entries_are_misses_and_are_rewritten(cache, tmp_path):
    counted(cache, "key", 1.0)
    (entry,) = (tmp_path / "cache").rglob("*.json")
    for damage in (b"", b"{\"key\": ", b"\xff\xfe", json.dumps({"key": "another", "value": 9}).encode(),
                   json.dumps([1, 2]).encode()):
        entry.write_bytes(damage)
        assert counted(cache, "key", 2.0) == (2.0, True)
        assert counted(cache, "key", 3.0) == (2.0, False)
    undecodable = cache.remember("key", lambda: 4.0, decode=lambda v: v["missing"])                # a value the
    assert undecodable == 4.0                                                                    # caller rejects


def test_a_cache_that_cannot_be_written_does_not_stop_the_computation(monkeypatch, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("EVSDA_CACHE", "on")
    monkeypatch.setenv("EVSDA_CACHE_DIR", str(blocker / "cache"))
    cache = ResultCache("test", [Path(__file__)])
    assert counted(cache, "key") == (1.0, True)
    assert counted(cache, "key", 2.0) == (2.0, True)


def test_off_writes_nothing_and_a_wrong_switch_is_one_clear_error(monkeypatch, tmp_path, cache):
    for off in ("off", "OFF", "0", "false", "no"):
        monkeypatch.setenv("EVSDA_CACHE", off)
        assert cache_root() is None
        assert counted(cache, "key") == (1.0, True)
    assert not (tmp_path / "cache").exists()
    monkeypatch.setenv("EVSDA_CACHE", "of")
    with pytest.raises(UserError, match="EVSDA_CACHE must be 'on' or 'off', got 'of'"):
        cache_root()


def test_the_folder_is_evsda_cache_dir_else_the_users_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("EVSDA_CACHE", "on")
    monkeypatch.setenv("EVSDA_CACHE_DIR", str(tmp_path / "here"))
    assert cache_root() == tmp_path / "here"
    monkeypatch.delenv("EVSDA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root() == tmp_path / "xdg" / "evsda"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_root() == tmp_path / "home" / ".cache" / "evsda"


def test_the_least_recently_used_entries_go_beyond_the_bound(cache, tmp_path):
    for i in range(6):
        counted(cache, i, "x" * 1000)
    paths = sorted((tmp_path / "cache").rglob("*.json"))
    for age, path in enumerate(paths):               # entry k last used k * 10 s ago, in name order
        os.utime(path, (1e9 - 10 * age, 1e9 - 10 * age))
    size = paths[0].stat().st_size
    ResultCache.prune(tmp_path / "cache" / "test", max_bytes=6 * size)          # within the bound: none goes
    assert sorted((tmp_path / "cache").rglob("*.json")) == paths
    ResultCache.prune(tmp_path / "cache" / "test", max_bytes=4 * size)          # beyond it: down to 3/4 of it
    assert sorted((tmp_path / "cache").rglob("*.json")) == paths[:3]
    stale = paths[0].parent / ".stale.tmp"
    stale.write_text("half")
    os.utime(stale, (0, 0))
    ResultCache.prune(tmp_path / "cache" / "test")
    assert not stale.exists()


def test_a_process_lists_the_folder_at_its_first_write_and_once_past_the_bound(cache, monkeypatch, tmp_path):
    """The bound without a listing at every write: the first write lists (and prunes), later ones count their bytes
    until the tally passes MAX_BYTES, and that write prunes the folder to 3/4 of it."""
    import evsda.graph.result_cache as result_cache
    listings = []
    prune = ResultCache.prune
    monkeypatch.setattr(ResultCache, "prune", staticmethod(lambda folder: listings.append(folder) or prune(folder)))
    counted(cache, 0, "x" * 1000)
    size = next((tmp_path / "cache").rglob("*.json")).stat().st_size
    monkeypatch.setattr(result_cache, "MAX_BYTES", 4 * size)
    for i in range(1, 4):
        counted(cache, i, "x" * 1000)
    assert len(listings) == 1                       # the first write only: 4 entries are within the bound
    counted(cache, 4, "x" * 1000)
    assert len(listings) == 2                       # the fifth passed it: pruned to 3 entries (3/4 of the bound)
    assert len(list((tmp_path / "cache").rglob("*.json"))) == 3
    counted(cache, 5, "x" * 1000)
    assert len(listings) == 2                       # the sixth fits again without a listing
    assert len(list((tmp_path / "cache").rglob("*.json"))) == 4


def _hammer(args):
    """A sweep worker: remember the same keys many times; every value read must be the one computed."""
    folder, worker = args
    os.environ["EVSDA_CACHE"], os.environ["EVSDA_CACHE_DIR"] = "on", folder
    cache = ResultCache("test", [__file__])
    wrong = 0
    for i in range(200):
        key = i % 7
        wrong += cache.remember(key, lambda: [key, 0.1 * key] * 50) != [key, 0.1 * key] * 50
    return wrong


def test_concurrent_workers_read_only_whole_entries(tmp_path):
    with ProcessPoolExecutor(4) as pool:
        assert sum(pool.map(_hammer, [(str(tmp_path), w) for w in range(4)])) == 0
    assert len(list(tmp_path.rglob("*.json"))) == 7 and not list(tmp_path.rglob("*.tmp"))
