"""The small blocks' steps replayed side by side (issue 13): the lock-held Python beside the optics chain.

The tracked pass's scene and readout blocks (the satellite, the stars, the sky, the arbiter, the metrics) hold
the interpreter lock for most of their steps, and in a pipelined run that Python competes with the optics
chain's. Their CPU is a few milliseconds a window, too little to resolve in whole runs on a loaded host. This
benchmark runs the pass once, one step at a time on one thread, keeping every input each small block was given,
then steps fresh copies of those blocks over the same inputs ``--rounds`` times, in the run's order (the scene
models the blocks share, the star catalogue and the spectra's tables built afresh each round, as a run builds them), and prints each block's thread CPU a
window (window 0, with its one-time set-up, apart; medians over the rounds).

``--against DIR`` steps DIR's ``blocks/scene`` and ``blocks/readout`` too (imported here as packages of their own,
their block classes given the same parameters), alternated window by window in this process, and checks every
output of the two identical, byte for byte. ``--beside none,python,numpy`` replays each round once per kind of
thread kept busy beside it (:class:`Beside`), alternated: how much a second busy thread slows the small blocks'
Python, apart from the run's schedule.

    OPENBLAS_NUM_THREADS=1 python benchmarks/framework_small_blocks.py [--duration 10] [--rounds 5]
        [--against /work/h-audit] [--beside none,python,numpy]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import os
import statistics
import sys
import threading
import time
import types
from pathlib import Path

os.environ.update(EVSDA_THREADS="1", EVSDA_PIPELINE="0")

import numpy as np  # noqa: E402

from evsda.graph import executor  # noqa: E402
from evsda.graph.graphfile import load_graph  # noqa: E402

SMALL = ("sat", "stars", "site/sky", "sensor/arbiter", "metrics")
BESIDE = ("none", "python", "numpy")
PACKAGES = ("scene", "readout")


def captured(graph_file: str, duration: float) -> list[tuple[str, object, dict]]:
    """``(block, window, inputs)`` of every small block's step in a serial run of the graph, in order."""
    steps = []
    step_block = executor.Executor._step_block

    def keeping(self, name, window, inputs):
        if name in SMALL:
            steps.append((name, window, dict(inputs)))
        return step_block(self, name, window, inputs)
    executor.Executor._step_block = keeping
    try:
        executor.run_graph(load_graph(graph_file, [f"run.duration_s={duration}"]), None, progress=False,
                           keep_outputs=False, pipeline=False)
    finally:
        executor.Executor._step_block = step_block
    return steps


def other_packages(checkout: Path) -> dict[str, types.ModuleType]:
    """``blocks/scene`` and ``blocks/readout`` of another checkout as packages of their own (their relative imports
    read that checkout's modules; the ports and the framework are this checkout's)."""
    packages = {}
    for name in PACKAGES:
        folder = (checkout / "blocks" / name).resolve()
        package = types.ModuleType(f"{name}_" + hashlib.md5(str(folder).encode()).hexdigest()[:8])
        package.__path__ = [str(folder)]
        sys.modules[package.__name__] = package
        packages[name] = package
    return packages


def fresh_blocks(graph_file: str, duration: float, others: dict | None) -> dict[str, object]:
    """The small blocks of the graph built and set up afresh, as this checkout's classes or, with ``others``,
    as the same classes of the other checkout's packages with the same parameters."""
    run = executor.Executor(load_graph(graph_file, [f"run.duration_s={duration}"]), None, progress=False,
                            keep_outputs=False, pipeline=False)
    blocks = {}
    for name in SMALL:
        block = run.blocks[name]
        if others is not None:
            package, module = type(block).__module__.split(".")[-2:]
            cls = getattr(importlib.import_module(f"{others[package].__name__}.{module}"), type(block).__name__)
            block = cls(block.params.model_dump(), name=block.name, seed=block.seed)
        block.setup(run.run)
        blocks[name] = block
    return blocks


def flattened(value, into: list) -> list:
    """Every array and plain value in a block's outputs, in a fixed order, for a byte-for-byte comparison."""
    if isinstance(value, np.ndarray):
        into.append((value.dtype.str, value.shape, np.ascontiguousarray(value).tobytes()))
    elif isinstance(value, dict):
        for key in sorted(value, key=str):
            into.append(str(key))
            flattened(value[key], into)
    elif isinstance(value, (list, tuple)):
        for item in value:
            flattened(item, into)
    elif hasattr(value, "__dict__") and not isinstance(value, type):
        flattened(vars(value), into)
    else:
        into.append(repr(value))
    return into


