"""Paper Sec. 3 metrics: hand-counted ratios and losses, brute-force ordering errors,
delay percentiles against numpy, the background rate against an exact distance-to-path
mask, window independence, and end-to-end conservation through the arbiters."""

import numpy as np
import pytest

from evsda.blocks.ports import Events, FocalPlane, PointSources, SourceKind, TriggeredEvents
from evsda.blocks.readout import EventMetrics, IdealReadout, RowScanArbiter
from evsda.graph import RunInfo, Window

FP = FocalPlane(64, 48, 10e-6, 1.0)


def recorded(t_a, t_t, x=None, y=None, p=None, cause=None, n_dropped=0, fp=FP):
    n = len(t_a)
    z = np.zeros(n, np.int64)
    return Events(fp, np.asarray(t_t, np.int64), np.asarray(t_a, np.int64),
                  np.asarray(z if x is None else x, np.uint16), np.asarray(z if y is None else y, np.uint16),
                  np.ones(n, np.int8) if p is None else np.asarray(p, np.int8),
                  np.zeros(n, np.uint8) if cause is None else np.asarray(cause, np.uint8), n_dropped=n_dropped)


def trig(n, n_loss=0, fp=FP, cause=None):
    z = np.zeros(n, np.int64)
    c = np.zeros(n, np.uint8) if cause is None else np.asarray(cause, np.uint8)
    return TriggeredEvents(fp, z, z.astype(np.uint16), z.astype(np.uint16), np.ones(n, np.int8), c, n_loss=n_loss)


def test_ratios_and_losses_by_hand():
    """10 triggered, 5 lost in the pixels (expected 15), 7 recorded, 3 dropped by the arbiter."""
    m = EventMetrics()
    m.step(Window(0, 0, 1000), triggered=trig(10, n_loss=5, cause=[0] * 6 + [3] * 4),
           events=recorded(np.arange(7) * 10, np.arange(7) * 10, cause=[0] * 4 + [3] * 3, n_dropped=3))
    v = m.finish()["metrics"].values
    assert v["events_expected"] == 15 and v["events_pending_readout"] == 0
    assert v["ratio_recorded_to_expected"] == pytest.approx(7 / 15)
    assert v["loss_fraction_pixel"] == pytest.approx(5 / 15)
    assert v["loss_fraction_readout"] == pytest.approx(3 / 15)
    assert v["loss_to_recorded"] == pytest.approx(8 / 7)
    assert (v["events_triggered_signal"], v["events_triggered_shot"]) == (6, 4)
    assert (v["events_recorded_signal"], v["events_recorded_shot"]) == (4, 3)
    assert m.finish()["metrics"].units["ratio_recorded_to_expected"] == "1"


def test_out_of_order_by_hand():
    """t_a = 10, 20, 20, 30 with t_t = 5, 8, 3, 4: the event of t_t = 3 follows one of t_t = 5
    recorded earlier, and t_t = 4 follows t_t = 8; two of four are out of order. Events
    recorded at the same time (t_a = 20) do not count against each other."""
    m = EventMetrics()
    m.step(Window(0, 0, 100), triggered=trig(4), events=recorded([10, 20, 20, 30], [5, 8, 3, 4]))
    assert m.finish()["metrics"].values["out_of_order_fraction"] == pytest.approx(0.5)
    m = EventMetrics()
    m.step(Window(0, 0, 100), triggered=trig(2), events=recorded([10, 10], [8, 3]))
    assert m.finish()["metrics"].values["out_of_order_fraction"] == 0


def brute_out_of_order(t_a, t_t):
    return sum(any(t_t[j] > t_t[i] for j in range(len(t_a)) if t_a[j] < t_a[i]) for i in range(len(t_a)))


@pytest.mark.parametrize("seed", range(5))
def test_out_of_order_matches_brute_force_across_windows(seed):
    rng = np.random.default_rng(seed)
    n = 400
    t_a = np.sort(rng.integers(0, 300, n))                 # many ties
    t_t = t_a - rng.integers(0, 40, n)
    m = EventMetrics()
    cuts = np.sort(rng.integers(0, 300, 4))
    for i, (lo, hi) in enumerate(zip([0, *cuts], [*cuts, 300])):
        sel = (t_a >= lo) & (t_a < hi)
        m.step(Window(i, lo, hi), triggered=trig(int(sel.sum())), events=recorded(t_a[sel], t_t[sel]))
    got = m.finish()["metrics"].values["out_of_order_fraction"] * n
    assert round(got) == brute_out_of_order(t_a.tolist(), t_t.tolist())


