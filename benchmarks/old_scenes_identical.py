"""Do old scenes give identical events across a range of commits? (issue 15.5: new blocks and parameters
must leave scenes that do not use them unchanged.)

Checks out two commits of this repository side by side (``git worktree``, removed afterwards), runs the
same small versions of the example scenes of the older commit with each (in separate processes, each
importing its own commit's code) and compares the recorded events array by array.

    OPENBLAS_NUM_THREADS=1 python benchmarks/old_scenes_identical.py OLD_COMMIT NEW_COMMIT

Prints, per scene, the events of each commit and whether they are identical. A difference is expected
where a commit between the two changes physics on purpose (its message says so).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HALF = {"sensor/camera.width_px": 640, "sensor/camera.height_px": 360, "sensor/camera.pixel_pitch_m": 9.72e-6}
SCENES = {   # the scenes of the end-to-end tests, shortened
    "iss_pass.yaml": {**HALF, "run.start": "2023-03-20T19:18:39.4Z", "run.duration_s": 0.3,
                      "stars.faint_limit_mag": 9.0},
    "geo_sidereal.yaml": {**HALF, "run.start": "2013-03-24T09:40:01.5Z", "run.duration_s": 0.5,
                          "stars.faint_limit_mag": 11.0},
    "space_based.yaml": {"run.duration_s": 0.3},
}
RUN = """
import json, sys, numpy as np
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore
scene, overrides, out = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3]
run_graph(load_graph(scene, overrides), out + ".zarr", progress=False)
np.savez(out, **RunStore.open(out + ".zarr").read_events())
"""


def checkout(commit: str, folder: Path) -> Path:
    """A worktree of ``commit`` and a folder that makes ``import evsda`` load it; returns that folder."""
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "-q", "--detach", str(folder / "tree"), commit],
                   check=True)
    package = folder / "path" / "evsda"
    package.mkdir(parents=True)
    for part in ("graph", "blocks", "library"):
        (package / part).symlink_to(folder / "tree" / part)
    return folder / "path"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old")
    parser.add_argument("new")
    args = parser.parse_args()
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = {c: checkout(c, tmp / c) for c in (args.old, args.new)}
        try:
            print(f"{'scene':20} {args.old:>12} {args.new:>12}  identical")
            for scene, overrides in SCENES.items():
                graph = tmp / args.old / "tree" / "examples" / scene
                events = {}
                for commit, path in paths.items():
                    out = tmp / commit / scene.replace(".yaml", "")
                    subprocess.run([sys.executable, "-c", RUN, str(graph), json.dumps(overrides), str(out)],
                                   check=True, env={**_env(), "PYTHONPATH": str(path)})
                    events[commit] = np.load(f"{out}.npz")
                a, b = events[args.old], events[args.new]
                same = a.files == b.files and all(np.array_equal(a[k], b[k]) for k in a.files)
                print(f"{scene:20} {len(a['x']):12d} {len(b['x']):12d}  {'yes' if same else 'NO'}", flush=True)
        finally:
            for commit in paths:
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tmp / commit / "tree")],
                               check=False)


def _env() -> dict:
    import os

    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


if __name__ == "__main__":
    main()
