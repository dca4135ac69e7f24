"""The SL-16 rocket body's glints as event bursts: runs examples/sl-16-rb.yaml and prints, side by side,
the glints of the model's light curve and the bursts of events the sensor records at the rocket.

    python examples/sl16_rb_glints.py [--store RUN.zarr] [--png FIGURE.png] [--set block.param=value ...]

Without ``--store`` the scene runs into a temporary store first (about 40 s on 2 cores). The
light curve is the satellite block's V magnitude every millisecond; a glint is a stretch at
least ``--glint-mag`` brighter than the light curve's median. Events count when they trigger
within ``--radius`` pixels of the rocket's position; a burst is where the ON events in 50 ms
exceed ``--burst-factor`` times their median (the rocket's steady flicker through turbulence).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from evsda.blocks.scene.sky import sky_photon_flux_per_pixel
from evsda.graph import Window
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

SCENE = Path(__file__).with_name("sl-16-rb.yaml")
BIN_NS = 10_000_000


def light_curve(graph, step_ns: int = 1_000_000) -> dict[str, np.ndarray]:
    """The rocket's time, V magnitude and focal-plane position from the scene's satellite block."""
    run = graph.run_info()
    blocks = graph.blocks
    whole = Window(0, 0, run.duration_ns, run.epoch)
    orbit = blocks["rocket"].step(whole)["orbit"]
    view = blocks["sat"].view(whole, orbit, blocks["site/site"].step(whole)["observer"],
                              blocks["pointing"].step(whole, target=orbit)["pointing"],
                              blocks["sensor/camera"].step(whole)["focal_plane"])
    t_ns = np.arange(0, run.duration_ns, step_ns)
    s = view.sample(t_ns)
    return {"t_ns": t_ns, "magnitude": s.magnitude, "x_px": s.x_px, "y_px": s.y_px}


def sky_brightness(graph) -> np.ndarray:
    """The sky block's V surface brightness at the boresight at the run's start and end [mag/arcsec^2]."""
    run = graph.run_info()
    blocks = graph.blocks
    whole = Window(0, 0, run.duration_ns, run.epoch)
    sky = blocks["site/sky"]
    sky.setup(run)
    orbit = blocks["rocket"].step(whole)["orbit"]
    focal_plane = blocks["sensor/camera"].step(whole)["focal_plane"]
    inputs = {"observer": blocks["site/site"].step(whole)["observer"],
              "pointing": blocks["pointing"].step(whole, target=orbit)["pointing"], "focal_plane": focal_plane}
    ends = [sky.step(Window(0, t, t + 1, run.epoch), **inputs)["background"].photon_flux_per_pixel[0]
            for t in (0, run.duration_ns - 1)]
    return -2.5 * np.log10(np.array(ends) / sky_photon_flux_per_pixel(0.0, focal_plane))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` of runs of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def glints(curve: dict[str, np.ndarray], brighter_mag: float) -> list[dict]:
    """Stretches of the light curve at least ``brighter_mag`` above its median: start, peak time and peak V."""
    m = curve["magnitude"]
    out = []
    for a, b in _runs(m < np.median(m) - brighter_mag):
        k = a + int(np.argmin(m[a:b]))
        out.append({"start_s": curve["t_ns"][a] / 1e9, "peak_s": curve["t_ns"][k] / 1e9, "peak_mag": float(m[k]),
                    "duration_s": (curve["t_ns"][b - 1] - curve["t_ns"][a]) / 1e9})
    return out


def events_near(store: RunStore, curve: dict[str, np.ndarray], radius_px: float) -> dict[str, np.ndarray]:
    """ON and OFF counts per 10 ms bin of events triggered within ``radius_px`` of the rocket."""
    n_bins = int(curve["t_ns"][-1] // BIN_NS) + 1
    counts = {"on": np.zeros(n_bins, dtype=np.int64), "off": np.zeros(n_bins, dtype=np.int64)}
    for chunk in store.iter_events():
        t = chunk["t_trigger_ns"]
        x = np.interp(t, curve["t_ns"], curve["x_px"])
        y = np.interp(t, curve["t_ns"], curve["y_px"])
        near = np.hypot(chunk["x"] + 0.5 - x, chunk["y"] + 0.5 - y) <= radius_px
        b = np.minimum(t[near] // BIN_NS, n_bins - 1)
        for name, polarity in (("on", 1), ("off", -1)):
            np.add.at(counts[name], b[chunk["p"][near] == polarity], 1)
    return counts


MIN_BURST_EVENTS = 10.0      # fewest ON events in 50 ms that make a burst [event]


def bursts(counts: dict[str, np.ndarray], factor: float, window_bins: int = 5) -> list[dict]:
    """Stretches where ON events over ``window_bins`` bins (50 ms) exceed ``factor`` times their median
    and ``MIN_BURST_EVENTS`` (a photoreceptor slower than the flicker leaves a median of zero).

    Each burst gives its start, stop, ON events, and the OFF events from its start to 0.2 s after it.
    """
    on = counts["on"]
    running = np.convolve(on, np.ones(window_bins, dtype=np.int64), mode="same")
    floor = max(MIN_BURST_EVENTS, factor * float(np.median(running)))
    out = []
    for a, b in _runs(running > floor):
        tail = slice(a, min(len(on), b + 20))
        out.append({"start_s": a * BIN_NS / 1e9, "stop_s": b * BIN_NS / 1e9, "on": int(on[a:b].sum()),
                    "off": int(counts["off"][tail].sum())})
    return out


def report(graph, store: RunStore, glint_mag: float = 1.5, radius_px: float = 4.0, burst_factor: float = 3.0):
    """Glints of the model and bursts of the events, and each glint's nearest burst."""
    curve = light_curve(graph)
    found = glints(curve, glint_mag)
    counts = events_near(store, curve, radius_px)
    seen = bursts(counts, burst_factor)
    for g in found:
        starts = np.array([b["start_s"] for b in seen]) if seen else np.array([np.inf])
        g["burst_delay_s"] = float(starts[np.argmin(np.abs(starts - g["start_s"]))] - g["start_s"])
    return curve, found, counts, seen


