"""Numba at a run's start (``evsda.graph.numba_loads``): its runtime set up ahead, and its cached loads' CPU.

Without ``--loads``: each fresh process loads the tracked pass's graph (its block modules, Numba with them), applies
``numba_loads.lazy_registries`` as ``run_graph`` does (which starts the runtime's set-up on its thread unless
``EVSDA_RUNTIME_AHEAD=off``), then holds the interpreter for ``--busy`` milliseconds of Python (what a run does
before its first compiled call: its set-up and window 0's scene steps), then makes a first compiled call (one
cached load, the pixels' ``drive_rows``). It prints the medians of the first call's wall time and of the wall time
from ``lazy_registries`` to the call's end, with the runtime set up ahead and at the first load, alternated, and the
load average (the set-up ahead needs the other core free).

``--loads``: the CPU (each loading thread's clock) of every cached load (``Cache._load_overload``) in a run of the
tracked pass (``--duration`` simulated seconds, one step at a time, the probe cache off), with Numba's events
around each LLVM call taken off as :func:`evsda.graph.numba_loads.lazy_registries` does and kept
(``EVSDA_QUICKER_LLVM_CALLS=off``), alternated, medians.

    OPENBLAS_NUM_THREADS=1 python benchmarks/numba_start.py [--busy 50] [--repeats 9]
    OPENBLAS_NUM_THREADS=1 python benchmarks/numba_start.py --loads [--duration 0.5] [--repeats 7]
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

CHILD = r"""
import gc, time
gc.disable()                                      # as the command holds it during its start
from evsda.graph.graphfile import load_graph
load_graph({graph!r}, [])
import numpy as np
from evsda.blocks.pixel.drive_kernel import drive_rows
from evsda.graph.numba_loads import lazy_registries
started = time.perf_counter()
lazy_registries()
until = time.perf_counter() + {busy_s!r}
while time.perf_counter() < until:                # the run's set-up and first steps: interpreter-held Python
    sum(range(100))
called = time.perf_counter()
drive_rows(np.ones(1), np.zeros(64), np.zeros((1, 64)))
done = time.perf_counter()
print(done - called, done - started)
"""

LOADS_CHILD = r"""
import json, threading, time
from numba.core import caching
numbas = caching.Cache._load_overload
spent = [0.0, 0]

def timed(self, sig, target_context):
    start = time.thread_time()
    try:
        return numbas(self, sig, target_context)
    finally:
        spent[0] += time.thread_time() - start
        spent[1] += 1

caching.Cache._load_overload = timed
from evsda.graph.cli import main
main(["run", {graph!r}, "--set", "run.duration_s={duration}", "-o", {out!r}, "--overwrite", "-q"])
print(json.dumps(spent))
"""


def cached_loads(graph: Path, duration: float, repeats: int) -> None:
    """Print the medians of the cached loads' CPU in a run, Numba's LLVM lock events off and on (alternated)."""
    variants = {"events off": "on", "events on": "off"}
    spent = {name: [] for name in variants}
    loads_avg = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory() as tmp:
        child = LOADS_CHILD.format(graph=str(graph), duration=duration, out=str(Path(tmp) / "run.zarr"))
        for _ in range(repeats):
            for name, switch in variants.items():
                env = dict(os.environ, OPENBLAS_NUM_THREADS="1", EVSDA_CACHE="off", EVSDA_PIPELINE="0",
                           EVSDA_QUICKER_LLVM_CALLS=switch)
                out = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True,
                                     check=True)
                spent[name].append(json.loads(out.stdout.splitlines()[-1]))
            loads_avg.append(os.getloadavg()[0])
    print(f"Numba's cached loads in a run of {graph.name} ({duration:g} s, one step at a time), CPU of the loading "
          f"threads, medians of {repeats} (alternated), load average {min(loads_avg):.1f}-{max(loads_avg):.1f}")
    for name, runs in spent.items():
        print(f"  LLVM lock {name:10s} {statistics.median(cpu for cpu, _ in runs) * 1e3:6.1f} ms in "
              f"{runs[0][1]} loads")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=float, default=50.0, help="interpreter-held Python before the call [ms]")
    parser.add_argument("--repeats", type=int, default=9, help="fresh processes of each variant, alternated")
    parser.add_argument("--loads", action="store_true", help="the cached loads' CPU in a run instead")
    parser.add_argument("--duration", type=float, default=0.5, help="simulated seconds of --loads' runs [s]")
    args = parser.parse_args()
    graph = Path(__file__).with_name("end_to_end.yaml").resolve()
    if args.loads:
        cached_loads(graph, args.duration, args.repeats)
        return
    child = CHILD.format(graph=str(graph), busy_s=args.busy / 1e3)
    variants = {"ahead": "on", "at the first load": "off"}
    times = {name: [] for name in variants}
    loads = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        for name, switch in variants.items():
            env = dict(os.environ, OPENBLAS_NUM_THREADS="1", EVSDA_RUNTIME_AHEAD=switch)
            out = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True, check=True)
            times[name].append(tuple(map(float, out.stdout.split())))
        loads.append(os.getloadavg()[0])
    print(f"Numba's runtime set up ahead or at the first load, {args.busy:g} ms of Python between; medians of "
          f"{args.repeats} (alternated), load average {min(loads):.1f}-{max(loads):.1f}")
    for name, runs in times.items():
        first = statistics.median(call for call, _ in runs)
        span = statistics.median(whole for _, whole in runs)
        print(f"  {name:18s} first compiled call {first * 1e3:6.1f} ms, lazy_registries to its end {span * 1e3:6.1f} ms")


if __name__ == "__main__":
    main()
