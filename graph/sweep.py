"""Parameter sweeps: run one graph over a grid of parameter values (a trade study).

A grid file maps ``block.param`` to the list of values to try; the sweep runs the
Cartesian product. Every point is checked before the first one runs. The first point
runs in full; later points reuse every upstream output that does not depend on the
swept parameters from the points already run (see :mod:`evsda.graph.executor`), so
sweeping an arbiter's clock rate does not recompute the optics. Results go to one run
store per point plus ``sweep.csv`` with each point's parameters and metrics::

    # temperature.yaml
    sensor/pixel.temperature_K: [250, 270, 290]
    sensor/arbiter.clock_hz: [1.0e6, 1.0e7]
"""

from __future__ import annotations

import csv
import itertools
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import GraphError, Problem, UserError
from .executor import run_graph
from .graphfile import load_graph, parse_value, read_yaml
from .store import RunStore, is_run_store


@dataclass(frozen=True)
class SweepPoint:
    index: int
    values: dict[str, Any]
    store: Path


def read_grid(path: str | Path | None, vary: list[str] = ()) -> dict[str, list[Any]]:
    """The grid from a YAML file and/or ``--vary block.param=[v1, v2]`` strings."""
    grid: dict[str, list[Any]] = {}
    if path is not None:
        data = read_yaml(Path(path))
        if not isinstance(data, dict) or not data:
            raise GraphError([Problem(str(path), "", "expected a mapping of block.param to a list of values")])
        grid.update(data)
    for text in vary:
        key, sep, value = text.partition("=")
        if not sep:
            raise UserError(f"--vary '{text}': expected block.param=[v1, v2, ...]")
        grid[key.strip()] = parse_value(value.strip())
    problems = [Problem(str(path or "--vary"), f"'{k}'", "expected a non-empty list of values")
                for k, v in grid.items() if not isinstance(v, list) or not v]
    if problems:
        raise GraphError(problems)
    if not grid:
        raise UserError("the sweep has no parameters to vary; give --grid FILE or --vary block.param=[...]")
    return grid


def plan(graph_path: str, grid: dict[str, list[Any]], out_dir: Path, overrides: list[str] = ()) -> list[SweepPoint]:
    """Every point of the grid, each checked by loading its graph (all problems reported together)."""
    keys = list(grid)
    points, problems = [], []
    for index, combo in enumerate(itertools.product(*(grid[k] for k in keys))):
        values = dict(zip(keys, combo))
        try:
            load_graph(graph_path, [*overrides, *(f"{k}={v}" for k, v in values.items())])
        except GraphError as exc:
            problems.extend(p for p in exc.problems if p not in problems)
        points.append(SweepPoint(index, values, out_dir / f"point_{index:03d}.zarr"))
    if problems:
        raise GraphError(problems)
    return points


def _run_point(graph_path: str, overrides: list[str], point: SweepPoint, reuse: list[Path], overwrite: bool) -> dict:
    graph = load_graph(graph_path, [*overrides, *(f"{k}={v}" for k, v in point.values.items())])
    if point.store.exists() and not overwrite:
        if is_run_store(point.store):      # else a point killed before its first window: resume starts it over
            store = RunStore.open(point.store)
            if store.complete and store.attrs.get("graph_hash") == graph.digest():
                return {"metrics": store.metrics, "reused": {}, "skipped": True}
        result = run_graph(graph, point.store, resume=True, reuse=reuse, progress=False)
    else:
        result = run_graph(graph, point.store, overwrite=overwrite, reuse=reuse, progress=False)
    return {"metrics": result.metrics, "reused": result.reused, "skipped": False}


def _share_cores(threads: int) -> None:
    """Let each of ``--jobs`` worker processes run its blocks' threads on its share of the cores only."""
    os.environ.setdefault("EVSDA_THREADS", str(threads))


def run_sweep(graph_path: str, grid: dict[str, list[Any]], out_dir: str | Path, overrides: list[str] = (),
              jobs: int = 1, overwrite: bool = False, report=print) -> list[dict]:
    """Run every point; returns one row (parameters + metrics) per point and writes ``sweep.csv``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    points = plan(graph_path, grid, out_dir, overrides)
    report(f"sweep: {len(points)} points into {out_dir}")
    outcomes: dict[int, dict] = {}
    first, rest = points[0], points[1:]
    outcomes[first.index] = _run_point(graph_path, list(overrides), first, [], overwrite)
    if jobs > 1 and rest:
        threads = max(1, (os.cpu_count() or 1) // jobs)
        with ProcessPoolExecutor(max_workers=jobs, initializer=_share_cores, initargs=(threads,)) as pool:
            futures = {p.index: pool.submit(_run_point, graph_path, list(overrides), p, [first.store], overwrite)
                       for p in rest}
            outcomes.update({i: f.result() for i, f in futures.items()})
    else:
        done = [first.store]
        for point in rest:
            outcomes[point.index] = _run_point(graph_path, list(overrides), point, list(done), overwrite)
            done.append(point.store)
    rows = []
    for point in points:
        outcome = outcomes[point.index]
        status = "already complete" if outcome["skipped"] else (
            f"reused {', '.join(sorted(outcome['reused']))}" if outcome["reused"] else "computed in full")
        report(f"  point {point.index}: {point.values} -> {point.store.name} ({status})")
        rows.append({"point": point.index, **point.values, **outcome["metrics"], "store": str(point.store)})
    columns = list(dict.fromkeys(key for row in rows for key in row))
    with open(out_dir / "sweep.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    report(f"sweep: results in {out_dir / 'sweep.csv'}")
    return rows
