"""End to end, scene (a): the ISS crossing a staring Gen4 sensor, through every stage family.

orbit (SGP4) -> radiometry -> optics with turbulence -> DVS pixels -> row-scan arbiter ->
Zarr store, on a small version of ``examples/iss_pass.yaml`` (the same field on a 640 x 360
sensor of doubled pitch, 0.4 s while the ISS is in the field). The checks are physics-level
facts that no single stage guarantees on its own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import EventCause, FocalPlane, Irradiance
from evsda.graph import RunInfo, Window
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

SCENE = Path(__file__).resolve().parents[1] / "examples" / "iss_pass.yaml"
SMALL = {
    "run.start": "2023-03-20T19:18:39.4Z", "run.duration_s": 0.4, "run.store_products": ["sat", "telescope/optics"],
    "sensor/camera.width_px": 640, "sensor/camera.height_px": 360, "sensor/camera.pixel_pitch_m": 9.72e-6,
    "stars.faint_limit_mag": 9.0,
}


@pytest.fixture(scope="module")
def iss_run(tmp_path_factory):
    graph = load_graph(SCENE, dict(SMALL))
    out = tmp_path_factory.mktemp("e2e") / "iss.zarr"
    result = run_graph(graph, out, progress=False)
    store = RunStore.open(out)
    events = {k: np.concatenate([c[k] for c in store.iter_events()]) for k in ("t_trigger_ns", "x", "y", "p", "cause")}
    sources = list(store.product_windows("sat", "sources"))
    irradiance = list(store.product_windows("telescope/optics", "irradiance"))
    return graph, result, store, events, sources, irradiance


def satellite_track(sources):
    t = np.concatenate([s.t_ns for s in sources])
    x = np.concatenate([s.x_px[:, 0] for s in sources])
    y = np.concatenate([s.y_px[:, 0] for s in sources])
    return t, x, y


def test_every_triggered_event_is_recorded_or_dropped(iss_run):
    _, result, store, events, _, _ = iss_run
    m = result.metrics
    assert m["events_triggered"] > 0
    assert m["events_triggered"] == m["events_recorded"] + m["events_dropped_readout"] + m["events_pending_readout"]
    assert store.n_events == m["events_recorded"] == len(events["x"])


def test_track_events_follow_the_projected_satellite_path(iss_run):
    _, _, _, events, sources, _ = iss_run
    t, x, y = satellite_track(sources)
    signal = events["cause"] == EventCause.SIGNAL
    near_track = signal & (np.hypot(events["x"] - np.interp(events["t_trigger_ns"], t, x),
                                     events["y"] - np.interp(events["t_trigger_ns"], t, y)) < 6)
    assert near_track.sum() > 1000
    edges = np.arange(t[0], t[-1], 20_000_000)            # 20 ms bins
    offsets = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = near_track & (events["t_trigger_ns"] >= lo) & (events["t_trigger_ns"] < hi)
        if sel.sum() < 50:
            continue
        t_mid = events["t_trigger_ns"][sel].mean()
        offsets.append((events["x"][sel].mean() - np.interp(t_mid, t, x), events["y"][sel].mean() - np.interp(t_mid, t, y)))
    offsets = np.array(offsets)
    assert len(offsets) >= 10
    # the centroid of the track's events sits within a pixel of the geometry block's prediction
    assert np.all(np.hypot(offsets[:, 0], offsets[:, 1]) < 1.0), offsets


def test_on_events_lead_off_events_along_the_motion(iss_run):
    _, _, _, events, sources, _ = iss_run
    t, x, y = satellite_track(sources)
    velocity = np.array([x[-1] - x[0], y[-1] - y[0]]) / (t[-1] - t[0])
    direction = velocity / np.hypot(*velocity)
    # position along the motion relative to the satellite at each event's trigger time
    along = ((events["x"] - np.interp(events["t_trigger_ns"], t, x)) * direction[0]
             + (events["y"] - np.interp(events["t_trigger_ns"], t, y)) * direction[1])
    across = np.abs((events["x"] - np.interp(events["t_trigger_ns"], t, x)) * direction[1]
                    - (events["y"] - np.interp(events["t_trigger_ns"], t, y)) * direction[0])
    track = (events["cause"] == EventCause.SIGNAL) & (across < 3) & (np.abs(along) < 8)
    on, off = track & (events["p"] > 0), track & (events["p"] < 0)
    assert on.sum() > 500 and off.sum() > 500
    # the satellite's leading edge brightens pixels (ON), its trailing edge darkens them (OFF)
    assert along[on].mean() > along[off].mean() + 1.0


def test_background_rates_match_the_configured_noise(iss_run):
    """Pixels away from every source see the uniform sky: no signal events, and the noise of the
    configured pixel circuit under that flux, i.e. the rates of the pixel block alone (Eq. 18-20
    with their rebound events; tests/pixel checks those against the analytic rates)."""
    graph, _, _, events, _, irradiance = iss_run
    focal_plane = irradiance[0].focal_plane
    duration_s = graph.run_info().duration_ns * 1e-9
    near_source = np.zeros((focal_plane.height_px, focal_plane.width_px), bool)
    for irr in irradiance:
        size_y, size_x = irr.stamp_flux.shape[2:]
        for x0, y0 in irr.stamp_origin.reshape(-1, 2):
            near_source[max(y0 - 5, 0):max(y0 + size_y + 5, 0), max(x0 - 5, 0):max(x0 + size_x + 5, 0)] = True
    quiet = ~near_source[events["y"], events["x"]]
    n_quiet = int((~near_source).sum())
    assert n_quiet > 0.8 * near_source.size
    assert int((quiet & (events["cause"] == EventCause.SIGNAL)).sum()) == 0

    sky_flux = float(np.concatenate([irr.background for irr in irradiance]).mean())
    # the same sensor for the same time from the same start (noise rates settle over seconds)
    patch = focal_plane
    alone = DvsPixel(graph.nodes["sensor/pixel"].block.params, seed=11)
    alone.setup(RunInfo(duration_ns=graph.run_info().duration_ns))
    triggered = []
    for i in range(graph.run_info().n_windows):
        window = Window.from_seconds(0.1 * i, 0.1 * (i + 1), index=i)
        t = window.sample_times_ns(1_000_000)
        uniform = Irradiance(patch, irradiance[0].wavelength_m, t, np.full(t.size, sky_flux),
                             np.zeros((t.size, 0, 2), np.int32), np.zeros((t.size, 0, 1, 1)))
        triggered.append(alone.step(window, irradiance=uniform)["events"])
    cause = np.concatenate([e.cause for e in triggered])
    polarity = np.concatenate([e.p for e in triggered])
    exposure_alone = patch.width_px * patch.height_px * duration_s        # pixel seconds
    exposure_scene = n_quiet * duration_s
    for kind in (EventCause.LEAK, EventCause.SHOT):
        for sign in (1, -1):
            n_alone = int(((cause == kind) & (polarity == sign)).sum())
            n_scene = int((quiet & (events["cause"] == kind) & (events["p"] == sign)).sum())
            rate_alone, rate_scene = n_alone / exposure_alone, n_scene / exposure_scene
            sigma = np.sqrt(n_alone / exposure_alone**2 + n_scene / exposure_scene**2)
            assert abs(rate_scene - rate_alone) < 5 * sigma + 1e-9, (kind.name, sign, rate_scene, rate_alone)
    # and the configured leak shows: ON leak events at about R_leak (shot events spend part of its drift)
    leak_rate = ((events["cause"] == EventCause.LEAK) & quiet).sum() / exposure_scene
    assert 0.7 * alone.params.leak_rate_hz < leak_rate < 1.3 * alone.params.leak_rate_hz
