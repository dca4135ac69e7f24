"""The plots SDA users expect from a stored run: a track's light curve, the event rate by cause, and
the x-t / y-t space-time plot with the true tracks.

Each plot has a function computing what it shows (arrays, usable without matplotlib) and one that
returns a :class:`matplotlib.figure.Figure`. Figures are built with ``Figure()`` directly, not through
``pyplot``: no module here selects a backend or registers figures globally, so a notebook keeps its
backend and a saved figure leaves nothing open. The ``evsda plot-*`` commands save them.

Times: events are binned by their trigger time ``t_t`` (when the pixel fired, paper Eq. 22) for the
light curve, and by the time the user picks (readout ``t_a`` by default) for the rate; the truth is the
store's ``truth`` group (:meth:`~evsda.graph.store.RunStore.read_truth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evsda.blocks.ports import EventCause, SourceKind
from evsda.graph import NS_PER_S, UserError

from .object_metrics import passages
from .render import accumulate, event_figure

TIME_FIELDS = {"readout": "t_readout_ns", "trigger": "t_trigger_ns"}
CAUSE_COLOURS = {EventCause.SIGNAL: "tab:blue", EventCause.LEAK: "tab:orange", EventCause.PARASITIC: "tab:purple",
                 EventCause.SHOT: "tab:gray"}


def _figure(width_in: float, height_in: float, dpi: float = 100):
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=dpi, layout="constrained")


def _truth(store) -> dict[str, np.ndarray]:
    truth = store.read_truth()
    if not truth:
        raise UserError(f"{store.path} holds no ground truth (run with run.store_truth: false, or by an evsda older "
                        f"than the truth group); re-run it to draw the true tracks")
    return truth


def _run_end_ns(store) -> int:
    last = 0
    if store.n_events:
        chunk = next(store.iter_events(1, start=store.n_events - 1))
        last = int(max(chunk["t_readout_ns"][-1], chunk["t_trigger_ns"][-1])) + 1
    return max(int(store.attrs.get("duration_ns") or 0), last)


def _bins(end_ns: int, bin_s: float) -> np.ndarray:
    if not 0 < bin_s < float("inf"):
        raise UserError(f"the time bin must be a positive number of seconds, got {bin_s}")
    step = max(1, round(bin_s * NS_PER_S))
    if end_ns // step > 1_000_000:
        raise UserError(f"a {bin_s} s bin makes more than a million bins over {end_ns / NS_PER_S:g} s; choose a "
                        f"longer bin")
    return np.arange(0, end_ns + step, step, dtype=np.int64)


# -- the light curve along a track -------------------------------------------------------------------
@dataclass(frozen=True)
class LightCurve:
    """Events along one source's true path per time bin, and its true brightness."""

    source_id: str
    edges_ns: np.ndarray          # int64 [n_bins + 1] bin edges (event trigger time) [ns]
    on: np.ndarray                # int64 [n_bins] ON events of the track per bin
    off: np.ndarray               # int64 [n_bins] OFF events
    signal: np.ndarray            # int64 [n_bins] of which the simulation labels signal (the rest is noise)
    truth_t_ns: np.ndarray        # int64 [n] render times while the source was on the detector [ns]
    magnitude: np.ndarray         # float32 [n] its apparent magnitude then [mag]
    radius_px: float
    latency_s: float


def default_source(truth: dict[str, np.ndarray]) -> str:
    """The satellite longest on the detector (else the brightest star)."""
    sat = truth["kind"] == SourceKind.SATELLITE
    if sat.any():
        ids, counts = np.unique(truth["source_id"][sat], return_counts=True)
        return str(ids[np.argmax(counts)])
    return str(truth["source_id"][np.argmin(truth["magnitude"])])


def light_curve(store, source_id: str | None = None, bin_s: float = 0.01, radius_px: float = 3.0,
                latency_s: float = 1.0, chunk_size: int = 1 << 20) -> LightCurve:
    """ON and OFF events per ``bin_s`` along ``source_id``'s true path (default :func:`default_source`).

    An event belongs to the track when its pixel centre lies within ``radius_px`` of the source's true
    path (the store's truth, straight between render times) and the path covered that pixel at most
    ``latency_s`` before the event fired (or one render step after): the attribution of
    ``object_metrics`` with this one source, so with its defaults the curve's total is the object's
    ``object_ID_events`` when no other object shares its pixels.
    """
    truth = _truth(store)
    source_id = default_source(truth) if source_id is None else str(source_id)
    mine = truth["source_id"] == source_id
    if not mine.any():
        known = ", ".join(sorted(set(truth["source_id"].tolist()))[:10])
        raise UserError(f"{store.path}: no source '{source_id}' on the detector in the truth (sources: {known})")
    t, x, y = truth["t_ns"][mine], truth["x_px"][mine].astype(float), truth["y_px"][mine].astype(float)
    fp = store.focal_plane
    keys, first, last = passages(t, x, y, radius_px, fp.width_px, fp.height_px)
    step = int(np.median(np.diff(t))) if len(t) > 1 else 0
    latency_ns = round(latency_s * NS_PER_S)
    edges = _bins(_run_end_ns(store), bin_s)
    on, off, signal = (np.zeros(len(edges) - 1, np.int64) for _ in range(3))
    for chunk in store.iter_events(chunk_size):
        if not keys.size or not len(chunk["x"]):
            continue
        pixel = chunk["y"].astype(np.int64) * fp.width_px + chunk["x"].astype(np.int64)
        at = np.clip(np.searchsorted(keys, pixel), 0, keys.size - 1)
        t_event = chunk["t_trigger_ns"].astype(np.int64)
        ok = (keys[at] == pixel) & (t_event >= first[at] - step) & (t_event <= last[at] + latency_ns)
        where = np.searchsorted(edges, t_event[ok], side="right") - 1
        positive = chunk["p"][ok] > 0
        on += np.bincount(where[positive], minlength=len(on))[: len(on)]
        off += np.bincount(where[~positive], minlength=len(off))[: len(off)]
        signal += np.bincount(where[chunk["cause"][ok] == EventCause.SIGNAL], minlength=len(on))[: len(on)]
    return LightCurve(source_id, edges, on, off, signal, t, truth["magnitude"][mine], radius_px, latency_s)


