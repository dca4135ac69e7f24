"""CPU time of the path choice's reference probes (``psf_path: auto``) on the tracked pass of end_to_end.yaml.

Runs one window of the pass (so that the optics block builds its imager and meets the run's
conditions), then times, on one thread, :meth:`.PathChooser.pupil_estimate` afresh for each
pupil-error bin the run met (the Fresnel reference propagations, 4-24 per bin), alternating the
probes' frame pairs made from both halves of each complex FFT draw (``both``: as ``auto`` does,
:meth:`.LayerScreen.twin`) and the second frame of each pair drawn on its own (``one``: every frame
its own draw, the probes' cost before). Prints the medians of ``--repeats`` rounds and each bin's
estimate, frames and verdict. ``--all-frames`` makes every bin take all 24 frames (a tolerance no
estimate can clear: the same count both ways, the cost per frame).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py [--repeats 5] [--all-frames]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.optics.paths import PUPIL_ERROR_ZENITH_BIN_RAD
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--all-frames", action="store_true", help="every bin takes all 24 frames")
    args = parser.parse_args()
    os.environ["EVSDA_THREADS"] = "1"

    imagers = []
    step = PointSourceOptics.step

    @functools.wraps(step)                 # the registry checks step()'s parameters against the block's inputs
    def kept(self, *a, **k):
        out = step(self, *a, **k)
        imagers.append(self._imager)
        return out

    PointSourceOptics.step = kept
    with tempfile.TemporaryDirectory() as tmp:
        run_graph(load_graph(str(GRAPH), ["run.duration_s=0.002", "telescope/optics.psf_path=pupil_fft"]),
                  Path(tmp) / "probe.zarr", overwrite=True)
    PointSourceOptics.step = step
    imager = imagers[-1]
    chooser = imager.chooser
    if args.all_frames:
        imager.tolerance = float("nan")
    bins = [(6, 19), (6, -1)]              # the tracked pass at 65 deg: the ISS (7.4e5 m) and the stars (far)
    conditions = [((z + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD, np.inf if r < 0 else 2.0 ** (r + 0.5)) for z, r in bins]

    twin = LayerScreen.twin
    ways = {"one": lambda self, seed: None, "both": twin}
    times = {name: [] for name in ways}
    estimates = {}
    for _ in range(args.repeats):
        for name, way in ways.items():
            LayerScreen.twin = way
            chooser._pupil_errors.clear()
            t = time.process_time()
            estimates[name] = [chooser.pupil_estimate(z, r) for z, r in conditions]
            times[name].append(time.process_time() - t)
    LayerScreen.twin = twin
    for name in ways:
        found = ", ".join(f"{e.error:.3g} +- {e.standard_error:.2g} on {e.frames} ({'in' if e.within else 'out'})"
                          for e in estimates[name])
        print(f"  {name:4s} draw(s) a pair: {statistics.median(times[name]):6.2f} s CPU (median of {args.repeats}; "
              f"{', '.join(f'{t:.2f}' for t in times[name])}); bins {bins}: {found}")
    print(f"  ratio both / one {statistics.median(times['both']) / statistics.median(times['one']):.2f}")


if __name__ == "__main__":
    main()
