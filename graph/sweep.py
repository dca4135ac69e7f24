"""Parameter sweeps (trade studies): one graph over many parameter values, as Dask tasks.

A grid file maps ``block.param`` (or ``run.field``) to a list of values or to a range::

    # temperature.yaml
    sensor/pixel.temperature_K: [250, 270, 290]          # a list: every value (grid) or drawn from it
    sensor/arbiter.clock_hz: {min: 1.0e6, max: 1.0e8, log: true}   # a range: sampled (random, lhs)

``grid`` sampling runs the Cartesian product of the lists; ``random`` and ``lhs`` (Latin hypercube)
draw ``points`` points from the lists and ranges with a seed. Each distinct value is checked once
against its block's parameters before anything runs (:func:`~evsda.graph.graphfile.check_override`).

Points run as Dask tasks, on a ``distributed.LocalCluster`` (one single-threaded worker process per
job) or on a running cluster (``scheduler``); ``jobs=1`` runs them one after another in this process.
Each point writes its own run store in the sweep folder, which every worker must reach. Points that
share upstream blocks (those no swept value reaches) reuse them: the first point with given upstream
values stores the outputs the others need and they wait for it (:func:`reuse_plan`).

A failing point is recorded with its parameters and a one-line error; the others go on. Results
stream as points finish: a row per point appended to ``sweep.csv`` and rewritten atomically into
``sweep.parquet`` (parameters, status, wall and CPU time, error, store, metrics). Re-running the same
command skips finished points (their stores are complete and made by the same graph), resumes
interrupted ones from their last commit, and retries failed ones.
"""

from __future__ import annotations

import csv
import itertools
import json
import logging
import math
import os
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import GraphError, Interrupted, Problem, StoreError, UserError, clip
from .executor import requested_outputs, run_graph
from .graphfile import Graph, check_override, load_graph, parse_value, read_yaml
from .limits import Limits
from .lock import StoreLock, describe_holder, read_holder
from .store import RunStore, is_run_store
from .threads import limit_blas

log = logging.getLogger("evsda.sweep")

SAMPLING = ("grid", "random", "lhs")
PLAN_FILE = "sweep-plan.json"
RESULTS_CSV = "sweep.csv"
RESULTS_PARQUET = "sweep.parquet"
#: the fixed columns of the results table; parameters follow ``status``, metrics follow ``store``
FIXED_COLUMNS = ("point", "status")
TAIL_COLUMNS = ("wall_s", "cpu_s", "run_s", "reused", "error", "store")
PARQUET_EVERY_S = 2.0       # the Parquet copy of the table is rewritten at most this often (and at the end)
#: a sweep has at most this many points (each a run store; planning takes ~0.7 ms each) unless
#: ``--limit points=N`` raises it: counted before any point's values are built
MAX_POINTS = 10_000


@dataclass(frozen=True)
class Range:
    """A range of a swept parameter: uniform in value (or in log10 with ``log``), rounded with ``integer``."""

    low: float
    high: float
    log: bool = False
    integer: bool = False

    def at(self, u: float) -> float | int:
        """The value at the fraction ``u`` in [0, 1) of the range."""
        if self.log:
            value = 10 ** (math.log10(self.low) + u * (math.log10(self.high) - math.log10(self.low)))
        else:
            value = self.low + u * (self.high - self.low)
        return int(round(value)) if self.integer else float(value)


Axis = list | Range


@dataclass(frozen=True)
class SweepPoint:
    index: int
    values: dict[str, Any]
    store: Path


@dataclass
class SweepResult:
    """What a sweep produced: one row per point (in point order) and where the tables are."""

    rows: list[dict[str, Any]]
    failed: int
    csv: Path
    parquet: Path

    @property
    def ok(self) -> bool:
        return self.failed == 0


# -- the grid ------------------------------------------------------------------------------------------
def _range_axis(where: str, key: str, value: dict, problems: list[Problem]) -> Range | None:
    """``{min:, max:, log:, integer:}`` as a :class:`Range`, or None with its problem added."""
    unknown = set(value) - {"min", "max", "log", "integer"}
    low, high = value.get("min"), value.get("max")
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in (low, high))
    if unknown or not numbers or not low <= high:
        problems.append(Problem(where, f"'{key}'", "expected a range {min: LOW, max: HIGH} with finite "
                                                   "LOW <= HIGH (and optional log: true, integer: true)"
                                + (f"; unknown keys {sorted(unknown)}" if unknown else "")))
        return None
    log_scale, integer = bool(value.get("log", False)), bool(value.get("integer", False))
    if log_scale and low <= 0:
        problems.append(Problem(where, f"'{key}'", f"a log range needs min > 0, got {clip(repr(low))}"))
        return None
    return Range(float(low), float(high), log_scale, integer)


