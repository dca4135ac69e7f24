"""The README's quick-start figures are the output of examples/quickstart_figures.py, kept in a marked block."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("quickstart_figures", ROOT / "examples" / "quickstart_figures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _readme_figures(script) -> dict[str, float]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = text[text.index(script.BEGIN):text.index(script.END)]
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"^(\w+)\s+([-+0-9.e]+)", block, re.M)}


def test_readme_block_holds_every_figure_the_script_writes():
    script = _script()
    figures = _readme_figures(script)
    assert set(figures) == {name for name, _ in script.SHOWN}
    # the block is exactly what the script formats from those numbers (no hand edits)
    units = {n: "event" for n in figures if n.startswith("events_")}
    units.update(readout_delay_p99_s="s", background_rate_hz_per_pixel="Hz pixel^-1", track_snr="1",
                 ratio_recorded_to_expected="1", out_of_order_fraction="1")
    values = {n: (int(v) if n.startswith("events_") or n == "out_of_order_fraction" else v)
              for n, v in figures.items()}
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    written = text[text.index(script.BEGIN) + len(script.BEGIN) + 1:text.index(script.END) - 1]
    assert written == script.figures_block(values, units)


def test_readme_background_rate_is_the_presets_configured_noise():
    # The main job's Gen4 preset: ON leak 0.1 + shot 0.1, OFF shot 0.1 per pixel in the dark: the
    # quoted background rate of the run must be that sum (a figure from a run, checked against the
    # parameters that made it).
    figures = _readme_figures(_script())
    assert figures["background_rate_hz_per_pixel"] == pytest.approx(0.3, rel=0.02)
    assert figures["events_triggered"] == figures["events_recorded"]
    assert figures["events_lost_pixel"] < 0.01 * figures["events_triggered"]


def test_replace_block_swaps_only_the_marked_text():
    script = _script()
    text = f"before\n{script.BEGIN}\nold\nlines\n{script.END}\nafter\n"
    assert script.replace_block(text, "new") == f"before\n{script.BEGIN}\nnew\n{script.END}\nafter\n"
    with pytest.raises(ValueError, match="no"):
        script.replace_block("no markers here", "new")
