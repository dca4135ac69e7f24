"""Helpers of the fault-injection suite (imported by its tests; the fixtures are in conftest.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

GRAPH = """\
evsda: 1
name: chain
run: {{start: "2024-03-01T02:15:00Z", duration_s: {duration_s}, window_s: 0.01, seed: 7}}
blocks:
  ramp: {{type: test_ramp}}
  spikes: {{type: test_spikes, params: {{sleep_s: {sleep_s}, step: 2.0}}}}
  count: {{type: test_counter}}
connections:
  - {{from: ramp.samples, to: spikes.samples}}
  - {{from: spikes.events, to: count.events}}
"""


def graph_file(folder: Path, duration_s: float = 0.12, sleep_s: float = 0.0, name: str = "chain.yaml") -> Path:
    path = folder / name
    path.write_text(GRAPH.format(duration_s=duration_s, sleep_s=sleep_s))
    return path


def committed(store: Path) -> dict:
    try:
        return json.loads((store / "zarr.json").read_text())["attributes"]["committed"]
    except (OSError, ValueError, KeyError):
        return {}


def contents(store: Path) -> dict:
    """Everything a run store holds that a resume must reproduce: events, products, metrics."""
    from evsda.graph.store import RunStore

    opened = RunStore.open(store)
    out = {f"events/{k}": v.tobytes() for k, v in opened.read_events().items()}
    for w, value in enumerate(opened.product_windows("ramp", "samples")):
        arrays, attrs = value.to_arrays()
        out[f"products/ramp/{w}"] = ({k: np.asarray(v).tobytes() for k, v in arrays.items()},
                                    json.dumps(attrs, sort_keys=True, default=str))
    out["metrics"] = opened.metrics
    out["complete"] = opened.complete
    return out


def assert_identical(store: Path, reference: Path) -> None:
    got, want = contents(store), contents(reference)
    assert got.keys() == want.keys()
    for key in want:
        assert got[key] == want[key], key


def one_line_error(proc, *fragments: str, status: int = 2) -> str:
    """Assert the command failed with ``status`` and exactly one ``evsda:`` line holding every fragment."""
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == status, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]



def cli(capsys, *args) -> tuple[int, list[str]]:
    """Run ``evsda`` in this process; returns its exit status and its non-empty stderr lines."""
    from evsda.graph.cli import main

    capsys.readouterr()
    status = main([str(a) for a in args])
    return status, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def run_in_process(folder: Path, name: str = "run.zarr", **options) -> Path:
    """A finished (or, with ``max_windows``, unfinished) run of the fault graph in ``folder``."""
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph

    store = folder / name
    run_graph(load_graph(graph_file(folder)), store, progress=False, **options)
    return store


def chunk_file(store: Path, array: str, index: int = 0) -> Path:
    """The file of chunk ``index`` of a 1-D array of a run store."""
    return store / array / "c" / str(index)
