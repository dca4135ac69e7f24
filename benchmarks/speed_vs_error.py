"""Speed against error end to end (issue 13 item 5; the paper's proposed time-step sensitivity study).

Runs the tracked LEO pass of benchmarks/end_to_end.yaml (first ``--duration`` seconds; through
benchmarks/speed_vs_error.yaml, which adds an event detector and its scoring) with
the fidelity knobs turned one at a time from the most faithful combination this machine can
afford, and prints each run's wall and CPU time beside its errors against that combination:

* knobs: the pixel time step (``sensor/pixel.time_step_s``), the PSF render rate
  (``telescope/optics.render_rate_hz``), the PSF path (``psf_path``; the Fresnel ``reference``
  costs minutes per simulated second and is left out: the optics block's own probes give its
  error against ``pupil_fft``, 8-12 % of the flux here), the screen update
  (``screen_update``), the satellite's Skyfield knot step (``sat.knot_step_s``) and each source's render
  interval from its physics (``source_intervals``, ``interval_factor``: blocks/optics/render_interval.py; the
  faithful run renders every source at every render time) and the profile's layers rendered as fewer equivalent
  layers (``equivalent_layers``: blocks/optics/equivalent_layers.py);
* statistics, against the faithful run: the track's event count (events within 4 pixels of
  the true satellite position at their time, relative difference), the centroid error (RMS
  distance between the two runs' 50 ms centroids of those events [pixel]), the event-timing
  error (median |difference| between each of the faithful run's track events and the nearest
  event of the same pixel and polarity, within 5 ms [us]), the background
  rate (events not caused by the signal, per pixel and second, relative difference), and the
  detection probability of the satellite in the events alone (``event_detector``, looks of 0.1 s,
  scored by ``detection_scoring``: the fraction of looks in which it was found; an absolute figure,
  printed beside the faithful run's); and for the stars streaming across: their events (within 4
  pixels of a star's true position at their time, all stars together, relative difference), the
  per-star count error (RMS over stars of the difference of each star's count, relative to the
  faithful run's mean count per star) and the star-streak centroid error (RMS distance between the
  two runs' 50 ms centroids of each star's events, where both have at least 5).

Saves a Pareto plot (CPU time against centroid error, track-count error and detection probability) next to the
printed table. The seed is fixed, so differences are the knobs' (plus the noise drawn
differently where the knob changes the random streams: compare with the repeat of the
faithful run at another seed, printed as ``seed 2``, and with two other draws of the optics' and
pixels' noise, ``noise draw`` and ``noise draw 2``).

``--scene FILE`` runs another scene the same way (e.g. ``examples/iss_pass.yaml``, the staring main job),
as it is, without the event detector (no P_d); pick its rows with ``--rows``.

    OPENBLAS_NUM_THREADS=1 nice -n 10 python benchmarks/speed_vs_error.py [--duration 1] [--plot speed_vs_error.png]
    ... --scene examples/iss_pass.yaml --duration 4 --rows "seed 2" "noise draw" "render 500 Hz" --plot ''
    ... --scene examples/iss_pass.yaml --warm-s 0 --duration 4 --plot '' --rows "3 equivalent layers" "noise draw" \
        "3 equivalent layers, noise draw" --extra-draws h i j       # paired: star and track events' mean difference
    ... --duration 2 --plot '' --rows "noise draw" "3 equivalent layers" --extra-draws c d \
        --set telescope/optics.profile_file=library:atmospheres/las_campanas.csv       # another profile, every row
    ... (the same) --equivalent auto      # the rows "3 equivalent layers..." at equivalent_layers: auto, so named
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from end_to_end import run_cli                                          # noqa: E402

from evsda.blocks.ports import EventCause, SourceKind                    # noqa: E402
from evsda.graph.store import RunStore                                   # noqa: E402

GRAPH = Path(__file__).with_name("speed_vs_error.yaml")    # end_to_end.yaml as 'scene', plus detector and scoring
#: the faithful run with the optics' and the pixels' random numbers drawn anew but the same stars and satellite
#: (the stars are drawn from star counts with the run's seed, so "seed 2" has other stars): the noise floor of
#: the star statistics. Block random streams follow the seed and the block's name, so this variant renames the
#: sensor and telescope sub-graphs (sensor -> sensor_b, telescope -> telescope_b) in a copy of the scene.
NOISE_DRAW = "noise draw"
RENAMED = ("sensor", "telescope")
EQUIVALENT = "telescope/optics.equivalent_layers"
#: the most faithful affordable run: every layer of the profile (the block's default is ``auto`` since the
#: seventeenth session)
FAITHFUL = {"sensor/pixel.time_step_s": 1e-6, "telescope/optics.render_rate_hz": 2000,
            "telescope/optics.source_intervals": False, "telescope/optics.psf_path": "pupil_fft",
            "telescope/optics.screen_update": "extend", "sat.knot_step_s": 1.0, EQUIVALENT: "null"}
#: the scene's defaults (benchmarks/end_to_end.yaml as it runs) but with each source at every render time, on every
#: layer (the defaults before the seventeenth session's)
DEFAULTS_EVERY = {"telescope/optics.render_rate_hz": 1000, "telescope/optics.psf_path": "auto", "sat.knot_step_s": 10.0}
#: the scene's defaults before the seventeenth session: each source rendered as often as its physics needs (the
#: block's interval_factor), every layer
DEFAULTS = {**DEFAULTS_EVERY, "telescope/optics.source_intervals": True}


def paired_draws(draws) -> list:
    """Rows "noise draw LABEL" and "3 equivalent layers, noise draw LABEL" on the noise draw SUFFIX, for each
    (LABEL, SUFFIX) of ``draws``: every layer and 3 equivalent layers on the same random numbers."""
    return [(f"{name}noise draw {label}", {NOISE_DRAW: suffix, **change}) for label, suffix in draws
            for name, change in (("", {}), ("3 equivalent layers, ", {EQUIVALENT: 3}))]


VARIANTS = [
    ("faithful", {}),
    ("seed 2", {"run.seed": 2}),
    ("noise draw", {NOISE_DRAW: "b"}),
    ("noise draw 2", {NOISE_DRAW: "c"}),
    ("dt 10 us", {"sensor/pixel.time_step_s": 1e-5}),
    ("dt 100 us", {"sensor/pixel.time_step_s": 1e-4}),
    ("render 1 kHz", {"telescope/optics.render_rate_hz": 1000}),
    ("render 500 Hz", {"telescope/optics.render_rate_hz": 500}),
    ("render 200 Hz", {"telescope/optics.render_rate_hz": 200}),
    ("long_exposure", {"telescope/optics.psf_path": "long_exposure"}),
    ("airy", {"telescope/optics.psf_path": "airy"}),
    ("regenerate", {"telescope/optics.screen_update": "regenerate"}),
    ("knots 10 s", {"sat.knot_step_s": 10.0}),
    ("knots 60 s", {"sat.knot_step_s": 60.0}),
    ("auto", {"telescope/optics.psf_path": "auto"}),
    ("auto, no detector", {"telescope/optics.psf_path": "auto", "telescope/optics.detector": "null"}),
    ("defaults", DEFAULTS),
    ("defaults, every source at 1 kHz", DEFAULTS_EVERY),
    ("defaults at 500 Hz", {"telescope/optics.render_rate_hz": 500, "telescope/optics.psf_path": "auto",
                            "sat.knot_step_s": 10.0}),
    ("fast", {"telescope/optics.render_rate_hz": 500, "telescope/optics.psf_path": "long_exposure",
              "sensor/pixel.time_step_s": 1e-5, "sat.knot_step_s": 10.0}),
    # 500 Hz again on the noise draws' random numbers: compare with those rows (a paired second and third draw)
    ("500 Hz, noise draw", {NOISE_DRAW: "b", "telescope/optics.render_rate_hz": 500}),
    ("500 Hz, noise draw 2", {NOISE_DRAW: "c", "telescope/optics.render_rate_hz": 500}),
    # each source rendered every m-th render time, m from its physics (blocks/optics/render_interval.py), at other
    # factors than the default's 2, on the defaults (1 kHz base)
    ("intervals x1", {**DEFAULTS, "telescope/optics.interval_factor": 1.0}),
    ("intervals x4", {**DEFAULTS, "telescope/optics.interval_factor": 4.0}),
    # the profile's 7 layers rendered as fewer equivalent layers (blocks/optics/equivalent_layers.py), also on both
    # noise draws' random numbers (the screens are other draws: compare with those rows)
    ("3 equivalent layers", {EQUIVALENT: 3}),
    ("4 equivalent layers", {EQUIVALENT: 4}),
    ("3 equivalent layers, noise draw", {NOISE_DRAW: "b", EQUIVALENT: 3}),
    ("3 equivalent layers, noise draw 2", {NOISE_DRAW: "c", EQUIVALENT: 3}),
    ("noise draw 3", {NOISE_DRAW: "d"}),
    ("3 equivalent layers, noise draw 3", {NOISE_DRAW: "d", EQUIVALENT: 3}),
    ("4 equivalent layers, noise draw", {NOISE_DRAW: "b", EQUIVALENT: 4}),
    ("4 equivalent layers, noise draw 2", {NOISE_DRAW: "c", EQUIVALENT: 4}),
    ("defaults, 3 equivalent layers", {**DEFAULTS, EQUIVALENT: 3}),
    ("defaults now (auto layers)", {**DEFAULTS, EQUIVALENT: "auto"}),
    # three more paired draws (the staring main job's stars need six: docs/speed.md, "Equivalent layers")
    *paired_draws(((4, "e"), (5, "f"), (6, "g"))),
]
FLOORS = ("seed 2", *(f"noise draw{n}" for n in ("", " 2", " 3", " 4", " 5", " 6")))     # the noise floors' rows
TRACK_RADIUS_PX = 4.0
BIN_NS = 50_000_000
STAR_CENTROID_EVENTS = 5


def star_statistics(events: dict, truth: dict) -> dict:
    """Each star's events (within TRACK_RADIUS_PX of its true position at the latest render time before
    the event) and their 50 ms centroids, keyed by star and bin."""
    star = truth["kind"] == SourceKind.STAR
    t, index = truth["t_ns"][star], np.unique(truth["source_id"][star], return_inverse=True)[1]
    x, y = truth["x_px"][star].astype(float), truth["y_px"][star].astype(float)
    times, row = np.unique(t, return_inverse=True)
    # the stars on the detector at each render time, padded: (times, most stars at once)
    order = np.lexsort((index, row))
    row, index, x, y = row[order], index[order], x[order], y[order]
    slot = np.arange(row.size) - np.searchsorted(row, row)
    width = int(slot.max()) + 1 if slot.size else 0
    sx, sy = np.full((times.size, width), np.nan), np.full((times.size, width), np.nan)
    sid = np.full((times.size, width), -1)
    sx[row, slot], sy[row, slot], sid[row, slot] = x, y, index
    k = np.searchsorted(times, events["t_trigger_ns"], side="right") - 1
    valid = k >= 0
    counts, centroids = {}, {}
    if not width or not valid.any():
        return {"counts": counts, "centroids": centroids, "total": 0}
    ex, ey, kk = events["x"][valid].astype(float), events["y"][valid].astype(float), k[valid]
    distance = np.hypot(sx[kk] - ex[:, None], sy[kk] - ey[:, None])
    distance = np.where(np.isnan(distance), np.inf, distance)
    nearest = distance.argmin(axis=1)
    near = distance[np.arange(nearest.size), nearest] <= TRACK_RADIUS_PX
    who = sid[kk[near], nearest[near]]
    bins = events["t_trigger_ns"][valid][near] // BIN_NS
    for s in np.unique(who):
        mine = who == s
        counts[int(s)] = int(mine.sum())
        for b in np.unique(bins[mine]):
            sel = mine & (bins == b)
            if sel.sum() >= STAR_CENTROID_EVENTS:
                centroids[(int(s), int(b))] = (ex[near][sel].mean(), ey[near][sel].mean())
    return {"counts": counts, "centroids": centroids, "total": int(near.sum())}


def statistics(store_path: Path, duration_s: float, pixels: int = 1280 * 720) -> dict:
    """Track events, 50 ms centroids, track events keyed by pixel and polarity, background rate of one run."""
    store = RunStore.open(store_path)
    events, truth = store.read_events(), store.read_truth()
    sat = truth["kind"] == SourceKind.SATELLITE
    t_true, x_true, y_true = truth["t_ns"][sat], truth["x_px"][sat], truth["y_px"][sat]
    at = np.clip(np.searchsorted(t_true, events["t_trigger_ns"], side="right") - 1, 0, None)
    dx = events["x"].astype(float) - x_true[at]
    dy = events["y"].astype(float) - y_true[at]
    track = np.hypot(dx, dy) <= TRACK_RADIUS_PX
    t = events["t_trigger_ns"][track]
    bins = t // BIN_NS
    centroids = {int(b): (events["x"][track][bins == b].mean(), events["y"][track][bins == b].mean())
                 for b in np.unique(bins) if np.count_nonzero(bins == b) >= 10}
    # track events by (pixel, polarity), each key's times in order: matched against the faithful run's
    key = (events["y"][track].astype(np.int64) * 100_000 + events["x"][track]) * 2 + (events["p"][track] > 0)
    stamp = key << 40 | t                                       # t < 2^40 ns (18 minutes)
    background = np.count_nonzero(events["cause"] != EventCause.SIGNAL) / (pixels * duration_s)
    return {"track": int(track.sum()), "centroids": centroids, "stamps": np.sort(stamp), "background": background,
            "events": int(events["t_trigger_ns"].size), "stars": star_statistics(events, truth),
            "detection_probability": float(store.metrics.get("detection_probability", np.nan))}


def errors(run: dict, faithful: dict) -> dict:
    common = sorted(set(run["centroids"]) & set(faithful["centroids"]))
    centroid = (np.sqrt(np.mean([np.hypot(run["centroids"][b][0] - faithful["centroids"][b][0],
                                          run["centroids"][b][1] - faithful["centroids"][b][1]) ** 2
                                 for b in common])) if common else np.nan)
    # each faithful track event's nearest event of the same pixel and polarity in this run (within 5 ms)
    mine, theirs = run["stamps"], faithful["stamps"]
    timing = np.nan
    if mine.size and theirs.size:
        i = np.clip(np.searchsorted(mine, theirs), 1, mine.size - 1)
        nearest = np.minimum(np.abs(mine[i] - theirs), np.abs(mine[i - 1] - theirs))
        matched = nearest < 5_000_000                           # same key: otherwise the difference is >= 2^40
        timing = float(np.median(nearest[matched])) * 1e-3 if matched.any() else np.nan
    mine, theirs = run["stars"], faithful["stars"]
    stars = sorted(set(mine["counts"]) | set(theirs["counts"]))
    per_star = np.array([mine["counts"].get(s, 0) - theirs["counts"].get(s, 0) for s in stars], dtype=float)
    mean_count = theirs["total"] / max(len(theirs["counts"]), 1)
    both = sorted(set(mine["centroids"]) & set(theirs["centroids"]))
    star_centroid = (np.sqrt(np.mean([np.hypot(mine["centroids"][b][0] - theirs["centroids"][b][0],
                                               mine["centroids"][b][1] - theirs["centroids"][b][1]) ** 2
                                      for b in both])) if both else np.nan)
    return {"track": run["track"] / max(faithful["track"], 1) - 1, "centroid_px": centroid, "timing_us": timing,
            "background": run["background"] / faithful["background"] - 1 if faithful["background"] else np.nan,
            "p_d": run["detection_probability"],
            "star_events": mine["total"] / max(theirs["total"], 1) - 1,
            "star_count_rms": float(np.sqrt(np.mean(per_star**2))) / max(mean_count, 1e-9) if stars else np.nan,
            "star_centroid_px": star_centroid}


def scene(settings: dict, prefix: str = "scene/") -> list[str]:
    """``--set`` values for the scene's blocks (included as ``scene`` in the benchmark graph; ``prefix`` ''
    for a scene run as it is); a noise draw's renamed sub-graphs get their suffix; ``run.*`` stays as it is."""
    suffix = settings.get(NOISE_DRAW)

    def key(k: str) -> str:
        head, _, rest = k.partition("/")
        return prefix + (f"{head}_{suffix}/{rest}" if rest and suffix and head in RENAMED else k)
    return [f"{k if k.startswith('run.') else key(k)}={v}" for k, v in settings.items() if k != NOISE_DRAW]


