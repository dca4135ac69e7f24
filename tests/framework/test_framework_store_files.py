"""The run store's files written without Zarr (evsda.graph.store_files) are Zarr's files, byte for byte: each
array kind and each way of writing it (appends across chunks, a chunk completed later, a chunk that holds rows
past a shortened array's end, a whole array replaced), and the groups' documents; a run store written by
RunStore reads back with Zarr and imports no Zarr."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

from evsda.graph.store import RunStore
from evsda.graph.store_files import ArrayFiles, GroupFiles

STRING = np.dtypes.StringDType()
DTYPES = ["int8", "uint8", "uint16", "int32", "uint32", "int64", "float32", "float64", "bool", STRING]


def files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def zarr_array(group: zarr.Group, key: str, dtype, shape, chunks, dims, attrs) -> zarr.Array:
    """An array made as the store made its arrays with Zarr (its codec chains, every chunk written)."""
    codecs = ([ZstdCodec(level=3), Crc32cCodec()] if np.dtype(dtype).kind == "T"
              else [BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle"), Crc32cCodec()])
    return group.create_array(key, shape=shape, chunks=chunks, dtype=dtype, compressors=codecs,
                              config={"write_empty_chunks": True}, dimension_names=dims, attributes=attrs,
                              overwrite=True)


def values(dtype, rows: int, trailing: tuple[int, ...], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (rows, *trailing)
    if np.dtype(dtype).kind == "T":
        return np.array([f"s{k}-é" * (k % 4) for k in rng.integers(0, 1000, int(np.prod(shape)))],
                        dtype=STRING).reshape(shape)
    if np.dtype(dtype).kind == "b":
        return rng.integers(0, 2, shape).astype(bool)
    return (rng.normal(0, 1e3, shape) if np.dtype(dtype).kind == "f" else rng.integers(0, 100, shape)).astype(dtype)


def appended_both_ways(tmp_path, dtype, trailing, appends, chunk=7):
    """Append blocks of ``appends`` rows to a new array with Zarr and with ArrayFiles; the two folders."""
    dims, attrs = ["row", *(f"axis{i}" for i in range(len(trailing)))], {"units": "m", "long_name": "é"}
    made = zarr_array(zarr.create_group(str(tmp_path / "zarr"), zarr_format=3), "a", dtype, (0, *trailing),
                      (chunk, *trailing), dims, attrs)
    ours = ArrayFiles.create(tmp_path / "ours" / "a", np.dtype(dtype), (0, *trailing), (chunk, *trailing), dims,
                             dict(attrs))
    start = 0
    for k, rows in enumerate(appends):
        data = values(dtype, rows, trailing, k)
        made.resize((start + rows, *trailing))
        made[start:start + rows] = data
        ours.resize(start + rows)
        ours.write(start, data)
        start += rows
    return tmp_path / "zarr" / "a", tmp_path / "ours" / "a"


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
def test_appended_arrays_are_zarrs_files_byte_for_byte(tmp_path, dtype):
    theirs, ours = appended_both_ways(tmp_path, dtype, (), [3, 2, 9, 7, 1, 0, 15])
    assert files(theirs) == files(ours)
    assert len(files(ours)) == 1 + 6


@pytest.mark.parametrize("trailing", [(3,), (2, 2), (0,)], ids=str)
def test_arrays_of_rows_are_zarrs_files_byte_for_byte(tmp_path, trailing):
    for dtype in ("int64", "float32"):
        theirs, ours = appended_both_ways(tmp_path / dtype, dtype, trailing, [1, 5, 4, 12])
        assert files(theirs) == files(ours)


@pytest.mark.parametrize("dtype", ["int64", STRING], ids=str)
def test_a_chunk_past_a_shortened_end_keeps_its_rows_as_zarr_does(tmp_path, dtype):
    """A resumed run's array, cut back to its committed length by Zarr: the chunk there still holds the rows
    written past it, and writing into it keeps them beyond the new end, as Zarr's writes do."""
    theirs, ours = appended_both_ways(tmp_path, dtype, (), [5, 6])
    for folder in (theirs, ours):
        zarr.open_array(str(folder), mode="r+").resize((8,))
    made, again = zarr.open_array(str(theirs), mode="r+"), ArrayFiles.open(ours)
    data = values(dtype, 2, (), 9)
    made.resize((10,))
    made[8:10] = data
    again.resize(10)
    again.write(8, data)
    assert files(theirs) == files(ours)
    np.testing.assert_array_equal(zarr.open_array(str(ours))[8:10], data)


def test_a_replaced_whole_array_is_zarrs(tmp_path):
    group = zarr.create_group(str(tmp_path / "zarr"), zarr_format=3)
    for k, rows in enumerate([4, 2, 0]):
        data = values("float64", rows, (), k)
        made = zarr_array(group, "m", "float64", data.shape, (max(1, rows),), ["metric"], {"k": k})
        ours = ArrayFiles.create(tmp_path / "ours" / "m", data.dtype, data.shape, (max(1, rows),), ["metric"],
                                 {"k": k})
        if rows:
            made[...] = data
            ours.write(0, data)
        assert files(tmp_path / "zarr" / "m") == files(tmp_path / "ours" / "m")


