"""The executor: runs a checked graph window by window.

* Only blocks upstream of the requested outputs run ("model only what a scene needs").
* Blocks run in topological order; each window's outputs are passed to consumers.
* Outputs of every block are stored per window under ``products/`` (unless the graph
  says otherwise), keyed by a hash of everything upstream, so a later run that changes
  only downstream blocks reuses them (``reuse=[other_store]``) instead of recomputing.
* Block state and RNG state are checkpointed; a killed run resumes from its last
  commit and produces byte-identical output (see :mod:`evsda.graph.store`).
* Windows are pipelined by default: a block steps over window k + 1 while the blocks downstream of it are
  still on window k (:mod:`evsda.graph.executor_pipeline`); the store records the same bytes as one step at a
  time (``pipeline=False``, ``--no-pipeline``, ``EVSDA_PIPELINE=0``).
* A pipelined run may step each block that is worth it (``Block.worth_a_process``) in a worker process of its
  own (:mod:`evsda.graph.worker`), beside the others with no interpreter lock shared; the same bytes again. Off
  by default (``workers="auto"``, ``EVSDA_WORKERS=auto``: where
  it pays; ``True``, ``--workers``, ``1``: wherever a block is worth one).
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


from . import __version__
from . import store as store_module
from .block import Block, RunInfo, Window
from .errors import Interrupted, StoreError
from .executor_pipeline import Pipeline, pipeline_enabled
from .files import os_reason
from .graphfile import Graph
from .lock import StoreLock
from .numba_loads import lazy_registries
from .ports import EVENT_STREAM, METRICS, TRUTH, PortValue
from .store import RunStore, check_replaceable, is_run_store
from .threads import keep_freed_memory, limit_blas, limit_malloc_arenas
from .worker import WorkerBlock, WorkerDied, threads_per_worker, workers_choice, workers_pay

STORE = "(store)"           # the timing entry of the run store's writes
log = logging.getLogger("evsda.executor")


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
    leaf) plus the event streams (outputs whose port type records as EVENT_STREAM) upstream of them,
    which the store records."""
    if graph.outputs:
        return list(graph.outputs)
    import networkx as nx        # with the graph's check (graph.checks.new_digraph), not the command line

    sinks = _sinks(graph)
    upstream = set().union(*(nx.ancestors(graph.digraph, n) for n in sinks)) - set(sinks)
    streams = [(n, port) for n in nx.topological_sort(graph.digraph) if n in upstream
               for port, spec in type(graph.nodes[n].block).outputs.items() if spec.type.record == EVENT_STREAM]
    return [(n, port) for n in sinks for port in type(graph.nodes[n].block).outputs] + streams


def _sinks(graph: Graph) -> list[str]:
    """The blocks that declare themselves sinks, else the graph's leaves."""
    sinks = [n for n, node in graph.nodes.items() if type(node.block).is_sink]
    return sinks or [n for n in graph.nodes if graph.digraph.out_degree(n) == 0]


def upstream_hashes(graph: Graph, run: RunInfo) -> dict[str, str]:
    """For every block, a hash of its type, params, name, seed, time range and everything upstream."""
    import networkx as nx

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


class Stopwatch:
    """Wall-clock seconds spent under each name (a block's name, or :data:`STORE`)."""

    def __init__(self, names: list[str]):
        self.seconds = {name: 0.0 for name in names}

    @contextmanager
    def timing(self, name: str):
        start = time.perf_counter()
        yield
        self.seconds[name] += time.perf_counter() - start


