"""How much of the optics' step runs without the interpreter lock (issue 13): what two threads could overlap.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) in a fresh process with
``EVSDA_THREADS=1``, ``EVSDA_PIPELINE=0`` and the probe cache off, and splits the optics block's step CPU time
(``time.thread_time``, one thread) into:

* compiled calls made without the interpreter lock (Numba functions compiled ``nogil``, called from Python; the time
  of their first call, the compiled code's load from Numba's cache, is left out and counted with the rest), by
  function;
* the path choice's probes (``PathChooser._probe`` and, where it exists, ``probe_ahead``: the probes
  helper's, at the head of the run), whole;
* the rest: the interpreter and numpy between those calls. NumPy's own loops (the stamps' ``sin`` and ``cos``, the
  pocketfft transforms of the probes) release the lock too, so this is an upper bound of what holds it.

Each Python call of a compiled function goes through one timing wrapper (``Dispatcher.__call__``; ~0.3 us a call);
calls from compiled code to compiled code are not seen. ``--against DIR`` runs another checkout's code (its own
``.venv``) the same way, alternated; the medians over ``--repeats`` runs are printed, with the load average.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_gil.py [--repeats 3] [--against DIR]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import GRAPH, ONE_THREAD, alternated, checkouts, fresh  # noqa: E402

CHILD = r"""
import functools, json, sys, tempfile, time
from collections import defaultdict
clock = time.thread_time
spent, depth = defaultdict(float), [0]

from numba.core import dispatcher
from numba import _dispatcher
base_call = _dispatcher.Dispatcher.__call__
inner_compile = dispatcher.Dispatcher._compile_for_args
loading = [0.0]

def compile_for_args(self, *args, **kwargs):          # first calls: the cache's load (or a compile), lock held
    t = clock()
    try:
        return inner_compile(self, *args, **kwargs)
    finally:
        loading[0] += clock() - t
dispatcher.Dispatcher._compile_for_args = compile_for_args

def call(self, *args, **kwargs):
    if depth[0] == 0 or not self.targetoptions.get("nogil"):
        return base_call(self, *args, **kwargs)
    t, load = clock(), loading[0]
    try:
        return base_call(self, *args, **kwargs)
    finally:
        spent["nogil " + self.py_func.__module__.rpartition(".")[2] + "." + self.py_func.__name__] += (
            clock() - t - (loading[0] - load))
dispatcher.Dispatcher.__call__ = call

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.blocks.optics import block, paths

inside = defaultdict(int)

def timed(owner, attribute, label, outer=False):
    inner = getattr(owner, attribute)
    @functools.wraps(inner)
    def wrapper(*args, **kwargs):
        if inside[label]:                               # the outermost call of a label only
            return inner(*args, **kwargs)
        t, before = clock(), dict(spent)
        inside[label] += 1
        if outer:
            depth[0] += 1
        try:
            return inner(*args, **kwargs)
        finally:
            inside[label] -= 1
            if outer:
                depth[0] -= 1
            else:                                       # nested compiled calls count here, not twice
                for key in spent:
                    if key.startswith("nogil "):
                        spent[key] = before.get(key, 0.0)
            spent[label] += clock() - t
    setattr(owner, attribute, wrapper)

timed(block.PointSourceOptics, "step", "step", outer=True)
for name in ("_probe", "probe_ahead"):                  # the probes made as choices need them, or a window ahead
    if hasattr(paths.PathChooser, name):
        timed(paths.PathChooser, name, "probes")
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
with tempfile.TemporaryDirectory() as tmp:
    run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
print(json.dumps(spent))
"""


def one_run(graph: Path, duration: float, checkout: Path | None) -> dict:
    """One fresh run's figures, the probe cache off; ``checkout``: another checkout's code (its ``.venv``)."""
    return fresh(CHILD, {**ONE_THREAD, "EVSDA_CACHE": "off"}, (str(graph.resolve()), str(duration)), checkout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh runs of each tree (medians)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), alternated")
    args = parser.parse_args()
    trees = checkouts(parser, args.against)
    runs, loads = alternated(trees, args.repeats, lambda checkout: one_run(args.graph, args.duration, checkout),
                             lambda k, name, r, load: print(f"  {name}: step {r['step']:.2f} s CPU", flush=True))
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, the optics' step on one thread [CPU s]; medians of "
          f"{args.repeats} fresh runs, load {statistics.median(loads):.1f} ({min(loads):.1f}-{max(loads):.1f})")
    keys = sorted({k for rs in runs.values() for r in rs for k in r if k.startswith("nogil ")},
                  key=lambda k: -statistics.median(r.get(k, 0.0) for r in runs["this checkout"]))
    med = {name: {k: statistics.median(r.get(k, 0.0) for r in rs) for k in ["step", "probes", *keys]}
           for name, rs in runs.items()}
    for m in med.values():
        m["nogil"] = sum(m[k] for k in keys)
        m["rest"] = m["step"] - m["probes"] - m["nogil"]
    print(f"  {'item':58s}" + "".join(f" {name[-14:]:>14s}" for name in trees))

    def row(label, key):
        print(f"  {label:58s}" + "".join(f" {med[name][key]:14.2f}" for name in trees))

    row("the optics' step", "step")
    row("  path-choice probes (whole)", "probes")
    row("  compiled, without the interpreter lock", "nogil")
    for k in keys:
        if max(med[name][k] for name in trees) >= 0.01:
            row("    " + k[6:], k)
    row("  the rest: the interpreter, numpy (upper bound of the lock held)", "rest")
    for name in trees:
        m = med[name]
        print(f"  {name}: outside the probes, {m['nogil'] / (m['step'] - m['probes']):.0%} of the step compiled "
              f"without the lock")


if __name__ == "__main__":
    main()
