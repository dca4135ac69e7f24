"""Screens the optics hold over a tracked pass with every source on the pupil path: dropped as sources leave
(the block's rule, docs/optics.md 'Screens of sources out of view') against kept all run (``Imager.forget``
made a no-op: the block before the rule).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_screens_held.py [--duration 3]

Prints, every 10 windows, the sources whose screens are held and the bytes of arrays in the optics'
checkpoint state (``optics_state``), for both, then the largest of each.
"""

from __future__ import annotations

import argparse
import functools
import tempfile
from pathlib import Path

import numpy as np

from evsda.blocks.optics.block import PointSourceOptics
from evsda.blocks.optics.imaging import Imager
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

GRAPH = Path(__file__).with_name("end_to_end.yaml")


def array_bytes(value) -> int:
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, dict):
        return sum(array_bytes(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(array_bytes(v) for v in value)
    return 0


def held_per_window(duration_s: float, keep: bool) -> list[tuple[int, int]]:
    """(sources with screens, bytes of the optics' state) after each window of the pass."""
    record, step, forget = [], PointSourceOptics.step, Imager.forget

    @functools.wraps(step)                 # the registry checks step()'s parameters against the block's inputs
    def recorded(self, *args, **kwargs):
        out = step(self, *args, **kwargs)
        record.append((len(self._imager.holding()), array_bytes(self._imager.state())))
        return out

    PointSourceOptics.step = recorded
    if keep:
        Imager.forget = lambda self, sources: None
    try:
        graph = load_graph(str(GRAPH), [f"run.duration_s={duration_s}", "telescope/optics.psf_path=pupil_fft"])
        with tempfile.TemporaryDirectory() as store:
            run_graph(graph, str(Path(store) / "run.zarr"), overwrite=True)
    finally:
        PointSourceOptics.step, Imager.forget = step, forget
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds [s]")
    args = parser.parse_args()
    dropped = held_per_window(args.duration, keep=False)
    kept = held_per_window(args.duration, keep=True)
    print(f"pupil_fft tracked pass, {args.duration:g} s ({GRAPH.name}): sources with screens / optics state MB")
    print(f"{'window':>6} {'dropped':>16} {'kept all run':>16}")
    for w in range(0, len(dropped), 10):
        (n_d, b_d), (n_k, b_k) = dropped[w], kept[w]
        print(f"{w:6d} {n_d:6d} {b_d / 1e6:8.2f} MB {n_k:6d} {b_k / 1e6:8.2f} MB")
    print(f"most   {max(n for n, _ in dropped):6d} {max(b for _, b in dropped) / 1e6:8.2f} MB "
          f"{max(n for n, _ in kept):6d} {max(b for _, b in kept) / 1e6:8.2f} MB")


if __name__ == "__main__":
    main()
