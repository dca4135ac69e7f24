"""End to end, scenes (b) and (c): a GEO under sidereal tracking, and a space-based observer.

Small versions of ``examples/geo_sidereal.yaml`` and ``examples/space_based.yaml`` (the same
fields on sensors of half the pixels per side and doubled pitch, under a second) run through
orbit (SGP4) -> radiometry -> optics -> DVS pixels -> row-scan arbiter -> Zarr store. The
checks are physics-level facts that no single stage guarantees on its own. The scenes aim
their boresights with Skyfield, independently of the scene blocks: the target must sit at
the detector's centre at mid-run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evsda.blocks.ports import EventCause
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
EARTH_ROTATION_ARCSEC_S = np.degrees(7.2921150e-5) * 3600   # IERS Conventions (2010) Table 1.1 [arcsec s^-1]


def half_size_sensor(width_px: int, height_px: int, pitch_m: float) -> dict:
    """Overrides of ``sensor/camera`` that keep the field with half the pixels per side."""
    return {"sensor/camera.width_px": width_px // 2, "sensor/camera.height_px": height_px // 2,
            "sensor/camera.pixel_pitch_m": 2 * pitch_m}


def run_small(path: Path, overrides: dict, out: Path) -> dict:
    result = run_graph(load_graph(path, overrides), out, progress=False)
    store = RunStore.open(out)
    events = {k: np.concatenate([c[k] for c in store.iter_events()])
              for k in ("t_trigger_ns", "t_readout_ns", "x", "y", "p", "cause")}
    return {"result": result, "store": store, "events": events, "out": out}


def source_tracks(store: RunStore, block: str):
    """Sample times [ns] and positions ``[n_t, n_src]`` [pixel] of a block's stored PointSources."""
    windows = list(store.product_windows(block, "sources"))
    return (np.concatenate([w.t_ns for w in windows]), np.concatenate([w.x_px for w in windows]),
            np.concatenate([w.y_px for w in windows]), windows[0].focal_plane)


def offsets_from(events, t, x, y):
    """Event positions minus the source's position at each event's trigger time [pixel]."""
    return (events["x"] - np.interp(events["t_trigger_ns"], t, x),
            events["y"] - np.interp(events["t_trigger_ns"], t, y))


def check_event_accounting(run):
    m, events = run["result"].metrics, run["events"]
    assert m["events_recorded"] > 0
    assert m["events_triggered"] == m["events_recorded"] + m["events_dropped_readout"] + m["events_pending_readout"]
    assert run["store"].n_events == m["events_recorded"] == len(events["x"])
    assert RunStore.open(run["out"]).metrics["events_recorded"] == m["events_recorded"]
    assert np.all(events["t_readout_ns"] >= events["t_trigger_ns"])


# --- (b) GEO under sidereal tracking --------------------------------------------------------

GEO = EXAMPLES / "geo_sidereal.yaml"
GEO_SMALL = {"run.start": "2013-03-24T09:40:01.5Z", "run.duration_s": 1.0, "run.store_products": ["sat", "stars"], "stars.faint_limit_mag": 11.0,
             **half_size_sensor(1280, 720, 4.86e-6)}


@pytest.fixture(scope="module")
def geo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("geo") / "geo.zarr"
    return run_small(GEO, dict(GEO_SMALL), out)


def test_geo_events_are_all_accounted_for(geo_run):
    check_event_accounting(geo_run)


