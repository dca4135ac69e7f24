"""The event detector on synthetic streams: it finds a moving source where it is, at its velocity, holds its
false alarms under the rate it was set for, does not depend on the executor's windows, and refuses a run
without events. The matched filter's compiled box search is checked against a brute-force count."""

import numpy as np
import pytest
from scipy import stats

from evsda.blocks.detection import EventDetector
from evsda.blocks.detection import matched_filter as mf
from evsda.graph import RunInfo, SceneError, Window

from .conftest import NS_PER_S, focal_plane, synthetic_events


def run_detector(events, duration_s, windows=1, **params):
    detector = EventDetector(params, name="detector", seed=0)
    duration_ns = round(duration_s * NS_PER_S)
    detector.setup(RunInfo(duration_ns=duration_ns, window_ns=duration_ns // windows))
    edges = np.linspace(0, duration_ns, windows + 1).astype(np.int64)
    out = []
    for k in range(windows):
        mine = (events.t_readout_ns >= edges[k]) & (events.t_readout_ns < edges[k + 1])
        part = type(events)(events.focal_plane, events.t_trigger_ns[mine], events.t_readout_ns[mine],
                            events.x[mine], events.y[mine], events.p[mine], events.cause[mine])
        out.append(detector.step(Window(k, int(edges[k]), int(edges[k + 1])), part)["detections"])
    detector.finish()
    return out


def test_moving_source_found_at_its_position_and_velocity(rng):
    fp = focal_plane()
    track = (20.0, 30.0, 3.0, -2.0, 40.0)          # x0, y0 [px], vx, vy [px/s], 40 events/s
    events = synthetic_events(rng, fp, 2.0, 0.3, [track])
    found = run_detector(events, 2.0, look_s=1.0, max_rate_px_s=5.0)[0]
    assert found.look_start_ns.tolist() == [0, NS_PER_S]
    assert len(found) == 2                          # one per look, no false alarm
    t = found.t_ns / NS_PER_S
    np.testing.assert_allclose(found.x_px, 20 + 3 * t, atol=0.7)
    np.testing.assert_allclose(found.y_px, 30 - 2 * t, atol=0.7)
    np.testing.assert_allclose(found.vx_px_s, 3.0, atol=0.6)
    np.testing.assert_allclose(found.vy_px_s, -2.0, atol=0.6)
    assert (found.significance_sigma > 5).all()
    assert (found.t_reported_ns == found.t_ns + NS_PER_S // 2).all()


def test_false_alarms_stay_under_the_rate_set(rng):
    """Background alone: the Bonferroni threshold bounds the expected false alarms by the rate set."""
    fp = focal_plane()
    far = 2e5                                      # [h^-1 Mpixel^-1]: 0.23 per 1 s look on 64 x 64 pixels
    looks = 40
    events = synthetic_events(rng, fp, looks, 0.5)
    found = run_detector(events, looks, windows=4, look_s=1.0, max_rate_px_s=2.0,
                         false_alarm_rate_per_hour_per_mpx=far)
    n = sum(len(d) for d in found)
    bound = far * looks / 3600 * fp.width_px * fp.height_px / 1e6
    assert n <= stats.poisson.isf(1e-4, bound)
    # the same stream with a 10^4 times laxer threshold finds many: the threshold is what holds them
    lax = run_detector(events, looks, look_s=1.0, max_rate_px_s=2.0, false_alarm_rate_per_hour_per_mpx=far * 1e4)
    assert sum(len(d) for d in lax) > 10 * max(n, 1)


def test_results_do_not_depend_on_the_windows(rng):
    fp = focal_plane()
    events = synthetic_events(rng, fp, 3.0, 0.3, [(10.0, 10.0, 4.0, 5.0, 30.0), (50.0, 40.0, -2.0, 1.0, 25.0)])
    one = run_detector(events, 3.0, windows=1, look_s=1.0, max_rate_px_s=8.0)
    seven = run_detector(events, 3.0, windows=7, look_s=1.0, max_rate_px_s=8.0)
    cat = {f: np.concatenate([getattr(d, f) for d in seven]) for f in ("t_ns", "x_px", "y_px", "vx_px_s")}
    assert len(one[0]) == cat["t_ns"].size == 6
    for f, values in cat.items():
        np.testing.assert_array_equal(getattr(one[0], f), values)


def test_a_hot_pixel_is_left_out_after_three_looks(rng):
    """A pixel firing at 30 Hz in every look is a detection until it has been marked hot in hot_pixel_looks (3)
    looks; a source moving at 3 px/s beside it is found in every look."""
    fp = focal_plane()
    events = synthetic_events(rng, fp, 6.0, 0.3, [(40.0, 12.0, 0.0, 0.0, 30.0), (10.0, 50.0, 3.0, 0.0, 30.0)])
    found = run_detector(events, 6.0, look_s=1.0, max_rate_px_s=4.0)[0]
    at_hot = np.hypot(found.x_px - 40, found.y_px - 12) < 2
    assert sorted(found.t_ns[at_hot] // NS_PER_S) == [0, 1, 2]
    assert np.unique(found.t_ns[~at_hot]).size == 6 and (~at_hot).sum() == 6


def test_no_events_is_one_clear_error():
    fp = focal_plane()
    empty = synthetic_events(np.random.default_rng(0), fp, 1.0, 0.0)
    with pytest.raises(SceneError, match="recorded no events"):
        run_detector(empty, 1.0, look_s=0.5)


def test_thinning_merges_a_pixels_rebound():
    t = np.array([0, 50_000, 2_000_000, 2_000_100, 9_000_000], np.int64)
    pixel = np.array([3, 3, 3, 4, 3], np.int64)
    last = np.full(8, -10**12, np.int64)
    counts = np.zeros(8, np.int32)
    keep = mf.thin_events(t, pixel, last, counts, 1_000_000, 0)
    assert keep.tolist() == [True, False, True, True, True]
    counts[:] = 0
    last[:] = -10**12
    assert mf.thin_events(t, pixel, last, counts, 0, 2).tolist() == [True, True, False, True, False]


def test_box_search_matches_brute_force(rng):
    width, height, box, pad = 20, 16, 2, 3
    n = 300
    t = rng.uniform(-0.5, 0.5, n)
    x = rng.integers(0, width, n).astype(float)
    y = rng.integers(0, height, n).astype(float)
    velocities = mf.velocity_grid(3.0, 0.0, 1.0, 1.0)
    rows, found = mf.candidate_boxes(t, x, y, velocities, box, pad, width, height, 4, 1 << 16)
    got = {tuple(r) for r in rows[:found]}
    expected = set()
    for k, (vx, vy) in enumerate(velocities):
        i = np.floor(x - vx * t + 0.5).astype(int) + pad
        j = np.floor(y - vy * t + 0.5).astype(int) + pad
        image = np.zeros((height + 2 * pad, width + 2 * pad), int)
        ok = (i >= 0) & (j >= 0) & (i < width + 2 * pad) & (j < height + 2 * pad)
        np.add.at(image, (j[ok], i[ok]), 1)
        sums = np.array([[image[j0:j0 + box, i0:i0 + box].sum() for i0 in range(image.shape[1] - box + 1)]
                         for j0 in range(image.shape[0] - box + 1)])
        padded = np.pad(sums, 1, constant_values=-1)
        for j0, i0 in zip(*np.nonzero(sums >= 4)):
            if sums[j0, i0] >= padded[j0:j0 + 3, i0:i0 + 3].max():        # a local maximum (ties kept)
                expected.add((k, i0, j0, sums[j0, i0]))
    assert got == expected and len(expected) > 5 and len(got) == found       # each box once per velocity


def test_velocity_grid_and_exposure_fraction():
    grid = mf.velocity_grid(2.0, 1.0, 0.5, 1.0)       # spacing 2 px/s: (+-2, 0), (0, +-2)
    assert sorted(map(tuple, grid)) == [(-2.0, 0.0), (0.0, -2.0), (0.0, 2.0), (2.0, 0.0)]
    # a box at the centre of a 10-pixel detector moving 10 px/s is on it for the middle 1 s of a 2 s look
    np.testing.assert_allclose(mf.exposure_fraction(4.5, 4.5, 10.0, 0.0, 2.0, 10, 10), 0.5)
    np.testing.assert_allclose(mf.exposure_fraction(4.5, 4.5, 0.0, 0.0, 2.0, 10, 10), 1.0)
    np.testing.assert_allclose(mf.exposure_fraction(-3.0, 4.5, 0.0, 0.0, 2.0, 10, 10), 0.0)