class Beside:
    """A thread kept busy beside the replay: ``python`` (a loop of interpreter-held Python, which takes the
    interpreter lock at every switch interval) or ``numpy`` (NumPy sums over 8 MB, which release the lock for
    ~1 ms at a time and take it back in between, as the optics' compiled loops do); ``none`` starts nothing."""

    def __init__(self, kind: str):
        self.kind, self.stop, self.thread = kind, threading.Event(), None

    def __enter__(self):
        if self.kind != "none":
            self.thread = threading.Thread(target=getattr(self, "_" + self.kind), daemon=True)
            self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        if self.thread is not None:
            self.thread.join()

    def _python(self) -> None:
        while not self.stop.is_set():
            total = 0
            for i in range(10_000):
                total += i * i

    def _numpy(self) -> None:
        a, b = np.ones(1 << 20), np.empty(1 << 20)
        while not self.stop.is_set():
            np.multiply(a, 0.5, out=b)
            np.add(b, 0.5, out=a)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graph", default="benchmarks/end_to_end.yaml", help="graph file")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--rounds", type=int, default=5, help="replays of the captured steps")
    parser.add_argument("--against", type=Path, help="another checkout: its scene and readout blocks side by side")
    parser.add_argument("--beside", default="none", help=f"comma-separated, of {', '.join(BESIDE)}: a thread kept "
                                                         f"busy beside the replay, round by round (see Beside)")
    args = parser.parse_args()
    steps = captured(args.graph, args.duration)
    trees = {"this checkout": None}
    if args.against is not None:
        trees[str(args.against)] = other_packages(args.against)
    scene = ["evsda.blocks.scene"] + [others["scene"].__name__ for others in trees.values() if others]
    models = [importlib.import_module(f"{package}.pointing") for package in scene]
    catalogues = [importlib.import_module(f"{package}.catalog").load_hipparcos for package in scene]
    tables = [cached for package in scene for cached in vars(importlib.import_module(f"{package}.spectra")).values()
              if hasattr(cached, "cache_clear")]       # the spectra's tables (the stars' band factors, ...)
    kinds = args.beside.split(",")
    if not set(kinds) <= set(BESIDE):
        raise SystemExit(f"--beside: of {', '.join(BESIDE)}")
    columns = [(tree, kind) for kind in kinds for tree in trees]
    cpu = {column: {name: [] for name in SMALL} for column in columns}
    first = {column: {name: [] for name in SMALL} for column in columns}
    n_later = max(1, max(window.index for _, window, _ in steps))
    for r in range(args.rounds):
        for kind in kinds[r % len(kinds):] + kinds[:r % len(kinds)]:
            for module, catalogue in zip(models, catalogues):
                module._SHARED_MODELS.clear()           # the scene's models, and the star catalogue, read afresh
                catalogue.cache_clear()
            for cached in tables:                       # and the spectra's tables made again, as a run makes them
                cached.cache_clear()
            blocks = {tree: fresh_blocks(args.graph, args.duration, others) for tree, others in trees.items()}
            spent = {tree: {name: [0.0, 0.0] for name in SMALL} for tree in trees}
            load = os.getloadavg()[0]
            with Beside(kind):
                replay(steps, blocks, spent)
            for tree in trees:
                for name in SMALL:
                    first[tree, kind][name].append(spent[tree][name][0] * 1e3)
                    cpu[tree, kind][name].append(spent[tree][name][1] * 1e3 / n_later)
            print(f"round {r + 1}, beside {kind} (load {load:.2f}): " + "; ".join(
                f"{tree}: {sum(cpu[tree, kind][n][-1] for n in SMALL):.3f} ms a window" for tree in trees)
                + ("; outputs identical" if len(trees) > 1 else ""), flush=True)
    print(f"\neach block's thread CPU [ms]: window 0 / a later window (of {n_later}), medians of {args.rounds} "
          f"rounds, one thread, one process")
    for tree, kind in columns:
        print(f"  {tree}" + ("" if kinds == ["none"] else f", beside {kind}"))
        for name in SMALL:
            print(f"    {name:16s} {statistics.median(first[tree, kind][name]):8.2f} / "
                  f"{statistics.median(cpu[tree, kind][name]):6.3f}")
        print(f"    {'all':16s} {'':8s}   {statistics.median(map(sum, zip(*cpu[tree, kind].values()))):6.3f}")


def replay(steps: list, blocks: dict, spent: dict) -> None:
    """Step every tree's blocks over the captured steps, alternating which tree goes first, adding each step's
    thread CPU to ``spent[tree][block][window > 0]``; the trees' outputs compared byte for byte."""
    trees = list(blocks)
    for i, (name, window, inputs) in enumerate(steps):
        outputs = {}
        for tree in (trees if i % 2 == 0 else trees[::-1]):
            t = time.thread_time()
            outputs[tree] = blocks[tree][name].step(window, **inputs)
            spent[tree][name][window.index > 0] += time.thread_time() - t
        if len(trees) > 1:
            a, b = (flattened(o, []) for o in outputs.values())
            if a != b:
                raise SystemExit(f"{name}, window {window.index}: the outputs differ")

if __name__ == "__main__":
    main()
