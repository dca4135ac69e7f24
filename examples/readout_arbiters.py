"""Compare readouts on one synthetic scene: a satellite track plus background noise.

The triggered events stand in for a pixel stage (a track of ON events along a moving
source, and uniform ON/OFF noise); they go through the ideal readout, the row-scan
arbiter and the column-burst arbiter, and ``event_metrics`` reports the paper's Sec. 3
figures for each. The row-scan result is drawn as the paper's Fig. 6.

    python examples/readout_arbiters.py [--png fig6.png]
"""

from __future__ import annotations

import argparse

import numpy as np

from evsda.blocks.ports import FocalPlane, PointSources, SourceKind, TriggeredEvents
from evsda.blocks.readout import ColumnBurstArbiter, EventMetrics, IdealReadout, RowScanArbiter
from evsda.blocks.readout.render import render_png
from evsda.graph import RunInfo

FP = FocalPlane(640, 480, 15e-6, 0.5)
DURATION_NS, WINDOW_NS = 2_000_000_000, 100_000_000


def scene(seed: int = 0):
    """Noise at 0.5 Hz per pixel and a source crossing at 300 pixel/s firing 20 kHz of ON events."""
    rng = np.random.default_rng(seed)
    n_noise = rng.poisson(0.5 * FP.width_px * FP.height_px * DURATION_NS / 1e9)
    t_noise = rng.integers(0, DURATION_NS, n_noise)
    x_noise, y_noise = rng.integers(0, FP.width_px, n_noise), rng.integers(0, FP.height_px, n_noise)
    n_track = int(20e3 * DURATION_NS / 1e9)
    t_track = rng.integers(0, DURATION_NS, n_track)
    x_track = np.clip(np.round(20 + 300 * t_track / 1e9 + rng.normal(0, 0.7, n_track)), 0, FP.width_px - 1)
    y_track = np.clip(np.round(400 - 150 * t_track / 1e9 + rng.normal(0, 0.7, n_track)), 0, FP.height_px - 1)
    t = np.concatenate([t_noise, t_track])
    x = np.concatenate([x_noise, x_track]).astype(np.uint16)
    y = np.concatenate([y_noise, y_track]).astype(np.uint16)
    p = np.concatenate([rng.choice(np.array([-1, 1], np.int8), n_noise), np.ones(n_track, np.int8)])
    cause = np.concatenate([np.full(n_noise, 3, np.uint8), np.zeros(n_track, np.uint8)])
    order = np.lexsort((x, y, t))
    samples = np.arange(0, DURATION_NS, 10_000_000)
    sources = (samples, 20 + 300 * samples / 1e9, 400 - 150 * samples / 1e9)
    return (t[order], x[order], y[order], p[order], cause[order]), sources


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", default=None, help="write the row-scan events as Fig. 6 to this file")
    args = parser.parse_args()
    (t, x, y, p, cause), (ts, xs, ys) = scene()
    readouts = {
        "ideal": IdealReadout(),
        "row scan 50 MHz, bus 5 Mev/s": RowScanArbiter(clock_hz=50e6, bus_throughput_eps=5e6, queue_depth=32),
        "column burst 16 cols": ColumnBurstArbiter(clock_hz=50e6, bus_throughput_eps=5e6, group_width_px=16),
    }
    rows = {}
    kept = {}
    for name, arbiter in readouts.items():
        run = RunInfo(duration_ns=DURATION_NS, window_ns=WINDOW_NS)
        arbiter.setup(run)
        metrics = EventMetrics(track_radius_px=4)
        recorded = []
        for window in run.windows():
            a, b = np.searchsorted(t, [window.start_ns, window.stop_ns])
            triggered = TriggeredEvents(FP, t[a:b], x[a:b], y[a:b], p[a:b], cause[a:b])
            events = arbiter.step(window, events=triggered)["events"]
            s0, s1 = np.searchsorted(ts, [window.start_ns, window.stop_ns])
            n = s1 - s0
            sources = PointSources(FP, 550e-9, ts[s0:s1], np.array(["SAT"]), np.array([SourceKind.SATELLITE], np.int8),
                                   xs[s0:s1, None], ys[s0:s1, None], np.ones((n, 1)), np.full((n, 1), 6.0),
                                   np.full((n, 1), 8e5), np.full(n, 0.6))
            metrics.step(window, triggered=triggered, events=events, sources=sources)
            recorded.append(events)
        rows[name] = metrics.finish()["metrics"]
        kept[name] = recorded
    keys = ["events_triggered", "events_recorded", "events_dropped_readout", "ratio_recorded_to_expected",
            "out_of_order_fraction", "readout_delay_p50_s", "readout_delay_p99_s", "background_rate_hz_per_pixel",
            "track_events", "track_snr"]
    print(f"{'metric':32s}" + "".join(f"{name:>30s}" for name in rows))
    for key in keys:
        unit = next(iter(rows.values())).units.get(key, "")
        print(f"{key + ' [' + unit + ']':32s}" + "".join(f"{m.values.get(key, float('nan')):30.6g}" for m in rows.values()))
    if args.png:
        chunks = ({"t_readout_ns": e.t_readout_ns, "x": e.x, "y": e.y, "p": e.p} for e in kept["row scan 50 MHz, bus 5 Mev/s"])
        on, off = render_png(chunks, args.png, FP.width_px, FP.height_px, title="row-scan readout: ON green, OFF red")
        print(f"wrote {args.png} ({on} ON, {off} OFF events)")


if __name__ == "__main__":
    main()
