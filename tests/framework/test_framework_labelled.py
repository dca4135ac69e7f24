"""Run stores as labelled data: xarray opens every group (dimension names, units, CF flags), metrics are
data, and ``evsda info`` / ``run --json`` say what a store holds."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import xarray as xr

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.blocks.ports import Events
from evsda.graph.store import RunStore

from .conftest import write

EVENT_ATTRS = {name: attrs for name, (_, attrs) in Events.stream_columns.items()}   # events/ columns, CF attributes


def counted(tmp_path):
    return write(tmp_path / "counted.yaml", """\
        evsda: 1
        name: counted
        run: {start: "2024-03-01T02:15:00Z", duration_s: 0.05, window_s: 0.01, seed: 7}
        blocks:
          ramp: {type: test_ramp}
          spikes: {type: test_spikes}
          count: {type: test_counter}
        connections:
          - {from: ramp.samples, to: spikes.samples}
          - {from: spikes.events, to: count.events}
        outputs: [count.metrics, spikes.events]
        """)


@pytest.fixture
def store_path(plugin, tmp_path):
    out = tmp_path / "run.zarr"
    run_graph(load_graph(counted(tmp_path)), out, progress=False, keep_checkpoint=True)
    return out


def open_group(path, group):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # the lock file and xarray's consolidated-metadata note
        return xr.open_zarr(path, group=group, consolidated=False).load()


def test_events_open_as_a_labelled_dataset(store_path):
    events = open_group(store_path, "events")
    stored = RunStore.open(store_path).read_events()
    assert set(events.data_vars) == set(EVENT_ATTRS) and events.sizes["event"] == len(stored["x"]) > 0
    for name in EVENT_ATTRS:
        assert np.array_equal(events[name].values, stored[name])
        assert events[name].dims == ("event",)
    assert events.t_readout_ns.attrs["units"] == "ns" and events.x.attrs["units"] == "pixel"
    # cause is a CF categorical whose labels are the EventCause members, in order
    from evsda.blocks.ports import EventCause
    assert events.cause.attrs["flag_values"] == [c.value for c in EventCause]
    assert events.cause.attrs["flag_meanings"].split() == [c.name.lower() for c in EventCause]
    assert events.p.attrs["flag_meanings"] == "OFF ON"


def test_metrics_products_and_checkpoint_are_data(store_path):
    metrics = open_group(store_path, "metrics")
    n = RunStore.open(store_path).n_events
    assert metrics.value.sel(metric="events_counted").item() == n
    assert metrics.unit.sel(metric="events_counted").item() == "event"
    tree = xr.open_datatree(store_path, engine="zarr", consolidated=False)
    samples = tree["products/ramp/samples"].dataset
    assert samples.sizes["window"] == 5 and samples.t_ns.attrs["units"] == "ns"
    assert samples["t_ns.shape"].dims == ("window", "t_ns_axis")
    assert len(tree["checkpoint"].dataset.data_vars) == 1


def test_tables_append_and_open_in_xarray(tmp_path):
    store = RunStore.create(tmp_path / "t.zarr")
    for start in (0, 3):
        store.append_table("truth", {"t_ns": np.arange(start, start + 3, dtype=np.int64),
                                     "id": np.array(["a", "b", "c"])}, "sample",
                           {"t_ns": {"units": "ns"}})
    store.commit(windows=1)
    assert list(store.read_table("truth")["t_ns"]) == list(range(6))
    truth = open_group(tmp_path / "t.zarr", "truth")
    assert truth.t_ns.dims == ("sample",) and truth.t_ns.attrs["units"] == "ns"
    assert list(truth.id.values) == ["a", "b", "c"] * 2
    from evsda.graph.report import describe_store, store_info
    info = store_info(RunStore.open(tmp_path / "t.zarr"))
    assert info["tables"] == {"truth": {"id": 6, "t_ns": 6}}
    assert "table        truth: 6 rows of id, t_ns" in describe_store(info)