def _axis(where: str, key: str, value: Any, problems: list[Problem]) -> Axis | None:
    if isinstance(value, list):
        if not value:
            problems.append(Problem(where, f"'{key}'", "expected a non-empty list of values or a range {min:, max:}"))
            return None
        return value
    if isinstance(value, dict):
        return _range_axis(where, key, value, problems)
    problems.append(Problem(where, f"'{key}'", "expected a non-empty list of values or a range {min:, max:}"))
    return None


def _grid_file_entries(path: str | Path | None) -> list[tuple[str, str, Any]]:
    """(where, key, value) of each parameter in the grid file (none without one)."""
    if path is None:
        return []
    data = read_yaml(Path(path), what="sweep grid")
    if not isinstance(data, dict) or not data:
        raise GraphError([Problem(str(path), "", "expected a mapping of block.param to a list of values or a range")])
    return [(str(path), str(k), v) for k, v in data.items()]


def _vary_entries(vary: list[str]) -> list[tuple[str, str, Any]]:
    """(where, key, value) of each ``--vary block.param=VALUES``."""
    raw = []
    for text in vary:
        key, sep, value = text.partition("=")
        if not sep:
            raise UserError(f"--vary '{clip(text)}': expected block.param=[v1, v2, ...] or block.param={{min: a, max: b}}")
        raw.append(("--vary", key.strip(), parse_value(value.strip())))
    return raw


def read_grid(path: str | Path | None, vary: list[str] = ()) -> dict[str, Axis]:
    """The swept parameters from a YAML file and/or ``--vary block.param=[v1, v2]`` (or ``={min: a, max: b}``)
    strings: each a list of values or a :class:`Range`."""
    raw = _grid_file_entries(path) + _vary_entries(vary)
    problems: list[Problem] = []
    grid: dict[str, Axis] = {}
    given: dict[str, str] = {}
    for where, key, value in raw:
        if key in given:        # a second list would silently replace the first
            problems.append(Problem(where, f"'{clip(key)}'", f"is varied twice (also in {given[key]}); give its "
                                                             f"values once"))
            continue
        given[key] = where
        axis = _axis(where, key, value, problems)
        if axis is not None:
            grid[key] = axis
    if problems:
        raise GraphError(problems)
    if not grid:
        raise UserError("the sweep has no parameters to vary; give --grid FILE or --vary block.param=[...]")
    return grid


def parse_limits(items: list[str] | tuple[str, ...] = ()) -> tuple[Limits, int]:
    """``--limit NAME=VALUE`` of a sweep: ``points`` (the sweep's size, default :data:`MAX_POINTS`) and the
    run limits every point is checked against (:class:`~evsda.graph.limits.Limits`)."""
    max_points, others = MAX_POINTS, []
    for item in items:
        name, _, text = item.partition("=")
        if name.strip() != "points":
            others.append(item)
            continue
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value >= 1):
            raise UserError(f"--limit points: expected a finite number >= 1, got {clip(text, 40)}")
        max_points = int(value)
    try:
        return Limits.parse(others), max_points
    except UserError as exc:
        raise UserError(f"{exc}, or points (the sweep's size)") from None


def _check_size(n_points: int, max_points: int, how: str) -> None:
    if n_points > max_points:
        raise UserError(f"the sweep has {n_points:.4g} points ({how}), more than the limit of {max_points:.4g}; "
                        f"vary fewer values, draw fewer with --sample lhs --points N, or raise the limit with "
                        f"--limit points={n_points:.4g}")


def _grid_points(grid: dict[str, Axis], points: int | None, max_points: int) -> list[dict[str, Any]]:
    """Every combination of the lists (ranges refused: they have no finite set of values)."""
    keys = list(grid)
    ranges = [k for k in keys if isinstance(grid[k], Range)]
    if ranges:
        raise UserError(f"{ranges[0]} is a range: ranges need --sample random or lhs with --points N")
    if points is not None:
        raise UserError("--points goes with --sample random or lhs; a grid runs every combination")
    _check_size(math.prod(len(grid[k]) for k in keys), max_points,
                " x ".join(str(len(grid[k])) for k in keys) + " values")
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def _check_draws(method: str, points: int | None, seed: int, max_points: int) -> None:
    if method not in SAMPLING:
        raise UserError(f"--sample must be one of {', '.join(SAMPLING)}, got {clip(method)!r}")
    if points is None or points < 1:
        raise UserError(f"--sample {method} needs --points N (at least 1)")
    _check_size(points, max_points, f"--points {points}")
    if seed < 0:
        raise UserError(f"--seed must be >= 0, got {seed}")


