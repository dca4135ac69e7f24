"""A checkpoint is streamed into the store: writing it holds about one chunk beside the states, not a copy."""

from __future__ import annotations

import tracemalloc

import numpy as np

from evsda.graph.store import CHECKPOINT_CHUNK_BYTES, RunStore


def test_checkpoint_round_trip_in_bounded_memory(tmp_path):
    rng = np.random.default_rng(3)
    real = rng.standard_normal((1_000_000, 12))                       # 96 MB: a 1280 x 720 sensor's float table
    count = rng.integers(0, 2**40, size=(300_000, 7))
    states = {"sensor": {"real": real, "count": count, "key": 7, "name": "x"}, "optics": {"held": {"0": [1.5, 2.5]}}}
    # a first, small checkpoint imports what writing one needs (Zarr, its codecs: ~10 MB of module objects that
    # tracemalloc would count, and that a process imports once), so the peak below is the stream's alone
    RunStore.create(tmp_path / "warm.zarr").write_checkpoint(0, {"sensor": {"real": real[:10]}})
    store = RunStore.create(tmp_path / "run.zarr")
    tracemalloc.start()
    try:
        name = store.write_checkpoint(4, states)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # a copy of the archive alone would be 113 MB; the stream holds a few chunks (numpy's and Zarr's buffers)
    assert peak < 5 * CHECKPOINT_CHUNK_BYTES, peak / 1e6
    store.commit(windows=5, checkpoint=name)
    back = RunStore.open(tmp_path / "run.zarr").read_checkpoint()
    assert np.array_equal(back["sensor"]["real"], real) and np.array_equal(back["sensor"]["count"], count)
    assert back["sensor"]["key"] == 7 and back["sensor"]["name"] == "x"
    assert back["optics"]["held"] == {"0": [1.5, 2.5]}
