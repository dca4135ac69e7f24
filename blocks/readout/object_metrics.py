"""Per-object figures of a run with many satellites: the events each object caused, by space and time.

An event belongs to a satellite when its pixel centre lies within ``track_radius_px`` of
the satellite's path and the path covered that pixel no more than ``latency_s`` before the
event fired (or one sample after: the image moves between samples). The pixels answer a
passing image with a delay and their OFF events trail it: for faint objects whose
photocurrent is close to the dark current the trail lasts up to ~0.9 s (measured on
``examples/starlink_field.yaml``), hence the 1 s default. An event that qualifies for
several satellites belongs to the one whose path covered its pixel last. A path is
straight between consecutive samples (``PointSources`` cadence), taken every 0.5 pixel,
so the tube is exact to 0.25 pixel; objects crossing each other's paths at different
times (a train of satellites on one track) are told apart by time. The counts split by
the simulation's own cause label (:class:`~evsda.blocks.ports.EventCause`): signal events
are what a perfect detector could use, the others are noise (leak, parasitic, shot) that
fell in the object's space-time tube.

Figures per source id ``ID`` (the NORAD number for catalogued objects; ``HIP_123`` for a
star, spaces becoming ``_``) of the ``kinds`` asked for (satellites by default), all
recorded events [event] unless stated:

* ``object_ID_events``, ``object_ID_on_events``, ``object_ID_off_events``;
* ``object_ID_signal_events``, ``object_ID_noise_events`` (by cause);
* ``object_ID_snr``: ``signal / sqrt(signal + noise)`` [1] (Poisson);
* ``object_ID_observed_s``: time the object was observable on the detector [s];
* ``object_ID_peak_magnitude``: its brightest apparent magnitude there [mag];

and ``objects_observed`` (with any observable sample) and ``objects_with_signal``
(with at least one signal event) [1].
"""

from __future__ import annotations

import numpy as np
from typing import Literal

from pydantic import Field

from evsda.blocks.ports import EventCause, Events, Metrics, PointSources, SourceKind
from evsda.graph import NS_PER_S, Block, BlockParams, Input, Output, Window

#: accumulator columns per object
COLUMNS = ("events", "on_events", "off_events", "signal_events", "noise_events", "observed_ns", "peak_magnitude")