def _value_at(axis: Axis, fraction: float) -> Any:
    """The value of ``axis`` at ``fraction`` in [0, 1): a point of a range, or the list item of that slice."""
    return axis.at(fraction) if isinstance(axis, Range) else axis[min(int(fraction * len(axis)), len(axis) - 1)]


def sample(grid: dict[str, Axis], method: str = "grid", points: int | None = None, seed: int = 0,
           max_points: int = MAX_POINTS) -> list[dict[str, Any]]:
    """The points' values: the Cartesian product of the lists (``grid``), or ``points`` draws from every
    list and range, independent (``random``) or stratified so that each axis is cut into ``points``
    equal slices each sampled once (``lhs``, McKay, Beckman & Conover 1979), with ``seed``. More than
    ``max_points`` points are refused before any is built."""
    if method == "grid":
        return _grid_points(grid, points, max_points)
    _check_draws(method, points, seed, max_points)
    keys = list(grid)
    if method == "random":
        u = np.random.default_rng(seed).random((points, len(keys)))
    else:
        from scipy.stats import qmc
        u = qmc.LatinHypercube(d=len(keys), rng=np.random.default_rng(seed)).random(points)
    return [{key: _value_at(grid[key], float(fraction)) for key, fraction in zip(keys, row)} for row in u]


def _overrides_dict(overrides: list[str]) -> dict[str, Any]:
    out = {}
    for text in overrides:
        key, sep, value = text.partition("=")
        if not sep:
            raise UserError(f"--set '{clip(text)}': expected block.param=value")
        out[key.strip()] = parse_value(value.strip())
    return out


def _key(value: Any) -> str:
    return json.dumps(value, sort_keys=True, default=str)


def _value_problems(base: Graph, graph_path: str, values: list[dict[str, Any]]) -> list[Problem]:
    """Each distinct value checked once against its block: the first refused value's problems of each
    parameter, then how many more of its values were refused."""
    problems: list[Problem] = []
    refused: dict[str, int] = {}        # values of each parameter refused (the first one's problems are listed)
    checked: set[tuple[str, str]] = set()
    for point in values:
        for key, value in point.items():
            marker = (key, _key(value))
            if marker in checked:
                continue
            checked.add(marker)
            found = check_override(base, key, value)
            if found:
                refused[key] = refused.get(key, 0) + 1
                if refused[key] == 1:
                    problems.extend(p for p in found if p not in problems)
    problems.extend(Problem(graph_path, f"'{key}'", f"{n - 1} more of its values refused")
                    for key, n in refused.items() if n > 1)
    return problems


def plan(graph_path: str, values: list[dict[str, Any]], out_dir: Path, overrides: list[str] = (),
         base: Graph | None = None) -> list[SweepPoint]:
    """The points, each distinct value checked once against its block (every problem reported together);
    ``base`` is the graph with ``overrides`` if already loaded."""
    base = base or load_graph(graph_path, list(overrides))
    problems = _value_problems(base, graph_path, values)
    if problems:
        raise GraphError(problems)
    width = max(3, len(str(len(values) - 1)))
    return [SweepPoint(i, v, out_dir / f"point_{i:0{width}d}.zarr") for i, v in enumerate(values)]


def _keys_reaching(graph: Graph, keys: list[str]) -> dict[str, list[str]]:
    """For each block, the swept keys its outputs depend on: its own, its ancestors', and every ``run.`` key."""
    import networkx

    reached: dict[str, list[str]] = {}
    for key in keys:
        if key.startswith("run."):
            touched = set(graph.nodes)
        else:
            block = key.partition(".")[0]
            touched = {block} | networkx.descendants(graph.digraph, block) if block in graph.nodes else set(graph.nodes)
        for name in touched:
            reached.setdefault(name, []).append(key)
    return reached


def _best_provider(point: SweepPoint, candidates: set[int], points: list[SweepPoint], shareable: list[str],
                   reached: dict[str, list[str]]) -> tuple[int | None, set[str]]:
    """The earliest candidate sharing the swept values of the most shareable blocks, and those blocks."""
    best, best_shared = None, set()
    for q in sorted(candidates):
        other = points[q].values
        shared = {b for b in shareable if all(_key(other[k]) == _key(point.values[k]) for k in reached.get(b, []))}
        if len(shared) > len(best_shared):
            best, best_shared = q, shared
    return best, best_shared


