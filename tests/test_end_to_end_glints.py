"""End to end, the tumbling SL-16 rocket body: its glints must come out of the pixels as event bursts.

A small version of ``examples/sl-16-rb.yaml`` (a 64 x 64 crop of the field around the tracked rocket,
0.7 s around the first glint, stars to V 6) runs through orbit -> facet model and attitude ->
optics with turbulence -> DVS pixels -> arbiter -> store, and the analysis of
``examples/sl16_rb_glints.py`` finds the light curve's glint and the bursts of events at the rocket.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# the spin turned 32.4 deg ahead (0.9 s at 36 deg/s) brings the first glint from t = 1.23 s to 0.33 s
SMALL = {"sensor/camera.width_px": 64, "sensor/camera.height_px": 64, "stars.faint_limit_mag": 6,
         "sat.spin_phase_deg": 32.4, "run.duration_s": 0.7}


def _analysis():
    spec = importlib.util.spec_from_file_location("sl16_rb_glints", EXAMPLES / "sl16_rb_glints.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sl16_glint_is_an_event_burst_at_the_rocket(tmp_path):
    analysis = _analysis()
    graph = load_graph(EXAMPLES / "sl-16-rb.yaml", [f"{k}={v}" for k, v in SMALL.items()])
    run_graph(graph, tmp_path / "sl16.zarr", progress=False)
    curve, glints, counts, bursts = analysis.report(graph, RunStore.open(tmp_path / "sl16.zarr"))
    assert np.all(np.abs(curve["x_px"] - 31.5) < 0.5) and np.all(np.abs(curve["y_px"] - 31.5) < 0.5)   # tracked
    assert len(glints) == 1 and glints[0]["peak_mag"] < np.median(curve["magnitude"]) - 3.0
    assert len(bursts) == 1                                                   # the glint, and nothing else
    assert abs(glints[0]["burst_delay_s"]) < 0.03
    burst = bursts[0]
    assert burst["on"] > 50 and burst["off"] > 50      # a dark photoreceptor is slow: fewer events than a fast one
    # ON while the glint rises, OFF while it fades: the ON events' mean time leads the OFF events'
    t = (np.arange(len(counts["on"])) + 0.5) * 0.01
    near = (t > burst["start_s"] - 0.05) & (t < burst["stop_s"] + 0.15)
    mean_on = np.average(t[near], weights=counts["on"][near])
    mean_off = np.average(t[near], weights=counts["off"][near])
    assert mean_on < mean_off - 0.02
