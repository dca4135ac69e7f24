"""Pipelined windows (issue 13.1): the same bytes as one step at a time, whatever the threads' timing.

The toy blocks below draw random numbers, keep state and sleep for random (unseeded) moments, so the
order in which steps of different windows finish changes from run to run; the stores must not.
"""

from __future__ import annotations

import random
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from pydantic import Field

from evsda.blocks.ports import Events, FocalPlane
from evsda.graph import Block, BlockParams, Input, Output, PortValue, SceneError, UserError, Window, registry
from evsda.graph.executor import run_graph
from evsda.graph.executor_pipeline import pipeline_enabled
from evsda.graph.graphfile import graph_from_dict
from evsda.graph.store import RunStore

sys.path.insert(0, str(Path(__file__).parents[1]))
from test_examples_identical import SHORT, store_digest  # noqa: E402

GEOMETRY = FocalPlane(width_px=16, height_px=8, pixel_pitch_m=5e-6, focal_length_m=1.0)
JITTER = random.Random()            # timing only: unseeded on purpose
LOG: list[tuple[str, int, str, float]] = []     # (block, window, "start" / "end", perf_counter)
LOG_LOCK = threading.Lock()


@dataclass(frozen=True, eq=False)
class PipeToken(PortValue):
    """A few numbers per window."""

    unit = "1"
    value: np.ndarray


class _Toy(Block):
    class Params(BlockParams):
        jitter_s: float = Field(0.0, ge=0, description="Longest random pause per step [s]")
        fail_at_window: int | None = Field(None, description="Raise a SceneError in this window")

    state = ("total",)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.total = 0.0

    def _enter(self, window: Window) -> None:
        with LOG_LOCK:
            LOG.append((self.name, window.index, "start", time.perf_counter()))
        time.sleep(JITTER.uniform(0.0, self.params.jitter_s))
        if window.index == self.params.fail_at_window:
            raise SceneError(f"{self.label} fails in window {window.index}")

    def _leave(self, window: Window, value: np.ndarray) -> np.ndarray:
        self.total += float(value.sum())
        with LOG_LOCK:
            LOG.append((self.name, window.index, "end", time.perf_counter()))
        return value


class ToySource(_Toy):
    type_name = "pipe_source"
    outputs = {"out": Output(PipeToken, "numbers")}

    def step(self, window: Window) -> dict:
        self._enter(window)
        return {"out": PipeToken(self._leave(window, self.rng.standard_normal(5) + self.total))}


class ToyFilter(_Toy):
    type_name = "pipe_filter"
    inputs = {"inp": Input(PipeToken, "numbers")}
    outputs = {"out": Output(PipeToken, "numbers")}

    def step(self, window: Window, inp: PipeToken) -> dict:
        self._enter(window)
        return {"out": PipeToken(self._leave(window, inp.value * self.rng.random() + 1e-3 * self.total))}


class ToySink(_Toy):
    type_name = "pipe_sink"
    is_sink = True
    inputs = {"inp": Input(PipeToken, "numbers", multi=True)}
    outputs = {"events": Output(Events, "events")}

    def step(self, window: Window, inp: list) -> dict:
        self._enter(window)
        total = self._leave(window, np.concatenate([v.value for v in inp]))
        n = int(abs(total.sum() * 10)) % 7 + self.rng.integers(0, 4)
        t = np.sort(self.rng.integers(window.start_ns, window.stop_ns, n))
        x = self.rng.integers(0, GEOMETRY.width_px, n).astype(np.uint16)
        y = self.rng.integers(0, GEOMETRY.height_px, n).astype(np.uint16)
        p = np.where(self.rng.random(n) < 0.5, 1, -1).astype(np.int8)
        return {"events": Events(GEOMETRY, t, t, x, y, p, np.zeros(n, np.uint8))}


@pytest.fixture(scope="module", autouse=True)
def toys():
    for cls in (ToySource, ToyFilter, ToySink):
        registry.register(cls, "test")
    yield
    for cls in (ToySource, ToyFilter, ToySink):
        registry.unregister(cls.type_name)


def diamond(windows: int = 24, jitter_s: float = 0.004, **params) -> dict:
    """src -> a -> b -> sink and src -> sink: a chain beside a short cut, every block jittered."""
    def block(kind, name):
        return {"type": kind, "params": {"jitter_s": jitter_s, **params.get(name, {})}}
    return {
        "evsda": 1, "name": "diamond",
        "run": {"start": "2024-01-01T00:00:00Z", "duration_s": windows * 0.01, "window_s": 0.01, "seed": 3,
                "store_products": True},
        "blocks": {"src": block("pipe_source", "src"), "a": block("pipe_filter", "a"),
                   "b": block("pipe_filter", "b"), "sink": block("pipe_sink", "sink")},
        "connections": [{"from": "src.out", "to": "a.inp"}, {"from": "a.out", "to": "b.inp"},
                        {"from": "b.out", "to": "sink.inp"}, {"from": "src.out", "to": "sink.inp"}],
    }


