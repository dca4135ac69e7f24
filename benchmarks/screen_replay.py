"""The pupil path's phase screens alone: the tracked pass's screen calls captured once, replayed on a fresh pupil path.

``--capture`` runs a graph (default: the tracked 10 s pass of benchmarks/end_to_end.yaml) once in a fresh process on
one thread (``EVSDA_THREADS=1``, ``EVSDA_PIPELINE=0``, the probe cache off) and keeps every
``PupilPath._phases`` call's arguments (sources, times, epochs, lines of sight, zenith angles, ranges) with what the
screens read of the imager (geometry, seeds, outer scale, layers, wavelength) in a pickle (``--calls``). A replay
makes a fresh ``PupilPath`` in a fresh process and calls ``_phases`` with each in turn, as the pass did (the screens
are made, extended and regenerated the same way): once to warm up, then ``--runs`` times timed with the thread's CPU
clock around each call (nothing else of the pass runs, so its other blocks' noise is gone). Prints the median of
those CPU times per replay and the digest of every phase returned (SHA-1 over the arrays, in order): a change to
the screens is bit for bit when the digests agree. ``--against OTHER`` replays another checkout (its own ``.venv``)
alternately, side by side, on the same calls.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/screen_replay.py --capture   # ~30 s, once
    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/screen_replay.py [--repeats 5] [--against DIR]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import GRAPH, ONE_THREAD, alternated, checkouts, fresh  # noqa: E402

CALLS = Path(tempfile.gettempdir()) / "evsda-screen-calls.pkl"

CAPTURE = r"""
import copy, json, pickle, sys, tempfile
from evsda.blocks.optics import pupil_path
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
calls, owners = [], []
phases = pupil_path.PupilPath._phases
def kept(self, *args):
    if self not in owners:
        owners.append(self)
    if self is owners[0]:                         # the pass has one optics block
        calls.append(copy.deepcopy(args[:6]))      # the phases' arguments (not the stamps' that render_many adds)
    return phases(self, *args)
pupil_path.PupilPath._phases = kept
graph = load_graph(sys.argv[1], [f"run.duration_s={sys.argv[2]}"])
with tempfile.TemporaryDirectory() as tmp:
    run_graph(graph, tmp + "/run.zarr", overwrite=True, progress=False, checkpoint_every_s=1e9)
path = owners[0]
imager = path.imager
seen = {"geometry": copy.deepcopy(imager.geometry), "atmosphere": copy.deepcopy(imager.atmosphere),
        "outer_scale_m": imager.outer_scale_m, "wavelength": imager.wavelength,
        "seeds": {key: imager.source_seed(key, 0) for args in calls for key in args[0]}}
with open(sys.argv[3], "wb") as f:
    pickle.dump((seen, path.screen_method, path.screen_update, path.n_zernike_modes, calls), f)
print(json.dumps({"calls": len(calls), "owners": len(owners)}))
"""

REPLAY = r"""
import hashlib, json, pickle, sys, time
from evsda.blocks.optics import pupil_path
seen, method, update, modes, calls = pickle.load(open(sys.argv[1], "rb"))

class Imager:                                      # what the screens read of the pass's imager
    def __init__(self, seen):
        self.__dict__.update(seen)
        self.flows, self.follow_sight_rate = {}, False
    def source_seed(self, key, window):
        return self.seeds[key]
    def source_flow(self, source, t_s, sight):     # the imager's own (equivalent layers' winds; None without them)
        from evsda.blocks.optics.imaging import Imager as Real
        return Real.source_flow(self, source, t_s, sight)

def replay():
    path = pupil_path.PupilPath(Imager(seen), method, update, modes)
    digest, spent = hashlib.sha1(), 0.0
    for args in calls:
        t = time.thread_time()
        phase = path._phases(*args)
        spent += time.thread_time() - t
        digest.update(phase.base.tobytes() if phase.base is not None else phase.tobytes())
    return spent, digest.hexdigest()[:16]

_, digest = replay()                               # compiles or loads the Numba cache
times = []
for _ in range(int(sys.argv[2])):
    spent, again = replay()
    assert again == digest, "a replay's phases differ from the first's"
    times.append(spent)
print(json.dumps({"cpu_s": times, "digest": digest, "calls": len(calls)}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", action="store_true", help="run the graph once and keep its screen calls")
    parser.add_argument("--calls", type=Path, default=CALLS, help=f"the captured calls (default: {CALLS})")
    parser.add_argument("--graph", type=Path, default=GRAPH, help="graph file (default: benchmarks/end_to_end.yaml)")
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds [s]")
    parser.add_argument("--repeats", type=int, default=3, help="fresh replay processes each (medians)")
    parser.add_argument("--runs", type=int, default=2, help="timed replays in each process")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), run alternately")
    args = parser.parse_args()
    if args.capture:
        out = fresh(CAPTURE, {**ONE_THREAD, "EVSDA_CACHE": "off"},
                    (str(args.graph.resolve()), str(args.duration), str(args.calls.resolve())))
        print(f"{out['calls']} calls of PupilPath._phases kept in {args.calls}")
        return
    if not args.calls.exists():
        parser.error(f"{args.calls}: no captured calls (run with --capture first)")
    trees = checkouts(parser, args.against)

    def show(k, name, r, load):
        print(f"  run {k + 1} ({name}): {', '.join(f'{t:.3f}' for t in r['cpu_s'])} s CPU, phases {r['digest']}, "
              f"load {load:.2f}", flush=True)

    runs, loads = alternated(trees, args.repeats, lambda tree: fresh(REPLAY, {"OPENBLAS_NUM_THREADS": "1"},
                                                                    (str(args.calls.resolve()), str(args.runs)),
                                                                    tree), show)
    print(f"\n{runs['this checkout'][0]['calls']} captured calls replayed, one thread; medians of {args.repeats} "
          f"processes x {args.runs} replays, load {statistics.median(loads):.2f} ({min(loads):.2f}-{max(loads):.2f})")
    for name, r in runs.items():
        print(f"  {name}: phase screens {statistics.median(t for x in r for t in x['cpu_s']):.3f} s CPU "
              f"(min {min(t for x in r for t in x['cpu_s']):.3f}), phases {r[0]['digest']}")
    if len({x["digest"] for r in runs.values() for x in r}) > 1:
        print("  the phases DIFFER between checkouts")
    elif args.against is not None:
        print("  the phases are identical (bit for bit)")


if __name__ == "__main__":
    main()
