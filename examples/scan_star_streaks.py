"""The scan rate above which stars leave no events, for one design (examples/scan_star_streaks.yaml).

A star streaking across an event camera deposits, on each pixel it crosses, its photon flux
times the dwell time (pixel scale / rate): the faster the scan, the smaller the log-intensity
step each pixel sees, and the photoreceptor's bandwidth (paper Eq. 16) low-pass filters it
further. Above some rate a star of a given magnitude no longer crosses the contrast threshold
and leaves no events at all. This script runs the scene at a series of RA scan rates, each
sampled finely enough (the star and optics sampling follow the rate, so a star moves at most
0.9 pixel per sample), and counts per magnitude bin the stars that crossed the detector and
those that left at least one signal event (``object_metrics`` with ``kinds: stars``).

    OPENBLAS_NUM_THREADS=1 python examples/scan_star_streaks.py [--rates 0.03 0.1 0.3 1 3 10 30] [--set KEY=VALUE ...]

``--set`` changes the design like ``evsda run --set`` (e.g. ``--set sensor/pixel.temperature_K=253``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

SCENE = Path(__file__).with_name("scan_star_streaks.yaml")
BINS = [(-2.0, 8.0), (8.0, 9.0), (9.0, 10.0), (10.0, 11.0), (11.0, 12.0)]
SWEEP_DEG = 3.0          # sky each run sweeps past the field (beyond the field itself) [deg]
DEC_DEG = 20.0           # the scene's declination: the sky moves rate * cos(Dec) [deg]


def run_rate(rate_deg_s: float, design: dict, workdir: Path) -> dict:
    """Run the scene at one RA rate; per magnitude bin, stars seen on the detector and stars with events."""
    graph = load_graph(SCENE, {"pointing.ra_rate_deg_s": rate_deg_s})
    camera = graph.nodes["sensor/camera"].block.params
    focal = design.get("sensor/camera.focal_length_m", camera.focal_length_m)
    pitch = design.get("sensor/camera.pixel_pitch_m", camera.pixel_pitch_m)
    scale_deg = np.degrees(pitch / focal)
    sky_rate = rate_deg_s * np.cos(np.radians(DEC_DEG))
    cadence_s = min(1e-3, 0.9 * scale_deg / sky_rate)
    duration_s = float(np.clip(SWEEP_DEG / sky_rate, 0.1, 8.0))
    overrides = {"pointing.ra_rate_deg_s": rate_deg_s, "run.duration_s": duration_s,
                 "stars.cadence_s": cadence_s, "telescope/optics.render_rate_hz": 1.0 / cadence_s, **design}
    graph = load_graph(SCENE, overrides)
    out = workdir / f"rate_{rate_deg_s:g}.zarr"
    started = time.perf_counter()
    result = run_graph(graph, out, progress=False)
    elapsed = time.perf_counter() - started
    stars = list(RunStore.open(out).product_windows("stars", "sources"))
    ids = stars[0].source_id
    magnitude = np.nanmin(np.concatenate([w.magnitude for w in stars]), axis=0)
    seen = np.zeros(len(ids), bool)
    for w in stars:
        seen |= np.isfinite(w.x_px).any(axis=0)
    m = result.metrics
    events = np.array([m.get(f"object_{i.replace(' ', '_')}_signal_events", 0) for i in ids])
    rows = []
    for lo, hi in BINS:
        in_bin = seen & (magnitude >= lo) & (magnitude < hi)
        rows.append((int(in_bin.sum()), int((in_bin & (events > 0)).sum())))
    return {"rate": rate_deg_s, "pixels_per_s": sky_rate / scale_deg, "cadence_s": cadence_s,
            "duration_s": duration_s, "bins": rows, "signal": int(m["events_triggered_signal"]),
            "seconds": elapsed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0],
                        help="RA scan rates [deg/s]")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="design override")
    args = parser.parse_args()
    design = {}
    for item in args.set:
        key, _, value = item.partition("=")
        design[key] = yaml.safe_load(value)
    header = "  ".join(f"V {lo:g}-{hi:g}".replace("-2-", "<") for lo, hi in BINS)
    print(f"stars with signal events / stars on the detector, per V magnitude bin ({SCENE.name})")
    print(f"{'RA rate':>8} {'sky':>9} {'cadence':>9} {'run':>5}  {header}  {'signal ev.':>10} {'wall':>6}")
    print(f"{'[deg/s]':>8} {'[px/s]':>9} {'[ms]':>9} {'[s]':>5}")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rates:
            r = run_rate(rate, design, Path(tmp))
            results.append(r)
            cells = "  ".join(f"{with_events:>3}/{seen:<3}" for seen, with_events in r["bins"])
            print(f"{rate:8g} {r['pixels_per_s']:9.0f} {1000 * r['cadence_s']:9.3f} {r['duration_s']:5.2f}  {cells}  "
                  f"{r['signal']:10d} {r['seconds']:5.0f}s", flush=True)
    print("\nfastest rate at which a star of each bin still left events (of the rates run):")
    for k, (lo, hi) in enumerate(BINS):
        with_events = [r["rate"] for r in results if r["bins"][k][1] > 0]
        silent = [r["rate"] for r in results if r["bins"][k][0] > 0 and r["bins"][k][1] == 0
                  and (not with_events or r["rate"] > max(with_events))]
        label = f"V {lo:g}-{hi:g}".replace("V -2-", "V <")
        if not with_events:
            print(f"  {label}: none at any rate run")
        else:
            above = f"; none at {min(silent):g} deg/s" if silent else ""
            print(f"  {label}: {max(with_events):g} deg/s{above}")


if __name__ == "__main__":
    main()