def renamed_graph(folder: Path, scene_file: Path, suffix: str, wrapped: bool) -> Path:
    """A copy of the scene whose sensor and telescope sub-graphs are renamed with ``suffix`` (:data:`NOISE_DRAW`),
    and of the benchmark graph around it where the scene is wrapped."""
    text = scene_file.read_text()
    for old in RENAMED:
        text = text.replace(f"as: {old}", f"as: {old}_{suffix}").replace(f" {old}.", f" {old}_{suffix}.")
    target = folder / suffix
    target.mkdir(exist_ok=True)
    (target / scene_file.name).write_text(text)
    if not wrapped:
        return target / scene_file.name
    (target / GRAPH.name).write_text(GRAPH.read_text())
    return target / GRAPH.name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1.0, help="simulated seconds per run [s]")
    parser.add_argument("--plot", default="speed_vs_error.png", help="Pareto plot to write (PNG)")
    parser.add_argument("--only", type=int, default=len(VARIANTS), help="run the first N combinations only")
    parser.add_argument("--rows", nargs="*", help="run only these combinations (names; the faithful one first)")
    parser.add_argument("--scene", type=Path, help="run this scene as it is instead of the tracked pass with its "
                                                   "detector (no P_d)")
    parser.add_argument("--warm-s", type=float, default=0.1, help="a first run this long for the compiled caches "
                                                                     "(0: none, e.g. where the satellite enters later) [s]")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of every row, the faithful one's too, as in FAITHFUL (repeatable), e.g. "
                             "telescope/optics.profile_file=library:atmospheres/las_campanas.csv")
    parser.add_argument("--equivalent", default="3", metavar="N",
                        help="equivalent_layers of the rows named '3 equivalent layers...' (an integer or 'auto'; "
                             "the rows are named after it)")
    parser.add_argument("--extra-draws", nargs="*", default=[], metavar="SUFFIX",
                        help="more noise draws (new suffixes, e.g. h i j): rows 'noise draw SUFFIX' and '3 equivalent "
                             "layers, noise draw SUFFIX' each, after the chosen rows")
    args = parser.parse_args()
    wrapped = args.scene is None
    scene_file = GRAPH.with_name("end_to_end.yaml") if wrapped else args.scene.resolve()
    main_graph, prefix = (GRAPH, "scene/") if wrapped else (scene_file, "")
    variants = [v for v in VARIANTS[:args.only] if not args.rows or v[0] in ("faithful", *args.rows)]
    variants += paired_draws((suffix, suffix) for suffix in args.extra_draws)
    variants = [with_equivalent(name, change, args.equivalent) for name, change in variants]
    faithful_settings = {**FAITHFUL, **dict(item.split("=", 1) for item in args.settings)}
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; {main_graph.name}, "
          f"{args.duration:g} s simulated per run; faithful: {faithful_settings}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.warm_s:
            # the compiled caches
            run_cli(args.warm_s, Path(tmp) / "warm.zarr", scene(faithful_settings, prefix), main_graph)
        faithful = None
        for name, change in variants:
            settings = {**faithful_settings, **change}
            store = Path(tmp) / f"{len(rows)}.zarr"
            graph = (renamed_graph(Path(tmp), scene_file, change[NOISE_DRAW], wrapped) if NOISE_DRAW in change
                     else main_graph)
            timing = run_cli(args.duration, store, scene(settings, prefix), graph)
            stats = statistics(store, args.duration)
            faithful = faithful or stats
            rows.append((name, timing, stats, errors(stats, faithful)))
            e = rows[-1][3]
            print(f"  {name:14s} wall {timing['wall_s']:6.1f} s  CPU {timing['cpu_s']:6.1f} s  "
                  f"track events {stats['track']:6d} ({e['track']:+6.1%})  centroid {e['centroid_px']:5.2f} px  "
                  f"timing {e['timing_us']:7.1f} us  background {e['background']:+6.1%}  P_d {e['p_d']:.2f}  "
                  f"star events {stats['stars']['total']:6d} ({e['star_events']:+6.1%}, per star "
                  f"{e['star_count_rms']:5.1%} RMS)  star centroid {e['star_centroid_px']:5.2f} px", flush=True)
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")
    paired_equivalent_layers(rows, f"{args.equivalent} equivalent layers")
    if args.plot:
        pareto(rows, args.plot)


