"""The SDA plots of a stored run (light curve, event rate by cause, space-time, the event image with the
true tracks at native resolution, the PSF stamp), each checked on what it shows, on a small ISS crossing
(the quick start's scene on half the pixels, 0.2 s)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from evsda.blocks.optics.plots import plot_psf_stamp, psf_stamp
from evsda.blocks.ports import EventCause
from evsda.blocks.readout.plots import event_rate, light_curve, plot_event_rate, plot_events, plot_light_curve, \
    plot_space_time
from evsda.blocks.readout.render import NATIVE_MARGINS_PX, accumulate, event_rgb
from evsda.graph.cli import main
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

ISS = Path(__file__).resolve().parents[2] / "examples" / "iss_pass.yaml"
SMALL = {"run.start": "2023-03-20T19:18:39.4Z", "run.duration_s": 0.2, "run.store_products": ["sat"],
         "stars.faint_limit_mag": 9.0, "sensor/camera.width_px": 640, "sensor/camera.height_px": 360,
         "sensor/camera.pixel_pitch_m": 9.72e-6}


@pytest.fixture(scope="module")
def iss(tmp_path_factory):
    out = tmp_path_factory.mktemp("plots") / "iss.zarr"
    run_graph(load_graph(ISS, dict(SMALL)), out, progress=False)
    store = RunStore.open(out)
    return {"out": out, "store": store, "events": store.read_events(), "truth": store.read_truth()}


def stairs(ax, label):
    """Values of the step patch (``ax.stairs``) labelled ``label``."""
    return next(p for p in ax.patches if p.get_label() == label).get_data().values


def track_of(truth, source_id="25544"):
    mine = truth["source_id"] == source_id
    return truth["t_ns"][mine], truth["x_px"][mine].astype(float), truth["y_px"][mine].astype(float)


def test_light_curve_total_is_the_tracks_event_count(iss):
    fig = plot_light_curve(light_curve(iss["store"], bin_s=0.01))
    ax = fig.axes[0]
    on, off = stairs(ax, "ON"), -stairs(ax, "OFF")
    # brute force: events whose pixel centre is within 3 px of a true position that the source held at
    # most 1 s before the event (or one 1 ms render step after)
    ev = iss["events"]
    t, x, y = track_of(iss["truth"])
    d2 = (ev["x"][:, None] - x[None]) ** 2 + (ev["y"][:, None] - y[None]) ** 2
    dt = ev["t_trigger_ns"][:, None] - t[None]
    on_track = ((d2 <= 9.0) & (dt >= -1_000_000) & (dt <= 1_000_000_000)).any(axis=1)
    assert on_track.sum() > 1000
    assert on.sum() + off.sum() == on_track.sum()
    assert on.sum() == (on_track & (ev["p"] > 0)).sum() and off.sum() == (on_track & (ev["p"] < 0)).sum()
    # the right axis is the truth's magnitude over the source's render times
    line = fig.axes[1].get_lines()[0]
    np.testing.assert_array_equal(line.get_xdata(), t / 1e9)


def test_event_rate_by_cause_integrates_to_the_stores_counts(iss):
    rate = event_rate(iss["store"], bin_s=0.005)
    ax = plot_event_rate(rate).axes[0]
    width = np.diff(rate.edges_ns)[0] / 1e9
    for cause in EventCause:
        label = next(p.get_label() for p in ax.patches if p.get_label().startswith(cause.name.lower()))
        n = int((iss["events"]["cause"] == cause).sum())
        assert label == f"{cause.name.lower()} ({n} events)"
        assert stairs(ax, label).sum() * width == pytest.approx(n, abs=1e-6)
    assert rate.counts.sum() == len(iss["events"]["x"])


def test_space_time_line_has_the_satellites_rate(iss):
    ax = plot_space_time(iss["store"], "x").axes[0]
    line = next(l for l in ax.get_lines() if l.get_label() == "25544")
    slope_line = np.polyfit(line.get_xdata(), line.get_ydata(), 1)[0]
    # the satellite block's own samples (1 ms cadence): its rate across the detector [pixel/s]
    windows = list(iss["store"].product_windows("sat", "sources"))
    t = np.concatenate([w.t_ns for w in windows]) / 1e9
    x = np.concatenate([w.x_px for w in windows])[:, 0]
    assert slope_line == pytest.approx(np.polyfit(t, x, 1)[0], rel=1e-3)
    assert abs(slope_line) > 100
    # and the events drawn along it move at that rate
    points = np.concatenate([c.get_offsets() for c in ax.collections])
    near = np.abs(points[:, 1] - np.interp(points[:, 0], line.get_xdata(), line.get_ydata())) < 3
    assert near.sum() > 1000
    assert np.polyfit(points[near, 0], points[near, 1], 1)[0] == pytest.approx(slope_line, rel=0.03)


def test_render_at_native_resolution_with_the_true_track(iss, tmp_path):
    store, fp = iss["store"], iss["store"].focal_plane
    path = tmp_path / "native.png"
    assert main(["render", str(iss["out"]), "--png", str(path), "--scale", "1"]) == 0
    left, right, bottom, top = NATIVE_MARGINS_PX
    png = np.asarray(Image.open(path).convert("RGB"))
    assert png.shape == (fp.height_px + bottom + top, fp.width_px + left + right, 3)
    on, off = accumulate(store.iter_events(), fp.width_px, fp.height_px)
    # one PNG pixel per sensor pixel: the image area is the event image itself: the same lit pixels, the same
    # colours to a few percent (matplotlib's RGB resampling moves levels by up to ~3 %; the outermost
    # pixels lie under the axes' frame)
    want = np.round(event_rgb(on, off) * 255).astype(int)[1:-1, 1:-1]
    got = png[top:top + fp.height_px, left:left + fp.width_px].astype(int)[1:-1, 1:-1]
    lit = want.sum(axis=2) > 0
    assert lit.sum() > 1000
    np.testing.assert_array_equal(got.sum(axis=2) > 0, lit)
    assert np.abs(got - want).max() <= 0.05 * 255
    # the true track on top, at twice the resolution: cyan pixels along the satellite's path (the event
    # image has none: red and green only)
    assert main(["render", str(iss["out"]), "--png", str(path), "--scale", "2", "--truth", "--overwrite"]) == 0
    png = np.asarray(Image.open(path).convert("RGB")).astype(int)
    t, x, y = track_of(iss["truth"])
    rows = top + np.floor(2 * (y[::20] + 0.5)).astype(int)       # sensor pixel edges at -0.5, 0.5 ...
    cols = left + np.floor(2 * (x[::20] + 0.5)).astype(int)
    near = np.stack([png[rows + dy, cols + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    cyan = ((near[..., 0] < 120) & (near[..., 1] > 150) & (near[..., 2] > 150)).any(axis=0)
    assert cyan.all()
    fig = plot_events(store, truth=True)
    assert any(l.get_label() == "25544 (truth)" for l in fig.axes[0].get_lines())


def test_psf_stamp_holds_the_sources_flux_at_its_true_position(iss):
    graph = load_graph(ISS, {**SMALL, "telescope/optics.atmosphere": "none", "telescope/optics.psf_path": "airy"})
    stamp = psf_stamp(graph, time_s=0.1)
    assert stamp.source_id == "25544" and stamp.t_ns == 100_000_000
    ax = plot_psf_stamp(stamp).axes[0]
    np.testing.assert_array_equal(ax.get_images()[0].get_array(), stamp.image)
    # the stamp encloses all but tolerance / 2 of the collected flux (optics default tolerance 0.1)
    assert 0.95 <= stamp.image.sum() / stamp.collected_photon_rate <= 1.0
    # at the truth's position; the Airy core (0.6 arcsec) is far inside a 5 arcsec pixel, so the brightest
    # pixel is the one holding the true position and the centroid is pulled towards its centre
    t, x, y = track_of(iss["truth"])
    k = np.searchsorted(t, stamp.t_ns)
    assert (stamp.x_px, stamp.y_px) == pytest.approx((x[k], y[k]), abs=1e-3)
    row, col = np.unravel_index(np.argmax(stamp.image), stamp.image.shape)
    assert (stamp.origin[0] + col, stamp.origin[1] + row) == (round(stamp.x_px), round(stamp.y_px))
    assert abs(stamp.centroid[0] - stamp.x_px) < 0.5 and abs(stamp.centroid[1] - stamp.y_px) < 0.5


def test_plot_commands_write_figures_and_refuse_mistakes(iss, tmp_path, capsys):
    store = str(iss["out"])
    for argv in (["plot-lightcurve", store, "--bin-s", "0.02"], ["plot-rate", store, "--time", "trigger"],
                 ["plot-spacetime", store, "--axis", "y", "--stars"]):
        out = tmp_path / f"{argv[0]}.png"
        assert main([*argv, "-o", str(out)]) == 0
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert main([*argv, "-o", str(out)]) == 2          # an existing file needs --overwrite
    assert main(["plot-lightcurve", store, "-o", str(tmp_path / "a.png"), "--source", "nope"]) == 2
    assert "no source 'nope'" in capsys.readouterr().err
    assert main(["plot-rate", store, "-o", str(tmp_path / "b.png"), "--bin-s", "0"]) == 2
    assert main(["plot-psf", str(ISS), "-o", str(tmp_path / "psf.png"), "--time-s", "5"]) == 2
    assert not any(tmp_path.glob("[ab].png"))


def test_no_module_switches_the_backend_or_leaves_figures_open(iss):
    code = ("import matplotlib; matplotlib.use('svg'); import matplotlib.pyplot as plt\n"
            "import evsda.blocks.scene.plot, evsda.blocks.optics.plots, evsda.blocks.readout.plots\n"
            "import evsda.blocks.readout.render, evsda.blocks.readout.commands, evsda.graph.cli\n"
            "from evsda.graph.store import RunStore\n"
            "from evsda.blocks.readout.plots import plot_events, plot_space_time\n"
            f"store = RunStore.open({str(iss['out'])!r})\n"
            "figs = [plot_events(store), plot_space_time(store)]\n"
            "print(matplotlib.get_backend(), len(plt.get_fignums()), type(figs[0]).__name__)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["svg", "0", "Figure"]