def test_delay_distribution_against_numpy():
    rng = np.random.default_rng(2)
    delay = np.round(rng.lognormal(np.log(2_000), 1.5, 50_000)).astype(np.int64)
    delay[:100] = 0
    t_t = np.sort(rng.integers(0, 10**9, delay.size))
    order = np.argsort(t_t + delay, kind="stable")
    m = EventMetrics(bins_per_decade=100)
    m.step(Window(0, 0, 2 * 10**9), triggered=trig(delay.size),
           events=recorded((t_t + delay)[order], t_t[order]))
    v = m.finish()["metrics"].values
    assert v["readout_delay_mean_s"] == pytest.approx(delay.mean() / 1e9, rel=1e-12)
    assert v["readout_delay_max_s"] == delay.max() / 1e9
    resolution = 10 ** (1 / 100)                            # one histogram bin
    for q, name in [(50, "p50"), (90, "p90"), (99, "p99"), (99.9, "p99_9")]:
        want = np.percentile(delay, q)
        got = v[f"readout_delay_{name}_s"] * 1e9
        assert want / resolution <= got <= want * resolution, (q, got, want)


def satellite(fp, t_ns, x, y):
    n = len(t_ns)
    return PointSources(fp, 550e-9, np.asarray(t_ns, np.int64), np.array(["25544"]),
                        np.array([SourceKind.SATELLITE], np.int8), np.asarray(x, float)[:, None],
                        np.asarray(y, float)[:, None], np.ones((n, 1)), np.full((n, 1), 5.0),
                        np.full((n, 1), 5e5), np.full(n, 0.5))


def distance_to_polyline(px, py, xs, ys):
    """Distance from pixel centres to the polyline through (xs, ys) (plain geometry)."""
    best = np.full(px.shape, np.inf)
    for x0, y0, x1, y1 in zip(xs[:-1], ys[:-1], xs[1:], ys[1:]):
        dx, dy = x1 - x0, y1 - y0
        u = np.clip(((px - x0) * dx + (py - y0) * dy) / max(dx * dx + dy * dy, 1e-12), 0, 1)
        best = np.minimum(best, np.hypot(px - (x0 + u * dx), py - (y0 + u * dy)))
    return best


def test_background_rate_away_from_the_track():
    """Uniform noise plus a satellite track; the background rate counts the noise in pixels
    whose centre is farther than the track radius from the path (exact to 0.25 pixel)."""
    rng = np.random.default_rng(5)
    duration = 10**9
    n_noise = 20_000
    xs, ys = np.array([3.2, 20.0, 60.7]), np.array([40.1, 25.5, 4.3])      # a bent path, sampled 3 times
    path_t = np.array([0, 400_000_000, 900_000_000])
    t = np.sort(rng.integers(0, duration, n_noise))
    x, y = rng.integers(0, 64, n_noise), rng.integers(0, 48, n_noise)
    m = EventMetrics(track_radius_px=2.5)
    # two windows, the path's samples split between them
    for i, (lo, hi) in enumerate([(0, 500_000_000), (500_000_000, duration)]):
        sel = (t >= lo) & (t < hi)
        s = (path_t >= lo) & (path_t < hi)
        m.step(Window(i, lo, hi), triggered=trig(int(sel.sum())),
               events=recorded(t[sel], t[sel], x[sel], y[sel]), sources=satellite(FP, path_t[s], xs[s], ys[s]))
    v = m.finish()["metrics"].values
    py, px = np.mgrid[0:48, 0:64]
    d = distance_to_polyline(px.astype(float), py.astype(float), xs, ys)
    tube = (m.tracks & 1).astype(bool)
    assert np.all(tube[d <= 2.5 - 0.25]) and not np.any(tube[d > 2.5])
    counts = np.zeros((48, 64), int)
    np.add.at(counts, (y, x), 1)
    assert v["background_pixels"] == int((~tube).sum())
    assert v["background_rate_hz_per_pixel"] == pytest.approx(counts[~tube].sum() / (~tube).sum() / 1.0)
    assert v["track_events"] == counts[tube].sum()
    expected_bg = v["background_rate_hz_per_pixel"] * tube.sum()
    assert v["track_snr"] == pytest.approx((counts[tube].sum() - expected_bg) / np.sqrt(counts[tube].sum()))
    # noise only: the track holds no excess, and the rate is the injected one within Poisson error
    rate = n_noise / (64 * 48)
    assert abs(v["background_rate_hz_per_pixel"] - rate) < 5 * np.sqrt(rate / (~tube).sum())
    assert abs(v["track_snr"]) < 4