class ObjectMetrics(Block):
    """Per-satellite event counts (space-time association with the simulation's truth), SNR and exposure."""

    type_name = "object_metrics"
    is_sink = True

    class Params(BlockParams):
        track_radius_px: float = Field(3.0, ge=0, description="An event within this distance of an object's path "
                                       "belongs to it [pixel]")
        latency_s: float = Field(1.0, ge=0, le=10, description="How long after the object passed a pixel its "
                                 "events still belong to it: the pixel latency and OFF trail, which reach ~0.9 s for "
                                 "a faint object whose photocurrent is near the dark current [s]")
        kinds: Literal["satellites", "stars", "all"] = Field("satellites", description="Which sources get "
                                                             "figures: satellites, stars (e.g. a scan's star "
                                                             "streaks) or all [-]")

    inputs = {
        "events": Input(Events, "events as the readout records them"),
        "sources": Input(PointSources, "satellites and/or stars (see kinds), one or more blocks", multi=True),
    }
    outputs = {"metrics": Output(Metrics, "per-object figures (running; final ones from finish)")}
    state = ("totals", "recent")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.totals: dict[str, np.ndarray] = {}       # object id -> accumulators (COLUMNS)
        self.recent: dict[str, dict] = {}             # object id -> its samples of the last latency_s

    def step(self, window: Window, events: Events, sources: list[PointSources] | PointSources) -> dict:
        if isinstance(sources, PointSources):
            sources = [sources]
        tracks = self._tracks(window, [s for s in sources if s is not None])
        if len(events) and tracks:
            self._attribute(events, tracks)
        return {"metrics": self.summary()}

    def finish(self) -> dict:
        return {"metrics": self.summary()}

    # -- paths ------------------------------------------------------------------------------------------
    def _tracks(self, window: Window, sources: list[PointSources]) -> dict[str, tuple]:
        """Each satellite's samples over this window plus the carried ``latency_s`` before it."""
        latency_ns = round(self.params.latency_s * NS_PER_S)
        tracks = {}
        for src in sources:
            t = np.asarray(src.t_ns, dtype=np.int64)
            if len(t) > 1:
                dt = np.diff(t)
                step = np.append(dt, dt[-1])
            else:
                step = np.full(len(t), window.duration_ns)
            for j, object_id in enumerate(np.asarray(src.source_id).astype(str)):
                if not self._counted(int(src.kind[j])):
                    continue
                x, y, mag = src.x_px[:, j], src.y_px[:, j], src.magnitude[:, j]
                seen = np.isfinite(x) & np.isfinite(y)
                totals = self.totals.setdefault(object_id, _fresh())
                if seen.any():
                    totals[5] += float(step[seen].sum())
                    peak = float(np.nanmin(mag[seen])) if np.isfinite(mag[seen]).any() else np.nan
                    totals[6] = peak if np.isnan(totals[6]) else min(totals[6], peak)
                before = self.recent.get(object_id, {"t": np.zeros(0, np.int64), "x": np.zeros(0), "y": np.zeros(0)})
                tt = np.concatenate([before["t"], t])
                xx, yy = np.concatenate([before["x"], x]), np.concatenate([before["y"], y])
                if np.isfinite(xx).any():
                    tracks[object_id] = (tt, xx, yy)
                keep = tt >= window.stop_ns - latency_ns
                self.recent[object_id] = {"t": tt[keep], "x": xx[keep], "y": yy[keep]}
        return tracks

    def _counted(self, kind: int) -> bool:
        wanted = self.params.kinds
        return wanted == "all" or (kind == SourceKind.STAR) == (wanted == "stars")

    def _attribute(self, events: Events, tracks: dict[str, tuple]) -> None:
        """Give each event to the object whose path passed its pixel most recently within ``latency_s``."""
        p = self.params
        latency_ns = round(p.latency_s * NS_PER_S)
        fp = events.focal_plane
        pixel = events.y.astype(np.int64) * fp.width_px + events.x.astype(np.int64)
        t_event = events.t_trigger_ns.astype(np.int64)
        best = np.full(len(events), np.inf)
        owner = np.full(len(events), -1)
        ids = list(tracks)
        for k, object_id in enumerate(ids):
            t, x, y = tracks[object_id]
            keys, first, last = passages(t, x, y, p.track_radius_px, fp.width_px, fp.height_px)
            if not keys.size:
                continue
            at = np.clip(np.searchsorted(keys, pixel), 0, keys.size - 1)
            hit = keys[at] == pixel
            step = int(np.median(np.diff(t))) if len(t) > 1 else 0
            # the path covered the pixel during [first, last]; the event may follow it by up to the latency
            # (and lead it by a sample: the image moves between samples)
            gap = np.where(t_event < first[at], first[at] - t_event, np.maximum(t_event - last[at], 0))
            ok = hit & (t_event >= first[at] - step) & (t_event <= last[at] + latency_ns)
            closer = ok & (gap < best)
            best[closer] = gap[closer]
            owner[closer] = k
        signal = events.cause == EventCause.SIGNAL
        for k, object_id in enumerate(ids):
            mine = owner == k
            if not mine.any():
                continue
            totals = self.totals[object_id]
            totals[0] += mine.sum()
            totals[1] += np.count_nonzero(mine & (events.p > 0))
            totals[2] += np.count_nonzero(mine & (events.p < 0))
            totals[3] += np.count_nonzero(mine & signal)
            totals[4] += np.count_nonzero(mine & ~signal)

    # -- the figures ------------------------------------------------------------------------------------
    def summary(self) -> Metrics:
        values, units = {}, {}
        observed = with_signal = 0
        for object_id, a in sorted(self.totals.items()):
            events, on, off, signal, noise, observed_ns, peak = a
            observed += observed_ns > 0
            with_signal += signal > 0
            prefix = f"object_{object_id.replace(' ', '_')}_"
            for name, value in (("events", events), ("on_events", on), ("off_events", off),
                                ("signal_events", signal), ("noise_events", noise)):
                values[prefix + name], units[prefix + name] = int(value), "event"
            values[prefix + "snr"] = float(signal / np.sqrt(signal + noise)) if signal + noise else 0.0
            values[prefix + "observed_s"] = observed_ns / NS_PER_S
            values[prefix + "peak_magnitude"] = float(peak)
            units.update({prefix + "snr": "1", prefix + "observed_s": "s", prefix + "peak_magnitude": "mag"})
        values.update(objects_observed=int(observed), objects_with_signal=int(with_signal))
        units.update(objects_observed="1", objects_with_signal="1")
        return Metrics(values, units)


def _fresh() -> np.ndarray:
    a = np.zeros(len(COLUMNS))
    a[6] = np.nan
    return a


def passages(t, x, y, radius, width, height, step_px: float = 0.5):
    """Pixels within ``radius`` of a path and when it covered them: ``(pixel, first [ns], last [ns])``, sorted.

    The path is straight between consecutive finite samples, taken every ``step_px``
    (so the tube is exact to ``step_px / 2``); ``pixel`` is ``row * width + column``.
    """
    finite = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    if not finite.size:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    joined = np.flatnonzero(np.diff(finite) == 1)
    a, b = finite[joined], finite[joined + 1]
    n = np.maximum(1, np.ceil(np.hypot(x[b] - x[a], y[b] - y[a]) / step_px).astype(np.int64))
    segment = np.repeat(np.arange(a.size), n)
    fraction = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    px = np.concatenate([x[a][segment] + (x[b] - x[a])[segment] * fraction, x[finite]])
    py = np.concatenate([y[a][segment] + (y[b] - y[a])[segment] * fraction, y[finite]])
    pt = np.concatenate([t[a][segment] + ((t[b] - t[a])[segment] * fraction).astype(np.int64), t[finite]])
    r = int(np.ceil(radius))
    dx, dy = np.meshgrid(np.arange(-r, r + 2), np.arange(-r, r + 2))
    cx = np.floor(px).astype(np.int64)[:, None] + dx.ravel()[None]
    cy = np.floor(py).astype(np.int64)[:, None] + dy.ravel()[None]
    near = ((cx - px[:, None]) ** 2 + (cy - py[:, None]) ** 2 <= radius * radius)
    near &= (cx >= 0) & (cx < width) & (cy >= 0) & (cy < height)
    keys = (cy * width + cx)[near]
    times = np.broadcast_to(pt[:, None], near.shape)[near]
    order = np.lexsort((times, keys))
    keys, times = keys[order], times[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    ends = np.r_[starts[1:], keys.size] - 1
    return keys[starts], times[starts], times[ends]
