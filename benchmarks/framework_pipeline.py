"""Pipelined windows against one step at a time (issue 13.1), side by side in one run.

Runs a graph (default: the tracked LEO pass of benchmarks/end_to_end.yaml) with ``evsda run`` in three
modes, alternately, in fresh processes: ``serial`` (``EVSDA_PIPELINE=0``, one step at a time), ``threads``
(pipelined, every block in one process: ``EVSDA_WORKERS=0``, the default) and ``worker`` (pipelined, the
blocks worth it in worker processes of their own where that may pay: ``EVSDA_WORKERS=auto``). It prints for each the median wall time, CPU time (the
run's process and its worker together) and peak memory (the sum of the two processes' peaks, an upper
bound of their peak together; and the largest sum of their proportional set sizes sampled every 0.2 s, shared
pages counted once), the wall-time speed-ups and the load average around each run. Every store
must record the same bytes (checked: a hash of every array). The machine's other load shares the cores,
so the ratio of the medians is the figure to quote. ``--against OTHER`` runs each mode of another checkout (its
own ``.venv`` and Numba cache) too, alternated with this one's in every round: a change's side-by-side figure.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/framework_pipeline.py [--duration 10] [--repeats 3]
    EVSDA_CACHE=off ... --modes threads --against /path/to/baseline-checkout --repeats 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))

from end_to_end import GRAPH, run_cli                     # noqa: E402
from test_examples_identical import store_digest          # noqa: E402


#: the environment of each mode
MODES = {"serial": {"EVSDA_PIPELINE": "0", "EVSDA_WORKERS": "0"},
         "threads": {"EVSDA_PIPELINE": "1", "EVSDA_WORKERS": "0"},
         "worker": {"EVSDA_PIPELINE": "1", "EVSDA_WORKERS": "auto"}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each mode, alternated (medians)")
    parser.add_argument("--warm-duration", type=float, default=0.1,
                        help="simulated seconds of the run that warms the compiled caches (a graph whose satellite "
                             "enters the field later needs longer, e.g. examples/iss_pass.yaml: 4) [s]")
    parser.add_argument("--modes", default=",".join(MODES), help=f"modes to run, of {', '.join(MODES)}")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv): each mode run there too")
    args = parser.parse_args()
    pythons = {"": Path(sys.executable)}
    if args.against is not None:
        pythons[f"{args.against.name}:"] = args.against / ".venv" / "bin" / "python"
        if not pythons[f"{args.against.name}:"].exists():
            parser.error(f"--against {args.against}: expected a checkout with its own .venv")
    print(f"machine: {os.cpu_count()} cores; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; "
          f"EVSDA_THREADS={os.environ.get('EVSDA_THREADS', 'unset')}; {args.graph.name}, {args.duration:g} s simulated")
    modes = [tree + mode for mode in args.modes.split(",") for tree in pythons]
    runs: dict[str, list[dict]] = {mode: [] for mode in modes}
    digests = set()
    with tempfile.TemporaryDirectory() as tmp:
        for python in pythons.values():             # warm the compiled caches
            run_cli(args.warm_duration, Path(tmp) / "warm.zarr", graph=args.graph, python=python)
        for repeat in range(args.repeats):
            for mode in modes:
                tree, _, plain = mode.rpartition(":")
                store = Path(tmp) / f"{plain}.zarr"
                load = os.getloadavg()[0]
                os.environ.update(MODES[plain])         # what --[no-]pipeline and --[no-]workers set
                run = run_cli(args.duration, store, graph=args.graph, python=pythons[f"{tree}:" if tree else ""])
                run["load"] = (load + os.getloadavg()[0]) / 2
                runs[mode].append(run)
                digests.add(store_digest(store))
                print(f"  {repeat + 1}. {mode:16s} wall {run['wall_s']:6.1f} s  CPU {run['cpu_s']:6.1f} s  "
                      f"peak {run['peak_mb']:5.0f} MB ({run['own_peak_mb']:.0f} + worker {run['worker_peak_mb']:.0f}; "
                      f"PSS together {run['pss_peak_mb']:.0f})"
                      f"  load {run['load']:.2f}", flush=True)
    print(f"\nmedians of {args.repeats} (alternated):")
    for mode, rows in runs.items():
        wall = statistics.median(r["wall_s"] for r in rows)
        print(f"  {mode:16s} wall {wall:6.2f} s = {args.duration / wall:.2f}x real time; "
              f"CPU {statistics.median(r['cpu_s'] for r in rows):.1f} s; "
              f"peak {statistics.median(r['peak_mb'] for r in rows):.0f} MB (sum of the processes' peaks), "
              f"{statistics.median(r['pss_peak_mb'] for r in rows):.0f} MB (largest sampled PSS together); "
              f"load {statistics.median(r['load'] for r in rows):.2f}")
    walls = {mode: statistics.median(r["wall_s"] for r in rows) for mode, rows in runs.items()}
    pairs = ([(f"{tree}{mode}", mode) for mode in args.modes.split(",") for tree in list(pythons)[1:]]
             if len(pythons) > 1 else [(modes[0], mode) for mode in modes[1:]])
    for base, mode in pairs:
        print(f"  {mode} against {base}: wall-time speed-up: {walls[base] / walls[mode]:.3f}x; each round: "
              + ", ".join(f"{a['wall_s'] / b['wall_s']:.3f}x" for a, b in zip(runs[base], runs[mode])))
    print(f"  stores identical: {len(digests) == 1} ({len(digests)} distinct hash{'es' if len(digests) > 1 else ''}: "
          f"{', '.join(d[:8] for d in sorted(digests))})")
    if len(digests) != 1:
        raise SystemExit("the modes' stores differ")


if __name__ == "__main__":
    main()