def plot_light_curve(curve: LightCurve, dpi: float = 100):
    """The light curve: ON events up, OFF events down per bin (left axis), the true magnitude (right)."""
    fig = _figure(9, 4.8, dpi)
    ax = fig.add_subplot()
    edges_s = curve.edges_ns / NS_PER_S
    width = float(np.diff(edges_s[:2])[0]) if len(edges_s) > 1 else 0.0
    ax.stairs(curve.on, edges_s, color="tab:green", fill=True, alpha=0.7, label="ON")
    ax.stairs(-curve.off, edges_s, color="tab:red", fill=True, alpha=0.7, label="OFF")
    ax.stairs(curve.signal, edges_s, color="k", lw=0.8, label="of which signal (ON + OFF)")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("event trigger time since the run's start [s]")
    ax.set_ylabel(f"events per {width * 1e3:.3g} ms bin (ON up, OFF down)")
    total = int(curve.on.sum() + curve.off.sum())
    ax.set_title(f"light curve of {curve.source_id}: {total} events within {curve.radius_px:g} px of its true "
                 f"path ({int(curve.on.sum())} ON, {int(curve.off.sum())} OFF; latency {curve.latency_s:g} s)",
                 fontsize=9)
    mag = ax.twinx()
    mag.plot(curve.truth_t_ns / NS_PER_S, curve.magnitude, color="tab:blue", lw=1.2, label="true magnitude")
    if np.isfinite(curve.magnitude).any():
        mag.invert_yaxis()
    mag.set_ylabel("apparent magnitude (truth) [mag]", color="tab:blue")
    handles = ax.get_legend_handles_labels()[0] + mag.get_legend_handles_labels()[0]
    ax.legend(handles=handles, fontsize=8, loc="upper right")
    return fig


# -- event rate by cause -------------------------------------------------------------------------------
@dataclass(frozen=True)
class EventRate:
    edges_ns: np.ndarray          # int64 [n_bins + 1] [ns]
    counts: np.ndarray            # int64 [4, n_bins] events per bin for each EventCause
    time: str                     # "readout" or "trigger"

    @property
    def rate_hz(self) -> np.ndarray:
        """Events per second in each bin, per cause [event s^-1]."""
        return self.counts / (np.diff(self.edges_ns) / NS_PER_S)


def event_rate(store, bin_s: float = 0.01, time: str = "readout", chunk_size: int = 1 << 20) -> EventRate:
    """Recorded events per ``bin_s`` of their ``time`` (readout ``t_a`` or trigger ``t_t``), for each cause."""
    edges = _bins(_run_end_ns(store), bin_s)
    counts = np.zeros((len(EventCause), len(edges) - 1), np.int64)
    for chunk in store.iter_events(chunk_size):
        where = np.searchsorted(edges, chunk[TIME_FIELDS[time]], side="right") - 1
        for cause in EventCause:
            counts[cause] += np.bincount(where[chunk["cause"] == cause], minlength=counts.shape[1])[: counts.shape[1]]
    return EventRate(edges, counts, time)


def plot_event_rate(rate: EventRate, dpi: float = 100):
    """Event rate against time, one line per cause (signal, leak, parasitic, shot) and their total."""
    fig = _figure(9, 4.5, dpi)
    ax = fig.add_subplot()
    edges_s = rate.edges_ns / NS_PER_S
    per_s = rate.rate_hz
    for cause in EventCause:
        ax.stairs(per_s[cause], edges_s, color=CAUSE_COLOURS[cause], lw=1.2,
                  label=f"{cause.name.lower()} ({int(rate.counts[cause].sum())} events)")
    ax.stairs(per_s.sum(axis=0), edges_s, color="k", lw=0.8, ls="--", label=f"all ({int(rate.counts.sum())})")
    if (per_s > 0).any():
        ax.set_yscale("log")
    ax.set_xlabel(f"{rate.time} time since the run's start [s]")
    ax.set_ylabel("event rate [event/s]")
    ax.set_title(f"recorded events by cause, {np.diff(edges_s[:2])[0] * 1e3:.3g} ms bins", fontsize=9)
    ax.legend(fontsize=8, loc="best")
    return fig


