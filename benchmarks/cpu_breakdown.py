"""Where a run's CPU goes (issue 13): one step at a time on one thread, CPU time per block and per part.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) in fresh processes with
``EVSDA_THREADS=1`` and ``EVSDA_PIPELINE=0``, so that the process's CPU time around each call is that
call's own, and prints the medians over ``--repeats`` runs of:

* fixed costs: importing the command line, loading the graph (which imports the blocks it names),
  the compiled code's load from Numba's cache (every first call of a compiled function), the pixels'
  start;
* each block's steps, and within the optics: the path choice's reference probes (``pupil_estimate``),
  the analytic-path probes, pupil-path PSFs (phase screens, stamps), analytic (long-exposure) stamps;
* the store's writes and commits (the executor's ``(store)``; no checkpoint before the end, as in a run
  shorter than ``evsda run``'s 30 s between checkpoints) and what is left (executor, finishing).

Every item is ``time.process_time`` around the calls (no profiler), nested items are shown indented
and are included in the line above them. The figures are CPU seconds, so a loaded machine moves them
less than wall times (cache contention still adds ~20-40 % at load 8-11); the load average is printed.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/cpu_breakdown.py [--graph G] [--duration 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

GRAPH = Path(__file__).with_name("end_to_end.yaml")

CHILD = r"""
import json, sys, tempfile, time
clock = time.process_time
spent = {}
start = clock()
import evsda.graph.cli
spent["import the command line"] = clock() - start

def timed(owner, attribute, label):
    # wrap owner.attribute so that its CPU time adds to spent[label] (the outermost call only, if it recurses)
    import functools
    inner = getattr(owner, attribute)
    depth = [0]
    @functools.wraps(inner)
    def wrapper(*args, **kwargs):
        if depth[0]:
            return inner(*args, **kwargs)
        depth[0] += 1
        t = clock()
        try:
            return inner(*args, **kwargs)
        finally:
            depth[0] -= 1
            spent[label] = spent.get(label, 0.0) + clock() - t
    setattr(owner, attribute, wrapper)

from numba.core.dispatcher import Dispatcher
timed(Dispatcher, "_compile_for_args", "compiled code's load (Numba cache)")
from evsda.graph import executor
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

class Stopwatch(executor.Stopwatch):          # the executor's stopwatch on the CPU clock
    from contextlib import contextmanager
    @contextmanager
    def timing(self, name):
        t = clock()
        yield
        self.seconds[name] += clock() - t
executor.Stopwatch = Stopwatch

t = clock()
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
spent["load the graph (imports its blocks)"] = clock() - t
parts = {"optics": ("evsda.blocks.optics", [
            ("paths", "PathChooser", "pupil_estimate", "  reference probes (pupil_fft vs Fresnel)"),
            ("paths", "PathChooser", "_probe", "  all path-choice probes"),
            ("pupil_path", "PupilPath", "turbulent_phase", "  pupil path: phase screens"),
            ("render", "PupilRenderer", "stamps", "  pupil path: stamps (FFT PSFs)"),
            ("analytic_path", "AnalyticPath", "render", "  analytic stamps (long exposure, airy)"),
            ("block", None, "truth_table", "  truth table"), ("block", None, "truth_rows", "  truth table")]),
         "pixel": ("evsda.blocks.pixel", [("eventdriven", None, "start_pixels", "  pixels' start")])}
import importlib
for package, items in parts.values():
    for module, cls, attribute, label in items:
        try:
            m = importlib.import_module(f"{package}.{module}")
        except ImportError:
            continue
        owner = getattr(m, cls) if cls else m
        if hasattr(owner, attribute):
            timed(owner, attribute, label)
t = clock()
with tempfile.TemporaryDirectory() as tmp:
    # no checkpoint before the end: they come every 30 s of wall time, which a loaded machine would reach
    result = run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
    spent["run (every block, the store, the executor)"] = clock() - t
for name, seconds in result.timing_s.items():
    spent["block " + name] = seconds
spent["whole process"] = clock()
print(json.dumps(spent))
"""


def one_run(graph: Path, duration: float) -> dict:
    env = {**os.environ, "EVSDA_THREADS": "1", "EVSDA_PIPELINE": "0"}
    out = subprocess.run([sys.executable, "-c", CHILD, str(graph), str(duration)], capture_output=True, text=True,
                         env=env)
    if out.returncode:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh runs (medians)")
    args = parser.parse_args()
    runs, loads = [], []
    for _ in range(args.repeats):
        before = os.getloadavg()[0]
        runs.append(one_run(args.graph, args.duration))
        loads.append((before + os.getloadavg()[0]) / 2)
        print(f"  run {len(runs)}: {runs[-1]['whole process']:.2f} s CPU, load {loads[-1]:.2f}", flush=True)
    names = list(dict.fromkeys(k for r in runs for k in r))
    med = {k: statistics.median(r.get(k, 0.0) for r in runs) for k in names}
    total = med["whole process"]
    blocks = sorted((k for k in names if k.startswith("block ")), key=lambda k: -med[k])
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, one thread, one step at a time; "
          f"medians of {args.repeats} fresh runs, load {statistics.median(loads):.2f} "
          f"({min(loads):.2f}-{max(loads):.2f})")
    print(f"  {'item':58s} {'CPU [s]':>8s} {'share':>6s}")

    def row(label, seconds):
        print(f"  {label:58s} {seconds:8.2f} {100 * seconds / total:5.1f}%")

    row("whole process", total)
    for k in ("import the command line", "load the graph (imports its blocks)", "compiled code's load (Numba cache)"):
        row(k, med.get(k, 0.0))
    row("run (every block, the store, the executor)", med["run (every block, the store, the executor)"])
    for k in blocks:
        row("  " + k, med[k])
        tag = k.split("/")[-1]
        for sub in names:
            if sub.startswith("  ") and ((tag == "optics" and "pixels'" not in sub) or (tag == "pixel" and "pixels'" in sub)):
                row("  " + sub, med[sub])
    rest = med["run (every block, the store, the executor)"] - sum(med[k] for k in blocks)
    row("  executor and finishing (the rest of the run; medians need not add up)", rest)


if __name__ == "__main__":
    main()
