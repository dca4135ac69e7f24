"""Validation metrics of an event-sensor run (paper Sec. 3), accumulated over windows.

The paper names three figures to compare a simulation with a real sensor: "the ratio of
number of events to the expected number of events, the event-loss rate, and background
noise rate" (Sec. 3), and the arbiter's ordering errors and delays (Sec. 2.5). Here:

* expected events ``N_exp = N_trig + N_loss``: the events the pixels would have produced
  had every threshold crossing been an event, i.e. the triggered events plus those lost
  in the pixel (:attr:`TriggeredEvents.n_loss`): events a pixel could not emit -- Eq. 17's
  owed events that the input took back before the pixel could compare again, and noise
  events that arrived while it was blind. The paper's ``N_loss`` summed at every comparison
  would count an event that waits through k comparisons k times (see
  :mod:`evsda.blocks.pixel.comparator`).
* ``ratio_recorded_to_expected = N_rec / N_exp``.
* loss: ``loss_fraction_pixel = N_loss / N_exp`` (events the pixels could not emit),
  ``loss_fraction_readout = N_drop / N_exp`` (dropped by the arbiter), and the paper's
  ``loss_to_recorded = (N_loss + N_drop) / N_rec``.
* background rate: recorded events per second per pixel in the pixels farther than
  ``track_radius_px`` from every source's path (satellites and stars) [Hz pixel^-1]. A
  path is drawn straight between the source's samples; a pixel is on it when its centre
  is within ``track_radius_px`` of a point of the path taken every 0.5 pixel, so the
  tube is exact to 0.25 pixel.
* track: recorded events within ``track_radius_px`` of a satellite's path, the background
  expected there, and ``track_snr = (N_track - B_track) / sqrt(N_track)``.
* ordering: the fraction of recorded events whose trigger time is earlier than that of an
  event recorded strictly before them (recorded out of trigger order).
* readout delay ``t_a - t_t``: mean and maximum exactly; percentiles from a histogram of
  ``bins_per_decade`` logarithmic bins per decade (relative resolution
  ``10**(1/bins_per_decade) - 1``; a zero delay has its own bin).

The block is a sink: it returns the running figures every window and the final ones
from :meth:`finish`; all units are in :attr:`Metrics.units`.
"""

from __future__ import annotations

import functools

import numpy as np
from pydantic import Field

from evsda.blocks.ports import Events, EventCause, Metrics, PointSources, SourceKind, TriggeredEvents
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, Window

from .metric_counts import SATELLITE_MARK, SOURCE_MARK, bin_delays, count_causes, count_recorded, mark_paths

DELAY_DECADES = 14            # delays from 1 ns to 1e14 ns (~28 h) [decade]
SOURCE_BIT, SATELLITE_BIT = SOURCE_MARK, SATELLITE_MARK
PATH_STEP_PX = 0.5           # a source's path drawn as points this far apart at most [pixel]