def run(tmp_path: Path, name: str, graph: dict, **options) -> str:
    out = tmp_path / f"{name}.zarr"
    run_graph(graph_from_dict(graph), out, progress=False, **options)
    return store_digest(out)


def test_pipelined_stores_equal_serial_ones_whatever_the_timing(tmp_path):
    serial = run(tmp_path, "serial", diamond(), pipeline=False)
    for i in range(3):
        assert run(tmp_path, f"pipelined{i}", diamond(), pipeline=True) == serial
    assert run(tmp_path, "every-window", diamond(), pipeline=True, checkpoint_every_s=0) == serial


def test_the_pipeline_overlaps_windows_and_keeps_each_blocks_order(tmp_path):
    LOG.clear()
    graph = diamond(windows=12, jitter_s=0.0, sink={"jitter_s": 0.02})
    run(tmp_path, "pipelined", graph, pipeline=True)
    spans = {(name, k, what): t for name, k, what, t in LOG}
    # the source ran ahead: its step over window k + 1 started before the sink finished window k
    assert any(spans[("src", k + 1, "start")] < spans[("sink", k, "end")] for k in range(11))
    # and nothing ran before what it depends on: its own previous window, its inputs of the same window
    for name, k, what, t in LOG:
        if what == "start" and k:
            assert t >= spans[(name, k - 1, "end")]
    for k in range(12):
        assert spans[("sink", k, "start")] >= max(spans[("b", k, "end")], spans[("src", k, "end")])
    LOG.clear()
    run(tmp_path, "serial", graph, pipeline=False)
    ends = [t for name, k, what, t in LOG if what == "end"]
    starts = [t for name, k, what, t in LOG if what == "start"]
    assert all(s >= e for s, e in zip(starts[1:], ends[:-1]))          # one step at a time


def test_a_stopped_pipelined_run_resumes_to_the_serial_bytes(tmp_path):
    serial = run(tmp_path, "serial", diamond(), pipeline=False)
    graph = graph_from_dict(diamond())
    run_graph(graph, tmp_path / "part.zarr", progress=False, pipeline=True, max_windows=9, checkpoint_every_s=1e3)
    assert RunStore.open(tmp_path / "part.zarr").committed_windows == 9
    run_graph(graph_from_dict(diamond()), tmp_path / "part.zarr", progress=False, pipeline=True, resume=True)
    assert store_digest(tmp_path / "part.zarr") == serial


def test_an_error_is_the_one_a_serial_run_meets_and_keeps_what_it_keeps(tmp_path):
    """The sink fails in window 5 after a pause; the source, running ahead, fails in window 6 first."""
    graph = diamond(jitter_s=0.0, sink={"fail_at_window": 5, "jitter_s": 0.05}, src={"fail_at_window": 6})
    for every_s, committed in ((1e3, 0), (0, 5)):     # 0: a commit after every window (a barrier each)
        errors, stores = [], []
        for pipeline in (False, True):
            out = tmp_path / f"{pipeline}-{every_s}.zarr"
            with pytest.raises(SceneError) as caught:
                run_graph(graph_from_dict(graph), out, progress=False, pipeline=pipeline, checkpoint_every_s=every_s)
            errors.append(str(caught.value))
            store = RunStore.open(out)
            stores.append((store.committed_windows, len(list(store.product_windows("a", "out")))))
        assert errors[0] == errors[1] == "pipe_sink 'sink' fails in window 5"
        assert stores[0] == stores[1] == (committed, committed)


def test_the_switch(tmp_path, monkeypatch):
    monkeypatch.setenv("EVSDA_PIPELINE", "0")
    assert not pipeline_enabled() and pipeline_enabled(True)
    monkeypatch.setenv("EVSDA_PIPELINE", "1")
    assert pipeline_enabled() and not pipeline_enabled(False)
    monkeypatch.setenv("EVSDA_PIPELINE", "yes")
    with pytest.raises(UserError, match="EVSDA_PIPELINE must be 1"):
        run_graph(graph_from_dict(diamond()), tmp_path / "x.zarr")
    assert not (tmp_path / "x.zarr").exists()


def test_a_physics_scene_records_the_same_bytes_pipelined(tmp_path):
    """The short ISS pass of tests/test_examples_identical.py (optics, pixels, readout, metrics): one step at a
    time, pipelined in threads, and pipelined with the optics in a worker process (evsda.graph.worker)."""
    from evsda.graph.graphfile import load_graph

    examples = Path(__file__).parents[2] / "examples"
    digests = []
    for pipeline, workers in ((False, False), (True, False), (True, True)):
        out = tmp_path / f"{pipeline}-{workers}.zarr"
        run_graph(load_graph(examples / "iss_pass.yaml", dict(SHORT["iss_pass.yaml"])), out, progress=False,
                  pipeline=pipeline, workers=workers)
        digests.append(store_digest(out))
    assert digests[0] == digests[1] == digests[2]