def test_window_length_does_not_change_the_metrics():
    rng = np.random.default_rng(7)
    n = 5000
    t_t = np.sort(rng.integers(0, 10**6, n))
    fp = FocalPlane(32, 32, 10e-6, 1.0)
    ev = TriggeredEvents(fp, t_t, rng.integers(0, 32, n).astype(np.uint16), rng.integers(0, 32, n).astype(np.uint16),
                         rng.choice(np.array([-1, 1], np.int8), n), rng.integers(0, 4, n).astype(np.uint8), n_loss=0)

    def run(edges):
        arb = RowScanArbiter(clock_hz=100e6, bus_throughput_eps=5e6, queue_depth=4)
        arb.setup(RunInfo(duration_ns=edges[-1], window_ns=edges[-1]))
        m = EventMetrics()
        for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
            sel = (ev.t_ns >= lo) & (ev.t_ns < hi)
            piece = TriggeredEvents(fp, ev.t_ns[sel], ev.x[sel], ev.y[sel], ev.p[sel], ev.cause[sel], n_loss=3)
            out = arb.step(Window(i, lo, hi), events=piece)["events"]
            m.step(Window(i, lo, hi), triggered=piece, events=out)
        return m.finish()["metrics"].values

    a, b = run([0, 10**6]), run([0, 123_457, 500_000, 500_001, 10**6])
    assert a["events_triggered"] == a["events_recorded"] + a["events_dropped_readout"] == n
    assert a["events_dropped_readout"] > 0 and a["out_of_order_fraction"] > 0
    for key in ("events_recorded", "events_dropped_readout", "out_of_order_fraction", "readout_delay_p50_s",
                "readout_delay_max_s", "background_rate_hz_per_pixel"):
        assert a[key] == b[key], key
    assert b["events_lost_pixel"] == 3 * 4 and a["events_lost_pixel"] == 3


def test_ideal_readout_has_no_delay_and_no_disorder():
    fp = FocalPlane(16, 16, 10e-6, 1.0)
    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 10**6, 1000))
    ev = TriggeredEvents(fp, t, rng.integers(0, 16, 1000).astype(np.uint16), rng.integers(0, 16, 1000).astype(np.uint16),
                         np.ones(1000, np.int8), np.zeros(1000, np.uint8), n_loss=10)
    out = IdealReadout().step(Window(0, 0, 10**6), events=ev)["events"]
    m = EventMetrics()
    m.step(Window(0, 0, 10**6), triggered=ev, events=out)
    v = m.finish()["metrics"].values
    assert v["readout_delay_max_s"] == 0 and v["out_of_order_fraction"] == 0
    assert v["ratio_recorded_to_expected"] == pytest.approx(1000 / 1010)
    assert v["background_rate_hz_per_pixel"] == pytest.approx(1000 / 256 / 1e-3)


def test_state_round_trip_continues_identically():
    m1, m2 = EventMetrics(), EventMetrics()
    a = recorded([10, 20, 30], [9, 5, 25], x=[1, 2, 3], y=[0, 0, 1])
    b = recorded([40, 50], [1, 45], x=[4, 5], y=[2, 2])
    m1.step(Window(0, 0, 35), triggered=trig(3), events=a)
    m1.step(Window(1, 35, 60), triggered=trig(2), events=b)
    m2.step(Window(0, 0, 35), triggered=trig(3), events=a)
    m3 = EventMetrics()
    m3.set_state(m2.get_state())
    m3.step(Window(1, 35, 60), triggered=trig(2), events=b)
    assert m1.finish()["metrics"].values == m3.finish()["metrics"].values


def test_state_round_trip_with_tracks_continues_identically():
    """The running track and background sums are worked out again from the image and tracks after a restart."""
    rng = np.random.default_rng(3)
    t = np.sort(rng.integers(0, 100, 400))
    x, y = rng.integers(0, 64, 400), rng.integers(0, 48, 400)
    windows = [(0, 50), (50, 100)]
    path = {0: ([10], [5.0], [20.0]), 1: ([60], [40.0], [30.0])}

    def step(m, i):
        lo, hi = windows[i]
        sel = (t >= lo) & (t < hi)
        return m.step(Window(i, lo, hi), triggered=trig(int(sel.sum())), events=recorded(t[sel], t[sel], x[sel], y[sel]),
                      sources=satellite(FP, *(np.asarray(v) for v in path[i])))["metrics"].values

    m1, m2 = EventMetrics(), EventMetrics()
    step(m1, 0)
    step(m2, 0)
    m3 = EventMetrics()
    m3.set_state(m2.get_state())
    assert step(m1, 1) == step(m3, 1)
    final = m3.finish()["metrics"].values
    assert final == m1.finish()["metrics"].values
    tube = (m3.tracks & 1).astype(bool)
    counts = np.zeros((48, 64), int)
    np.add.at(counts, (y, x), 1)
    assert final["track_events"] == counts[tube].sum() > 0
    assert final["background_pixels"] == (~tube).sum()
