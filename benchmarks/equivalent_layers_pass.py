"""The tracked pass with its profile rendered as fewer equivalent layers, side by side (issue 13).

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml, whose ``median_seeing.csv`` has 7
layers) with ``evsda run`` in fresh processes, pipelined as it runs by default, once per column and round,
alternated: the graph on every layer (``telescope/optics.equivalent_layers: null``) and with it set to each of
``--layers`` (blocks/optics/equivalent_layers.py; ``auto`` is the default since the seventeenth session). Prints each column's median wall and CPU time (the run's
process and its worker together), its ratio to the every-layer column in each round, the load average around
each run, and each column's store hash (every layer keeps the hash from before the default: d18dee90 for the 10 s
pass).
The errors the equivalent layers cost are ``benchmarks/speed_vs_error.py``'s rows "3 equivalent layers"...

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/equivalent_layers_pass.py [--layers 3 4] [--repeats 3]
    ... --graph examples/iss_pass.yaml --duration 4 --warm-duration 4        # the main job (store ce7d2360)
    ... --layers auto --set telescope/optics.profile_file=library:atmospheres/mauna_kea.csv   # another profile
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

SETTING = "telescope/optics.equivalent_layers"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=3, help="rounds, each column once per round (medians)")
    parser.add_argument("--layers", nargs="+", default=["3"], help="equivalent layers of each column: integers or "
                                                                      "'auto' [1]")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of every column (repeatable), e.g. "
                             "telescope/optics.profile_file=library:atmospheres/mauna_kea.csv")
    parser.add_argument("--warm-duration", type=float, default=0.1,
                        help="simulated seconds of the run that warms the compiled caches (a graph whose satellite "
                             "enters the field later needs longer, e.g. examples/iss_pass.yaml: 4) [s]")
    args = parser.parse_args()
    columns = {"every layer": [*args.settings, f"{SETTING}=null"],
               **{f"{n} equivalent layers": [*args.settings, f"{SETTING}={n}"] for n in args.layers}}
    print(f"{os.cpu_count()} cores; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; "
          f"{args.graph.name}, {args.duration:g} s simulated, pipelined as by default")
    runs: dict[str, list[dict]] = {name: [] for name in columns}
    digests: dict[str, set] = {name: set() for name in columns}
    with tempfile.TemporaryDirectory() as tmp:
        run_cli(args.warm_duration, Path(tmp) / "warm.zarr", args.settings, graph=args.graph)   # the compiled caches
        for repeat in range(args.repeats):
            for name, settings in columns.items():
                store = Path(tmp) / "run.zarr"
                load = os.getloadavg()[0]
                run = run_cli(args.duration, store, settings, graph=args.graph)
                run["load"] = (load + os.getloadavg()[0]) / 2
                runs[name].append(run)
                digests[name].add(store_digest(store)[:8])
                print(f"  {repeat + 1}. {name:22s} wall {run['wall_s']:6.1f} s  CPU {run['cpu_s']:6.1f} s  "
                      f"load {run['load']:.2f}", flush=True)
    print(f"\nmedians of {args.repeats} (alternated):")
    base = runs["every layer"]
    for name, rows in runs.items():
        wall, cpu = (statistics.median(r[key] for r in rows) for key in ("wall_s", "cpu_s"))
        load = statistics.median(r["load"] for r in rows)
        print(f"  {name:22s} wall {wall:6.2f} s  CPU {cpu:6.2f} s  load {load:.2f}"
              f"  store {', '.join(sorted(digests[name]))}")
        if rows is not base:
            print("    against every layer, each round: wall "
                  + ", ".join(f"{r['wall_s'] / b['wall_s']:.3f}" for r, b in zip(rows, base))
                  + "; CPU " + ", ".join(f"{r['cpu_s'] / b['cpu_s']:.3f}" for r, b in zip(rows, base)))


if __name__ == "__main__":
    main()
