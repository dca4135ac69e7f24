"""Screens the optics hold over a tracked pass with every source on the pupil path: held while a source is out of
view for less than ``Imager.hold_ns`` (the block's rule, docs/optics.md 'Screens of sources out of view'), against
dropped at once (a hold of one render time: the rule before) and kept all run (``Imager.forget`` made a no-op: the
block before either).

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/optics_screens_held.py [--duration 3] [--rules held,kept]

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


def held_per_window(duration_s: float, rule: str) -> list[tuple[int, int]]:
    """(sources with screens, bytes of the optics' state) after each window of the pass, under ``rule``: "held",
    "at once" or "kept"."""
    record, step, forget, hold = [], PointSourceOptics.step, Imager.forget, Imager.hold_ns

    @functools.wraps(step)                 # the registry checks step()'s parameters against the block's inputs
    def recorded(self, *args, **kwargs):
        out = step(self, *args, **kwargs)
        record.append((len(self._imager.holding()), array_bytes(self._imager.state())))
        return out

    PointSourceOptics.step = recorded
    if rule == "kept":
        Imager.forget = lambda self, sources: None
    if rule == "at once":
        # one render time (end_to_end.yaml renders at the block's default rate)
        Imager.hold_ns = property(lambda self: round(1e9 / PointSourceOptics.Params().render_rate_hz))
    try:
        graph = load_graph(str(GRAPH), [f"run.duration_s={duration_s}", "telescope/optics.psf_path=pupil_fft"])
        with tempfile.TemporaryDirectory() as store:
            run_graph(graph, str(Path(store) / "run.zarr"), overwrite=True)
    finally:
        PointSourceOptics.step, Imager.forget, Imager.hold_ns = step, forget, hold
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds [s]")
    parser.add_argument("--rules", default="held,at once,kept", help="which of held, at once, kept to run")
    args = parser.parse_args()
    rules = tuple(r.strip() for r in args.rules.split(","))
    records = {rule: held_per_window(args.duration, rule) for rule in rules}
    print(f"pupil_fft tracked pass, {args.duration:g} s ({GRAPH.name}): sources with screens / optics state MB")
    print(f"{'window':>6} " + " ".join(f"{rule:>18}" for rule in rules))
    for w in range(0, len(records[rules[0]]), 10):
        print(f"{w:6d} " + " ".join(f"{records[r][w][0]:6d} {records[r][w][1] / 1e6:8.2f} MB" for r in rules))
    print("most   " + " ".join(f"{max(n for n, _ in records[r]):6d} {max(b for _, b in records[r]) / 1e6:8.2f} MB"
                             for r in rules))

if __name__ == "__main__":
    main()
