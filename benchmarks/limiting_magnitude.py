"""Benchmark of the limiting-magnitude study: the example event design over a ladder of 20 magnitudes (10 s runs),
timed against the target (5 minutes on 2 cores), then its frame baseline over the same ladder, with the analytic
cross-check of both.

Prints the study's table (simulated m50 and m90 with their errors, the analytic limits, their difference), the
wall-clock time of the event design's study alone and of the frame design's, with the load average, and writes
the event-versus-frame figure and table into the study folder.

    python benchmarks/limiting_magnitude.py [--magnitudes 3.5:13:0.5] [--jobs 2] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from evsda.graph.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
EVENTS = str(EXAMPLES / "limiting_magnitude_events.yaml")
FRAMES = str(EXAMPLES / "limiting_magnitude_frames.yaml")
TARGET_S = 300.0


def timed(argv: list[str]) -> tuple[int, float, float]:
    """Exit status, wall-clock seconds and the 1-minute load average at the end of one ``evsda`` command."""
    start = time.perf_counter()
    code = main(argv)
    return code, time.perf_counter() - start, os.getloadavg()[0]


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--magnitudes", default="3.5:13:0.5", help="the ladder (20 rungs by default) [V mag]")
    parser.add_argument("--jobs", type=int, default=2, help="points run at once")
    parser.add_argument("--out", help="study folder (default: a temporary one; an existing one is resumed)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or str(Path(scratch) / "study")
        common = ["--magnitudes", args.magnitudes, "-o", out, "--jobs", str(args.jobs)]
        load = os.getloadavg()[0]
        code, events_s, events_load = timed(["limiting-magnitude", EVENTS, *common])
        if code:
            return code
        # the event design's rungs are complete: this runs the frame design's and draws both
        code, frames_s, frames_load = timed(["limiting-magnitude", EVENTS, FRAMES, *common])
    print(f"event design, {args.magnitudes} with {args.jobs} job(s): {events_s:.0f} s wall (target "
          f"{TARGET_S:.0f} s on 2 cores); load average {load:.1f} before, {events_load:.1f} after; "
          f"{os.cpu_count()} cores")
    print(f"frame design over the same ladder (and the event design's analytic limit again): {frames_s:.0f} s wall; "
          f"load average {frames_load:.1f} after")
    return code


if __name__ == "__main__":
    raise SystemExit(run())
