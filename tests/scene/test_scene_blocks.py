"""Scene blocks as a user meets them: parameters with units, ports that serialise, graph and plot."""

import argparse
import re

import numpy as np
import pytest

from evsda.blocks.ports.scene import Observer, Orbit, Pointing
from evsda.blocks.scene import BLOCKS, Camera
from evsda.blocks.scene.commands import PlotPass
from evsda.graph import ParameterError, SceneError
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph

EXAMPLE = "examples/scene_pass.yaml"


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: b.type_name)
def test_every_parameter_states_its_unit(block):
    for name, info in block.Params.model_fields.items():
        assert re.search(r"\[[^\]]+\]$", info.description or ""), f"{block.type_name}.{name}: {info.description!r}"


def test_scene_ports_round_trip(iss, graz, quickstart_pointing):
    for value in (iss, graz, quickstart_pointing):
        arrays, attrs = value.to_arrays()
        back = type(value).from_arrays(arrays, attrs)
        assert back.__dict__ == value.__dict__


def test_camera_field_of_view_or_focal_length():
    camera = Camera(width_px=1280, pixel_pitch_m=4.86e-6, fov_x_deg=2.0)
    fp = camera.focal_plane
    assert 2 * np.degrees(np.arctan(fp.width_px * fp.pixel_pitch_m / 2 / fp.focal_length_m)) == pytest.approx(2.0)
    with pytest.raises(ParameterError, match="exactly one of focal_length_m and fov_x_deg"):
        Camera(focal_length_m=1.0, fov_x_deg=2.0)


def test_quickstart_graph_runs(monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).parents[2])
    graph = load_graph(EXAMPLE)
    result = run_graph(graph, None, max_windows=34, progress=False)
    sources = result.outputs[("sat", "sources")]
    x = np.concatenate([w.x_px[:, 0] for w in sources])
    assert np.isfinite(x).sum() > 500                         # the crossing at t = 2.72-3.25 s
    stars = result.outputs[("stars", "sources")][0]
    assert stars.n_sources > 0 and np.isfinite(stars.x_px).any()


def test_quickstart_graph_misses_with_another_pointing(monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).parents[2])
    graph = load_graph(EXAMPLE, ["pointing.azimuth_deg=200"])
    with pytest.raises(SceneError, match="never enters the field of view"):
        run_graph(graph, None, max_windows=1, progress=False)


def test_plot_pass_writes_a_png(tmp_path, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).parents[2])
    command = PlotPass()
    parser = argparse.ArgumentParser()
    command.configure(parser)
    png = tmp_path / "pass.png"
    assert command.run(parser.parse_args([EXAMPLE, "--png", str(png), "--pad", "5"])) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


@pytest.mark.parametrize("block,param,lowest", [
    ("satellite", "cadence_s", 1e-6), ("satellite", "knot_step_s", 0.1), ("star_field", "cadence_s", 1e-6),
    ("star_field", "knot_step_s", 0.1), ("sky_background", "cadence_s", 1e-3),
    ("satellite_catalog", "cadence_s", 1e-6), ("satellite_catalog", "knot_step_s", 0.1),
    ("satellite_catalog", "screen_step_s", 0.1), ("satellite_catalog", "screen_fine_step_s", 0.01),
])
def test_sample_steps_have_a_floor(block, param, lowest):
    """A 1 ns step passed validate and allocated 10^8-10^10 samples per window or run (a MemoryError
    traceback); each sampling step now has a stated floor, checked with the other parameters."""
    from evsda.graph import registry

    params = {"catalog_file": "library:tle/iss.tle"} if block == "satellite_catalog" else {}
    cls = registry.get(block)
    with pytest.raises(ParameterError, match=f"{param}.*greater than or equal to"):
        cls(**params, **{param: lowest / 1000})
    assert cls(**params, **{param: lowest}).params.model_dump()[param] == lowest
