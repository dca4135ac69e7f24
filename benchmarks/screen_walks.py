"""The pupil path's phase screens on the tracked pass: their CPU, and how much of it holds the interpreter lock.

Runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) in a fresh process on one thread, one
step at a time (``EVSDA_THREADS=1``, ``EVSDA_PIPELINE=0``, the probe cache off), with ``time.process_time`` around
``PupilPath.turbulent_phase`` (and ``_phases``, which walks several sources together) and, inside them, around the
screens' compiled calls that release the lock (``screen_kernels``' ``walk_segments``, ``plan_layers``, the
footprint grids, and ``pupil_path.walk_and_stamp``, the walk with its frames' stamps in one call where the renderer's
frame path holds: then the item holds the pupil stamps too); the rest of the screens' time holds
it (Python, NumPy, regenerations). Prints the medians over ``--repeats`` runs, with the calls, PSFs (frames) and
layer reads counted. ``--against OTHER`` runs another checkout (its own ``.venv``) alternately, side by side.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/screen_walks.py [--duration 10] [--repeats 3] [--against DIR]
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
clock = time.process_time
spent = {"screens": 0.0, "compiled (nogil)": 0.0}
counts = {"calls": 0, "frames": 0, "layer reads": 0}
inside = [0]
from evsda.blocks.optics import layer_screen, pupil_path
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

def timed(owner, name, outer):
    inner = getattr(owner, name)
    @functools.wraps(inner)
    def wrapper(*args, **kwargs):
        if inside[0] != (0 if outer else 1):
            return inner(*args, **kwargs)
        inside[0] += outer
        t = clock()
        try:
            return inner(*args, **kwargs)
        finally:
            inside[0] -= outer
            spent["screens" if outer else "compiled (nogil)"] += clock() - t
    setattr(owner, name, wrapper)

timed(pupil_path.PupilPath, "turbulent_phase", True)
if hasattr(pupil_path.PupilPath, "_phases"):            # sources walked together (Imager.render_many) call it alone
    timed(pupil_path.PupilPath, "_phases", True)
for owner, name in ((layer_screen, "walk_segments"), (layer_screen, "plan_layers"), (pupil_path, "layer_grids"),
                    (pupil_path, "footprint_grids"), (pupil_path, "layer_grids_drifting"),
                    (pupil_path, "walk_and_stamp")):
    if hasattr(owner, name):
        timed(owner, name, False)
accumulate = pupil_path.accumulate_layers
def counted(screens, rows, *args, **kwargs):
    counts["calls"] += 1
    outputs = kwargs.get("outputs")                     # several lines of sight at once: their frames each
    counts["frames"] += rows.shape[1] * (1 if outputs is None else int(outputs.max()) + 1)
    counts["layer reads"] += rows.shape[0] * rows.shape[1]
    return accumulate(screens, rows, *args, **kwargs)
pupil_path.accumulate_layers = counted
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
with tempfile.TemporaryDirectory() as tmp:
    run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
print(json.dumps({**spent, **counts}))
"""


def one_run(graph: Path, duration: float, checkout: Path | None) -> dict:
    """One fresh run's figures, the probe cache off; ``checkout``: another checkout's code (its ``.venv``)."""
    return fresh(CHILD, {**ONE_THREAD, "EVSDA_CACHE": "off"}, (str(graph.resolve()), str(duration)), checkout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh runs each (medians)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), run alternately")
    args = parser.parse_args()
    trees = checkouts(parser, args.against)

    def show(k, name, r, load):
        print(f"  run {k + 1} ({name}): screens {r['screens']:.2f} s CPU, compiled {r['compiled (nogil)']:.2f} s, "
              f"load {load:.2f}", flush=True)

    runs, loads = alternated(trees, args.repeats, lambda tree: one_run(args.graph, args.duration, tree), show)
    print(f"\n{args.graph.name}, {args.duration:g} s simulated, one thread; medians of {args.repeats} fresh runs, load "
          f"{statistics.median(loads):.2f} ({min(loads):.2f}-{max(loads):.2f})")
    for name in trees:
        r = runs[name]
        screens = statistics.median(x["screens"] for x in r)
        compiled = statistics.median(x["compiled (nogil)"] for x in r)
        held = statistics.median(x["screens"] - x["compiled (nogil)"] for x in r)
        print(f"  {name}: phase screens {screens:.2f} s CPU = compiled, lock released {compiled:.2f} s + lock held "
              f"{held:.2f} s; {r[0]['calls']} calls, {r[0]['frames']} PSFs, {r[0]['layer reads']} layer reads "
              f"({1e6 * screens / max(r[0]['frames'], 1):.1f} us a PSF)")


if __name__ == "__main__":
    main()
