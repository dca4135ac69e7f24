"""Executor overhead and run-store throughput.

Prints
* the executor's own overhead per block per window (a chain of blocks that do no work),
  without a store and with every output stored as a product;
* event append throughput to the run store (events/s and MB/s), commit included, and its cost of
  the CRC-32C every chunk carries (appends with and without it, alternated, medians of 3).

Targets (issue 2): overhead below 1 ms per block per window; appending >= 20 M events/s.

    python benchmarks/framework_executor.py
"""

from __future__ import annotations

import platform
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evsda.graph import Block, Input, Output, PortValue, Window, registry
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import graph_from_dict
from evsda.graph.store import RunStore, event_fields


@dataclass(frozen=True, eq=False)
class Token(PortValue):
    unit = "1"
    value: np.ndarray


class Source(Block):
    """Emits a small array each window."""

    type_name = "bench_source"
    outputs = {"out": Output(Token)}

    def step(self, window: Window) -> dict:
        return {"out": Token(np.arange(4))}


class Relay(Block):
    """Passes its input on."""

    type_name = "bench_relay"
    inputs = {"inp": Input(Token)}
    outputs = {"out": Output(Token)}
    is_sink = True

    def step(self, window: Window, inp: Token) -> dict:
        return {"out": inp}


def chain_graph(n_blocks: int, n_windows: int, store_products: bool) -> dict:
    blocks = {"b0": {"type": "bench_source"}}
    blocks.update({f"b{i}": {"type": "bench_relay"} for i in range(1, n_blocks)})
    return {
        "evsda": 1, "name": "bench",
        "run": {"start": "2024-01-01T00:00:00Z", "duration_s": n_windows * 1e-3, "window_s": 1e-3, "seed": 0,
                "store_products": store_products},
        "blocks": blocks,
        "connections": [{"from": f"b{i - 1}.out", "to": f"b{i}.inp"} for i in range(1, n_blocks)],
        "outputs": [f"b{n_blocks - 1}.out"],
    }


def executor_overhead(n_blocks=20, n_windows=500, with_store=False) -> float:
    graph = graph_from_dict(chain_graph(n_blocks, n_windows, with_store))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run.zarr" if with_store else None
        t0 = time.perf_counter()
        run_graph(graph, out, progress=False, checkpoint_every_s=5.0, keep_outputs=False)
        elapsed = time.perf_counter() - t0
    return elapsed / (n_blocks * n_windows)


def event_append_throughput(n_events=40_000_000, batch=2_000_000) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.exponential(100.0, batch)).astype(np.int64)
    events = {
        "t_trigger_ns": t, "t_readout_ns": t + rng.integers(0, 5000, batch),
        "x": rng.integers(0, 1280, batch).astype(np.uint16), "y": rng.integers(0, 720, batch).astype(np.uint16),
        "p": rng.choice(np.array([-1, 1], np.int8), batch), "cause": rng.integers(0, 4, batch).astype(np.uint8),
    }
    nbytes = sum(np.dtype(d).itemsize for d in event_fields().values()) * n_events
    tmp = tempfile.mkdtemp()
    try:
        store = RunStore.create(Path(tmp) / "events.zarr")
        t0 = time.perf_counter()
        for _ in range(n_events // batch):
            store.append_events(events)
        store.commit()
        elapsed = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp)
    return n_events / elapsed, nbytes / elapsed / 1e6


def main() -> None:
    for cls in (Source, Relay):
        registry.register(cls, "benchmark")
    print(f"machine: {platform.machine()}, {platform.processor() or platform.platform()}")
    for with_store in (False, True):
        per_block = executor_overhead(with_store=with_store)
        label = "with every output stored" if with_store else "no store"
        print(f"executor overhead ({label}): {per_block * 1e3:.3f} ms per block per window")
    rate, mbps = event_append_throughput()
    print(f"event append to the store (commit included): {rate / 1e6:.1f} M events/s, {mbps:.0f} MB/s")
    print(f"checksum cost: {checksum_cost():.0%} of the append throughput (CRC-32C per chunk, medians of 3)")


def checksum_cost(repeats: int = 3, n_events: int = 20_000_000) -> float:
    """1 - (append rate with the CRC-32C) / (rate with a stand-in that computes none), runs alternated (the store's
    chunks are written by evsda.graph.store_files, whose codecs get the stand-in)."""
    from evsda.graph import store_files

    codecs = store_files._codecs

    def without_checksum():
        blosc, zstd, vlen, _ = codecs()
        return blosc, zstd, vlen, type("NoChecksum", (), {"value": staticmethod(lambda data: 0)})

    rates = {True: [], False: []}
    try:
        for _ in range(repeats):
            for checked in (True, False):
                store_files._codecs = codecs if checked else without_checksum
                rates[checked].append(event_append_throughput(n_events)[0])
    finally:
        store_files._codecs = codecs
    return 1 - float(np.median(rates[True]) / np.median(rates[False]))


if __name__ == "__main__":
    main()
