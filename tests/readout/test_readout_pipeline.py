"""The readout blocks inside the executor: a run killed after a few windows and resumed
from its Zarr checkpoint gives the same recorded events as an uninterrupted run, the
stored metrics conserve events, and an arbiter swaps by one `type` line."""

import numpy as np
import pytest
from pydantic import Field

from evsda.blocks.ports import FocalPlane, TriggeredEvents
from evsda.graph import Block, BlockParams, Output, Window, registry
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import graph_from_dict
from evsda.graph.store import RunStore

FP = FocalPlane(48, 32, 10e-6, 1.0)


class NoisyPixels(Block):
    """Test source: Poisson-distributed triggered events with a dense burst every 7 ms."""

    type_name = "test_readout_noisy_pixels"

    class Params(BlockParams):
        rate_hz: float = Field(2e6, gt=0, description="Events per second over the sensor [Hz]")

    outputs = {"events": Output(TriggeredEvents, "synthetic triggered events")}

    def step(self, window: Window) -> dict:
        n = self.rng.poisson(self.params.rate_hz * window.duration_s)
        t = np.sort(self.rng.integers(window.start_ns, window.stop_ns, n))
        burst = np.arange(-(-window.start_ns // 7_000_000), -(-window.stop_ns // 7_000_000)) * 7_000_000
        t = np.sort(np.concatenate([t, np.repeat(burst, 300)]))
        x = self.rng.integers(0, FP.width_px, t.size)
        y = self.rng.integers(0, FP.height_px, t.size)
        order = np.lexsort((x, y, t))
        return {"events": TriggeredEvents(FP, t[order], x[order].astype(np.uint16), y[order].astype(np.uint16),
                                          self.rng.choice(np.array([-1, 1], np.int8), t.size),
                                          np.full(t.size, 3, np.uint8), n_loss=int(self.rng.integers(0, 5)))}


@pytest.fixture
def noisy_source():
    registry.register(NoisyPixels)
    yield
    registry.unregister(NoisyPixels.type_name)


def graph(arbiter_type: str, params: dict):
    return graph_from_dict({
        "evsda": 1, "name": "readout_pipeline",
        "run": {"start": "2024-03-01T02:15:00Z", "duration_s": 0.02, "window_s": 0.005, "seed": 3},
        "blocks": {"pixels": {"type": NoisyPixels.type_name},
                   "arbiter": {"type": arbiter_type, "params": params},
                   "metrics": {"type": "event_metrics"}},
        "connections": [{"from": "pixels.events", "to": "arbiter.events"},
                        {"from": "pixels.events", "to": "metrics.triggered"},
                        {"from": "arbiter.events", "to": "metrics.events"}],
        "outputs": ["arbiter.events", "metrics.metrics"],
    })


ROW_SCAN = {"clock_hz": 100e6, "bus_throughput_eps": 10e6, "queue_depth": 8, "row_cycles": 4}


def test_killed_and_resumed_run_records_the_same_events(tmp_path, noisy_source):
    whole = run_graph(graph("row_scan_arbiter", ROW_SCAN), tmp_path / "whole.zarr", progress=False,
                      checkpoint_every_s=0)
    run_graph(graph("row_scan_arbiter", ROW_SCAN), tmp_path / "cut.zarr", progress=False,
              checkpoint_every_s=0, max_windows=2)
    resumed = run_graph(graph("row_scan_arbiter", ROW_SCAN), tmp_path / "cut.zarr", progress=False,
                        checkpoint_every_s=0, resume=True)
    a, b = whole.store.read_events(), RunStore.open(tmp_path / "cut.zarr").read_events()
    assert len(a["x"]) > 10_000
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    m = whole.metrics
    assert m["events_triggered"] == m["events_recorded"] + m["events_dropped_readout"]
    assert m["events_recorded"] == len(a["x"]) and m["events_dropped_readout"] > 0
    assert resumed.metrics["events_recorded"] == m["events_recorded"]


@pytest.mark.parametrize("arbiter, params", [("ideal_readout", {}), ("row_scan_arbiter", ROW_SCAN),
                                             ("column_burst_arbiter", {"group_width_px": 8})])
def test_arbiters_swap_by_type(tmp_path, noisy_source, arbiter, params):
    result = run_graph(graph(arbiter, params), tmp_path / "run.zarr", progress=False)
    m = result.metrics
    assert m["events_triggered"] == m["events_recorded"] + m["events_dropped_readout"]
    ev = result.store.read_events()
    assert np.all(np.diff(ev["t_readout_ns"]) >= 0)
    if arbiter == "ideal_readout":
        assert m["readout_delay_max_s"] == 0 and m["out_of_order_fraction"] == 0
    else:
        assert m["readout_delay_p50_s"] > 0 and m["out_of_order_fraction"] > 0
