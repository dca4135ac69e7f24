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

Every item is the main thread's CPU time around the calls (``time.thread_time``, no profiler; one thread, so
a block's steps run there), nested items are shown indented and are included in the line above them. The
store's own threads (Zarr's I/O thread and its encoders) work while the next steps run; their CPU is the
run's CPU on other threads, a line of its own (seventeenth session: with the process's clock around each call,
as before, it fell on whichever block's step it overlapped, ~0.2-0.35 s of the pass, most of it on the
scene's and readout's small blocks, and the rest on the executor). The one-core start is split as a run pays
it: the command line's import, then Numba's (a run meets it in the graph load, at the first block module that
compiles; it was counted nowhere before the seventeenth session), then the rest of the graph load. The
figures are CPU seconds, so a loaded machine moves them less than wall times (cache contention still adds
~20-40 % at load 8-11); the load average is printed.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/cpu_breakdown.py [--graph G] [--duration 10] [--repeats 3]
        [--cache cold,warm] [--against OTHER_CHECKOUT] [--sets "" "telescope/optics.source_intervals=false"]

The path choice's probe results are kept across runs (:mod:`evsda.graph.result_cache`); ``--cache`` says how
each column runs: ``off`` (the default: every probe computed, the figures of earlier sessions), ``cold``
(an empty cache folder for each run: computed and written) or ``warm`` (a folder filled by one unmeasured run
first: every probe read from the disk). Several columns alternate their runs side by side.
``--against`` adds a column of another checkout (its own ``.venv``; the probe cache off, as a checkout from before
the cache runs), measured with this script's instrumentation and alternated with the others.
``--sets`` makes a column of each list of ``--set`` values (``;``-separated, ``""`` the graph as it is), each run
with the probe cache as ``--cache``'s first column, alternated side by side.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import GRAPH, ONE_THREAD, fresh  # noqa: E402

CHILD = r"""
import json, sys, tempfile, time
clock = time.thread_time           # the main thread's: every block steps there, the store's threads apart
spent = {}
start = clock()
import evsda.graph.cli
spent["import the command line"] = clock() - start
t = clock()
import numba                       # before the items below wrap its dispatchers; a run imports it in the graph load
spent["import Numba (a run's graph load imports it)"] = clock() - t

depths = {}
def timed(owner, attribute, label):
    # wrap owner.attribute so that its CPU time adds to spent[label] (the outermost call only, if it recurses)
    import functools
    inner = getattr(owner, attribute)
    depth = depths.setdefault(label, [0])     # calls nested under another item of the same label count once
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
try:                       # as the evsda command does before it loads a graph (a checkout from before has no such step)
    from evsda.graph.scipy_imports import lean_array_api
    lean_array_api()
except ImportError:
    pass
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}", *sys.argv[3:]])
spent["load the graph (imports its blocks)"] = clock() - t
parts = {"optics": ("evsda.blocks.optics", [
            ("paths", "PathChooser", "pupil_estimate", "  reference probes (pupil_fft vs Fresnel)"),
            ("paths", "PathChooser", "_pair_distances", "  reference probes (pupil_fft vs Fresnel)"),
            ("paths", "PathChooser", "_probe", "  all path-choice probes"),
            ("paths", "PathChooser", "probe_ahead", "  all path-choice probes"),
            ("render", "PupilRenderer", "__init__", "  pupil renderer's set-up (Numba's first load; within the probes "
             "when made ahead)"),
            ("pupil_path", "PupilPath", "turbulent_phase", "  pupil path: phase screens"),
            ("pupil_path", "PupilPath", "_phases", "  pupil path: phase screens"),    # sources walked together
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
t, t_all = clock(), time.process_time()
with tempfile.TemporaryDirectory() as tmp:
    # no checkpoint before the end: they come every 30 s of wall time, which a loaded machine would reach
    result = run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
    spent["run (every block, the store, the executor)"] = clock() - t
    spent["run: other threads (the store's I/O and encoders)"] = time.process_time() - t_all - (clock() - t)
for name, seconds in result.timing_s.items():
    spent["block " + name] = seconds
spent["whole process"] = time.process_time()
print(json.dumps(spent))
"""


def one_run(graph: Path, duration: float, cache: dict[str, str], checkout: Path | None = None,
            settings: tuple[str, ...] = ()) -> dict:
    """One fresh run's figures; ``checkout``: run another checkout's code (its ``.venv``) instead of this one;
    ``settings``: ``--set`` values."""
    return fresh(CHILD, {**ONE_THREAD, **cache}, (str(graph.resolve()), str(duration), *settings), checkout)