class EventMetrics(Block):
    """Paper Sec. 3 metrics: recorded/expected ratio, losses, background rate, ordering, delays."""

    type_name = "event_metrics"
    is_sink = True

    class Params(BlockParams):
        track_radius_px: float = Field(3.0, ge=0, description="Pixels within this distance of a source's path "
                                                              "belong to its track [pixel]")
        bins_per_decade: int = Field(100, ge=1, le=1000, description="Logarithmic bins per decade of the "
                                                                     "readout-delay histogram [1]")

    inputs = {
        "triggered": Input(TriggeredEvents, "events as the pixels trigger them (counts and N_loss)"),
        "events": Input(Events, "events as the readout records them"),
        "sources": Input(PointSources, "source positions, to tell the track from the background", required=False),
    }
    outputs = {"metrics": Output(Metrics, "running figures of the run (final ones from finish)")}
    state = ("counts", "delays", "image", "tracks", "last_xy", "order")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.counts = {"triggered": 0, "lost_pixel": 0, "recorded": 0, "dropped": 0, "duration_ns": 0,
                       "out_of_order": 0, "delay_sum_ns": 0.0, "delay_max_ns": 0,
                       "triggered_by_cause": [0] * len(EventCause), "recorded_by_cause": [0] * len(EventCause)}
        self.delays = np.zeros(DELAY_DECADES * self.params.bins_per_decade + 1, np.int64)
        self.image = None          # recorded events per pixel, int64 (height, width)
        self.tracks = None         # uint8 (height, width): SOURCE_BIT near any source, SATELLITE_BIT near a satellite
        self.last_xy = None        # float64 [n_src, 2] last known position of each source (track continuity)
        self.order = {"last_t_a": -1, "max_before_last": np.iinfo(np.int64).min, "max_all": np.iinfo(np.int64).min}
        self._box = _box_offsets(self.params.track_radius_px)
        self._sums: dict[str, int] | None = None     # running sums over image and tracks (see _track_sums)

    def set_state(self, state: dict) -> None:
        super().set_state(state)
        if self.image is not None:          # counted into through flat views
            self.image, self.tracks = np.ascontiguousarray(self.image), np.ascontiguousarray(self.tracks)
        self._sums = None

    def _track_sums(self) -> dict[str, int]:
        """Recorded events in all, and pixels and their recorded events near any source and near a satellite,
        kept up to date as events and track pixels come (so that the running figures cost no pass over the
        frame each window); worked out from ``image`` and ``tracks`` after a restart."""
        if self._sums is None:
            source, satellite = (self.tracks & SOURCE_BIT) != 0, (self.tracks & SATELLITE_BIT) != 0
            self._sums = {"events": int(self.image.sum()),
                          "source_pixels": int(np.count_nonzero(source)), "source_events": int(self.image[source].sum()),
                          "satellite_pixels": int(np.count_nonzero(satellite)),
                          "satellite_events": int(self.image[satellite].sum())}
        return self._sums

    # -- accumulation -----------------------------------------------------------------------------
    def step(self, window: Window, triggered: TriggeredEvents, events: Events,
             sources: PointSources | None = None) -> dict:
        fp = events.focal_plane
        if self.image is None:
            self.image = np.zeros(fp.shape, np.int64)
            self.tracks = np.zeros(fp.shape, np.uint8)
        c = self.counts
        c["triggered"] += len(triggered)
        c["lost_pixel"] += int(triggered.n_loss)
        c["recorded"] += len(events)
        c["dropped"] += int(events.n_dropped)
        c["duration_ns"] += window.duration_ns
        if len(triggered):
            by_cause = np.zeros(len(EventCause), np.int64)
            count_causes(triggered.cause, by_cause)
            c["triggered_by_cause"] = [a + int(b) for a, b in zip(c["triggered_by_cause"], by_cause)]
        if len(events):
            self._count_recorded(events)
        if sources is not None:
            self._mark_tracks(sources)
        return {"metrics": self.summary(with_tracks=sources is not None)}

    def finish(self) -> dict:
        return {"metrics": self.summary(with_tracks=self.tracks is not None and bool(self.tracks.any()))}

    def _count_recorded(self, events: Events) -> None:
        """A window's recorded events counted in one compiled pass (:func:`.metric_counts.count_recorded`): the
        frame's counts and the track sums, causes, delays and ordering errors."""
        c, o, fp = self.counts, self.order, events.focal_plane
        sums = self._track_sums()
        by_cause = np.zeros(len(EventCause), np.int64)
        order = np.array([o["last_t_a"], o["max_before_last"], o["max_all"]], np.int64)
        delay_ns = np.empty(len(events), np.int64)
        (near_source, near_satellite, out_of_order, largest, positive, total, magnitude,
         outside) = count_recorded(self.image.reshape(-1), self.tracks.reshape(-1), fp.width_px, fp.height_px,
                                   events.x, events.y, events.t_readout_ns, events.t_trigger_ns, events.cause,
                                   by_cause, order, delay_ns)
        if outside >= 0:
            raise IndexError(f"event {outside} at ({events.x[outside]}, {events.y[outside]}) is outside the "
                             f"{fp.width_px} x {fp.height_px} focal plane")
        c["recorded_by_cause"] = [a + int(b) for a, b in zip(c["recorded_by_cause"], by_cause)]
        sums["events"] += len(events)
        sums["source_events"] += near_source
        sums["satellite_events"] += near_satellite
        c["out_of_order"] += out_of_order
        o["last_t_a"], o["max_before_last"], o["max_all"] = (int(v) for v in order)
        # integers below 2**53 add exactly in any order: their sum is NumPy's pairwise float64 sum
        exact = 0 <= magnitude < 2 ** 53
        c["delay_sum_ns"] += float(total) if exact else float(np.sum(delay_ns, dtype=np.float64))
        c["delay_max_ns"] = max(c["delay_max_ns"], int(largest))
        k = self.params.bins_per_decade
        if positive == delay_ns.size:
            bin_delays(np.log10(delay_ns), k, self.delays)
        else:
            self.delays[0] += delay_ns.size - positive
            bin_delays(np.log10(delay_ns[delay_ns > 0]), k, self.delays)

    def _mark_tracks(self, sources: PointSources) -> None:
        """Rasterise each source's path (straight between samples, 0.5 pixel steps) into ``tracks``."""
        xy = np.stack([sources.x_px, sources.y_px], axis=-1)           # [n_t, n_src, 2]
        if self.last_xy is not None and self.last_xy.shape[0] == xy.shape[1]:
            xy = np.concatenate([self.last_xy[None], xy])
        if xy.shape[0] == 0:
            return
        seen = np.where(np.isfinite(xy).all(axis=-1, keepdims=True), xy, np.nan)
        self.last_xy = seen[-1].copy()          # NaN if the source was lost: the next window starts afresh
        sums, added = self._track_sums(), np.zeros(4, np.int64)
        mark_paths(seen, sources.kind == SourceKind.SATELLITE, self._box, self.params.track_radius_px * self.params.track_radius_px,
                   PATH_STEP_PX, self.tracks, self.image, added)
        for name, value in zip(("source_pixels", "source_events", "satellite_pixels", "satellite_events"), added):
            sums[name] += int(value)

    # -- the figures ----------------------------------------------------------------------------------
    def summary(self, with_tracks: bool) -> Metrics:
        c = self.counts
        expected = c["triggered"] + c["lost_pixel"]
        duration_s = c["duration_ns"] / NS_PER_S
        values = {
            "events_triggered": c["triggered"],
            "events_lost_pixel": c["lost_pixel"],
            "events_expected": expected,
            "events_recorded": c["recorded"],
            "events_dropped_readout": c["dropped"],
            "events_pending_readout": c["triggered"] - c["recorded"] - c["dropped"],
            "ratio_recorded_to_expected": _ratio(c["recorded"], expected),
            "loss_fraction_pixel": _ratio(c["lost_pixel"], expected),
            "loss_fraction_readout": _ratio(c["dropped"], expected),
            "loss_to_recorded": _ratio(c["lost_pixel"] + c["dropped"], c["recorded"]),
            "out_of_order_fraction": _ratio(c["out_of_order"], c["recorded"]),
            "duration_s": duration_s,
        }
        for cause, triggered, recorded in CAUSE_NAMES:
            values[triggered] = c["triggered_by_cause"][cause]
            values[recorded] = c["recorded_by_cause"][cause]
        if c["recorded"]:
            values["readout_delay_mean_s"] = c["delay_sum_ns"] / c["recorded"] / NS_PER_S
            values["readout_delay_max_s"] = c["delay_max_ns"] / NS_PER_S
            cum = np.cumsum(self.delays)
            for q, name in PERCENTILE_NAMES:
                values[name] = self.delay_percentile(q, cum) / NS_PER_S
        if self.image is not None and duration_s > 0:
            sums = self._track_sums()
            n_bg = self.image.size - (sums["source_pixels"] if with_tracks else 0)
            rate = _ratio(sums["events"] - (sums["source_events"] if with_tracks else 0), n_bg * duration_s)
            values["background_rate_hz_per_pixel"] = rate
            values["background_pixels"] = n_bg
            if with_tracks:
                n_track, track_pixels = sums["satellite_events"], sums["satellite_pixels"]
                expected_bg = rate * track_pixels * duration_s
                values.update(track_pixels=track_pixels, track_events=n_track,
                              track_background_events=expected_bg,
                              track_snr=(n_track - expected_bg) / np.sqrt(n_track) if n_track else 0.0)
        return Metrics(values, dict(_units(tuple(values))))

    def delay_percentile(self, q: float, cum: np.ndarray | None = None) -> float:
        """The ``q``-th percentile of the readout delay from the histogram [ns] (log-interpolated in its bin);
        ``cum``: the histogram's cumulative sum, when the caller has it."""
        cum = np.cumsum(self.delays) if cum is None else cum
        total = int(cum[-1])
        if total == 0:
            return float("nan")
        rank = q / 100 * total
        b = int(np.searchsorted(cum, rank, side="left"))
        if b == 0:
            return 0.0
        k = self.params.bins_per_decade
        below = cum[b - 1]
        frac = (rank - below) / self.delays[b] if self.delays[b] else 0.0
        return float(10 ** ((b - 1 + frac) / k))


