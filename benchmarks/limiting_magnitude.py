"""Benchmark of the limiting-magnitude study: the example event design over a ladder of 20 magnitudes (10 s runs),
timed against the target (5 minutes on 2 cores), then its frame baseline over the same ladder, with the analytic
cross-check of both.

Prints the study's table (simulated m50 and m90 with their errors, the analytic limits, their difference), the
wall-clock time of the event design's study alone and of the frame design's, with the load average, and writes
the event-versus-frame figure and table into the study folder.

    python benchmarks/limiting_magnitude.py [--magnitudes 5:14.5:0.5] [--jobs 2] [--out DIR] [--png FILE]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

from evsda.graph.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
EVENTS = str(EXAMPLES / "limiting_magnitude_events.yaml")
FRAMES = str(EXAMPLES / "limiting_magnitude_frames.yaml")
TARGET_S = 300.0


def cpu_s() -> float:
    """CPU seconds of this process and its finished children (the sweep's workers) [s]."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed(argv: list[str]) -> tuple[int, float, float, float]:
    """Exit status, wall-clock and CPU seconds, and the 1-minute load average at the end of one ``evsda`` command."""
    start, cpu = time.perf_counter(), cpu_s()
    code = main(argv)
    return code, time.perf_counter() - start, cpu_s() - cpu, os.getloadavg()[0]


def run(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--magnitudes", default="5:14.5:0.5", help="the ladder (20 rungs by default) [V mag]")
    parser.add_argument("--jobs", type=int, default=2, help="points run at once")
    parser.add_argument("--out", help="study folder (default: a temporary one; an existing one is resumed)")
    parser.add_argument("--png", help="event-versus-frame figure (default: in the study folder)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or str(Path(scratch) / "study")
        common = ["--magnitudes", args.magnitudes, "-o", out, "--jobs", str(args.jobs)]
        load = os.getloadavg()[0]
        code, events_s, events_cpu, events_load = timed(["limiting-magnitude", EVENTS, *common])
        if code:
            return code
        # the event design's rungs are complete: this runs the frame design's and draws both
        figure = ["--png", args.png] if args.png else []
        code, frames_s, frames_cpu, frames_load = timed(["limiting-magnitude", EVENTS, FRAMES, *common, *figure])
    print(f"event design, {args.magnitudes} with {args.jobs} job(s): {events_s:.0f} s wall, {events_cpu:.0f} CPU s "
          f"({events_cpu / 2:.0f} s on 2 idle cores; target {TARGET_S:.0f} s); load average {load:.1f} before, "
          f"{events_load:.1f} after; {os.cpu_count()} cores")
    print(f"frame design over the same ladder (and the event design's analytic limit again): {frames_s:.0f} s wall, "
          f"{frames_cpu:.0f} CPU s; load average {frames_load:.1f} after")
    return code


if __name__ == "__main__":
    raise SystemExit(run())
