"""The scoring block on hand-made detections: every figure it reports is counted here independently."""

import math

import numpy as np

from evsda.blocks.detection import DetectionScoring
from evsda.blocks.ports import Detections, PointSources, SourceKind
from evsda.graph import RunInfo, Window

from .conftest import NS_PER_S, focal_plane


def sources(fp, t_ns):
    """Two sources: A moving +2 px/s in x from (10, 10), V 8; B static at (40, 40), V 11."""
    t = t_ns / NS_PER_S
    x = np.stack([10 + 2 * t, np.full_like(t, 40.0)], axis=1)
    y = np.stack([np.full_like(t, 10.0), np.full_like(t, 40.0)], axis=1)
    n = t.size
    return PointSources(fp, 550e-9, t_ns, np.array(["A", "B"]), np.full(2, SourceKind.SATELLITE, np.int8), x, y,
                        np.ones((n, 2)), np.tile([8.0, 11.0], (n, 1)), np.full((n, 2), np.inf), np.zeros(n))


def detections(fp, look_ns, starts, rows):
    """``rows``: (look start, x, y, vx, vy)."""
    rows = np.array(rows, float).reshape(-1, 5)
    t_mid = rows[:, 0].astype(np.int64) + look_ns // 2
    n = rows.shape[0]
    return Detections(fp, look_ns, 1.0, np.array(starts, np.int64), t_mid, t_mid + look_ns // 2, rows[:, 1],
                      rows[:, 2], rows[:, 3], rows[:, 4], np.full(n, 10.0), np.ones(n), np.full(n, 6.0),
                      np.full(n, 1e-6))


def test_scores_count_what_was_found():
    fp = focal_plane()
    look = NS_PER_S
    block = DetectionScoring({"match_radius_px": 2.0, "magnitude_bin_mag": 1.0}, name="score")
    block.setup(RunInfo(duration_ns=4 * look, window_ns=2 * look))
    t = np.arange(0, 2 * look, look // 100, dtype=np.int64)
    # window 1: looks 0 and 1. Look 0: A found 0.3 px off, a false alarm far away. Look 1: A found exactly.
    first = detections(fp, look, [0, look], [(0, 11.3, 10.0, 2.1, 0.0), (0, 30.0, 5.0, 0.0, 0.0),
                                             (look, 13.0, 10.0, 2.0, 0.0)])
    block.step(Window(0, 0, 2 * look), first, [sources(fp, t)])
    # window 2: looks 2 and 3. Look 2: B found 1 px off (its first detection, reported at 3 s); look 3 nothing.
    second = detections(fp, look, [2 * look, 3 * look], [(2 * look, 40.0, 41.0, 0.0, 0.0)])
    metrics = block.step(Window(1, 2 * look, 4 * look), second, [sources(fp, t + 2 * look)])["metrics"].values
    assert metrics["looks"] == 4 and metrics["detections"] == 4
    assert metrics["opportunities"] == 8 and metrics["detected_opportunities"] == 3
    assert metrics["detection_probability"] == 3 / 8
    assert metrics["pd_A"] == 0.5 and metrics["pd_B"] == 0.25
    assert metrics["pd_m8.00"] == 0.5 and metrics["opportunities_m11.00"] == 4
    assert metrics["false_alarms"] == 1
    hours, mpx = 4 / 3600, 64 * 64 / 1e6
    assert math.isclose(metrics["false_alarm_rate_per_hour_per_mpx"], 1 / (hours * mpx))
    errors = np.array([0.3, 0.0, 1.0])
    assert math.isclose(metrics["astrometric_error_px_rms"], math.sqrt(np.mean(errors**2)), rel_tol=1e-5)
    assert math.isclose(metrics["astrometric_error_arcsec_rms"],
                        metrics["astrometric_error_px_rms"] * 15e-6 / 0.085 * 180 / math.pi * 3600, rel_tol=1e-9)
    # A on the detector from t = 0, first reported at the end of look 0 (1 s); B first at the end of look 2 (3 s)
    assert metrics["first_detection_s_A"] == 1.0 and metrics["first_detection_s_B"] == 3.0
    assert metrics["time_to_first_detection_s_median"] == 2.0


def test_velocity_gate_turns_a_wrong_velocity_into_a_false_alarm():
    fp = focal_plane()
    look = NS_PER_S
    block = DetectionScoring({"match_radius_px": 2.0, "max_velocity_error_px_s": 0.5}, name="score")
    block.setup(RunInfo(duration_ns=look, window_ns=look))
    t = np.arange(0, look, look // 100, dtype=np.int64)
    found = detections(fp, look, [0], [(0, 11.0, 10.0, -2.0, 0.0)])      # right place, wrong direction
    metrics = block.step(Window(0, 0, look), found, [sources(fp, t)])["metrics"].values
    assert metrics["detected_opportunities"] == 0 and metrics["false_alarms"] == 1


def test_a_source_seen_for_part_of_a_look_is_no_false_alarm():
    """Source C enters at x = 60 at t = 0.6 s moving -2 px/s (NaN before): a detection on its track is neither a
    detected opportunity nor a false alarm; a detection off every track still is one."""
    fp = focal_plane()
    look = NS_PER_S
    t = np.arange(0, look, look // 100, dtype=np.int64)
    s = t / NS_PER_S
    x = np.where(s >= 0.6, 60 - 2 * (s - 0.6), np.nan)[:, None]
    y = np.full_like(x, 20.0)
    n = t.size
    c = PointSources(fp, 550e-9, t, np.array(["C"]), np.full(1, SourceKind.SATELLITE, np.int8), x, y, np.ones((n, 1)),
                     np.full((n, 1), 9.0), np.full((n, 1), np.inf), np.zeros(n))
    block = DetectionScoring({"match_radius_px": 2.0}, name="score")
    block.setup(RunInfo(duration_ns=look, window_ns=look))
    found = detections(fp, look, [0], [(0, 60.0, 20.0, -2.0, 0.0), (0, 30.0, 40.0, -2.0, 0.0)])
    metrics = block.step(Window(0, 0, look), found, [c])["metrics"].values
    assert metrics["opportunities"] == 0 and metrics["detections_of_partly_seen_sources"] == 1
    assert metrics["false_alarms"] == 1
