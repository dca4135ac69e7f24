"""Damaged stores and unfinished runs: a changed byte, a truncated or deleted chunk, a commit record
that claims more than the arrays hold, a damaged checkpoint; exports and images of unfinished runs.
Each is one line naming the array (exit 2), never zeros, wrong data or a traceback."""

from __future__ import annotations

import json

import numpy as np
import pytest
from evsda.graph import StoreError
from evsda.graph.store import RunStore
from faultkit import chunk_file, cli, run_in_process


def _flip(path, offset=-9):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x40
    path.write_bytes(bytes(data))


DAMAGE = {
    "flipped byte": lambda f: _flip(f),
    "truncated chunk": lambda f: f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 2]),
    "deleted chunk": lambda f: f.unlink(),
}


@pytest.mark.parametrize("damage", DAMAGE)
@pytest.mark.parametrize("array", ["events/x", "events/t_readout_ns", "events/cause"])
def test_a_damaged_event_chunk_is_an_error_naming_the_array(capsys, tmp_path, damage, array):
    store = run_in_process(tmp_path)
    DAMAGE[damage](chunk_file(store, array))
    status, lines = cli(capsys, "export", store, "--format", "npy", "-o", tmp_path / "out.npy")
    assert status == 2 and len(lines) == 1 and array in lines[0], lines
    assert "lost chunk 0" in lines[0] if damage == "deleted chunk" else "damaged in chunk 0" in lines[0]
    assert not list(tmp_path.glob("*.npy")) and not list(tmp_path.glob(".*partial*"))
    with pytest.raises(StoreError, match=array):
        RunStore.open(store).read_events()
    assert any(array in problem for problem in RunStore.open(store).verify())
    from evsda.graph.cli import main

    capsys.readouterr()
    assert main(["info", str(store)]) == 0           # says so, and shows the rest of what the store holds
    shown = capsys.readouterr().out.splitlines()
    assert shown[0].startswith(f"{store}: damaged: array {array} ") and shown[1] == "graph        chain"


def test_a_damaged_product_chunk_is_an_error_naming_the_array(tmp_path):
    store = run_in_process(tmp_path)
    _flip(chunk_file(store, "products/ramp/samples/value"))
    with pytest.raises(StoreError, match="products/ramp/samples/value is damaged in chunk 0"):
        list(RunStore.open(store).product_windows("ramp", "samples"))


def test_resume_never_extends_an_array_past_its_data(capsys, tmp_path):
    store = run_in_process(tmp_path, max_windows=4, checkpoint_every_s=0)
    document = json.loads((store / "zarr.json").read_text())
    document["attributes"]["committed"]["lengths"]["events/x"] += 100     # claims 100 events it lacks
    (store / "zarr.json").write_text(json.dumps(document))
    before = chunk_file(store, "events/x").read_bytes()
    status, lines = cli(capsys, "run", tmp_path / "chain.yaml", "-o", store, "--resume", "-q")
    assert status == 2 and len(lines) == 1 and "array events/x holds" in lines[0], lines
    assert chunk_file(store, "events/x").read_bytes() == before
    assert RunStore.open(store).status().describe().startswith("damaged: array events/x holds")


def test_a_damaged_checkpoint_refuses_resume_and_keeps_the_events(capsys, tmp_path):
    store = run_in_process(tmp_path, max_windows=4, checkpoint_every_s=0)
    (checkpoint,) = store.glob("checkpoint/w*/c/0")
    _flip(checkpoint)
    status, lines = cli(capsys, "run", tmp_path / "chain.yaml", "-o", store, "--resume", "-q")
    assert status == 2 and len(lines) == 1 and "checkpoint/w3 is damaged" in lines[0], lines
    assert RunStore.open(store).n_events > 0 and RunStore.open(store).read_events()["x"].size > 0


def test_an_unfinished_run_is_exported_only_with_partial_and_rendered_with_a_note(capsys, tmp_path):
    store = run_in_process(tmp_path, max_windows=4, checkpoint_every_s=0)
    assert RunStore.open(store).status().describe() == "incomplete: 4 of 12 windows committed; continue it with --resume"
    out = tmp_path / "events.npy"
    status, lines = cli(capsys, "export", store, "--format", "npy", "-o", out)
    assert status == 2 and len(lines) == 1 and "pass --partial" in lines[0] and "4 of 12" in lines[0]
    assert not out.exists()
    assert cli(capsys, "export", store, "--format", "npy", "-o", out, "--partial")[0] == 0
    assert np.load(out).size == RunStore.open(store).n_events
    status, lines = cli(capsys, "render", store, "--png", tmp_path / "image.png")
    assert status == 0 and lines == [f"evsda: note: {store} is not a finished run (incomplete: 4 of 12 windows "
                                     f"committed; continue it with --resume); drawing the events it has committed"]