def reuse_plan(graph_path: str, points: list[SweepPoint], overrides: list[str] = (),
               graph: Graph | None = None) -> tuple[dict[int, int], dict[int, list[str]]]:
    """Which earlier point each point reuses upstream outputs from, and which blocks each provider must store.

    A block's outputs depend on the swept values of the block and of its ancestors (every value for a
    ``run.`` key). Point p takes as provider the earliest point q < p sharing those values for the most
    blocks that p would otherwise compute; q stores the blocks at the edge of what they share (a shared
    block feeding one that is not), which p then loads instead of recomputing them and their ancestors.
    """
    graph = graph or load_graph(graph_path, list(overrides))
    requested = {block for block, _ in requested_outputs(graph)}
    import networkx

    active = set(requested).union(*(networkx.ancestors(graph.digraph, b) for b in requested))
    reached = _keys_reaching(graph, list(points[0].values) if points else [])
    shareable = [b for b in networkx.topological_sort(graph.digraph) if b in active and b not in requested]
    providers, stores = _assign_providers(graph, points, shareable, active, reached)
    return providers, {q: sorted(blocks) for q, blocks in stores.items()}


def _shared_edge(graph: Graph, active: set[str], shared: set[str]) -> set[str]:
    """The shared blocks feeding an active block that is not shared: what a provider must store."""
    return {b for b in shared if any(c in active and c not in shared for c in graph.digraph.successors(b))}


def _assign_providers(graph: Graph, points: list[SweepPoint], shareable: list[str], active: set[str],
                      reached: dict[str, list[str]]) -> tuple[dict[int, int], dict[int, set[str]]]:
    """:func:`reuse_plan`'s providers (point -> earlier point) and the blocks each provider stores."""
    first: dict[str, dict[str, int]] = {b: {} for b in shareable}    # block -> its values' key -> first point
    providers: dict[int, int] = {}
    stores: dict[int, set[str]] = {}
    for point in points:
        signature = {b: _key([point.values[k] for k in reached.get(b, [])]) for b in shareable}
        candidates = {first[b][signature[b]] for b in shareable if signature[b] in first[b]}
        best, best_shared = _best_provider(point, candidates, points, shareable, reached)
        for b in shareable:
            first[b].setdefault(signature[b], point.index)
        if best is not None:
            providers[point.index] = best
            stores.setdefault(best, set()).update(_shared_edge(graph, active, best_shared))
    return providers, stores


# -- one point -----------------------------------------------------------------------------------------
@dataclass
class PointTask:
    """Everything a worker needs to run one point (picklable)."""

    graph_path: str
    overrides: dict[str, Any]
    point: SweepPoint
    reuse: list[str]                        # stores of the provider chain, nearest first
    store_products: list[str] | None        # the run's store_products when points reuse this one's outputs
    overwrite: bool
    threads: int | None                     # EVSDA_THREADS for the point's blocks
    limits: Limits = field(default_factory=Limits)     # the size limits the point's graph is checked against


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, GraphError):
        first = str(exc.problems[0]) if exc.problems else str(exc)
        more = len(exc.problems) - 1
        return clip(first + (f" (and {more} more problems)" if more > 0 else ""), 300)
    text = " ".join(str(exc).split()) or type(exc).__name__
    return clip(text if isinstance(exc, UserError) else f"{type(exc).__name__}: {text}", 300)


def _point_graph(task: PointTask) -> Graph:
    """The graph of one point: the sweep's overrides, the point's values, and which products to store."""
    overrides = {**task.overrides, **task.point.values}
    if task.store_products is not None:
        overrides["run.store_products"] = task.store_products
    return load_graph(task.graph_path, overrides, limits=task.limits)


def _done_store(path: Path, graph: Graph) -> RunStore | None:
    """The run store at ``path`` if it is complete and made by this very graph (the point is done), else None."""
    if not is_run_store(path):
        return None
    store = RunStore.open(path)
    return store if store.complete and store.attrs.get("graph_hash") == graph.digest() else None


