"""The metrics block's compiled counts (evsda.blocks.readout.metric_counts) against the NumPy code they replace,
kept here as the reference: the same state (frame, track sums, causes, delay sum, maximum and histogram, ordering
state and errors) after the same windows, bit for bit."""

import numpy as np
import pytest

from evsda.blocks.ports import EventCause, Events, FocalPlane, PointSources, SourceKind, TriggeredEvents
from evsda.blocks.readout import EventMetrics
from evsda.blocks.readout.metric_counts import count_causes
from evsda.blocks.readout.metrics import SATELLITE_BIT, SOURCE_BIT, densify
from evsda.graph import Window

FP = FocalPlane(40, 30, 10e-6, 1.0)


class ReferenceMetrics(EventMetrics):
    """The metrics with a window's recorded events counted, and the sources' paths marked, by the NumPy
    expressions of before."""

    def _count_recorded(self, events: Events) -> None:
        c, fp = self.counts, events.focal_plane
        by_cause = np.bincount(events.cause, minlength=len(EventCause))[: len(EventCause)]
        c["recorded_by_cause"] = [a + int(b) for a, b in zip(c["recorded_by_cause"], by_cause)]
        index = events.y.astype(np.int64) * fp.width_px + events.x.astype(np.int64)
        sums = self._track_sums()
        np.add.at(self.image.reshape(-1), index, 1)
        marks = self.tracks.reshape(-1)[index]
        sums["events"] += index.size
        sums["source_events"] += int(np.count_nonzero(marks & SOURCE_BIT))
        sums["satellite_events"] += int(np.count_nonzero(marks & SATELLITE_BIT))
        self._reference_delays(events.t_readout_ns - events.t_trigger_ns)
        c["out_of_order"] += self._reference_out_of_order(events.t_readout_ns, events.t_trigger_ns)

    def _mark_tracks(self, sources: PointSources) -> None:
        xy = np.stack([sources.x_px, sources.y_px], axis=-1)
        if self.last_xy is not None and self.last_xy.shape[0] == xy.shape[1]:
            xy = np.concatenate([self.last_xy[None], xy])
        if xy.shape[0] == 0:
            return
        seen = np.where(np.isfinite(xy).all(axis=-1, keepdims=True), xy, np.nan)
        self.last_xy = seen[-1].copy()
        for s in np.flatnonzero(np.isfinite(seen[..., 0]).any(axis=0)):
            bit = SOURCE_BIT | (SATELLITE_BIT if sources.kind[s] == SourceKind.SATELLITE else 0)
            points = densify(seen[:, s])
            if points.size:
                self._reference_stamp(np.unique(points, axis=0), bit)

    def _reference_stamp(self, points: np.ndarray, bit: int) -> None:
        h, w = self.tracks.shape
        r = self.params.track_radius_px
        px = np.floor(points[:, 0]).astype(np.int64)[:, None] + self._box[:, 0]
        py = np.floor(points[:, 1]).astype(np.int64)[:, None] + self._box[:, 1]
        dx, dy = px - points[:, :1], py - points[:, 1:]
        near = dx * dx + dy * dy <= r * r
        near &= (px >= 0) & (px < w) & (py >= 0) & (py < h)
        index = np.unique(py[near] * w + px[near])
        tracks, image, sums = self.tracks.reshape(-1), self.image.reshape(-1), self._track_sums()
        for mark, name in ((SOURCE_BIT, "source"), (SATELLITE_BIT, "satellite")):
            if bit & mark:
                new = (tracks[index] & mark) == 0
                sums[f"{name}_pixels"] += int(np.count_nonzero(new))
                sums[f"{name}_events"] += int(image[index][new].sum())
        tracks[index] |= np.uint8(bit)

    def _reference_delays(self, delay_ns: np.ndarray) -> None:
        c = self.counts
        c["delay_sum_ns"] += float(np.sum(delay_ns, dtype=np.float64))
        c["delay_max_ns"] = max(c["delay_max_ns"], int(delay_ns.max()))
        k = self.params.bins_per_decade
        positive = delay_ns > 0
        if positive.all():
            bins = 1 + np.floor(np.log10(delay_ns) * k).astype(np.int64)
        else:
            bins = np.zeros(delay_ns.size, np.int64)
            bins[positive] = 1 + np.floor(np.log10(delay_ns[positive]) * k).astype(np.int64)
        self.delays += np.bincount(np.minimum(bins, self.delays.size - 1), minlength=self.delays.size)

    def _reference_out_of_order(self, t_a: np.ndarray, t_t: np.ndarray) -> int:
        o = self.order
        new_group = np.empty(t_a.size, bool)
        new_group[0] = t_a[0] != o["last_t_a"]
        np.not_equal(t_a[1:], t_a[:-1], out=new_group[1:])
        running = np.maximum.accumulate(t_t)
        if new_group.all():
            before = np.empty(t_a.size, np.int64)
            before[0] = np.iinfo(np.int64).min
            before[1:] = running[:-1]
            np.maximum(before, o["max_all"], out=before)
        else:
            start = np.maximum.accumulate(np.where(new_group, np.arange(t_a.size), 0))
            before = np.where(start > 0, running[np.maximum(start - 1, 0)], np.iinfo(np.int64).min)
            carried = np.where(~new_group[0] & (start == 0), o["max_before_last"], o["max_all"])
            before = np.maximum(before, carried)
        o["max_before_last"] = int(before[-1])
        o["max_all"] = max(o["max_all"], int(running[-1]))
        o["last_t_a"] = int(t_a[-1])
        return int(np.count_nonzero(t_t < before))


