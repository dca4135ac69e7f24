"""Output files and a full disk: exports and images go to a temporary name and are renamed when
complete; a bad path, an existing file, a full disk are one line (exit 2) and leave no partial file.
A run stopped by a full disk keeps its committed windows and resumes byte-identical."""

from __future__ import annotations

import errno
import os

import pytest
from faultkit import assert_identical, cli, graph_file, one_line_error, run_in_process

FORMATS = ["npy", "hdf5", "aedat4", "evt2", "evt3"]


@pytest.fixture
def store(tmp_path):
    return run_in_process(tmp_path)


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if "partial" in p.name)


@pytest.mark.parametrize("fmt", FORMATS)
def test_export_refuses_bad_paths_before_any_work(capsys, tmp_path, store, fmt):
    cases = {
        tmp_path / "missing" / f"out.{fmt}": "folder " + str(tmp_path / "missing") + " does not exist",
        tmp_path / "chain.yaml" / f"out.{fmt}": "is not a folder",
        tmp_path: "a folder is in the way",
    }
    for output, expected in cases.items():
        status, lines = cli(capsys, "export", store, "--format", fmt, "-o", output)
        assert status == 2 and len(lines) == 1 and expected in lines[0], lines
    assert not (tmp_path / "missing").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_export_refuses_a_read_only_folder(capsys, tmp_path, store):
    folder = tmp_path / "locked"
    folder.mkdir(mode=0o555)
    status, lines = cli(capsys, "export", store, "--format", "npy", "-o", folder / "out.npy")
    assert status == 2 and len(lines) == 1 and "is not writable" in lines[0]


@pytest.mark.parametrize("command", [["export", "--format", "hdf5", "-o"], ["render", "--png"], ["render", "--frames", "2", "--gif"]])
def test_an_existing_output_needs_overwrite(capsys, tmp_path, store, command):
    output = tmp_path / "existing.out"
    output.write_text("keep me")
    status, lines = cli(capsys, command[0], store, *command[1:], output)
    assert status == 2 and lines == [f"evsda: error: {output} already exists; pass --overwrite to replace it"]
    assert output.read_text() == "keep me"
    assert cli(capsys, command[0], store, *command[1:], output, "--overwrite")[0] == 0
    assert output.read_bytes() != b"keep me" and not leftovers(tmp_path)


def test_a_failed_export_leaves_no_file_under_either_name(capsys, monkeypatch, tmp_path, store):
    from evsda.blocks.readout import exporters

    def fills_the_disk(chunks, path, *args, **kwargs):
        with open(path, "wb") as handle:
            handle.write(b"\x93NUMPY partial")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setitem(exporters.WRITERS, "npy", fills_the_disk)
    status, lines = cli(capsys, "export", store, "--format", "npy", "-o", tmp_path / "out.npy")
    assert status == 2 and len(lines) == 1 and "no space left on the device" in lines[0], lines
    assert not (tmp_path / "out.npy").exists() and not leftovers(tmp_path)


def test_an_export_larger_than_the_free_space_is_refused_before_writing(capsys, monkeypatch, tmp_path, store):
    import shutil

    from evsda.graph import files

    monkeypatch.setattr(files.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10**9, 10**9, 1000))
    from evsda.graph.store import RunStore

    needed = (RunStore.open(store).n_events * 41 + (1 << 20)) / 1e6     # 41 bytes per event in HDF5, + 1 MiB
    status, lines = cli(capsys, "export", store, "--format", "hdf5", "-o", tmp_path / "out.h5")
    assert status == 2 and len(lines) == 1, lines
    assert f"needs up to {needed:.1f} MB" in lines[0] and "0.0 MB free" in lines[0]
    assert not (tmp_path / "out.h5").exists() and not leftovers(tmp_path)


@pytest.mark.parametrize("nth", [1, 30])
def test_a_run_stopped_by_a_full_disk_says_what_is_kept_and_resumes(evsda, reference, capsys, tmp_path, nth):
    """A store wrapper raises ENOSPC from the nth chunk write on (the first: before any commit). The resume is the
    same command through evsda's main() in this process (resuming in a new process: tests/faults/test_faults_kills.py)."""
    graph, store = graph_file(tmp_path), tmp_path / "run.zarr"
    full = evsda.fault(r"/c/", nth, "enospc", "run", graph, "-o", store, "-q", "--checkpoint-every", "0")
    line = one_line_error(full, f"writing run store {store} failed: no space left on the device")
    assert ("nothing was committed yet" in line) if nth == 1 else ("windows are committed" in line)
    status, lines = cli(capsys, "run", graph, "-o", store, "--resume", "-q")
    assert status == 0, lines
    assert_identical(store, reference)


def test_an_hdf5_export_stops_before_the_disk_fills_up(capsys, monkeypatch, tmp_path, store):
    """HDF5 crashes the process at exit once a write has hit ENOSPC, so the writer stops short of it."""
    import shutil

    from evsda.blocks.readout import exporters

    frees = iter([10**9] + [5 << 20] * 100)      # room at the start, then another writer fills the disk
    monkeypatch.setattr(exporters.shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10**9, 0, next(frees)))
    status, lines = cli(capsys, "export", store, "--format", "hdf5", "-o", tmp_path / "out.h5", "--chunk-size", "100")
    assert status == 2 and len(lines) == 1 and "stopped the HDF5 export before it runs out of space" in lines[0]
    assert not (tmp_path / "out.h5").exists() and not leftovers(tmp_path)


def test_nothing_is_written_inside_a_run_store(capsys, tmp_path, store):
    metadata = (store / "zarr.json").read_bytes()
    for args in (["export", store, "--format", "npy", "-o", store / "zarr.json", "--overwrite"],
                 ["render", store, "--png", store / "events" / "image.png"],
                 ["run", tmp_path / "chain.yaml", "-o", store / "inner.zarr"]):
        status, lines = cli(capsys, *args)
        assert status == 2 and len(lines) == 1 and f"inside the run store {store}" in lines[0], lines
    assert (store / "zarr.json").read_bytes() == metadata and not (store / "inner.zarr").exists()
