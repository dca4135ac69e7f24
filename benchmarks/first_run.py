"""What the first ``evsda run`` after an install costs: Numba compiling the optics' and pixels' loops.

Runs the main job (``examples/iss_pass.yaml``, or ``--graph``) with ``evsda run`` in fresh processes, each
round twice: first with an empty Numba cache folder (``NUMBA_CACHE_DIR``, as after an install: every compiled
loop is built and written), then again with the folder that run filled (every later run). It prints the median
wall and CPU times of both, their difference (the first run's compile) and the load average around each run.
The probe-result cache is off (``EVSDA_CACHE=off``), so both runs do the same work otherwise. The pixels' own
share, loop by loop: ``benchmarks/pixel_compile.py``.

    OPENBLAS_NUM_THREADS=1 python benchmarks/first_run.py [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import run_cli                             # noqa: E402

MAIN_JOB = Path(__file__).parents[1] / "examples" / "iss_pass.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=MAIN_JOB, help="graph file (default: the main job)")
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per run [s]")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of an empty-cache and a filled-cache run")
    args = parser.parse_args()
    os.environ["EVSDA_CACHE"] = "off"
    runs: dict[str, list[dict]] = {"empty": [], "filled": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeats):
            os.environ["NUMBA_CACHE_DIR"] = str(Path(tmp) / f"numba-{r}")       # empty: compile everything
            for cache in ("empty", "filled"):
                load = os.getloadavg()[0]
                run = run_cli(args.duration, Path(tmp) / "run.zarr", graph=args.graph)
                runs[cache].append(run)
                print(f"  {r + 1}. Numba cache {cache:6s} wall {run['wall_s']:6.1f} s  CPU {run['cpu_s']:6.1f} s  "
                      f"load {load:.2f} -> {os.getloadavg()[0]:.2f}", flush=True)
    wall = {c: statistics.median(x["wall_s"] for x in v) for c, v in runs.items()}
    cpu = {c: statistics.median(x["cpu_s"] for x in v) for c, v in runs.items()}
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, medians of {args.repeats}:")
    for c in runs:
        print(f"  Numba cache {c:6s} wall {wall[c]:6.1f} s  CPU {cpu[c]:6.1f} s")
    print(f"  the first run's compile: {wall['empty'] - wall['filled']:.1f} s wall, "
          f"{cpu['empty'] - cpu['filled']:.1f} s CPU")


if __name__ == "__main__":
    main()
