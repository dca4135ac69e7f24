"""The run store's CPU on the tracked pass (issue 13), itemised by thread: the recording, Zarr's I/O thread, the encoders.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) once, one step at a time on one thread,
keeping every call the executor makes to its :class:`evsda.graph.store.RunStore` (the store's attributes at its
creation, each window's ``append_events``, ``append_truth``, ``append_product``, ``set_metrics``, the final
``set_attrs``), then replays those calls ``--rounds`` times into fresh stores in a temporary folder and commits each
as a finished run does. Each replay's CPU is read per thread: the replaying thread (in a run, the main thread that
records each window), Zarr's I/O thread (``zarr_io``: the event loop that runs Zarr's coroutines: metadata, the
codec pipeline's orchestration), the event loop's workers (``asyncio``: Blosc, CRC-32C, file writes; read from ``/proc`` in clock ticks, the replaying
thread from its own clock) and the rest
(the store's flush threads, which end with each flush: since the eighteenth session, when the store is written
without Zarr, they compress and write the chunks). Zarr is imported before the replays; ``--import`` times its
import in ``--rounds`` fresh processes that first import what a run has imported by then (NumPy, Numba, SciPy,
pydantic, networkx), the store's first-window cost in a run until the eighteenth session; since then a run imports only the codecs
that :mod:`evsda.graph.store_files` uses (timed beside it).

``--against DIR`` replays into DIR's ``graph/store.py`` too (imported as a module of this checkout's ``evsda.graph``,
so the two share the framework's other modules), alternated round by round; the stores' digests (every array and
the metric and focal-plane attributes, as ``tests/test_examples_identical.py`` hashes them) must agree, and so must
every file of the two stores, byte for byte (the metadata documents included; the store written without Zarr,
eighteenth session, against one Zarr wrote).

    OPENBLAS_NUM_THREADS=1 python benchmarks/framework_store.py [--duration 10] [--rounds 5] [--against /work/h-audit]
        [--import]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

os.environ.update(EVSDA_THREADS="1", EVSDA_PIPELINE="0")
sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))

from evsda.graph import executor, store  # noqa: E402
from evsda.graph.graphfile import load_graph  # noqa: E402
from test_examples_identical import store_digest  # noqa: E402

#: the store calls a run makes per window and at its end, replayed in order
RECORDED = ("append_events", "append_truth", "append_product", "set_metrics", "set_attrs")
#: the threads the CPU is read for, by the start of their Python name; the rest is "other threads"
THREADS = ("MainThread", "zarr_io", "asyncio")

IMPORT = r"""
import sys, time
import numpy, numba, scipy.special, pydantic, networkx
from evsda.graph import store, store_files
t = time.process_time()
store._zarr() if sys.argv[1] == "zarr" else store_files._codecs()
print(time.process_time() - t)
"""


def captured(graph_file: str, duration: float) -> tuple[dict, list[tuple[str, tuple, dict]]]:
    """The store's attributes at its creation and the calls of :data:`RECORDED` in a serial run of the graph."""
    calls, created = [], {}
    originals = {name: getattr(store.RunStore, name) for name in RECORDED}
    create = store.RunStore.create

    def keeping(name):
        def call(self, *args, **kwargs):
            calls.append((name, args, kwargs))
            return originals[name](self, *args, **kwargs)
        return call

    def creating(path, attrs=None, overwrite=False):
        created.update(attrs or {})
        return create(path, attrs, overwrite)

    for name in RECORDED:
        setattr(store.RunStore, name, keeping(name))
    store.RunStore.create = staticmethod(creating)
    try:
        with tempfile.TemporaryDirectory() as folder:
            executor.run_graph(load_graph(graph_file, [f"run.duration_s={duration}"]), f"{folder}/run.zarr",
                               progress=False, checkpoint_every_s=1e9)
    finally:
        for name, method in originals.items():
            setattr(store.RunStore, name, method)
        store.RunStore.create = classmethod(create.__func__)
    return created, calls


