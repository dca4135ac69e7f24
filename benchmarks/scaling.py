"""How a run's cost grows (issue 13 item 6): time and memory against sensor pixels, duration, sources, noise.

Runs the tracked LEO pass of benchmarks/end_to_end.yaml (``evsda run``, every core, windows
pipelined as by default) with one axis changed at a time from a base run, and prints wall and CPU
time, peak memory, events and sources (the satellite and the stars rendered, from the store's
truth table) for each. The base keeps the optics cheap (``long_exposure`` PSFs at 500 Hz: turbulence
costs are in benchmarks/end_to_end.py) so that the axes show the rest of the pipeline:

* sensor pixels: 320 x 180 to 1920 x 1080 at the same pixel scale (the field, and so the
  stars, grow with the sensor);
* duration: 1 to 16 s (``--long`` adds 60 s);
* sources: stars to V 6 .. 14 (one to a few thousand stars over the run);
* background rate: the pixels' leak rate 0.1 .. 10 Hz.

Cost should follow events and sources, not pixels x time.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/scaling.py [--long] [--axes duration,pixels]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from end_to_end import run_cli                                         # noqa: E402

from evsda.graph.store import RunStore                                 # noqa: E402

BASE = {"telescope/optics.psf_path": "long_exposure", "telescope/optics.render_rate_hz": 500}
BASE_DURATION_S = 2.0


def axes(long: bool) -> list[tuple[str, float, dict]]:
    runs = []
    for width, height in ((320, 180), (640, 360), (1280, 720), (1920, 1080)):
        runs.append((f"pixels {width} x {height}", BASE_DURATION_S,
                     {"sensor/camera.width_px": width, "sensor/camera.height_px": height}))
    for duration in (1.0, 4.0, 16.0) + ((60.0,) if long else ()):
        runs.append((f"duration {duration:g} s", duration, {}))
    for magnitude in (6, 8, 10, 12, 14):
        runs.append((f"stars to V {magnitude}", BASE_DURATION_S, {"stars.faint_limit_mag": magnitude}))
    for leak in (0.1, 1.0, 10.0):
        runs.append((f"leak {leak:g} Hz", BASE_DURATION_S, {"sensor/pixel.leak_rate_hz": leak}))
    return runs


def sources(store: Path) -> int:
    """The sources the optics rendered over the run (the satellite and every star), from the truth table."""
    return RunStore.open(store).group["truth/source_id"].shape[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long", action="store_true", help="add a 60 s run")
    parser.add_argument("--axes", default="pixels,duration,stars,leak",
                        help="comma-separated axes to run (pixels, duration, stars, leak)")
    args = parser.parse_args()
    chosen = tuple(a.strip() for a in args.axes.split(","))
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; base: {BASE}, {BASE_DURATION_S:g} s")
    print(f"  {'run':22s} {'wall':>8s} {'CPU':>8s} {'CPU/sim s':>10s} {'peak':>8s} {'events':>10s} "
          f"{'CPU/M events':>13s} {'sources':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        run_cli(0.1, Path(tmp) / "warm.zarr", [f"{k}={v}" for k, v in BASE.items()])
        for name, duration, change in axes(args.long):
            if not name.startswith(chosen):
                continue
            r = run_cli(duration, Path(tmp) / "run.zarr", [f"{k}={v}" for k, v in {**BASE, **change}.items()])
            per_event = r["cpu_s"] / max(r["events"], 1) * 1e6
            print(f"  {name:22s} {r['wall_s']:7.1f}s {r['cpu_s']:7.1f}s {r['cpu_s'] / duration:9.2f}s "
                  f"{r['peak_mb']:6.0f}MB {r['events']:10d} {per_event:12.2f}s {sources(Path(tmp) / 'run.zarr'):8d}",
                  flush=True)
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