def test_group_documents_are_zarrs(tmp_path):
    attrs = {"format": "x", "n": None, "nan": float("nan"), "text": "é\n", "nested": {"a": [1, 2.5, True]}}
    group = zarr.create_group(str(tmp_path / "zarr"), zarr_format=3, attributes=dict(attrs))
    groups = GroupFiles(tmp_path / "ours")
    groups.create_root(dict(attrs))
    group.attrs.update({"n": 3, "later": {"b": "c"}})
    groups.update("", {"n": 3, "later": {"b": "c"}})
    group.require_group("products/block").attrs["upstream_hash"] = "abc"
    groups.update("products/block", {"upstream_hash": "abc"})
    zarr_array(group, "events/x", "uint16", (0,), (4,), ["event"], {})
    groups.require("events")
    ArrayFiles.create(tmp_path / "ours" / "events" / "x", np.dtype("uint16"), (0,), (4,), ["event"], {})
    assert files(tmp_path / "zarr") == files(tmp_path / "ours")


def test_a_written_run_store_reads_back_with_zarr(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr", attrs={"n_windows": 2})
    rows = {"t_ns": np.arange(40, dtype=np.int64), "name": np.array([f"n{k}" for k in range(40)])}
    store.append_table("truth", rows, "sample", chunk_bytes=64)
    store.set_metrics({"m": 1.5, "text": "x"}, {"m": "s"})
    store.commit(windows=1)
    store.append_table("truth", rows, "sample", chunk_bytes=64)
    store.commit(windows=2, complete=True)
    group = zarr.open_group(str(tmp_path / "run.zarr"), mode="r")
    np.testing.assert_array_equal(group["truth/t_ns"][:], np.tile(rows["t_ns"], 2))
    assert group["truth/name"][:].tolist() == rows["name"].tolist() * 2
    assert group["metrics/value"][:].tolist() == [1.5] and group["metrics"].attrs["units"] == {"m": "s"}
    again = RunStore.open(tmp_path / "run.zarr")
    assert again.complete and again.verify() == [] and again.metrics == {"m": 1.5, "text": "x"}


def test_a_run_store_is_written_without_importing_zarr(tmp_path):
    code = ("import sys, numpy as np\n"
            "from evsda.graph.store import RunStore\n"
            f"s = RunStore.create({str(tmp_path / 'run.zarr')!r})\n"
            "s.append_table('truth', {'t': np.arange(5), 'k': np.array(list('abcde'))}, 'sample')\n"
            "s.set_metrics({'m': 1.0}, {'m': 's'})\n"
            "s.commit(windows=1, complete=True)\n"
            "print(s.metrics, s.complete, 'zarr' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["{'m':", "1.0}", "True", "False"]


def test_an_array_of_another_kind_is_left_to_zarr(tmp_path):
    """Complex numbers (no evsda port type records them) are written by Zarr, beside the arrays written here."""
    store = RunStore.create(tmp_path / "run.zarr")
    rows = {"z": np.arange(6) * (1 + 2j), "t_ns": np.arange(6, dtype=np.int64)}
    store.append_table("table", rows, "row", chunk_bytes=32)
    store.commit(windows=1)
    store.append_table("table", rows, "row", chunk_bytes=32)
    store.commit(windows=2, complete=True)
    again = RunStore.open(tmp_path / "run.zarr").read_table("table")
    np.testing.assert_array_equal(again["z"], np.tile(rows["z"], 2))
    np.testing.assert_array_equal(again["t_ns"], np.tile(rows["t_ns"], 2))


def appended_store(path: Path) -> RunStore:
    store = RunStore.create(path, attrs={"n_windows": 30})
    rng = np.random.default_rng(3)
    for window in range(30):
        rows = int(rng.integers(0, 50))
        names = np.array([f"n{k}" for k in range(rows)], dtype=str)
        store.append_table("truth", {"t_ns": rng.integers(0, 10**9, rows), "name": names}, "sample", chunk_bytes=64)
        if window % 7 == 6:
            store.commit(windows=window + 1)
    store.commit(windows=30, complete=True)
    return store


def test_chunks_written_behind_the_appends_are_the_chunks_written_at_once(tmp_path, monkeypatch):
    """Whole chunks written on the store's writing thread while the appends go on land as if written in turn."""
    from evsda.graph import store as module

    monkeypatch.setattr(module, "WHOLE_CHUNK_BYTES", 64)
    behind = appended_store(tmp_path / "behind.zarr")
    monkeypatch.setattr(RunStore, "_write_behind", lambda self, jobs: module._write_slices(jobs))
    at_once = appended_store(tmp_path / "at_once.zarr")
    assert files(behind.path) == files(at_once.path)
    assert behind._writer is None and not behind._behind


def test_an_error_writing_behind_is_raised_by_the_next_commit(tmp_path, monkeypatch):
    from evsda.graph import store as module

    monkeypatch.setattr(module, "WHOLE_CHUNK_BYTES", 8)
    store = RunStore.create(tmp_path / "run.zarr")
    monkeypatch.setattr(ArrayFiles, "write", lambda *args: (_ for _ in ()).throw(OSError(28, "No space left")))
    store.append_table("truth", {"t_ns": np.arange(100)}, "sample", chunk_bytes=64)
    with pytest.raises(OSError, match="No space left"):
        store.commit(windows=1)
    assert store.committed_windows == 0
