"""What running on several threads costs (issue 13): CPU per block on every thread, one thread against two.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) in fresh processes for each of
``--modes`` (``THREADS/PIPELINE``: ``EVSDA_THREADS`` and ``EVSDA_PIPELINE``; default ``1/0,2/1``: one thread
one step at a time, against the default run on 2 cores), alternated, and prints per run and as medians:

* wall and CPU time of the run (after loading the graph), system time, context switches (voluntary: waits
  for the GIL, a lock or a pool; involuntary: preempted) and minor page faults;
* each block's CPU on every thread: its step (``time.thread_time`` on the step's thread) plus the items it
  hands to :func:`evsda.graph.threads.parallel_map` (sources, probe pairs, pixel chunks) on the helpers;
* the pipeline's critical path: the wall time during which the optics (``--critical``) is not stepping,
  while the run is (it waits for the window ahead to be recorded, or for its inputs).

The probes' results come from the cache of earlier runs unless ``EVSDA_CACHE=off`` (then every run pays
them). CPU that two threads add over one is the threads' cost (contention for the GIL, caches and memory,
hand-offs); its share per block says where. Quote medians with the load average printed beside them: a
loaded machine seldom runs two of the run's threads at once, which hides both the gain and the cost.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/framework_threads.py [--duration 10] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

GRAPH = Path(__file__).with_name("end_to_end.yaml")

CHILD = r"""
import json, resource, sys, threading, time
clock = time.thread_time
owner = threading.local()
spent, steps = {}, []
lock = threading.Lock()

def add(name, seconds):
    with lock:
        spent[name] = spent.get(name, 0.0) + seconds

from evsda.graph import threads
plain_map = threads.parallel_map
def parallel_map(fn, items, n):          # items run on helpers count towards the calling block
    name = getattr(owner, "block", None)
    def timed(item):
        outer = getattr(owner, "block", None)
        owner.block = name
        t = clock()
        try:
            return fn(item)
        finally:
            owner.block = outer
            if threading.current_thread() is not caller:
                add(name, clock() - t)
    caller = threading.current_thread()
    return plain_map(timed, items, n)
threads.parallel_map = parallel_map      # before the blocks import it

from evsda.graph import executor
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
step = executor.Executor._step_block
def timed_step(self, name, window, inputs):
    owner.block = name
    w, t = time.perf_counter(), clock()
    try:
        return step(self, name, window, inputs)
    finally:
        add(name, clock() - t)
        steps.append((name, w, time.perf_counter()))
        owner.block = None
executor.Executor._step_block = timed_step

graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
before, start = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
run_graph(graph, sys.argv[3], overwrite=True, progress=False)
after, stop = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
critical = sorted((a, b) for name, a, b in steps if name == sys.argv[4])
busy = sum(b - a for a, b in critical)
print(json.dumps({
    "wall_s": stop - start, "cpu_s": after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime,
    "sys_s": after.ru_stime - before.ru_stime, "voluntary": after.ru_nvcsw - before.ru_nvcsw,
    "involuntary": after.ru_nivcsw - before.ru_nivcsw, "page_faults": after.ru_minflt - before.ru_minflt,
    "blocks": spent, "critical_idle_s": (stop - start) - busy}))
"""


def run(graph: Path, duration: float, threads: str, pipeline: str, critical: str, store: Path) -> dict:
    env = {**os.environ, "EVSDA_THREADS": threads, "EVSDA_PIPELINE": pipeline}
    load = os.getloadavg()[0]
    out = subprocess.run([sys.executable, "-c", CHILD, str(graph), str(duration), str(store), critical],
                         capture_output=True, text=True, env=env)
    if out.returncode:
        raise RuntimeError(f"run failed:\n{out.stderr[-3000:]}")
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["load"] = (load + os.getloadavg()[0]) / 2
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=2, help="runs of each mode, alternated (medians)")
    parser.add_argument("--modes", default="1/0,2/1", help="THREADS/PIPELINE pairs, comma-separated")
    parser.add_argument("--critical", default="telescope/optics", help="the block on the pipeline's critical path")
    parser.add_argument("--warm-duration", type=float, default=0.1,
                        help="simulated seconds of the run that warms the compiled caches first [s]")
    parser.add_argument("--store", type=Path, default=Path("/tmp/framework_threads.zarr"), help="run store (replaced)")
    args = parser.parse_args()
    modes = [tuple(mode.split("/")) for mode in args.modes.split(",")]
    print(f"machine: {os.cpu_count()} cores; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; "
          f"EVSDA_CACHE={os.environ.get('EVSDA_CACHE', 'unset')}; {args.graph.name}, {args.duration:g} s simulated; "
          f"modes THREADS/PIPELINE {args.modes}")
    run(args.graph, args.warm_duration, "1", "0", args.critical, args.store)      # warm the compiled caches
    rows: dict[str, list[dict]] = {}
    for repeat in range(args.repeats):
        for threads, pipeline in modes:
            r = run(args.graph, args.duration, threads, pipeline, args.critical, args.store)
            rows.setdefault(f"{threads}/{pipeline}", []).append(r)
            top = sorted(r["blocks"].items(), key=lambda kv: -kv[1])[:3]
            print(f"  {repeat + 1}. {threads}/{pipeline}: wall {r['wall_s']:5.1f} s  CPU {r['cpu_s']:5.1f} s "
                  f"(sys {r['sys_s']:.2f})  switches {r['voluntary']}+{r['involuntary']}  "
                  f"faults {r['page_faults']}  {args.critical} idle {r['critical_idle_s']:.1f} s  load {r['load']:.2f}  "
                  + "  ".join(f"{name} {cpu:.2f}" for name, cpu in top), flush=True)
    median = statistics.median
    print(f"\nmedians of {args.repeats} (alternated):")
    names = sorted({n for rs in rows.values() for r in rs for n in r["blocks"]},
                   key=lambda n: -max(median(r["blocks"].get(n, 0.0) for r in rs) for rs in rows.values()))
    print(f"  {'mode':6s} {'wall':>6s} {'CPU':>6s} {'sys':>5s} {'volunt.':>8s} {'invol.':>7s} {'faults':>7s} "
          f"{'idle':>5s} {'load':>5s}  " + " ".join(f"{n.split('/')[-1][:9]:>9s}" for n in names[:6]))
    for mode, rs in rows.items():
        print(f"  {mode:6s} {median(r['wall_s'] for r in rs):6.1f} {median(r['cpu_s'] for r in rs):6.1f} "
              f"{median(r['sys_s'] for r in rs):5.2f} {median(r['voluntary'] for r in rs):8.0f} "
              f"{median(r['involuntary'] for r in rs):7.0f} {median(r['page_faults'] for r in rs):7.0f} "
              f"{median(r['critical_idle_s'] for r in rs):5.1f} {median(r['load'] for r in rs):5.2f}  "
              + " ".join(f"{median(r['blocks'].get(n, 0.0) for r in rs):9.2f}" for n in names[:6]))


if __name__ == "__main__":
    main()
