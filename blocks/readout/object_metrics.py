"""Per-object figures of a run with many satellites: the events each object caused, by space and time.

An event belongs to a satellite when its pixel centre lies within ``track_radius_px`` of
the path the satellite drew on the focal plane during the ``latency_s`` before the event
fired (the pixels answer a passing image with some delay, and the OFF events trail it);
an event near several satellites belongs to the nearest. The counts split by the
simulation's own cause label (:class:`~evsda.blocks.ports.EventCause`): signal events
are what a perfect detector could use, the others are noise (leak, parasitic, shot)
that happened to fall in the object's space-time tube. A path is straight between
consecutive samples (``PointSources`` cadence), so objects crossing each other's paths
at different times (a train of satellites on one track) are told apart by time.

Figures per satellite source id ``ID`` (the NORAD number for catalogued objects), all
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
        latency_s: float = Field(0.05, ge=0, le=10, description="How long after the object passed a pixel its "
                                 "events still belong to it (pixel latency, OFF trail) [s]")

    inputs = {
        "events": Input(Events, "events as the readout records them"),
        "sources": Input(PointSources, "satellites (stars are ignored), one or more blocks", multi=True),
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
                if src.kind[j] != SourceKind.SATELLITE:
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

    def _attribute(self, events: Events, tracks: dict[str, tuple]) -> None:
        """Give each event to the nearest object whose recent path passes within the track radius."""
        radius = self.params.track_radius_px
        latency_ns = round(self.params.latency_s * NS_PER_S)
        ex = events.x.astype(np.float64)
        ey = events.y.astype(np.float64)
        et = events.t_trigger_ns.astype(np.int64)
        best = np.full(len(events), np.inf)
        owner = np.full(len(events), -1)
        ids = list(tracks)
        for k, object_id in enumerate(ids):
            t, x, y = tracks[object_id]
            finite = np.isfinite(x)
            box = ((ex >= np.nanmin(x) - radius - 1) & (ex <= np.nanmax(x) + radius + 1)
                   & (ey >= np.nanmin(y) - radius - 1) & (ey <= np.nanmax(y) + radius + 1))
            candidates = np.flatnonzero(box)
            if not candidates.size:
                continue
            distance = _path_distance(t, x, y, finite, ex[candidates], ey[candidates], et[candidates], latency_ns)
            closer = (distance <= radius) & (distance < best[candidates])
            best[candidates[closer]] = distance[closer]
            owner[candidates[closer]] = k
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
            prefix = f"object_{object_id}_"
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


def _path_distance(t, x, y, finite, ex, ey, et, latency_ns) -> np.ndarray:
    """Distance [pixel] from each event to the object's path drawn in ``[t_event - latency, t_event]``.

    The path is the straight segments between consecutive finite samples; an event
    before the first sample in that range uses the segment into it.
    """
    n = len(t)
    hi = np.clip(np.searchsorted(t, et, side="right") - 1, 0, n - 1)
    lo = np.clip(np.searchsorted(t, et - latency_ns, side="left") - 1, 0, n - 1)
    span = int((hi - lo).max(initial=0)) + 1
    best = np.full(len(et), np.inf)
    for d in range(span):
        a = np.minimum(lo + d, hi)
        b = np.minimum(a + 1, n - 1)
        ok = finite[a] & finite[b] & (b <= np.maximum(hi, a + 1))
        single = finite[a] & ~ok
        ax, ay = x[a], y[a]
        bx, by = np.where(ok, x[b], ax), np.where(ok, y[b], ay)
        dx, dy = bx - ax, by - ay
        length2 = dx * dx + dy * dy
        with np.errstate(invalid="ignore", divide="ignore"):
            s = np.clip(np.where(length2 > 0, ((ex - ax) * dx + (ey - ay) * dy) / length2, 0.0), 0.0, 1.0)
        distance = np.hypot(ex - (ax + s * dx), ey - (ay + s * dy))
        distance = np.where(ok | single, distance, np.inf)
        best = np.minimum(best, np.nan_to_num(distance, nan=np.inf))
    return best