def with_equivalent(name: str, change: dict, value: str) -> tuple[str, dict]:
    """A row "3 equivalent layers..." (:data:`VARIANTS`) at ``equivalent_layers`` ``value`` (an integer or "auto"),
    named after it; other rows as they are."""
    if value == "3" or not name.startswith("3 equivalent layers"):
        return name, change
    return f"{value} equivalent layers" + name.removeprefix("3 equivalent layers"), {
        **change, EQUIVALENT: int(value) if value.isdigit() else value}


def paired_equivalent_layers(rows, prefix: str = "3 equivalent layers") -> None:
    """The star and track events of each row "PREFIX[, DRAW]" (:func:`with_equivalent`) against its every-layer twin
    on the same draw ("faithful" or DRAW), paired: each pair's relative difference, their mean and standard error
    [%]."""
    counts = {name: stats for name, _, stats, _ in rows}
    twins = {name: name.removeprefix(prefix).removeprefix(", ") or "faithful" for name in counts
             if name.startswith(prefix)}
    pairs = [(counts[twin], counts[name]) for name, twin in twins.items() if twin in counts]
    if not pairs:
        return
    for label, key in (("star events", lambda s: s["stars"]["total"]), ("track events", lambda s: s["track"])):
        d = np.array([key(three) / max(key(every), 1) - 1 for every, three in pairs]) * 100
        spread = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else np.nan
        print(f"{prefix} against every layer, {d.size} paired draws, {label}: mean {d.mean():+.2f} % "
              f"(standard error {spread:.2f}); each: " + " ".join(f"{x:+.1f}" for x in d))