def window_events(rng, start: int, n: int, spread: int, ties: bool, long_delays: bool) -> Events:
    """``n`` recorded events in readout order: delays of 0, negative ones now and then, and (``long_delays``)
    some whose magnitudes add past 2**53 (the delay sum then NumPy's own)."""
    t_a = np.sort(start + rng.integers(0, 1000 if ties else 10**9, n))
    delay = np.round(rng.lognormal(np.log(spread), 2.0, n)).astype(np.int64)
    delay[rng.random(n) < 0.05] = 0
    delay[rng.random(n) < 0.01] *= -1
    if long_delays:
        delay[rng.random(n) < 0.1] = 2**52 + rng.integers(0, 2**40, 1)
    x = rng.integers(0, FP.width_px, n).astype(np.uint16)
    y = rng.integers(0, FP.height_px, n).astype(np.uint16)
    cause = rng.integers(0, len(EventCause) + 2, n).astype(np.uint8)       # some past the causes' end
    return Events(FP, t_a - delay, t_a, x, y, np.ones(n, np.int8), cause)


def sources(rng, n_t: int) -> PointSources:
    """A satellite and two stars wandering (a step of 0 to 15 pixels), now and then unseen or off the frame, and
    a slow one repeating its places."""
    x = np.cumsum(rng.normal(0, rng.choice([0.0, 1.5, 15.0]), (n_t, 3)), axis=0) + [10, 20, 30]
    y = np.cumsum(rng.normal(0, 1.5, (n_t, 3)), axis=0) + [15, 10, 20]
    x[rng.random((n_t, 3)) < 0.15] = np.nan
    y[rng.random((n_t, 3)) < 0.05] = -50.0
    x[:, 2] = np.round(x[:, 2], 1)
    kind = np.array([SourceKind.SATELLITE, SourceKind.STAR, SourceKind.STAR], np.int8)
    ones = np.ones((n_t, 3))
    return PointSources(FP, 550e-9, np.zeros(n_t, np.int64), np.array(["a", "b", "c"]), kind, x, y, ones, ones, ones,
                        np.zeros(n_t))


def state(block: EventMetrics) -> tuple:
    return (block.counts, block.delays.tobytes(), block.image.tobytes(), block.tracks.tobytes(),
            block._track_sums(), block.order)


@pytest.mark.parametrize("seed", range(12))
def test_compiled_counts_equal_numpys(seed):
    rng = np.random.default_rng(seed)
    ties, long_delays = seed % 2 == 0, seed % 3 == 2
    fast, reference = EventMetrics(), ReferenceMetrics()
    for i in range(10):
        n = int(rng.integers(1, 400)) if i != 3 else 0
        events = window_events(rng, i * 10**9, n, 10 ** int(rng.integers(1, 7)), ties, long_delays)
        triggered = TriggeredEvents(FP, events.t_trigger_ns, events.x, events.y, events.p, events.cause)
        seen = sources(rng, int(rng.integers(1, 12))) if i % 2 else None
        outputs = [block.step(Window(i, i * 10**9, (i + 1) * 10**9), triggered=triggered, events=events,
                              sources=seen)["metrics"] for block in (fast, reference)]
        assert outputs[0].values == outputs[1].values
        assert state(fast) == state(reference)
    assert fast.finish()["metrics"].values == reference.finish()["metrics"].values


def test_causes_counted_as_bincount():
    cause = np.random.default_rng(1).integers(0, 9, 1000).astype(np.uint8)
    by_cause = np.zeros(len(EventCause), np.int64)
    count_causes(cause, by_cause)
    assert by_cause.tolist() == np.bincount(cause, minlength=len(EventCause))[: len(EventCause)].tolist()


def test_an_event_outside_the_frame_is_an_error():
    block = EventMetrics()
    events = Events(FP, np.zeros(2, np.int64), np.ones(2, np.int64), np.array([1, FP.width_px], np.uint16),
                    np.zeros(2, np.uint16), np.ones(2, np.int8), np.zeros(2, np.uint8))
    with pytest.raises(IndexError):
        block.step(Window(0, 0, 10), triggered=TriggeredEvents.empty(FP), events=events)