def run_point(task: PointTask, provider: dict | None = None) -> dict:
    """Run (or skip, or resume) one point; never raises for the point's own failure: the outcome says it.

    ``provider`` is the outcome of the point this one reuses from (passed so that a scheduler runs this
    point after it)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    if task.threads:
        os.environ.setdefault("EVSDA_THREADS", str(task.threads))
    point = task.point
    outcome: dict[str, Any] = {"point": point.index, "status": "ok", "metrics": {}, "units": {}, "reused": {},
                               "error": ""}
    try:
        graph = _point_graph(task)
        reuse = [p for p in task.reuse if is_run_store(p)]
        if point.store.exists() and not task.overwrite:
            store = _done_store(point.store, graph)
            if store is not None:
                outcome.update(status="done", metrics=store.metrics, units=store.metric_units,
                               reused=dict(store.attrs.get("reused", {})))
                return outcome
            run0 = time.perf_counter()
            result = run_graph(graph, point.store, resume=True, reuse=reuse, progress=False)
        else:
            run0 = time.perf_counter()
            result = run_graph(graph, point.store, overwrite=task.overwrite, reuse=reuse, progress=False)
        outcome.update(metrics=result.metrics, units=result.metric_units, reused=result.reused,
                       run_s=time.perf_counter() - run0)
    except Exception as exc:  # a point's failure is recorded, the sweep goes on
        outcome.update(status="failed", error=_one_line(exc))
    finally:
        outcome["wall_s"] = time.perf_counter() - wall0
        outcome["cpu_s"] = time.process_time() - cpu0
    return outcome


# -- the results table ---------------------------------------------------------------------------------
class ResultsTable:
    """``sweep.csv`` (a row appended as each point finishes) and ``sweep.parquet`` (rewritten atomically)."""

    def __init__(self, out_dir: Path, keys: list[str]):
        self.csv, self.parquet = out_dir / RESULTS_CSV, out_dir / RESULTS_PARQUET
        self.keys = keys
        self.rows: list[dict[str, Any]] = []
        self.columns: list[str] = [*FIXED_COLUMNS, *keys, *TAIL_COLUMNS]
        self._parquet_at = 0.0
        self._rewrite_csv()

    def add(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        new = [c for c in row if c not in self.columns]
        if new:
            self.columns.extend(new)
            self._rewrite_csv()
        else:
            with open(self.csv, "a", newline="") as handle:
                csv.DictWriter(handle, fieldnames=self.columns).writerow(row)
        if time.monotonic() - self._parquet_at >= PARQUET_EVERY_S:
            self.write_parquet()

    def _rewrite_csv(self) -> None:
        temporary = self.csv.with_name(self.csv.name + ".tmp")
        with open(temporary, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=self.columns)
            writer.writeheader()
            writer.writerows(self.rows)
        os.replace(temporary, self.csv)

    def write_parquet(self) -> None:
        import pandas as pd
        import pyarrow as pa

        frame = pd.DataFrame(sorted(self.rows, key=lambda r: r["point"]), columns=self.columns)
        temporary = self.parquet.with_name(self.parquet.name + ".tmp")
        try:
            frame.to_parquet(temporary, index=False)
        except (pa.ArrowInvalid, pa.ArrowTypeError):   # a parameter with values of several types
            mixed = [c for c in frame.columns if frame[c].dtype == object]
            frame[mixed] = frame[mixed].astype(str)
            frame.to_parquet(temporary, index=False)
        os.replace(temporary, self.parquet)
        self._parquet_at = time.monotonic()


def read_results(out_dir: str | Path):
    """A sweep's results table as a pandas DataFrame (from ``sweep.parquet``, else ``sweep.csv``)."""
    import pandas as pd

    out_dir = Path(out_dir)
    unreadable = []
    for name, reader in ((RESULTS_PARQUET, pd.read_parquet), (RESULTS_CSV, pd.read_csv)):
        if (out_dir / name).is_file():
            try:
                table = reader(out_dir / name)
            except (ValueError, OSError):    # damaged, truncated, not UTF-8 (pyarrow's and pandas' errors are these)
                unreadable.append(name)      # the CSV, streamed row by row, may still be whole
                continue
            if unreadable:
                warnings.warn(f"{out_dir}: {unreadable[0]} cannot be read (damaged?); the results come from {name}")
            return table
    if unreadable:
        raise UserError(f"{out_dir}: the sweep results ({' and '.join(unreadable)}) cannot be read: damaged or not "
                        f"written by evsda sweep; re-run the sweep command to write them again")
    raise UserError(f"{out_dir} holds no sweep results ({RESULTS_PARQUET} or {RESULTS_CSV})")