# -- space-time plot ----------------------------------------------------------------------------------
def plot_space_time(store, axis: str = "x", start_s: float | None = None, stop_s: float | None = None,
                    stars: bool = False, max_events: int = 200_000, chunk_size: int = 1 << 20, dpi: float = 100):
    """Events' column (``axis="x"``) or row (``"y"``) against trigger time, ON green and OFF red, with the
    true track of every satellite (and star, with ``stars``) drawn on top from the store's truth.

    A moving source is a slanted line whose slope is its rate [pixel/s]. At most ``max_events`` events
    are drawn (every k-th, in time order); the title says how many.
    """
    if axis not in ("x", "y"):
        raise UserError(f"the space-time axis is x or y, got {axis}")
    truth = _truth(store)
    lo = 0 if start_s is None else round(start_s * NS_PER_S)
    hi = _run_end_ns(store) if stop_s is None else round(stop_s * NS_PER_S)
    if hi <= lo:
        raise UserError(f"the time span is empty ({lo / NS_PER_S} s to {hi / NS_PER_S} s)")
    n_span = 0
    for chunk in store.iter_events(chunk_size):
        t = chunk["t_trigger_ns"]
        n_span += int(np.count_nonzero((t >= lo) & (t < hi)))
    every = max(1, -(-n_span // max_events))
    t_all, v_all, p_all = [], [], []
    seen = 0
    for chunk in store.iter_events(chunk_size):
        sel = np.flatnonzero((chunk["t_trigger_ns"] >= lo) & (chunk["t_trigger_ns"] < hi))
        pick = sel[(seen + np.arange(sel.size)) % every == 0]
        seen += sel.size
        t_all.append(chunk["t_trigger_ns"][pick])
        v_all.append(chunk[axis][pick])
        p_all.append(chunk["p"][pick])
    t_ev = np.concatenate(t_all) / NS_PER_S if t_all else np.zeros(0)
    v_ev = np.concatenate(v_all) if v_all else np.zeros(0)
    p_ev = np.concatenate(p_all) if p_all else np.zeros(0, np.int8)

    fp = store.focal_plane
    fig = _figure(9, 5.5, dpi)
    ax = fig.add_subplot()
    ax.scatter(t_ev[p_ev > 0], v_ev[p_ev > 0], s=1, color="tab:green", lw=0, label="ON events", rasterized=True)
    ax.scatter(t_ev[p_ev < 0], v_ev[p_ev < 0], s=1, color="tab:red", lw=0, label="OFF events", rasterized=True)
    span = (truth["t_ns"] >= lo) & (truth["t_ns"] < hi)
    wanted = span & ((truth["kind"] == SourceKind.SATELLITE) | stars)
    for source_id in dict.fromkeys(truth["source_id"][wanted].tolist()):
        mine = wanted & (truth["source_id"] == source_id)
        star = truth["kind"][mine][0] == SourceKind.STAR
        ax.plot(truth["t_ns"][mine] / NS_PER_S, truth[f"{axis}_px"][mine], color="0.5" if star else "tab:blue",
                lw=0.8 if star else 1.5, label=None if star else source_id)
    ax.set_xlim(lo / NS_PER_S, hi / NS_PER_S)
    ax.set_ylim((fp.width_px if axis == "x" else fp.height_px) - 0.5, -0.5)
    ax.set_xlabel("event trigger time since the run's start [s]")
    ax.set_ylabel(f"{'column x' if axis == 'x' else 'row y'} [pixel]")
    drawn = f"every {every}th of {n_span}" if every > 1 else f"all {n_span}"
    ax.set_title(f"{axis}-t space-time plot: {drawn} events; true tracks (truth) as lines", fontsize=9)
    ax.legend(fontsize=8, loc="best", markerscale=8)
    return fig


# -- the event image with the true tracks ---------------------------------------------------------------
def plot_events(store, start_s: float | None = None, stop_s: float | None = None, truth: bool = True,
                scale: float | None = None, dpi: float = 100, chunk_size: int = 1 << 20):
    """The accumulated event image of a stored run (paper Fig. 6) over readout times ``[start_s, stop_s)``,
    with the true paths on top (``truth``), at ``scale`` output pixels per sensor pixel (1: native)."""
    fp = store.focal_plane
    start = None if start_s is None else round(start_s * NS_PER_S)
    stop = None if stop_s is None else round(stop_s * NS_PER_S)
    on, off = accumulate(store.iter_events(chunk_size), fp.width_px, fp.height_px, start, stop)
    return event_figure(on, off, truth=_truth(store) if truth else None, start_ns=start, stop_ns=stop, scale=scale,
                        dpi=dpi)