#: the probe-result cache (evsda.graph.result_cache) each column runs with: switched off; empty at the start of
#: every run; filled by one run before the measured ones
CACHE_MODES = ("off", "cold", "warm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh runs (medians)")
    parser.add_argument("--cache", default="off",
                        help=f"comma-separated columns, runs alternated side by side: {', '.join(CACHE_MODES)} "
                             "(the probe-result cache: off, empty, or filled by one run first; default off)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv) measured side by side, "
                                                         "the probe cache off (e.g. main at an earlier commit)")
    parser.add_argument("--sets", nargs="+", metavar="K=V;K=V",
                        help="a column for each list of --set values ('' the graph as it is), alternated side by side, "
                             "the probe cache as --cache's first column")
    args = parser.parse_args()
    modes = args.cache.split(",")
    if not set(modes) <= set(CACHE_MODES):
        parser.error(f"--cache takes {', '.join(CACHE_MODES)}, got {args.cache}")
    # each column: its label, cache mode and --set values
    settings = {m: () for m in modes}
    if args.sets:
        settings = {(text or "as is"): tuple(v for v in text.split(";") if v) for text in args.sets}
        cache_of = dict.fromkeys(settings, modes[0])
        modes = list(settings)
    else:
        cache_of = {m: m for m in modes}
    if args.against is not None:
        if not (args.against / ".venv" / "bin" / "python").exists():
            parser.error(f"--against {args.against}: expected a checkout with its own .venv")
        modes.append("against")
    with tempfile.TemporaryDirectory() as tmp:
        warm = {"EVSDA_CACHE": "on", "EVSDA_CACHE_DIR": f"{tmp}/warm"}
        if "warm" in cache_of.values():
            one_run(args.graph, args.duration, warm)
        runs, loads = {m: [] for m in modes}, {m: [] for m in modes}
        for k in range(args.repeats):
            for mode in modes:
                cache = {"off": {"EVSDA_CACHE": "off"}, "warm": warm, "against": {"EVSDA_CACHE": "off"},
                         "cold": {"EVSDA_CACHE": "on", "EVSDA_CACHE_DIR": f"{tmp}/cold{k}"}}[cache_of.get(mode, mode)]
                before = os.getloadavg()[0]
                runs[mode].append(one_run(args.graph, args.duration, cache,
                                          args.against if mode == "against" else None, settings.get(mode, ())))
                loads[mode].append((before + os.getloadavg()[0]) / 2)
                what = (f"{args.against}, cache off" if mode == "against" else
                        f"{mode}, {cache_of[mode]} cache" if args.sets else f"{mode} cache")
                print(f"  run {k + 1} ({what}): {runs[mode][-1]['whole process']:.2f} s CPU, "
                      f"load {loads[mode][-1]:.2f}", flush=True)
    every = [r for m in modes for r in runs[m]]
    names = list(dict.fromkeys(k for r in every for k in r))
    med = {m: {k: statistics.median(r.get(k, 0.0) for r in runs[m]) for k in names} for m in modes}
    first = med[modes[0]]
    total = first["whole process"]
    blocks = sorted((k for k in names if k.startswith("block ")), key=lambda k: -first[k])
    all_loads = [x for m in modes for x in loads[m]]
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, one thread, one step at a time; "
          f"medians of {args.repeats} fresh runs, load {statistics.median(all_loads):.2f} "
          f"({min(all_loads):.2f}-{max(all_loads):.2f})")
    columns = "".join(f" {(m if m == 'against' or args.sets else m + ' cache') if len(modes) > 1 else 'CPU [s]':>11s}"
                      for m in modes)
    print(f"  {'item':58s}{columns} {'share':>6s}")

    def row(label, key=None):
        values = [med[m].get(key or label, 0.0) if not callable(key) else key(med[m]) for m in modes]
        print(f"  {label:58s}" + "".join(f" {v:11.2f}" for v in values) + f" {100 * values[0] / total:5.1f}%")

    row("whole process")
    for k in ("import the command line", "import Numba (a run's graph load imports it)",
              "load the graph (imports its blocks)", "compiled code's load (Numba cache)"):
        row(k)
    row("run (every block, the store, the executor)")
    row("run: other threads (the store's I/O and encoders)")
    for k in blocks:
        row("  " + k, k)
        tag = k.split("/")[-1]
        for sub in names:
            if sub.startswith("  ") and ((tag == "optics" and "pixels'" not in sub) or (tag == "pixel" and "pixels'" in sub)):
                row("  " + sub, sub)
    row("  executor and finishing (the rest of the run; medians need not add up)",
        lambda m: m["run (every block, the store, the executor)"] - sum(m[k] for k in blocks))


if __name__ == "__main__":
    main()