def _earlier_times(path: Path) -> dict[int, tuple[float, float, float]]:
    """Wall, CPU and run time of the points an earlier run of the sweep finished (from its ``sweep.csv``)."""
    times = {}
    try:
        with open(path, newline="") as handle:
            for row in csv.DictReader(handle):
                if row.get("status") in ("ok", "done"):
                    try:
                        times[int(row["point"])] = (float(row["wall_s"]), float(row["cpu_s"]),
                                                    float(row.get("run_s") or "nan"))
                    except (KeyError, TypeError, ValueError):
                        continue
    except (OSError, csv.Error, UnicodeDecodeError):
        pass
    return times


def _row(point: SweepPoint, outcome: dict) -> dict[str, Any]:
    row = {"point": point.index, "status": outcome["status"], **point.values,
           "wall_s": round(outcome.get("wall_s", float("nan")), 4), "cpu_s": round(outcome.get("cpu_s", float("nan")), 4),
           "run_s": round(outcome.get("run_s", float("nan")), 4),
           "reused": ";".join(sorted(outcome.get("reused", {}))), "error": outcome.get("error", ""),
           "store": str(point.store)}
    row.update({k: v for k, v in outcome.get("metrics", {}).items() if k not in row})
    return row


def _describe(point: SweepPoint, outcome: dict) -> str:
    status = outcome["status"]
    if status == "failed":
        what = f"FAILED: {outcome['error']}"
    elif status == "done":
        what = "already complete"
    else:
        reused = outcome.get("reused") or {}
        what = (f"reused {', '.join(sorted(reused))}" if reused else "computed in full") + f", {outcome['wall_s']:.1f} s"
    return f"  point {point.index}: {point.values} -> {point.store.name} ({what})"


# -- the sweep ---------------------------------------------------------------------------------------------
def _check_plan_file(out_dir: Path, document: dict, overwrite: bool) -> None:
    """A sweep folder holds one sweep: re-running another sweep into it is refused (its points would differ)."""
    path = out_dir / PLAN_FILE
    document = json.loads(json.dumps(document, default=str))     # as it reads back (dates become strings)
    if path.is_file() and not overwrite:
        try:
            previous = json.loads(path.read_text())
        except (OSError, ValueError):
            previous = None
        if previous != document:
            raise UserError(f"{out_dir} holds another sweep (other graph, parameters or values; see {PLAN_FILE}); "
                            f"choose another folder, or pass --overwrite to recompute every point")
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(document, indent=1))
    os.replace(temporary, path)


@contextmanager
def _sweep_lock(out_dir: Path) -> Iterator[None]:
    """Hold the sweep folder's lock (the run stores' lock file and rules, :mod:`.lock`) while the sweep runs:
    a second sweep into the folder is refused with one line naming the first, instead of both failing
    each other's points and truncating each other's results table."""
    lock = StoreLock(out_dir)
    try:
        lock.acquire()
    except StoreError as exc:
        holder = read_holder(out_dir)
        if holder is None:          # not held: the folder cannot be written (the reason ends the message)
            raise UserError(f"cannot lock the sweep folder {out_dir}: {str(exc).rpartition(': ')[2]}") from None
        raise UserError(f"{out_dir} is being written by another evsda sweep ({describe_holder(holder)}); wait "
                        f"for it to end or stop it") from None
    try:
        yield
    finally:
        lock.release()


def default_jobs() -> int:
    """Worker processes of a local cluster: one per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _sweep_folder(out_dir: str | Path) -> Path:
    """``out_dir`` as a local folder: URLs are refused (stores take file locks and rename files atomically)."""
    if "://" in str(out_dir):
        raise UserError(f"{clip(str(out_dir))}: a sweep writes run stores to a folder every worker mounts (a local "
                        f"disk, or a shared file system such as NFS or Lustre); URLs such as s3:// are not "
                        f"supported (stores take file locks and rename files atomically)")
    return Path(out_dir)


def _make_sweep_folder(out_dir: Path) -> None:
    """Create ``out_dir``, refusing a folder inside a run store (or the store itself)."""
    for folder in (out_dir.absolute(), *out_dir.absolute().parents):
        if is_run_store(folder):
            raise UserError(f"{out_dir}: cannot write a sweep inside the run store {folder}; choose another folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create the sweep folder {out_dir}: {exc.strerror or exc}") from None


def _provider_chain(index: int, providers: dict[int, int], sweep_points: list[SweepPoint]) -> list[str]:
    """The stores point ``index`` may reuse from: its provider's, that one's provider's, ... nearest first."""
    chain, q = [], providers.get(index)
    while q is not None:
        chain.append(str(sweep_points[q].store))
        q = providers.get(q)
    return chain


