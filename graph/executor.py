"""The executor: runs a checked graph window by window.

* Only blocks upstream of the requested outputs run ("model only what a scene needs").
* Blocks run in topological order; each window's outputs are passed to consumers.
* Outputs of every block are stored per window under ``products/`` (unless the graph
  says otherwise), keyed by a hash of everything upstream, so a later run that changes
  only downstream blocks reuses them (``reuse=[other_store]``) instead of recomputing.
* Block state and RNG state are checkpointed; a killed run resumes from its last
  commit and produces byte-identical output (see :mod:`evsda.graph.store`).
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx

from . import __version__
from .block import Block, RunInfo, Window
from .errors import StoreError
from .graphfile import Graph
from .ports import PortValue
from .progress import progress_bar
from .store import RunStore

EVENTS_TYPE = "Events"      # outputs of this port type are recorded under events/
METRICS_TYPE = "Metrics"    # outputs of this port type are recorded under metrics/


@dataclass
class RunResult:
    """What a run produced."""

    store: RunStore | None
    outputs: dict[tuple[str, str], list[PortValue]] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    metric_units: dict[str, str] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)
    reused: dict[str, str] = field(default_factory=dict)
    windows_run: int = 0


def requested_outputs(graph: Graph) -> list[tuple[str, str]]:
    """The graph's requested outputs; by default every output of every sink block (or of every
    leaf) plus the event streams (``Events`` outputs) upstream of them, which the store records."""
    if graph.outputs:
        return list(graph.outputs)
    sinks = [n for n, node in graph.nodes.items() if type(node.block).is_sink]
    if not sinks:
        sinks = [n for n in graph.nodes if graph.digraph.out_degree(n) == 0]
    upstream = set().union(*(nx.ancestors(graph.digraph, n) for n in sinks)) - set(sinks)
    streams = [(n, port) for n in nx.topological_sort(graph.digraph) if n in upstream
               for port, spec in type(graph.nodes[n].block).outputs.items() if spec.type.type_name() == EVENTS_TYPE]
    return [(n, port) for n in sinks for port in type(graph.nodes[n].block).outputs] + streams


def upstream_hashes(graph: Graph, run: RunInfo) -> dict[str, str]:
    """For every block, a hash of its type, params, name, seed, time range and everything upstream."""
    hashes: dict[str, str] = {}
    for name in nx.topological_sort(graph.digraph):
        block = graph.nodes[name].block
        inputs = sorted(
            (dport, hashes[src], sport) for src, sport, dst, dport in graph.connections if dst == name
        )
        doc = {
            "type": block.type_name,
            "name": name,
            "params": block.params.model_dump(mode="json"),
            "seed": run.seed,
            "time": [run.epoch.isoformat(), run.duration_ns, run.window_ns],
            "inputs": inputs,
        }
        hashes[name] = hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
    return hashes


class Executor:
    """Runs one graph; see :func:`run_graph` for the arguments."""

    def __init__(self, graph: Graph, out: str | Path | None = None, *, resume: bool = False,
                 overwrite: bool = False, reuse: list[str | Path] = (), progress: bool | None = None,
                 checkpoint_every_s: float = 30.0, keep_outputs: bool | None = None,
                 max_windows: int | None = None):
        self.graph = graph
        self.run = graph.run_info()
        self.requested = requested_outputs(graph)
        self.hashes = upstream_hashes(graph, self.run)
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.checkpoint_every_s = checkpoint_every_s
        self.keep_outputs = out is None if keep_outputs is None else keep_outputs
        self.max_windows = max_windows
        self.reuse_stores = [RunStore.open(p) for p in reuse]
        self.loaded: dict[str, RunStore] = {}
        self.order = self._plan()
        self.out = None if out is None else Path(out)
        self.resume, self.overwrite = resume, overwrite
        self.store: RunStore | None = None
        self._check_output()

    # -- planning --------------------------------------------------------------------------------
    def _consumed_ports(self, name: str, active: set[str]) -> set[str]:
        ports = {sport for src, sport, dst, _ in self.graph.connections if src == name and dst in active}
        return ports | {port for block, port in self.requested if block == name}

    def _reusable_from(self, name: str, ports: set[str]) -> RunStore | None:
        for store in self.reuse_stores:
            complete = store.committed_windows >= self.run.n_windows
            if complete and store.product_hash(name) == self.hashes[name] and all(
                store.has_product(name, port) for port in ports
            ):
                return store
        return None

    def _plan(self) -> list[str]:
        """Blocks to run or load, in topological order."""
        requested_blocks = {b for b, _ in self.requested}
        active = set(requested_blocks)
        for b in requested_blocks:
            active |= nx.ancestors(self.graph.digraph, b)
        needed: set[str] = set(requested_blocks)
        for name in reversed(list(nx.topological_sort(self.graph.digraph))):
            if name not in needed:
                continue
            if name not in requested_blocks:
                store = self._reusable_from(name, self._consumed_ports(name, active))
                if store is not None:
                    self.loaded[name] = store
                    continue
            needed |= set(self.graph.digraph.predecessors(name))
        return [n for n in nx.topological_sort(self.graph.digraph) if n in needed]

    def _stores_products(self, name: str) -> bool:
        choice = self.graph.run.store_products
        return choice if isinstance(choice, bool) else name in choice

    # -- the store ---------------------------------------------------------------------------------
    def _check_output(self) -> None:
        """Refuse a bad output before any work."""
        if self.out is None:
            return
        if self.resume and not self.out.exists():
            raise StoreError(f"cannot resume: {self.out} does not exist")
        if not self.resume and self.out.exists() and not self.overwrite:
            raise StoreError(f"{self.out} already exists; choose another output, pass --overwrite to replace it, "
                             f"or --resume to continue the run it holds")

    def _open_store(self) -> RunStore:
        out, digest = self.out, self.graph.digest()
        if self.resume:
            store = RunStore.open(out, mode="r+")
            if store.attrs.get("graph_hash") != digest:
                raise StoreError(f"cannot resume {out}: it was made by a different graph or parameters; "
                                 f"run with the same graph file and --set values, or start a new store")
            return store
        return RunStore.create(out, overwrite=self.overwrite, attrs={
            "evsda_version": __version__,
            "graph": self.graph.to_dict(),
            "graph_hash": digest,
            "seed": self.run.seed,
            "start_epoch": self.run.epoch.isoformat().replace("+00:00", "Z"),
            "duration_ns": self.run.duration_ns,
            "window_ns": self.run.window_ns,
            "n_windows": self.run.n_windows,
        })

    # -- running -----------------------------------------------------------------------------------
    def execute(self) -> RunResult:
        blocks: dict[str, Block] = {n: self.graph.nodes[n].block for n in self.order}
        running = [n for n in self.order if n not in self.loaded]
        timing = {n: 0.0 for n in running}
        timing["(store)"] = 0.0

        start_window = 0
        for name in running:
            blocks[name].setup(self.run)
        result = RunResult(store=None, reused={n: str(s.path) for n, s in self.loaded.items()})
        if self.resume:
            self._ensure_store(result, running)
            start_window = self.store.committed_windows
            states = self.store.read_checkpoint()
            for name in running:
                blocks[name].set_state(states.get(name, {}))

        readers = {
            (name, port): self.loaded[name].product_windows(name, port, start=start_window)
            for name in self.loaded for port in self._consumed_ports(name, set(self.order))
        }
        inputs_of = {n: [(src, sport, dport) for src, sport, dst, dport in self.graph.connections if dst == n]
                     for n in running}
        windows = list(self.run.windows())[start_window:]
        if self.max_windows is not None:
            windows = windows[: self.max_windows]
        last_commit = time.perf_counter()
        bar = progress_bar(total=self.run.n_windows, initial=start_window, enabled=self.progress,
                           desc=self.graph.name)
        try:
            for window in windows:
                values: dict[tuple[str, str], Any] = {}
                for key, reader in readers.items():
                    values[key] = next(reader)
                produced = []
                for name in running:
                    block = blocks[name]
                    kwargs = self._gather(block, inputs_of[name], values)
                    t0 = time.perf_counter()
                    outputs = block.step(window, **kwargs)
                    timing[name] += time.perf_counter() - t0
                    self._check_outputs(name, block, outputs)
                    for port, value in outputs.items():
                        values[(name, port)] = value
                    produced.append((name, outputs))
                # The store is created once the first window has been computed in full: a scene that
                # cannot be simulated (say, a satellite that never enters the field) leaves nothing behind.
                t0 = time.perf_counter()
                if self.out is not None and self.store is None:
                    self._ensure_store(result, running)
                for name, outputs in produced:
                    self._record(name, outputs, window, result)
                timing["(store)"] += time.perf_counter() - t0
                result.windows_run += 1
                if self.store is not None:
                    now = time.perf_counter()
                    last = window.index == self.run.n_windows - 1
                    if last or now - last_commit >= self.checkpoint_every_s:
                        t0 = time.perf_counter()
                        self._commit(window, {n: blocks[n] for n in running})
                        timing["(store)"] += time.perf_counter() - t0
                        last_commit = time.perf_counter()
                bar.update(1)
        finally:
            bar.close()

        finished = result.windows_run == len(list(self.run.windows())[start_window:])
        if finished:
            for name in running:
                t0 = time.perf_counter()
                outputs = blocks[name].finish() or {}
                timing[name] += time.perf_counter() - t0
                self._record(name, outputs, None, result)
        result.timing_s = timing
        if self.out is not None and self.store is None:
            self._ensure_store(result, running)
        if self.store is not None:
            previous = self.store.attrs.get("timing", {})
            self.store.set_attrs(timing={k: v + previous.get(k, 0.0) for k, v in timing.items()},
                                 reused=result.reused)
            self.store.commit()
            result.metrics, result.metric_units = self.store.metrics, self.store.metric_units
        return result

    def _ensure_store(self, result: RunResult, running: list[str]) -> None:
        self.store = result.store = self._open_store()
        for name in running:
            if self._stores_products(name):
                self.store.set_product_hash(name, self.hashes[name])

    def _gather(self, block: Block, connections, values) -> dict[str, Any]:
        kwargs: dict[str, Any] = {}
        for port, spec in type(block).inputs.items():
            if spec.multi:
                kwargs[port] = [values[(src, sport)] for src, sport, dport in connections if dport == port]
            else:
                found = [values[(src, sport)] for src, sport, dport in connections if dport == port]
                kwargs[port] = found[0] if found else None
        return kwargs

    def _check_outputs(self, name: str, block: Block, outputs: dict[str, Any]) -> None:
        declared = type(block).outputs
        for port, spec in declared.items():
            if port not in outputs:
                raise RuntimeError(f"block '{name}' ({block.type_name}) returned no value for output '{port}'")
            if not isinstance(outputs[port], spec.type):
                raise RuntimeError(f"block '{name}' output '{port}' returned {type(outputs[port]).__name__}, "
                                   f"declared {spec.type.type_name()}")

    def _record(self, name: str, outputs: dict[str, PortValue], window: Window | None, result: RunResult) -> None:
        for port, value in outputs.items():
            key = (name, port)
            requested = key in self.requested
            kind = type(value).type_name()
            if kind == METRICS_TYPE:
                result.metrics.update(value.values)
                result.metric_units.update(value.units)
                if self.store is not None:
                    self.store.set_metrics(value.values, value.units)
                continue
            if self.keep_outputs and requested:
                result.outputs.setdefault(key, []).append(value)
            if self.store is None or window is None:
                continue
            if kind == EVENTS_TYPE and requested and key == self._event_output():
                self.store.append_events({
                    "t_trigger_ns": value.t_trigger_ns, "t_readout_ns": value.t_readout_ns,
                    "x": value.x, "y": value.y, "p": value.p, "cause": value.cause,
                }, focal_plane=value.focal_plane)
            elif requested or self._stores_products(name):
                self.store.append_product(name, port, value)

    def _event_output(self) -> tuple[str, str] | None:
        if not hasattr(self, "_event_key"):
            candidates = [(b, p) for b, p in self.requested
                          if type(self.graph.nodes[b].block).outputs[p].type.type_name() == EVENTS_TYPE]
            self._event_key = candidates[0] if candidates else None
        return self._event_key

    def _commit(self, window: Window, blocks: dict[str, Block]) -> None:
        name = self.store.write_checkpoint(window.index, {n: b.get_state() for n, b in blocks.items()})
        self.store.commit(windows=window.index + 1, checkpoint=name)


def run_graph(graph: Graph, out: str | Path | None = None, **options) -> RunResult:
    """Run ``graph``; write a run store at ``out`` (or keep requested outputs in memory if None).

    Options: ``resume`` (continue the run in ``out``), ``overwrite`` (replace ``out``),
    ``reuse`` (stores whose matching upstream products are loaded instead of recomputed),
    ``progress`` (show a progress bar; default: when stderr is a terminal),
    ``checkpoint_every_s`` (wall-clock seconds between commits; 0 commits every window),
    ``keep_outputs`` (keep requested outputs in memory), ``max_windows`` (stop early).
    """
    return Executor(graph, out, **options).execute()