#: (cause, its triggered events' name, its recorded events' name) of every EventCause
CAUSE_NAMES = tuple((cause, f"events_triggered_{cause.name.lower()}", f"events_recorded_{cause.name.lower()}")
                    for cause in EventCause)
#: the readout delay's percentiles (q [%], name)
PERCENTILE_NAMES = tuple((q, f"readout_delay_p{q:g}_s".replace(".", "_")) for q in (50, 90, 99, 99.9))
#: the unit of every figure of :meth:`EventMetrics.summary` but the ``events_*`` and ``readout_delay_*`` ones
UNITS = {**dict.fromkeys(("ratio_recorded_to_expected", "loss_fraction_pixel", "loss_fraction_readout",
                          "loss_to_recorded", "out_of_order_fraction", "track_snr"), "1"),
         "duration_s": "s", "background_rate_hz_per_pixel": "Hz pixel^-1", "background_pixels": "pixel",
         "track_pixels": "pixel", "track_events": "event", "track_background_events": "event"}


@functools.lru_cache(maxsize=16)
def _units(names: tuple[str, ...]) -> dict[str, str]:
    """The units of a summary's figures, in their order (made once for each set of figures)."""
    return {name: "event" if name.startswith("events_") else "s" if name.startswith("readout_delay")
            else UNITS[name] for name in names}