@dataclass
class _TaskSettings:
    """What every point's :class:`PointTask` shares."""

    graph_path: str
    overrides: dict[str, Any]
    store_products: Any             # the graph's run.store_products: True, or a list of blocks, or None
    overwrite: bool
    threads: int | None
    limits: Limits
    absolute: bool                  # remote workers need paths that do not depend on this process's folder


def _point_task(point: SweepPoint, chain: list[str], needed: list[str] | None, settings: _TaskSettings) -> PointTask:
    if settings.absolute:
        point = SweepPoint(point.index, point.values, point.store.absolute())
        chain = [str(Path(c).absolute()) for c in chain]
    choice = settings.store_products
    store_products = None if not needed or choice is True else sorted(set(needed) | set(choice or []))
    return PointTask(settings.graph_path, settings.overrides, point, chain, store_products, settings.overwrite,
                     settings.threads, settings.limits)


def _workers(jobs: int | None, scheduler: str | None) -> int:
    """Worker processes: 1 runs the points in this process; default one per core."""
    return 1 if scheduler is None and jobs == 1 else (jobs or default_jobs())


def _where(scheduler: str | None, workers: int) -> str:
    if scheduler:
        return f"the Dask scheduler at {scheduler}"
    return "this process" if workers == 1 else f"a local Dask cluster of {workers} workers"


class _Finished:
    """Called as each point finishes: records its row (with the times of an earlier run for a point done
    then), reports it, and counts the failures."""

    def __init__(self, sweep_points: list[SweepPoint], earlier: dict, table: ResultsTable,
                 report: Callable[[str], None]):
        self.sweep_points, self.earlier, self.table, self.report = sweep_points, earlier, table, report
        self.failed = 0

    def __call__(self, index: int, outcome: dict) -> None:
        point = self.sweep_points[index]
        if outcome["status"] == "done" and index in self.earlier:    # the time it took when it ran
            outcome["wall_s"], outcome["cpu_s"], outcome["run_s"] = self.earlier[index]
        self.failed += outcome["status"] == "failed"
        self.table.add(_row(point, outcome))
        self.report(_describe(point, outcome))


def _run_in_process(tasks: dict[int, PointTask], providers: dict[int, int], sweep_points: list[SweepPoint],
                    finished: _Finished) -> None:
    outcomes: dict[int, dict] = {}
    for point in sweep_points:
        q = providers.get(point.index)
        outcomes[point.index] = run_point(tasks[point.index], outcomes.get(q))
        finished(point.index, outcomes[point.index])


def _run_points(tasks, providers, sweep_points, workers: int, scheduler: str | None, finished: _Finished) -> None:
    """Run the tasks here or on Dask; an interrupt keeps what finished and says how to resume."""
    table = finished.table
    try:
        if scheduler is None and workers == 1:
            _run_in_process(tasks, providers, sweep_points, finished)
        else:
            _run_on_dask(tasks, providers, workers, scheduler, finished)
    except KeyboardInterrupt as exc:
        raise Interrupted(getattr(exc, "signal_name", "SIGINT"),
                          f"sweep interrupted after {len(table.rows)} of {len(sweep_points)} points; finished "
                          f"points are kept and unfinished ones resume: re-run the same command") from None
    finally:
        if table.rows:
            table.write_parquet()


def _plan_sweep(graph_path: str, values: list[dict[str, Any]], out_dir: Path, overrides: list[str],
                limits: Limits) -> tuple[Graph, list[SweepPoint], dict[int, int], dict[int, list[str]]]:
    """The base graph, the points (checked), and :func:`reuse_plan`'s providers and stored blocks."""
    t0 = time.perf_counter()
    with limit_blas():
        base_graph = load_graph(graph_path, list(overrides), limits=limits)
        sweep_points = plan(graph_path, values, out_dir, overrides, base_graph)
        providers, stored = reuse_plan(graph_path, sweep_points, overrides, base_graph)
    log.info("planned %d points in %.2f s", len(sweep_points), time.perf_counter() - t0)
    return base_graph, sweep_points, providers, stored


def _last_line(failed: int, n_points: int, table: ResultsTable) -> str:
    if failed:
        return (f"sweep: {failed} of {n_points} points failed (see the error column of {table.csv}); "
                f"re-run the same command to retry them")
    return f"sweep: all {n_points} points done; results in {table.csv} and {table.parquet}"


