"""CPU time of the path choice's reference probes (``psf_path: auto``) on the tracked pass of end_to_end.yaml.

Runs one window of the pass (so that the optics block builds its imager and meets the run's
conditions), then times, on one thread with the cache of probe results across runs off,
:meth:`.PathChooser.pupil_estimate` afresh for each pupil-error bin the run met (the Fresnel reference propagations, 4-24 per bin), alternating the
probes' frame pairs made from both halves of each complex FFT draw (``both``: as ``auto`` does,
:meth:`.LayerScreen.twin`) and the second frame of each pair drawn on its own (``one``: every frame
its own draw, the probes' cost before). Prints the medians of ``--repeats`` rounds and each bin's
estimate, frames and verdict. ``--all-frames`` makes every bin take all 24 frames (a tolerance no
estimate can clear: the same count both ways, the cost per frame). ``--against DIR`` alternates this tree's
probes (pairs, as ``auto`` makes them) with those through another checkout's reference path (its
``blocks/optics/reference_path.py`` with its ``propagation.py``, ``layer_screen.py`` and ``fft_screens.py``), and
prints how far the estimates of the two are apart. Every round starts cold, as a run's first probes do: the
screens' spectra and the propagation's transfer functions kept within a process are emptied first.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/path_probes.py [--repeats 5] [--all-frames] [--against DIR]
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from evsda.blocks.optics import fft_screens, propagation
from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.layer_screen import LayerScreen
from evsda.blocks.optics.paths import PUPIL_ERROR_ZENITH_BIN_RAD
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def checkout_module(checkout: Path, name: str):
    """``blocks/optics/<name>.py`` of another checkout, imported inside this tree's optics package (its relative
    imports are this tree's modules)."""
    spec = importlib.util.spec_from_file_location(f"evsda.blocks.optics._against_{name}",
                                                  checkout / "blocks" / "optics" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.lru_cache(maxsize=None)
def checkout_modules(checkout: Path) -> dict:
    """Another checkout's reference path: its ``reference_path.py`` with its ``propagation.py``, ``layer_screen.py``
    and that one's ``fft_screens.py`` (the FFT screens' draws, spectra and transforms); the rest is this tree's."""
    modules = {name: checkout_module(checkout, name)
               for name in ("reference_path", "propagation", "layer_screen", "fft_screens")}
    modules["reference_path"].propagate = modules["propagation"].propagate
    modules["reference_path"].LayerScreen = modules["layer_screen"].LayerScreen
    modules["layer_screen"].fft_spline_corners = modules["fft_screens"].fft_spline_corners
    return modules


def against(checkout: Path, imager) -> Callable[[], None]:
    """Make ``imager``'s reference path that of ``checkout`` (:func:`checkout_modules`); returns the undo."""
    reference = imager.reference
    kept = reference.__class__
    reference.__class__ = checkout_modules(checkout)["reference_path"].ReferencePath

    def undo():
        reference.__class__ = kept
    return undo


def forget_tables(checkout: Path | None) -> None:
    """Empty the tables kept across probes within a process (the FFT screens' spectra, the propagation's transfer
    functions), this tree's and ``checkout``'s, so that every round costs what a run's first probes cost."""
    trees = [{"fft_screens": fft_screens, "propagation": propagation}]
    if checkout is not None:
        trees.append(checkout_modules(checkout))
    for modules in trees:
        modules["fft_screens"]._spectra.cache_clear()
        kept = getattr(modules["propagation"], "_kept_transfer_functions", None)
        if kept is not None:
            kept.cache_clear()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--all-frames", action="store_true", help="every bin takes all 24 frames")
    parser.add_argument("--against", type=Path, help="another checkout: its propagation and FFT screens' cut")
    args = parser.parse_args()
    os.environ["EVSDA_THREADS"] = "1"
    os.environ["EVSDA_CACHE"] = "off"      # the probes themselves, every round (not the results kept across runs)

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

    def one_draw_a_frame():
        LayerScreen.twin = lambda self, seed: None
        return lambda: setattr(LayerScreen, "twin", twin)

    if args.against:
        ways = {str(args.against): lambda: against(args.against, imager), "this tree": lambda: (lambda: None)}
    else:
        ways = {"one draw(s) a pair": one_draw_a_frame, "both draw(s) a pair": lambda: (lambda: None)}
    times = {name: [] for name in ways}
    estimates = {}
    loads = []
    for _ in range(args.repeats):
        loads.append(os.getloadavg()[0])
        for name, way in ways.items():
            undo = way()
            chooser._pupil_errors.clear()
            forget_tables(args.against)
            t = time.process_time()
            estimates[name] = [chooser.pupil_estimate(z, r) for z, r in conditions]
            times[name].append(time.process_time() - t)
            undo()
    for name in ways:
        found = ", ".join(f"{e.error:.3g} +- {e.standard_error:.2g} on {e.frames} ({'in' if e.within else 'out'})"
                          for e in estimates[name])
        print(f"  {name}: {statistics.median(times[name]):6.2f} s CPU (median of {args.repeats}; "
              f"{', '.join(f'{t:.2f}' for t in times[name])}); bins {bins}: {found}")
    first, second = ways
    print(f"  ratio {second} / {first}: {statistics.median(times[second]) / statistics.median(times[first]):.2f}; "
          f"load {statistics.median(loads):.1f}")
    if args.against:
        pairs = list(zip(*estimates.values()))
        apart = max(abs(a.error - b.error) for a, b in pairs)
        print(f"  estimates apart by at most {apart:.2g}; frames {[(a.frames, b.frames) for a, b in pairs]}; "
              f"verdicts {'the same' if all(a.within == b.within for a, b in pairs) else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