def other_store(checkout: Path):
    """DIR's ``graph/store.py`` as a module of this checkout's ``evsda.graph`` (its relative imports read ours)."""
    path = (checkout / "graph" / "store.py").resolve()
    name = "evsda.graph._store_" + hashlib.md5(str(path).encode()).hexdigest()[:8]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def thread_cpu() -> Counter:
    """CPU seconds of this process's live threads so far, by :data:`THREADS` (``other`` for the rest)."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    tick = os.sysconf("SC_CLK_TCK")
    spent = Counter()
    for tid in os.listdir("/proc/self/task"):
        try:
            fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        name = names.get(int(tid), "")
        spent[next((k for k in THREADS if name.startswith(k)), "other")] += (int(fields[11]) + int(fields[12])) / tick
    return spent


def replay(module, created: dict, calls: list, digest: bool = False, files: dict | None = None) -> dict:
    """One replay into a fresh store of ``module``: process CPU, each thread group's CPU [s], and the digest;
    each file's bytes into ``files`` (by path in the store) if given."""
    with tempfile.TemporaryDirectory() as folder:
        path = f"{folder}/run.zarr"
        before, process, own = thread_cpu(), time.process_time(), time.thread_time()
        target = module.RunStore.create(path, attrs=created)
        for name, args, kwargs in calls:
            getattr(target, name)(*args, **kwargs)
        windows = int(created.get("n_windows", 0))
        target.commit(windows=windows, complete=True, drop_checkpoint=True)
        spent = {"process": time.process_time() - process}
        after = thread_cpu()
        spent.update({key: after[key] - before[key] for key in THREADS})
        spent["MainThread"] = time.thread_time() - own        # finer than /proc's clock ticks
        # the flush threads have ended by now: the rest of the process's CPU is theirs
        spent["other"] = spent["process"] - sum(spent[key] for key in THREADS)
        if digest:
            spent["digest"] = store_digest(Path(path))[:8]
        if files is not None:
            files.update({str(p.relative_to(path)): p.read_bytes() for p in Path(path).rglob("*") if p.is_file()})
        return spent


def import_cpu(rounds: int, what: str) -> list[float]:
    """Zarr's import (``what`` "zarr") or the codecs that store_files imports at a store's first chunk ("codecs"),
    in fresh processes after a run's other imports [s CPU]."""
    return [float(subprocess.run([sys.executable, "-c", IMPORT, what], capture_output=True, text=True,
                                 check=True).stdout.split()[-1]) for _ in range(rounds)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graph", default="benchmarks/end_to_end.yaml", help="graph file")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--rounds", type=int, default=5, help="replays of the captured calls (and fresh imports)")
    parser.add_argument("--against", type=Path, help="another checkout: its graph/store.py replayed alternately")
    parser.add_argument("--import", dest="imports", action="store_true",
                        help="also time Zarr's import and store_files' codecs' in fresh processes")
    args = parser.parse_args()
    created, calls = captured(args.graph, args.duration)
    counts = Counter(name for name, _, _ in calls)
    print(f"{args.graph}, {args.duration:g} s: " + ", ".join(f"{n} {name}" for name, n in counts.items()))
    trees = {"this checkout": store}
    if args.against is not None:
        trees[str(args.against)] = other_store(args.against)
    store._zarr()
    files = {tree: {} for tree in trees}
    digests = {tree: replay(module, created, calls, digest=True, files=files[tree])["digest"]
               for tree, module in trees.items()}
    print("store digests: " + ", ".join(f"{tree} {d}" for tree, d in digests.items())
          + ("" if len(set(digests.values())) == 1 else "  DIFFER"))
    if len(trees) > 1:
        first, second = files.values()
        differ = sorted(k for k in first.keys() | second.keys() if first.get(k) != second.get(k))
        print(f"store files: {len(first)} and {len(second)}, "
              + ("every file's bytes the same" if not differ else f"{len(differ)} DIFFER: {', '.join(differ[:5])}"))
    spent = {tree: [] for tree in trees}
    for r in range(args.rounds):
        order = list(trees) if r % 2 == 0 else list(trees)[::-1]
        load = os.getloadavg()[0]
        for tree in order:
            spent[tree].append(replay(trees[tree], created, calls))
        print(f"round {r + 1} (load {load:.2f}): " + "; ".join(
            f"{tree} {spent[tree][-1]['process']:.3f} s" for tree in trees), flush=True)
    print(f"\nthe store's CPU [s] replaying the run's calls, medians of {args.rounds} rounds")
    print(f"  {'':28s} {'process':>8s} " + " ".join(f"{k:>10s}" for k in (*THREADS, "other")))
    for tree in trees:
        med = {k: statistics.median(s[k] for s in spent[tree]) for k in ("process", *THREADS, "other")}
        print(f"  {tree:28s} {med['process']:8.3f} " + " ".join(f"{med[k]:10.3f}" for k in (*THREADS, "other")))
    if args.imports:
        for what, label in (("zarr", "Zarr's import"), ("codecs", "store_files' codecs (numcodecs, google-crc32c)")):
            seconds = import_cpu(args.rounds, what)
            print(f"{label} after a run's other imports: {statistics.median(seconds):.3f} s CPU "
                  f"(median of {args.rounds} fresh processes; {min(seconds):.3f}-{max(seconds):.3f})")


if __name__ == "__main__":
    main()