def run_sweep(graph_path: str, grid: dict[str, Axis], out_dir: str | Path, overrides: list[str] = (),
              jobs: int | None = None, scheduler: str | None = None, overwrite: bool = False,
              method: str = "grid", points: int | None = None, seed: int = 0,
              report: Callable[[str], None] = print, limits: Limits | None = None,
              max_points: int = MAX_POINTS) -> SweepResult:
    """Run every point of the sweep (see the module docstring); returns a :class:`SweepResult`.

    ``jobs``: worker processes of a local Dask cluster (default: one per core; 1 runs the points in this
    process); ``scheduler``: the address of a running Dask scheduler to use instead. ``limits``: the size
    limits each point's graph is checked against; ``max_points``: the most points the sweep may have.
    """
    limits = limits or Limits()
    out_dir = _sweep_folder(out_dir)
    if jobs is not None and jobs < 1:
        raise UserError(f"--jobs must be at least 1, got {jobs}")
    graph_path = str(graph_path)
    values = sample(grid, method, points, seed, max_points)
    base_graph, sweep_points, providers, stored = _plan_sweep(graph_path, values, out_dir, overrides, limits)
    _make_sweep_folder(out_dir)
    with _sweep_lock(out_dir):     # one sweep per folder: its plan file and results table are shared
        _check_plan_file(out_dir, {"graph": graph_path, "overrides": list(overrides), "sampling": method,
                                   "seed": seed if method != "grid" else None,
                                   "points": [p.values for p in sweep_points]}, overwrite)
        workers = _workers(jobs, scheduler)
        settings = _TaskSettings(graph_path, _overrides_dict(list(overrides)), base_graph.run.store_products,
                                 overwrite, None if scheduler else max(1, default_jobs() // workers), limits,
                                 absolute=bool(scheduler))
        tasks = {p.index: _point_task(p, _provider_chain(p.index, providers, sweep_points), stored.get(p.index),
                                      settings) for p in sweep_points}
        report(f"sweep: {len(sweep_points)} points into {out_dir}, on {_where(scheduler, workers)}")
        earlier = _earlier_times(out_dir / RESULTS_CSV)
        table = ResultsTable(out_dir, list(grid))
        finished = _Finished(sweep_points, earlier, table, report)
        _run_points(tasks, providers, sweep_points, workers, scheduler, finished)
        report(_last_line(finished.failed, len(sweep_points), table))
        return SweepResult(sorted(table.rows, key=lambda r: r["point"]), finished.failed, table.csv, table.parquet)


def _quiet_resource_tracker() -> None:
    """Start Python's multiprocessing resource tracker (shared by the local cluster's worker processes) with
    its 'leaked semaphore objects' warning silenced. A sweep stopped while points run ends its workers
    mid-point; the tracker then frees their semaphores at exit, as it should, but says so in two lines
    after the sweep's own one-line message. Nothing else of the tracker's output is silenced."""
    from multiprocessing import resource_tracker

    rule = "ignore:resource_tracker:UserWarning"
    previous = os.environ.get("PYTHONWARNINGS")
    os.environ["PYTHONWARNINGS"] = ",".join(filter(None, [previous, rule]))
    try:
        resource_tracker.ensure_running()       # inherits the environment now (a no-op if already running)
    finally:
        if previous is None:
            del os.environ["PYTHONWARNINGS"]
        else:
            os.environ["PYTHONWARNINGS"] = previous


def _run_on_dask(tasks: dict[int, PointTask], providers: dict[int, int], workers: int, scheduler: str | None,
                 finished: Callable[[int, dict], None]) -> None:
    """Submit every point as a task (after its provider) and report each as it finishes."""
    from distributed import Client, LocalCluster, as_completed

    logging.getLogger("distributed").setLevel(logging.ERROR)
    cluster = None
    if scheduler is None:
        _quiet_resource_tracker()
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:        # ValueError: not an address
            raise UserError(f"cannot reach the Dask scheduler at {clip(scheduler)}: {clip(str(exc))}") from None
    try:
        futures = {}
        for index in sorted(tasks):
            provider = futures.get(providers.get(index))
            futures[index] = client.submit(run_point, tasks[index], provider, pure=False,
                                           key=f"evsda-point-{index}-{os.getpid()}-{time.time_ns()}")
        index_of = {f.key: i for i, f in futures.items()}
        for future in as_completed(list(futures.values())):
            index = index_of[future.key]
            if future.status == "finished":
                outcome = future.result()
            else:       # the worker died under the point (after Dask's retries): recorded like any failure
                exc = future.exception()
                outcome = {"point": index, "status": "failed", "error": _one_line(exc), "metrics": {},
                           "reused": {}, "wall_s": float("nan"), "cpu_s": float("nan")}
            finished(index, outcome)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
