"""Loading a graph imports only the block packages it names; the built-in index matches the blocks."""

from __future__ import annotations

import importlib
import inspect
import json
import pkgutil
import subprocess
import sys

import pytest

import evsda.blocks
from evsda.blocks.catalog import BLOCKS
from evsda.graph import Block, registry

SCENE_ONLY = """
import json, sys
from evsda.graph import registry
from evsda.graph.graphfile import graph_from_dict
graph_from_dict({"evsda": 1, "run": {"start": "2024-03-01T02:15:00Z", "duration_s": 0.1, "window_s": 0.1},
                 "blocks": {"site": {"type": "ground_site", "params": {"latitude_deg": 47.0, "longitude_deg": 15.4}}}})
names = list(registry.available())
print(json.dumps({"modules": sorted(m for m in sys.modules if m.startswith("evsda.blocks")), "names": names}))
"""


def test_a_graph_imports_only_the_blocks_it_names():
    out = subprocess.run([sys.executable, "-c", SCENE_ONLY], capture_output=True, text=True, check=True)
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert "evsda.blocks.scene.sources" in seen["modules"]
    for package in ("optics", "pixel", "readout", "detection"):
        assert not any(m.startswith(f"evsda.blocks.{package}") for m in seen["modules"]), package
    assert set(BLOCKS) <= set(seen["names"])                 # every type is still listed, unimported

CLI_START = """
import json, sys
import evsda.graph.cli
from evsda.graph.commands import contributed_commands
names = [command.name for command in contributed_commands()]
print(json.dumps({"modules": sorted(sys.modules), "names": names}))
"""


def test_the_command_line_starts_without_importing_any_block():
    """`evsda` (every contributed command loaded) imports no block module, nor scipy.stats or numba that
    the detection blocks need: each CLI start paid ~1 s of CPU for them (issue 13.3)."""
    out = subprocess.run([sys.executable, "-c", CLI_START], capture_output=True, text=True, check=True)
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert {"plot-pass", "plot-psf", "export", "limiting-magnitude"} <= set(seen["names"])
    imported = set(seen["modules"])
    assert not imported & {spec.partition(":")[0] for spec in BLOCKS.values()}
    assert not imported & {"scipy.stats", "numba", "skyfield"}


def test_a_package_gives_its_blocks_on_first_use():
    """`from evsda.blocks.<stage> import Class` and the package's BLOCKS still work (imported lazily)."""
    import evsda.blocks.readout as readout
    from evsda.blocks.scene import Satellite, spectra

    assert Satellite.type_name == "satellite" and spectra.__name__ == "evsda.blocks.scene.spectra"
    assert [block.type_name for block in readout.BLOCKS] == [n for n, s in BLOCKS.items() if ".readout." in s]
    assert {"BLOCKS", "FrameSensor"} <= set(dir(readout))
    with pytest.raises(ImportError, match="cannot import name 'NoSuchBlock'"):
        from evsda.blocks.readout import NoSuchBlock  # noqa: F401


def test_the_index_names_every_builtin_block_by_its_type():
    found = {}
    for info in pkgutil.walk_packages(evsda.blocks.__path__, "evsda.blocks."):
        module = importlib.import_module(info.name)
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, Block) and cls.type_name and cls.__module__ == info.name:
                found[cls.type_name] = f"{cls.__module__}:{cls.__qualname__}"
    assert found == BLOCKS
    for name in BLOCKS:
        assert registry.get(name).type_name == name and registry.is_builtin(name)


def test_a_clashing_plugin_hides_no_other_block(tmp_path):
    """A plugin declaring a built-in type name is reported; every block stays listed (issue 16.4)."""
    (tmp_path / "evsda_clash.py").write_text("BLOCKS = {'dvs_pixel': 'evsda_clash:Other', 'clash_extra': 'x:Y'}\n")
    dist = tmp_path / "evsda_clash-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evsda-clash\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[evsda.blocks]\nclash = evsda_clash:BLOCKS\n")
    env = {"PYTHONPATH": str(tmp_path)}
    import os
    proc = subprocess.run([sys.executable, "-m", "evsda.graph.cli", "blocks"], capture_output=True, text=True,
                          env={**os.environ, **env})
    assert proc.returncode == 0, proc.stderr
    assert "dvs_pixel" in proc.stdout and "optics" in proc.stdout
    assert "block plugin 'clash' (evsda_clash:BLOCKS): block type 'dvs_pixel'" in proc.stderr
    assert "clashes with the one from entry point 'builtin'" in proc.stderr
    assert "Traceback" not in proc.stderr
