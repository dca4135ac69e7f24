"""Do the example scenes record identical bytes at two commits? (issue 15.5: new blocks and parameters must
leave scenes that do not use them unchanged; issue 16: a redesign changes no behaviour.)

Checks out two commits of this repository side by side (``git worktree``, removed afterwards) and runs
every example scene of the older commit, in the short versions of ``tests/test_examples_identical.py``
(this checkout's), with each commit's code (separate processes, each importing its own commit's code).
Compares the SHA-256 of everything each run store records (events, products, truth, metrics).

    OPENBLAS_NUM_THREADS=1 python benchmarks/old_scenes_identical.py OLD_COMMIT NEW_COMMIT

Prints, per scene, the events of each commit and whether the stores are identical. A difference is expected
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
SCENES = REPO / "tests" / "test_examples_identical.py"   # the short versions and the store digest
RUN = """
import json, runpy, sys
from pathlib import Path
from evsda.graph.store import RunStore
test = runpy.run_path(sys.argv[1])
scene, examples, out = sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4])
graph, store = test["run_example"](scene, out, examples)
print(json.dumps({"store": store, "events": RunStore.open(out).n_events}))
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
    scenes = sorted(runpy_short())

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        paths = {c: checkout(c, tmp / c) for c in (args.old, args.new)}
        examples = tmp / args.old / "tree" / "examples"
        try:
            print(f"{'scene':32} {args.old:>12} {args.new:>12}  identical")
            for scene in scenes:
                if not (examples / scene).exists():
                    print(f"{scene:32} {'(not at ' + args.old + ')':>26}")
                    continue
                runs = {}
                for commit, path in paths.items():
                    out = tmp / commit / scene.replace(".yaml", ".zarr")
                    done = subprocess.run([sys.executable, "-c", RUN, str(SCENES), scene, str(examples), str(out)],
                                          check=True, capture_output=True, text=True,
                                          env={**_env(), "PYTHONPATH": str(path)})
                    runs[commit] = json.loads(done.stdout.strip().splitlines()[-1])
                a, b = runs[args.old], runs[args.new]
                same = "yes" if a["store"] == b["store"] else "NO"
                print(f"{scene:32} {a['events']:12d} {b['events']:12d}  {same}", flush=True)
        finally:
            for commit in paths:
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tmp / commit / "tree")],
                               check=False)


def runpy_short() -> dict:
    """The short versions of the example scenes (``SHORT`` of the test file)."""
    import runpy

    return runpy.run_path(str(SCENES))["SHORT"]


def _env() -> dict:
    import os

    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


if __name__ == "__main__":
    main()
