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


class ScriptedPolicy:
    """A stand-in for the core gauge's policy (graph/core_share.py): one step at a time after the steps it says."""

    def __init__(self, solo_after: list[bool]):
        self.solo_after = solo_after
        self.ended = 0

    def update(self) -> bool:
        self.ended += 1
        return self.solo_after[(self.ended - 1) % len(self.solo_after)]


@pytest.fixture
def scripted(monkeypatch):
    """Pipelined runs switch between the pipeline and one step at a time as ``script`` says, step end after step
    end."""
    from evsda.graph import executor_pipeline

    def use(script: list[bool]) -> None:
        monkeypatch.setattr(executor_pipeline, "SoloPolicy", lambda: ScriptedPolicy(script))
    return use


@pytest.mark.parametrize("script", [[True], [False, True, True], [True, False], [False] * 7 + [True] * 5])
def test_one_step_at_a_time_inside_a_pipelined_run_keeps_the_bytes(tmp_path, scripted, script):
    serial = run(tmp_path, "serial", diamond(), pipeline=False)
    scripted(script)
    assert run(tmp_path, "switching", diamond(), pipeline=True, adapt=True) == serial
    assert run(tmp_path, "every-window", diamond(), pipeline=True, adapt=True, checkpoint_every_s=0) == serial


def test_one_step_at_a_time_runs_on_the_recording_thread_alone(tmp_path, scripted):
    scripted([False] * 12 + [True] * 10**4)          # solo from the thirteenth step's end on
    LOG.clear()
    threads = {}
    original = _Toy._enter

    def enter(self, window):
        threads[(self.name, window.index)] = threading.get_ident()
        original(self, window)

    _Toy._enter = enter
    try:
        run(tmp_path, "solo", diamond(windows=30, jitter_s=0.002), pipeline=True, adapt=True)
    finally:
        _Toy._enter = original
    spans = {}
    for name, k, what, t in LOG:
        spans.setdefault((name, k), {})[what] = t
    mine = [span for key, span in spans.items() if threads[key] == threading.get_ident()]
    pool = [span for key, span in spans.items() if threads[key] != threading.get_ident()]
    assert len(mine) >= 20 and pool           # the pool's steps up to the switch (the source ran ahead), then solo
    for span in mine:                         # none beside another step
        assert all(other["end"] <= span["start"] or other["start"] >= span["end"]
                   for other in spans.values() if other is not span)
    assert max(span["end"] for span in pool) <= min(span["start"] for span in mine)


def test_an_error_one_step_at_a_time_is_the_serial_one(tmp_path, scripted):
    graph = diamond(jitter_s=0.0, sink={"fail_at_window": 5, "jitter_s": 0.05}, src={"fail_at_window": 6})
    scripted([False, True])
    for every_s, committed in ((1e3, 0), (0, 5)):
        out = tmp_path / f"{every_s}.zarr"
        with pytest.raises(SceneError, match="pipe_sink 'sink' fails in window 5"):
            run_graph(graph_from_dict(graph), out, progress=False, pipeline=True, adapt=True,
                      checkpoint_every_s=every_s)
        store = RunStore.open(out)
        assert (store.committed_windows, len(list(store.product_windows("a", "out")))) == (committed, committed)


def test_a_run_held_to_one_core_goes_one_step_at_a_time_throughout(tmp_path, monkeypatch):
    serial = run(tmp_path, "serial", diamond(), pipeline=False)
    monkeypatch.setenv("EVSDA_THREADS", "1")
    threads = set()
    original = _Toy._enter

    def enter(self, window):
        threads.add(threading.get_ident())
        original(self, window)

    monkeypatch.setattr(_Toy, "_enter", enter)
    assert run(tmp_path, "one-core", diamond(), pipeline=True, adapt=True) == serial
    assert threads == {threading.get_ident()}
    threads.clear()
    run(tmp_path, "one-core-kept", diamond(), pipeline=True, adapt=False)
    assert threading.get_ident() not in threads
