"""The small blocks' steps replayed side by side (issue 13): the lock-held Python beside the optics chain.

The tracked pass's scene and readout blocks (the satellite, the stars, the sky, the arbiter, the metrics) hold
the interpreter lock for most of their steps, and in a pipelined run that Python competes with the optics
chain's. Their CPU is a few milliseconds a window, too little to resolve in whole runs on a loaded host. This
benchmark runs the pass once, one step at a time on one thread, keeping every input each small block was given,
then steps fresh copies of those blocks over the same inputs ``--rounds`` times, in the run's order (the scene
models the blocks share and the star catalogue built afresh each round, as a run builds them), and prints each block's thread CPU a
window (window 0, with its one-time set-up, apart; medians over the rounds).

``--against DIR`` steps DIR's ``blocks/scene`` and ``blocks/readout`` too (imported here as packages of their own,
their block classes given the same parameters), alternated window by window in this process, and checks every
output of the two identical, byte for byte.

    OPENBLAS_NUM_THREADS=1 python benchmarks/framework_small_blocks.py [--duration 10] [--rounds 5]
        [--against /work/h-audit]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import os
import statistics
import sys
import time
import types
from pathlib import Path

os.environ.update(EVSDA_THREADS="1", EVSDA_PIPELINE="0")

import numpy as np  # noqa: E402

from evsda.graph import executor  # noqa: E402
from evsda.graph.graphfile import load_graph  # noqa: E402

SMALL = ("sat", "stars", "site/sky", "sensor/arbiter", "metrics")
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graph", default="benchmarks/end_to_end.yaml", help="graph file")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--rounds", type=int, default=5, help="replays of the captured steps")
    parser.add_argument("--against", type=Path, help="another checkout: its scene and readout blocks side by side")
    args = parser.parse_args()
    steps = captured(args.graph, args.duration)
    trees = {"this checkout": None}
    if args.against is not None:
        trees[str(args.against)] = other_packages(args.against)
    scene = ["evsda.blocks.scene"] + [others["scene"].__name__ for others in trees.values() if others]
    models = [importlib.import_module(f"{package}.pointing") for package in scene]
    catalogues = [importlib.import_module(f"{package}.catalog").load_hipparcos for package in scene]
    cpu = {tree: {name: [] for name in SMALL} for tree in trees}
    first = {tree: {name: [] for name in SMALL} for tree in trees}
    n_later = max(1, max(window.index for _, window, _ in steps))
    for r in range(args.rounds):
        for module, catalogue in zip(models, catalogues):
            module._SHARED_MODELS.clear()           # the scene's models, and the star catalogue, read afresh
            catalogue.cache_clear()
        blocks = {tree: fresh_blocks(args.graph, args.duration, others) for tree, others in trees.items()}
        spent = {tree: {name: [0.0, 0.0] for name in SMALL} for tree in trees}
        load = os.getloadavg()[0]
        for i, (name, window, inputs) in enumerate(steps):
            outputs = {}
            for tree in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
                t = time.thread_time()
                outputs[tree] = blocks[tree][name].step(window, **inputs)
                spent[tree][name][window.index > 0] += time.thread_time() - t
            if len(trees) > 1:
                a, b = (flattened(o, []) for o in outputs.values())
                if a != b:
                    raise SystemExit(f"{name}, window {window.index}: the outputs differ")
        for tree in trees:
            for name in SMALL:
                first[tree][name].append(spent[tree][name][0] * 1e3)
                cpu[tree][name].append(spent[tree][name][1] * 1e3 / n_later)
        print(f"round {r + 1} (load {load:.2f}): " + "; ".join(
            f"{tree}: {sum(cpu[tree][n][-1] for n in SMALL):.3f} ms a window" for tree in trees)
            + ("; outputs identical" if len(trees) > 1 else ""), flush=True)
    print(f"\neach block's thread CPU [ms]: window 0 / a later window (of {n_later}), medians of {args.rounds} "
          f"rounds, one thread, one process")
    for tree in trees:
        print(f"  {tree}")
        for name in SMALL:
            print(f"    {name:16s} {statistics.median(first[tree][name]):8.2f} / "
                  f"{statistics.median(cpu[tree][name]):6.3f}")
        print(f"    {'all':16s} {'':8s}   {statistics.median(map(sum, zip(*cpu[tree].values()))):6.3f}")


if __name__ == "__main__":
    main()
