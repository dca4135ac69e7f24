"""Bytes per event of each export format on a real event stream, HDF5 compressed and narrow against the
uncompressed int64 layout it replaced (issue 14.7: "HDF5 is uncompressed int64, 48 B/event").

Runs the main job (``library:examples/iss_pass.yaml``) for ``--duration`` s (1.5 by default: the ISS in
the field over noise and stars), then exports its events to every format and prints the file sizes.

    python benchmarks/export_sizes.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from evsda.blocks.readout.exporters import EXTENSIONS, WRITERS, export_events
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1.5, help="simulated seconds of the main job")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        t0 = time.perf_counter()
        result = run_graph(load_graph("library:examples/iss_pass.yaml", {"run.duration_s": args.duration}),
                           folder / "run.zarr", progress=False)
        store = result.store
        fp, n = store.focal_plane, store.n_events
        max_time_us = -(-int(store.attrs["duration_ns"]) // 1000)
        print(f"main job, {args.duration:g} s: {n} events in {time.perf_counter() - t0:.0f} s "
              f"(load average {os.getloadavg()[0]:.1f})")
        cases = [(fmt, {"max_time_us": max_time_us}) for fmt in WRITERS]
        cases.append(("hdf5", {"compression": False}))        # the former layout: int64, uncompressed
        for fmt, options in cases:
            path = folder / f"out{EXTENSIONS[fmt][0]}"
            t0 = time.perf_counter()
            export_events(store.iter_events(), path, fmt, fp.width_px, fp.height_px, **options)
            label = fmt + (" (int64, uncompressed)" if options.get("compression") is False else "")
            print(f"  {label:<28} {path.stat().st_size / n:6.2f} bytes per event  "
                  f"({time.perf_counter() - t0:.1f} s)")
            path.unlink()


if __name__ == "__main__":
    main()
