"""Bundled sensor presets: graph files with a ``pixel`` block that load, include and run."""

from __future__ import annotations

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import FocalPlane
from evsda.graph import Window
from evsda.graph.graphfile import load_graph

PRESETS = {"prophesee_gen4": (1280, 720, 4.86e-6), "davis346": (346, 260, 18.5e-6)}


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_is_a_sensor_subgraph(name):
    graph = load_graph(f"library:sensors/{name}.yaml")
    assert isinstance(graph.nodes["pixel"].block, DvsPixel)
    assert graph.exposed_inputs == {"irradiance": ("pixel", "irradiance")}
    assert graph.exposed_outputs["triggered"] == ("pixel", "events")


def test_including_a_preset_overrides_its_temperature(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text(
        "evsda: 1\n"
        "include:\n"
        "  - {file: 'library:sensors/davis346.yaml', as: sensor, set: {pixel.temperature_K: 280}}\n"
        "expose:\n"
        "  inputs: {irradiance: sensor.irradiance}\n"
        "  outputs: {events: sensor.triggered}\n")
    graph = load_graph(scene)
    assert graph.nodes["sensor/pixel"].block.params.temperature_K == 280.0


def test_davis346_preset_runs_on_its_focal_plane(scenes):
    width, height, pitch = PRESETS["davis346"]
    block = load_graph("library:sensors/davis346.yaml").nodes["pixel"].block
    fp = FocalPlane(width, height, pitch, 0.5)
    out = block.step(Window.from_seconds(0, 0.05), irradiance=scenes.uniform(fp, [0], 1e4))["events"]
    # only noise: about (0.1 Hz leak + 2 x 0.1 Hz shot) x 90k pixels x 0.05 s
    assert 0 < len(out) < 5000 and out.counts_by_cause[0] == 0
    assert np.all(out.x < width) and np.all(out.y < height)
