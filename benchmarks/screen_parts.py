"""The phase screens' compiled parts one at a time, at the tracked pass's shapes: a frame's read, the y pass by span,
a conditional column.

The tracked pass (benchmarks/end_to_end.yaml) reads 40 x 40 pupil grids from three layers: the first's screen samples
0.55 of the pupil's spacing apart (a read spans ~25 coefficient columns), the other two's 0.21 (~12); its walks make
~74 000 conditional columns of 40 rows and ~277 000 of 20 (benchmarks/screen_replay.py's calls). Each part is timed
in a fresh process, the best of ``--runs`` timings of a loop of calls (the kernels are called from Python: the
y pass's figures include ~0.6 us of dispatch, the same in every row), ``--against OTHER`` runs another checkout (its
own ``.venv``) alternately, side by side; a digest of every output says whether the two agree bit for bit.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/screen_parts.py [--repeats 3] [--against DIR]
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from end_to_end import alternated, checkouts, fresh  # noqa: E402

CHILD = r"""
import hashlib, json, sys, time
import numpy as np
from evsda.blocks.optics import screen_kernels as sk
from evsda.blocks.optics.autoregressive import extension_operator
from evsda.blocks.optics.large_scales import split_outer_scale
runs, digest, out = int(sys.argv[1]), hashlib.sha1(), {}

def best(call, loops):
    call()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        for _ in range(loops):
            call()
        times.append((time.perf_counter() - t) / loops)
    return min(times)

rng = np.random.default_rng(1)
frames = 100
for name, ratio, n in (("read, first layer (ns a frame)", 0.548, 40), ("read, upper layers (ns a frame)", 0.21, 20)):
    coefficients = rng.standard_normal((n + 8, n + 40))
    grid = 4 + np.arange(40)[None] * ratio + np.linspace(0, 20, frames)[:, None] + rng.uniform(0, 1, (frames, 1))
    phase, weight = np.zeros((frames, 40, 40)), np.ones(frames)
    read = lambda: sk.sample_grids_transposed(coefficients, 0, 0, grid, grid, weight, 0, frames, phase, True)
    out[name] = best(read, 20) / frames * 1e9
    digest.update(phase.tobytes())
coefficients = rng.standard_normal((30, 30))
rows = np.sort(rng.integers(0, 20, 40))
weights = rng.random((4, 40))
lines, combined = np.empty((30, 40)), np.empty(30)
for span in range(12, 17):
    out[f"y pass, {span} columns (ns a call)"] = best(lambda: sk._y_pass(coefficients, rows, weights, 0, span, lines,
                                                                        combined), 3000) * 1e9
    digest.update(lines[:span].tobytes())
for n, delta in ((40, 0.0096), (20, 0.025)):
    operator = extension_operator(n, 1, delta, split_outer_scale(n, delta, 25.0), n)
    steps = 2000
    canvas = rng.standard_normal((n, n + steps))
    lefts = np.arange(steps, dtype=np.int64)
    noise = rng.standard_normal(n * steps)
    extend = lambda: sk.extend_columns(canvas, np.zeros(steps, np.int64), lefts, np.zeros(steps, np.int8), operator.A,
                                       operator.B, operator.stencil_rows, operator.stencil_cols, noise, n)
    out[f"conditional column, {n} rows (ns)"] = best(extend, 1) / steps * 1e9
    digest.update(canvas.tobytes())
print(json.dumps({"ns": out, "digest": digest.hexdigest()[:16]}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes each (medians)")
    parser.add_argument("--runs", type=int, default=20, help="timings in each process (the best kept)")
    parser.add_argument("--against", type=Path, help="another checkout (with its own .venv), run alternately")
    args = parser.parse_args()
    trees = checkouts(parser, args.against)

    def show(k, name, r, load):
        print(f"  run {k + 1} ({name}): load {load:.2f}, outputs {r['digest']}", flush=True)

    runs, loads = alternated(trees, args.repeats, lambda tree: fresh(CHILD, {"OPENBLAS_NUM_THREADS": "1"},
                                                                    (str(args.runs),), tree), show)
    print(f"\nmedians of {args.repeats} processes, load {statistics.median(loads):.2f} "
          f"({min(loads):.2f}-{max(loads):.2f}); {' | '.join(runs)}")
    for part in runs["this checkout"][0]["ns"]:
        print(f"  {part:40s} " + " | ".join(f"{statistics.median(r['ns'][part] for r in rs):8.0f}"
                                             for rs in runs.values()))
    if len({r["digest"] for rs in runs.values() for r in rs}) > 1:
        print("  the outputs DIFFER between checkouts")
    elif args.against is not None:
        print("  the outputs are identical (bit for bit)")


if __name__ == "__main__":
    main()
