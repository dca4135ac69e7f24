"""CPU time of the path choice's reference probes (``psf_path: auto``) on the tracked pass of end_to_end.yaml.

Runs one window of the pass (so that the optics block builds its imager and meets the run's
conditions), then times, on one thread, :meth:`.PathChooser.pupil_error` afresh for each
pupil-error bin the run met (the Fresnel reference propagations, 3-12 per bin), alternating the
reference screens cut from the whole FFT screen (``full``: ``fft_phase_screens``, as before)
and made by ``fft_phase_screen_corner`` (``corner``: the same numbers, checked here). Prints
the medians of ``--repeats`` rounds and the estimates, which must not differ.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import functools
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from evsda.blocks.optics import layer_screen
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.fft_screens import fft_phase_screen_corner, fft_phase_screens
from evsda.blocks.optics.paths import PUPIL_ERROR_ZENITH_BIN_RAD
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def full_cut(rng, n, m, delta, r0, L0=np.inf):
    """The reference screens as cut before: the whole screen pair transformed, its first m x m kept."""
    return np.ascontiguousarray(fft_phase_screens(rng, n, delta, r0, L0)[0][:m, :m])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    imagers = []
    step = PointSourceOptics.step

    @functools.wraps(step)                 # the registry checks step()'s parameters against the block's inputs
    def kept(self, *a, **k):
        out = step(self, *a, **k)
        imagers.append(self._imager)
        return out

    PointSourceOptics.step = kept
    with tempfile.TemporaryDirectory() as tmp:
        run_graph(load_graph(str(GRAPH), ["run.duration_s=0.1"]), Path(tmp) / "probe.zarr", overwrite=True)
    PointSourceOptics.step = step
    chooser = imagers[-1].chooser
    bins = list(chooser._pupil_errors)
    conditions = [((z + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD, np.inf if r < 0 else 2.0 ** (r + 0.5)) for z, r in bins]

    cuts = {"full": full_cut, "corner": fft_phase_screen_corner}
    times = {name: [] for name in cuts}
    errors = {name: None for name in cuts}
    for _ in range(args.repeats):
        for name, cut in cuts.items():
            layer_screen.fft_phase_screen_corner = cut
            chooser._pupil_errors.clear()
            t = time.process_time()
            errors[name] = [chooser.pupil_error(z, r) for z, r in conditions]
            times[name].append(time.process_time() - t)
    layer_screen.fft_phase_screen_corner = fft_phase_screen_corner
    print(f"pupil-error bins {bins}: estimates {errors['corner']}")
    assert errors["full"] == errors["corner"], errors
    for name in cuts:
        print(f"  {name:7s} screens: {statistics.median(times[name]):6.2f} s CPU (median of {args.repeats}; "
              f"{', '.join(f'{t:.2f}' for t in times[name])})")
    print(f"  ratio corner / full {statistics.median(times['corner']) / statistics.median(times['full']):.2f}")


if __name__ == "__main__":
    main()