def _ratio(a, b) -> float:
    return float(a) / float(b) if b else 0.0


def _box_offsets(radius: float) -> np.ndarray:
    """Offsets from ``floor(point)`` covering every pixel centre within ``radius`` of the point."""
    r = int(np.ceil(radius))
    dx, dy = np.meshgrid(np.arange(-r, r + 2), np.arange(-r, r + 2))
    return np.stack([dx.ravel(), dy.ravel()], axis=-1).astype(np.int64)


def densify(xy: np.ndarray, step_px: float = PATH_STEP_PX) -> np.ndarray:
    """Points every ``step_px`` along the straight segments between consecutive finite samples."""
    finite = np.isfinite(xy).all(axis=1)
    pts = xy[finite]
    if pts.shape[0] < 2:
        return pts
    # only join samples that were consecutive (a gap of NaN breaks the path)
    idx = np.flatnonzero(finite)
    joined = np.diff(idx) == 1
    a, b = pts[:-1][joined], pts[1:][joined]
    n = np.maximum(1, np.ceil(np.abs(b - a).max(axis=1) / step_px).astype(np.int64))
    seg = np.repeat(np.arange(a.shape[0]), n)
    frac = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    inner = a[seg] + (b[seg] - a[seg]) * frac[:, None]
    return np.concatenate([inner, pts])