def plot(curve: dict[str, np.ndarray], counts: dict[str, np.ndarray], path: Path) -> None:
    """The model's light curve above the ON and OFF events per 10 ms at the rocket."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 4.5), sharex=True, constrained_layout=True)
    top.plot(curve["t_ns"] / 1e9, curve["magnitude"], color="k", lw=0.8)
    top.invert_yaxis()
    top.set_ylabel("V [mag]")
    top.set_title("SL-16 R/B tumbling end over end (10 s): model light curve and events at the rocket")
    t_bins = (np.arange(len(counts["on"])) + 0.5) * BIN_NS / 1e9
    bottom.step(t_bins, counts["on"], where="mid", color="tab:green", lw=0.8, label="ON")
    bottom.step(t_bins, -counts["off"], where="mid", color="tab:red", lw=0.8, label="OFF (down)")
    bottom.set_ylabel("events / 10 ms")
    bottom.set_xlabel("time since 2013-03-25 03:09:40 UTC [s]")
    bottom.legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", type=Path, help="a finished run of examples/sl-16-rb.yaml (else run it)")
    parser.add_argument("--set", action="append", default=[], help="parameter override, as for evsda run")
    parser.add_argument("--glint-mag", type=float, default=1.5)
    parser.add_argument("--radius", type=float, default=4.0)
    parser.add_argument("--burst-factor", type=float, default=3.0)
    parser.add_argument("--png", type=Path, help="draw the light curve above the event rates")
    args = parser.parse_args()
    graph = load_graph(str(SCENE), args.set)
    with tempfile.TemporaryDirectory() as scratch:
        path = args.store
        if path is None:
            path = Path(scratch) / "sl16.zarr"
            run_graph(graph, path, progress=False)
        curve, found, counts, seen = report(graph, RunStore.open(path), args.glint_mag, args.radius,
                                            args.burst_factor)
    start, end = sky_brightness(graph)
    print(f"sky at the rocket: V {start:.2f} mag/arcsec^2 at the start, {end:.2f} at the end")
    m = curve["magnitude"]
    print(f"light curve: V {np.median(m):.2f} median, {m.max():.2f} faintest, {m.min():.2f} brightest")
    print(f"events within {args.radius:g} px of the rocket: median {np.median(counts['on']):.0f} ON and "
          f"{np.median(counts['off']):.0f} OFF per 10 ms (the turbulent image's flicker)")
    print(f"glints (>= {args.glint_mag:g} mag above the median) and the nearest burst "
          f"(ON events in 50 ms > {args.burst_factor:g}x their median):")
    for g in found:
        print(f"  t = {g['start_s']:6.3f} s  peak V {g['peak_mag']:5.2f} at {g['peak_s']:6.3f} s, "
              f"{1000 * g['duration_s']:4.0f} ms long; burst starts {1000 * g['burst_delay_s']:+5.0f} ms from it")
    print("bursts:")
    for b in seen:
        print(f"  {b['start_s']:6.2f}-{b['stop_s']:6.2f} s  {b['on']:6d} ON, then {b['off']:6d} OFF within 0.2 s")
    if args.png:
        plot(curve, counts, args.png)
        print(f"wrote {args.png}")
    if len(found) > 1:
        print(f"glint interval {np.mean(np.diff([g['peak_s'] for g in found])):.3f} s "
              f"(half the 10 s tumble: the side's lobe sweeps the observer twice per turn)")


if __name__ == "__main__":
    main()
