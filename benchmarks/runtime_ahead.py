"""Numba's runtime set up ahead on a thread of its own (``evsda.graph.numba_loads``), against at the first load.

Each fresh process loads the tracked pass's graph (its block modules, Numba with them), applies
``numba_loads.lazy_registries`` as ``run_graph`` does (which starts the runtime's set-up on its thread unless
``EVSDA_RUNTIME_AHEAD=off``), then holds the interpreter for ``--busy`` milliseconds of Python (what a run does
before its first compiled call: its set-up and window 0's scene steps), then makes a first compiled call (one
cached load, the pixels' ``drive_rows``). It prints the medians of the first call's wall time and of the wall time
from ``lazy_registries`` to the call's end, with the runtime set up ahead and at the first load, alternated, and the
load average (the set-up ahead needs the other core free).

    OPENBLAS_NUM_THREADS=1 python benchmarks/runtime_ahead.py [--busy 50] [--repeats 9]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=float, default=50.0, help="interpreter-held Python before the call [ms]")
    parser.add_argument("--repeats", type=int, default=9, help="fresh processes of each variant, alternated")
    args = parser.parse_args()
    graph = Path(__file__).with_name("end_to_end.yaml").resolve()
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