class _NoProgress:
    """The progress bar of a run that shows none."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


class Executor:
    """Runs one graph; see :func:`run_graph` for the arguments."""

    def __init__(self, graph: Graph, out: str | Path | None = None, *, resume: bool = False,
                 overwrite: bool = False, reuse: list[str | Path] = (), progress: bool | None = None,
                 checkpoint_every_s: float = 30.0, keep_outputs: bool | None = None,
                 max_windows: int | None = None, keep_checkpoint: bool = False, pipeline: bool | None = None,
                 workers: bool | str | None = None):
        self.graph = graph
        self.pipeline = pipeline_enabled(pipeline)
        self.workers = workers_choice(workers)
        self.run = graph.run_info()
        self.requested = requested_outputs(graph)
        self.hashes = upstream_hashes(graph, self.run)
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.checkpoint_every_s = checkpoint_every_s
        self.keep_outputs = out is None if keep_outputs is None else keep_outputs
        self.max_windows = max_windows
        self.keep_checkpoint = keep_checkpoint
        self.lock: StoreLock | None = None
        self.reuse_stores = [RunStore.open(p) for p in reuse]
        self.loaded: dict[str, RunStore] = {}
        self.order = self._plan()
        self._prepare()
        self.out = None if out is None else Path(out)
        self.resume, self.overwrite = resume, overwrite
        self.store: RunStore | None = None
        self._check_output()

    def _prepare(self) -> None:
        """What every window needs, worked out once: the blocks that step (those not loaded), their inputs,
        the event stream the store records, and a stopwatch per block."""
        self.blocks: dict[str, Block] = {n: self._unused(n) for n in self.order}
        #: what runs each block's lifecycle calls: the block itself, or a worker process (:meth:`_start_workers`)
        self.stepper: dict[str, Block | WorkerBlock] = dict(self.blocks)
        self.running = [n for n in self.order if n not in self.loaded]
        self.watch = Stopwatch([*self.running, STORE])
        self.event_output = self._event_output()
        #: each block's incoming connections as (source block, source port, input port)
        self.inputs_of = {n: [(c.src, c.src_port, c.dst_port) for c in self.graph.connections if c.dst == n]
                          for n in self.graph.nodes}

    def _unused(self, name: str) -> Block:
        """Block ``name``, built afresh (as the graph file builds it) if an earlier run of this graph set it up: a
        block keeps its run's state, so a second run of one loaded graph would go on from the first one's end."""
        node = self.graph.nodes[name]
        if node.block.run_info is not None:
            node.block = type(node.block)(node.block.params, name=node.block.name, seed=node.block.seed)
        return node.block

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
        import networkx as nx

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
        out = self.out
        if out is None:
            return
        if out.exists() or out.is_symlink():
            if self._check_existing_output(out):
                return
        elif out.parent.exists() and not out.parent.is_dir():   # a missing parent is created, like `mkdir -p`
            raise StoreError(f"cannot create run store {out}: {out.parent} is not a folder")
        for folder in out.resolve().parents:
            if is_run_store(folder):
                raise StoreError(f"cannot create run store {out} inside the run store {folder}")

    def _check_existing_output(self, out: Path) -> bool:
        """Refuse an existing ``out`` that may not be written; True where it is a store to resume."""
        if not out.is_dir() or out.is_symlink():
            raise StoreError(f"{out} exists and is not an evsda run store (a run store is a folder); "
                             f"choose another output")
        if self.resume:
            if is_run_store(out) or store_module._is_empty(out):
                return True
            raise StoreError(f"cannot resume {out}: it is not an evsda run store")
        if not self.overwrite:
            raise StoreError(f"{out} already exists; choose another output, pass --overwrite to replace it, "
                             f"or --resume to continue the run it holds")
        check_replaceable(out)
        return False

    def _take_store_folder(self) -> None:
        """Create the output folder if needed (noting that this run created it) and lock it."""
        self._created = not self.out.exists()
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"cannot create run store {self.out}: {os_reason(exc)}") from None
        self.lock = StoreLock(self.out).acquire()

    def _open_for_resume(self) -> RunStore | None:
        """The store to continue, or None when there is nothing to continue (start over)."""
        if not is_run_store(self.out):
            log.info("%s: no run was committed yet; starting it from the beginning", self.out)
            return None
        store = RunStore.open(self.out, mode="r+")
        if store.attrs.get("graph_hash") != self.graph.digest():
            raise StoreError(f"cannot resume {self.out}: it was made by a different graph or parameters; "
                             f"run with the same graph file and --set values, or start a new store")
        return store

    def _create_store(self) -> RunStore:
        return RunStore.create(self.out, overwrite=True, attrs={
            "evsda_version": __version__,
            "graph": self.graph.to_dict(),
            "graph_hash": self.graph.digest(),
            "seed": self.run.seed,
            "start_epoch": self.run.epoch.isoformat().replace("+00:00", "Z"),
            "duration_ns": self.run.duration_ns,
            "window_ns": self.run.window_ns,
            "n_windows": self.run.n_windows,
        })

    # -- running -----------------------------------------------------------------------------------
    def execute(self) -> RunResult:
        if self.out is None:
            return self._execute()
        self._created = False
        try:
            self._take_store_folder()
            return self._execute()
        except BaseException as exc:
            if self.store is None and self._created:
                shutil.rmtree(self.out, ignore_errors=True)   # nothing was computed: leave nothing behind
            if isinstance(exc, KeyboardInterrupt):
                raise Interrupted(getattr(exc, "signal_name", "SIGINT"), self._interrupted_note()) from None
            raise
        finally:
            if self.lock is not None:
                self.lock.release()

    @contextmanager
    def _writing(self):
        """Store writes: a full disk or a lost folder is one line saying what is kept."""
        try:
            yield
        except OSError as exc:
            raise StoreError(f"writing run store {self.out} failed: {os_reason(exc)}; "
                             f"{self._committed_note()}") from None

    def _committed_note(self) -> str:
        windows = self.store.committed_windows if self.store is not None else 0
        if windows == 0:
            return "nothing was committed yet: run it again (--resume starts it over)"
        return (f"{windows} of {self.run.n_windows} windows are committed in {self.out}; "
                f"continue with --resume")

    def _interrupted_note(self) -> str:
        if self.store is None:
            return "interrupted before the first window was stored; nothing to keep (--resume starts it over)"
        return f"interrupted; {self._committed_note()}"

    def _execute(self) -> RunResult:
        self._start_workers()
        ended = False
        try:
            result = self._execute_windows()
            ended = True
            return result
        except WorkerDied as exc:
            raise WorkerDied(f"{exc}; {self._committed_note()}") from None
        except Exception as exc:
            raise self._earlier_worker_error() or exc
        finally:
            self._close_workers(kill=not ended)

    def _start_workers(self) -> None:
        """A worker process for each running block worth one, in a pipelined run, where they pay
        (:func:`.worker.workers_pay`) or wherever they are asked for."""
        names = [n for n in self.running if type(self.blocks[n]).worth_a_process]
        windows = self.run.n_windows if self.max_windows is None else min(self.max_windows, self.run.n_windows)
        if not (names and self.pipeline) or self.workers == "off" or (self.workers == "auto"
                                                                       and not workers_pay(windows)):
            return
        for name in names:
            self.stepper[name] = WorkerBlock(self.blocks[name], threads=threads_per_worker())
            if self.stepper[name].in_worker:
                log.info("%s steps in a worker process (pid %d)", self.blocks[name].label,
                         self.stepper[name].process.pid)

    def _workers(self) -> list[WorkerBlock]:
        return [s for s in self.stepper.values() if isinstance(s, WorkerBlock)]

    def _earlier_worker_error(self) -> BaseException | None:
        """After an error: the error of a worker's set-up or state restore, which the serial loop meets first."""
        for worker in self._workers():
            try:
                worker.settle()
            except Exception as exc:        # noqa: BLE001 -- returned to be raised instead
                return exc
        return None

    def _close_workers(self, kill: bool) -> None:
        for name, worker in list(self.stepper.items()):
            if isinstance(worker, WorkerBlock):
                worker.close(kill=kill)
                if worker.peak_rss_mb is not None:
                    log.info("%s: its worker process stepped %.1f s, waited %.1f s between steps, used %.1f s of CPU "
                             "and peaked at %.0f MB", self.blocks[name].label, worker.stepping_s, worker.waiting_s,
                             worker.cpu_s, worker.peak_rss_mb)
                self.stepper[name] = self.blocks[name]

    def _execute_windows(self) -> RunResult:
        for name in self.running:
            self.stepper[name].setup(self.run)
        result = RunResult(store=None, reused={n: str(s.path) for n, s in self.loaded.items()})
        start_window = self._resume(result) if self.resume and self.out is not None else 0
        if start_window is None:
            return result
        self._run_windows(start_window, result)
        finished = start_window + result.windows_run == self.run.n_windows
        finals = self._finish_blocks() if finished else {}
        result.timing_s = self.watch.seconds
        with self._writing():
            for name, outputs in finals.items():
                self._record(name, outputs, None, result)
            self._finish_store(result, self.running, self.watch.seconds, finished)
        return result

    def _finish_blocks(self) -> dict[str, dict[str, Any]]:
        """Each running block's final outputs (:meth:`Block.finish`) once the run's last window is done."""
        finals = {}
        for name in self.running:
            with self.watch.timing(name):
                finals[name] = self.stepper[name].finish() or {}
        return finals

    def _resume(self, result: RunResult) -> int | None:
        """The window to continue from, the blocks' state restored; None when the run is already complete."""
        store = self._open_for_resume()
        if store is None:
            return 0
        self._use_store(store, result, self.running)
        if store.complete:
            log.info("%s: the run is already complete; nothing to resume", self.out)
            result.metrics, result.metric_units = store.metrics, store.metric_units
            result.timing_s = dict(store.attrs.get("timing", {}))
            return None
        start_window = store.committed_windows
        states = store.read_checkpoint()
        if not states and start_window:
            raise StoreError(f"cannot resume {self.out}: it has {start_window} committed windows but no "
                             f"checkpoint to continue from; start again with --overwrite")
        for name in self.running if states else ():
            self.stepper[name].set_state(states.get(name, {}))
        return start_window

    def _run_windows(self, start_window: int, result: RunResult) -> None:
        """Step every running block over windows ``start_window`` on, recording and committing as it goes."""
        readers = {
            (name, port): self.loaded[name].product_windows(name, port, start=start_window)
            for name in self.loaded for port in self._consumed_ports(name, set(self.order))
        }
        stop_window = self.run.n_windows
        if self.max_windows is not None:
            stop_window = min(stop_window, start_window + self.max_windows)
        self._last_commit = time.perf_counter()
        bar = self._progress_bar(start_window)

        def loaded(index: int) -> dict[tuple[str, str], Any]:
            return {key: next(reader) for key, reader in readers.items()}

        def commit_due(index: int) -> bool:
            return self._commit_due(index, stop_window)

        if self.pipeline:
            pipeline = Pipeline(self.running, self._upstream(), self._inputs_for, self._step_block)
            windows = pipeline.windows(self.run, start_window, stop_window, loaded, commit_due)
        else:
            windows = self._serial_windows(start_window, stop_window, loaded, commit_due)
        try:
            for window, produced, commit in windows:
                with self.watch.timing(STORE), self._writing():
                    self._record_window(window, produced, result)
                result.windows_run += 1
                if commit:
                    with self.watch.timing(STORE), self._writing():
                        self._commit(window, {n: self.stepper[n] for n in self.running})
                    self._last_commit = time.perf_counter()
                bar.update(1)
                del produced                     # this window's values go before the next one is waited for
        finally:
            windows.close()                  # a pipeline waits for its running steps
            bar.close()

    def _progress_bar(self, start_window: int):
        """The run's progress bar, or, where none is shown, a stand-in that shows nothing (tqdm's import, ~7 ms of
        CPU, is then left out)."""
        if not self.progress:
            return _NoProgress()
        from .progress import progress_bar
        return progress_bar(total=self.run.n_windows, initial=start_window, desc=self.graph.name)

    def _serial_windows(self, start_window: int, stop_window: int, loaded, commit_due):
        """``(window, produced, commit)`` of each window in turn, one step at a time (no pipeline)."""
        for index in range(start_window, stop_window):
            window = self.run.window(index)
            values = loaded(index)
            produced = []
            for name in self.running:
                outputs = self._step_block(name, window, self._inputs_for(name, values))
                values.update({(name, port): value for port, value in outputs.items()})
                produced.append((name, outputs))
            yield window, produced, commit_due(index)

    def _upstream(self) -> dict[str, set[str]]:
        """Each running block's upstream blocks (those whose outputs it takes)."""
        return {name: {src for src, _, _ in self.inputs_of[name]} for name in self.running}

    def _inputs_for(self, name: str, values: dict[tuple[str, str], Any]) -> dict[str, Any]:
        return self._gather(self.blocks[name], self.inputs_of[name], values)

    def _step_block(self, name: str, window: Window, inputs: dict[str, Any]) -> dict[str, Any]:
        """Step block ``name`` over ``window`` with ``inputs``; its outputs, checked against its declaration."""
        block = self.blocks[name]
        with self.watch.timing(name):
            outputs = self.stepper[name].step(window, **inputs)
        self._check_outputs(block, outputs)
        return outputs

    def _record_window(self, window: Window, produced: list[tuple[str, dict[str, Any]]], result: RunResult) -> None:
        # The store is created once the first window has been computed in full: a scene that
        # cannot be simulated (say, a satellite that never enters the field) leaves nothing behind.
        if self.out is not None and self.store is None:
            self._use_store(self._create_store(), result, self.running)
        for name, outputs in produced:
            self._record(name, outputs, window, result)
        if self.store is not None and self.graph.run.store_truth:
            for name in self._loaded_truth():
                self.store.copy_truth(self.loaded[name], name, window.start_ns, window.stop_ns)

    def _commit_due(self, index: int, stop_window: int) -> bool:
        """Whether to commit after window ``index``: every ``checkpoint_every_s`` and at the last window this
        call runs. The run's last window is committed with the final outputs instead (no checkpoint is written
        only to be dropped), unless the checkpoint is kept."""
        if self.out is None:
            return False
        if index == self.run.n_windows - 1:
            return self.keep_checkpoint
        return time.perf_counter() - self._last_commit >= self.checkpoint_every_s or index == stop_window - 1

    def _finish_store(self, result: RunResult, running: list[str], timing: dict[str, float], finished: bool) -> None:
        if self.out is not None and self.store is None:
            self._use_store(self._create_store(), result, running)
        if self.store is not None:
            previous = self.store.attrs.get("timing", {})
            self.store.set_attrs(timing={k: v + previous.get(k, 0.0) for k, v in timing.items()},
                                 reused=result.reused)
            if finished:
                self.store.commit(windows=self.run.n_windows, complete=True,
                                  drop_checkpoint=not self.keep_checkpoint)
            result.metrics, result.metric_units = self.store.metrics, self.store.metric_units

    def _use_store(self, store: RunStore, result: RunResult, running: list[str]) -> None:
        self.store = result.store = store
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

    def _check_outputs(self, block: Block, outputs: dict[str, Any]) -> None:
        declared = type(block).outputs
        for port, spec in declared.items():
            if port not in outputs:
                raise RuntimeError(f"{block.label} returned no value for output '{port}'")
            if not isinstance(outputs[port], spec.type):
                raise RuntimeError(f"{block.label} output '{port}' returned {type(outputs[port]).__name__}, "
                                   f"declared {spec.type.type_name()}")

    def _record(self, name: str, outputs: dict[str, PortValue], window: Window | None, result: RunResult) -> None:
        """Record ``name``'s outputs as their port types say (:attr:`PortValue.record`); ``window`` is None
        for the values a block returns when the run finishes."""
        for port, value in outputs.items():
            key = (name, port)
            requested = key in self.requested
            if type(value).record == METRICS:
                self._record_metrics(value, result)
                continue
            if self.keep_outputs and requested:
                result.outputs.setdefault(key, []).append(value)
            if self.store is not None and window is not None:
                self._store_value(key, value, requested)

    def _store_value(self, key: tuple[str, str], value: PortValue, requested: bool) -> None:
        """One window's value of ``key`` into the store: truth rows, the event stream, or a product."""
        if type(value).record == TRUTH:
            if self.graph.run.store_truth:
                self.store.append_truth(key[0], value)
        elif key == self.event_output:
            columns, geometry = value.stream()
            self.store.append_events(columns, focal_plane=geometry)
        elif requested or self._stores_products(key[0]):
            self.store.append_product(*key, value)

    def _record_metrics(self, value: PortValue, result: RunResult) -> None:
        values, units = value.figures()
        result.metrics.update(values)
        result.metric_units.update(units)
        if self.store is not None:
            self.store.set_metrics(values, units)

    def _loaded_truth(self) -> list[str]:
        """Blocks loaded from another store whose ground truth is copied from it (their TRUTH outputs)."""
        return [name for name in self.loaded if any(spec.type.record == TRUTH
                                                    for spec in type(self.graph.nodes[name].block).outputs.values())]

    def _event_output(self) -> tuple[str, str] | None:
        """The output the store records as its event stream: the first requested EVENT_STREAM output."""
        candidates = [(b, p) for b, p in self.requested
                      if type(self.graph.nodes[b].block).outputs[p].type.record == EVENT_STREAM]
        return candidates[0] if candidates else None

    def _commit(self, window: Window, blocks: dict[str, Block | WorkerBlock]) -> None:
        name = self.store.write_checkpoint(window.index, {n: b.get_state() for n, b in blocks.items()})
        self.store.commit(windows=window.index + 1, checkpoint=name, complete=False)


