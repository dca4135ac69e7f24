"""The frame detector on Gaussian frames, the Poisson and Gaussian thresholds against scipy's tails, and the
logistic fit of the study against binomial draws of a known curve."""

import math

import numpy as np
import pytest
from scipy import stats

from evsda.blocks.detection import FrameDetector
from evsda.blocks.detection.significance import local_p_threshold, poisson_count_threshold, poisson_p_value
from evsda.blocks.detection.study import fit_logistic, parse_ladder
from evsda.blocks.ports import Frame
from evsda.graph import RunInfo, UserError, Window

from .conftest import NS_PER_S, focal_plane


def frames(rng, fp, n, sources=(), sigma=5.0, level=100.0):
    image = rng.normal(level, sigma, (n, fp.height_px, fp.width_px))
    for x, y, total in sources:                   # a source spread evenly over 2 x 2 pixels
        image[:, y:y + 2, x:x + 2] += total / 4
    return Frame(fp, np.arange(n, dtype=np.int64) * NS_PER_S, NS_PER_S, np.rint(image).astype(np.uint16))


def run(block, frame):
    block.setup(RunInfo(duration_ns=frame.t_start_ns.size * NS_PER_S, window_ns=NS_PER_S))
    return block.step(Window(0, 0, frame.t_start_ns.size * NS_PER_S), frame)["detections"]


def test_frame_detector_finds_a_source_at_its_centroid(rng):
    fp = focal_plane()
    found = run(FrameDetector({}, name="d"), frames(rng, fp, 3, [(20, 30, 200.0)]))
    assert len(found) == 3
    np.testing.assert_allclose(found.x_px, 20.5, atol=0.3)
    np.testing.assert_allclose(found.y_px, 30.5, atol=0.3)
    # box sum 200 DN over noise 2 x 5 DN: 20 sigma, give or take the box's own noise (1 sigma)
    np.testing.assert_allclose(found.significance_sigma, 20.0, atol=4.0)
    np.testing.assert_allclose(found.counts, 200.0, atol=40.0)
    assert np.isnan(found.vx_px_s).all()


def test_frame_detector_false_alarms_under_the_rate_set(rng):
    fp = focal_plane()
    far = 3e5                                       # 0.34 per 1 s frame of 64 x 64 pixels at most
    found = run(FrameDetector({"false_alarm_rate_per_hour_per_mpx": far}, name="d"), frames(rng, fp, 40))
    bound = far * 40 / 3600 * fp.width_px * fp.height_px / 1e6
    assert len(found) <= stats.poisson.isf(1e-4, bound)
    lax = run(FrameDetector({"false_alarm_rate_per_hour_per_mpx": far * 1e4}, name="d"), frames(rng, fp, 40))
    assert len(lax) > 10 * max(len(found), 1)


@pytest.mark.parametrize("mu", [0.0, 0.05, 1.5, 30.0, 400.0])
def test_poisson_threshold_is_the_smallest_count_below_p(mu):
    p = 3e-7
    k = poisson_count_threshold(mu, p)
    assert stats.poisson.sf(k - 1, mu) <= p
    if k > 1:
        assert stats.poisson.sf(k - 2, mu) > p
    np.testing.assert_allclose(poisson_p_value(k, mu), stats.poisson.sf(k - 1, mu), rtol=1e-9, atol=1e-300)


def test_local_threshold_is_the_rate_shared_over_the_trials():
    # 1 false alarm per hour per megapixel, 1 s looks of 1 Mpx with 10 trials per pixel
    assert math.isclose(local_p_threshold(1.0, 1.0, 1_000_000, 10_000_000), 1 / 3600 / 1e7)


def test_logistic_fit_recovers_a_known_curve():
    rng = np.random.default_rng(7)
    m = np.arange(8.0, 13.01, 0.25)
    n = np.full(m.size, 200)
    truth_m50, truth_w = 10.6, 0.35
    k = rng.binomial(n, 1 / (1 + np.exp((m - truth_m50) / truth_w)))
    fit = fit_logistic(m, n, k)
    assert abs(fit["m50"] - truth_m50) < 3 * fit["m50_err"] and 0.005 < fit["m50_err"] < 0.1
    truth_m90 = truth_m50 - truth_w * math.log(9)
    assert abs(fit["m90"] - truth_m90) < 3 * fit["m90_err"]
    assert fit["brackets"]
    assert math.isnan(fit_logistic(m, n, np.zeros_like(n))["m50"])      # nothing detected: no limit to fit
    # P_d jumping from 1 to 0 between two rungs: the 50 % point is somewhere between them
    gap = fit_logistic([8, 9, 10, 11], [5, 5, 5, 5], [5, 5, 0, 0])
    assert (gap["m50"], gap["m50_err"], gap["gap"]) == (9.5, 0.5, (9.0, 10.0)) and math.isnan(gap["m90"])


def test_ladder_parsing():
    assert parse_ladder("8:9:0.5") == [8.0, 8.5, 9.0]
    assert parse_ladder("10,8.5") == [8.5, 10.0]
    for bad in ("8:7:0.5", "8:9:0", "eight", ""):
        with pytest.raises(UserError, match="START:STOP:STEP"):
            parse_ladder(bad)