def test_geo_drifts_at_the_earth_rotation_rate_through_the_centre(geo_run):
    t, x, y, fp = source_tracks(geo_run["store"], "sat")
    x, y = x[:, 0], y[:, 0]
    scale_arcsec = np.degrees(fp.pixel_scale_rad) * 3600
    # the field was aimed (Skyfield) at the GEO's apparent place at mid-run
    mid = np.searchsorted(t, (t[0] + t[-1]) // 2)
    assert np.hypot(x[mid] - (fp.width_px - 1) / 2, y[mid] - (fp.height_px - 1) / 2) < 0.5
    # a geostationary object keeps pace with the Earth: it drifts east (image left, north up)
    # through the stars at the Earth's rotation rate times cos(declination), to ~0.5 % from the
    # topocentric parallax of a 17.6 deg elevation, 39 800 km away
    rate_arcsec_s = np.polyfit(t * 1e-9, x, 1)[0] * scale_arcsec
    assert rate_arcsec_s == pytest.approx(-EARTH_ROTATION_ARCSEC_S * np.cos(np.radians(-3.04)), rel=0.01)
    assert np.ptp(y) < 0.05


def test_geo_events_follow_it_while_the_stars_stay_put(geo_run):
    events = geo_run["events"]
    t, x, y, _ = source_tracks(geo_run["store"], "sat")
    _, sx, sy, _ = source_tracks(geo_run["store"], "stars")
    in_field = ~np.isnan(sx).all(axis=0)
    sx, sy = sx[:, in_field], sy[:, in_field]
    assert sx.shape[1] >= 1
    # sidereal tracking: the stars' images do not move (to a thousandth of a pixel)
    assert np.nanmax(np.abs(sx - sx[0])) < 1e-3 and np.nanmax(np.abs(sy - sy[0])) < 1e-3
    signal = events["cause"] == EventCause.SIGNAL
    dx, dy = offsets_from(events, t, x[:, 0], y[:, 0])
    on_geo = signal & (np.hypot(dx, dy) < 3)
    star_distance = np.min(np.hypot(events["x"][:, None] - sx[0], events["y"][:, None] - sy[0]), axis=1)
    on_star = signal & ~on_geo & (star_distance < 4)
    assert on_geo.sum() > 20 and on_star.sum() > 100
    # every signal event belongs to the GEO or to a star: nothing else changes in the field
    assert (on_geo | on_star).sum() >= 0.99 * signal.sum()
    # the GEO's events sit on its predicted position (centroid within a pixel) ...
    assert abs(dx[on_geo].mean()) < 1.0 and abs(dy[on_geo].mean()) < 1.0, (dx[on_geo].mean(), dy[on_geo].mean())
    # ... and move with it, while the stars' events (scintillation, image motion) stay put
    t_mid = (t[0] + t[-1]) / 2
    early, late = events["t_trigger_ns"] < t_mid, events["t_trigger_ns"] >= t_mid
    geo_shift = events["x"][on_geo & late].mean() - events["x"][on_geo & early].mean()
    expected_shift = np.interp(t_mid + (t[-1] - t[0]) / 4, t, x[:, 0]) - np.interp(t_mid - (t[-1] - t[0]) / 4, t, x[:, 0])
    assert geo_shift == pytest.approx(expected_shift, abs=1.0)
    assert expected_shift < -3.0
    nearest_star = np.argmin(np.hypot(events["x"][:, None] - sx[0], events["y"][:, None] - sy[0]), axis=1)
    checked = 0
    for star in range(sx.shape[1]):
        mine = on_star & (nearest_star == star)
        if (mine & early).sum() < 20 or (mine & late).sum() < 20:
            continue
        checked += 1
        for c in ("x", "y"):
            assert abs(events[c][mine & late].mean() - events[c][mine & early].mean()) < 0.5
    assert checked >= 1


# --- (c) a space-based observer ------------------------------------------------------------

SPACE = EXAMPLES / "space_based.yaml"
SPACE_SMALL = {"run.start": "2023-03-19T20:57:44.8Z", "run.duration_s": 0.4, "run.store_products": ["sat"],
               "stars.faint_limit_mag": 9.0, **half_size_sensor(640, 480, 15.0e-6)}
SPACE_MID_NS = 200_000_000     # 2023-03-19T20:57:45Z, where the stare was aimed


@pytest.fixture(scope="module")
def space_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("space") / "space.zarr"
    return run_small(SPACE, dict(SPACE_SMALL), out)


def test_space_events_are_all_accounted_for(space_run):
    check_event_accounting(space_run)


def test_space_target_crosses_the_centre_of_the_stare(space_run):
    t, x, y, fp = source_tracks(space_run["store"], "sat")
    assert not np.isnan(x).any()
    k = np.searchsorted(t, SPACE_MID_NS)
    assert np.hypot(x[k, 0] - (fp.width_px - 1) / 2, y[k, 0] - (fp.height_px - 1) / 2) < 0.5
    # along the image's x axis: the stare was set at the target's azimuth rate, elevation fixed
    assert np.ptp(y[:, 0]) < 0.2 and x[-1, 0] - x[0, 0] > 15


def test_space_track_events_follow_the_target(space_run):
    events = space_run["events"]
    t, x, y, _ = source_tracks(space_run["store"], "sat")
    x, y = x[:, 0], y[:, 0]
    dx, dy = offsets_from(events, t, x, y)
    track = (events["cause"] == EventCause.SIGNAL) & (np.hypot(dx, dy) < 4)
    assert track.sum() > 60
    offsets = []
    for lo in np.arange(t[0], t[-1] - 40_000_000, 40_000_000):          # 40 ms bins
        sel = track & (events["t_trigger_ns"] >= lo) & (events["t_trigger_ns"] < lo + 40_000_000)
        if sel.sum() >= 6:
            offsets.append((dx[sel].mean(), dy[sel].mean()))
    offsets = np.array(offsets)
    assert len(offsets) >= 7
    assert np.all(np.hypot(offsets[:, 0], offsets[:, 1]) < 1.0), offsets
    # the target's leading edge brightens pixels (ON), its trailing edge darkens them (OFF)
    on, off = track & (events["p"] > 0), track & (events["p"] < 0)
    assert on.sum() > 25 and off.sum() > 25
    assert dx[on].mean() > dx[off].mean() + 0.5