def run_graph(graph: Graph, out: str | Path | None = None, **options) -> RunResult:
    """Run ``graph``; write a run store at ``out`` (or keep requested outputs in memory if None).

    Options: ``resume`` (continue the run in ``out``), ``overwrite`` (replace ``out``),
    ``reuse`` (stores whose matching upstream products are loaded instead of recomputed),
    ``progress`` (show a progress bar; default: when stderr is a terminal),
    ``checkpoint_every_s`` (wall-clock seconds between commits; 0 commits every window),
    ``keep_outputs`` (keep requested outputs in memory), ``max_windows`` (stop early),
    ``keep_checkpoint`` (keep the blocks' state at the end of a finished run; dropped by default).
    ``pipeline`` (step blocks of successive windows concurrently, recording the same bytes; default:
    ``EVSDA_PIPELINE``, on unless it is ``0``; see :mod:`evsda.graph.executor_pipeline`).
    ``workers`` (step the blocks worth it in worker processes of their own in a pipelined run: ``"auto"`` where
    that pays, True wherever, False never; default: ``EVSDA_WORKERS``, ``0`` (the default), ``auto`` or ``1``; see
    :mod:`evsda.graph.worker`).
    BLAS libraries run one thread while it runs, threads share few malloc arenas, and freed memory is kept for
    reuse (see :mod:`evsda.graph.threads`).
    """
    limit_malloc_arenas()
    keep_freed_memory()
    lazy_registries()
    with limit_blas():
        return Executor(graph, out, **options).execute()