def pareto(rows, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, key, label in ((axes[0], "centroid_px", "centroid error vs faithful [pixel]"),
                           (axes[1], "track", "|track event count error| vs faithful [1]"),
                           (axes[2], "p_d", "detection probability in the events alone [1]")):
        for name, timing, _, e in rows:
            value = e[key] if key == "p_d" else abs(e[key])
            if key == "track":
                value = max(value, 1e-3)                       # log axis: 'no difference' drawn at 0.1 %
            ax.scatter(timing["cpu_s"], value, color="C3" if name in FLOORS else "C0")
            ax.annotate(name, (timing["cpu_s"], value), fontsize=7, xytext=(3, 3), textcoords="offset points")
        floor = [e[key] if key == "p_d" else abs(e[key]) for name, _, _, e in rows if name in FLOORS]
        floor = [v for v in floor if np.isfinite(v)]
        if floor and key != "p_d":                             # the largest noise floor: within it = as good
            ax.axhline(max(floor), color="C3", lw=0.8, ls="--")
        elif floor:                                            # the noise draws' spread of P_d
            ax.axhspan(min(floor), max(floor), color="C3", alpha=0.1)
        if key == "track":
            ax.set_yscale("log")
        ax.set_xlabel("CPU time [s]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle("Speed against error, tracked LEO pass (red: the faithful run at another seed or noise draw; dashed: the largest of them = noise floor)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"Pareto plot: {path}")


if __name__ == "__main__":
    main()
