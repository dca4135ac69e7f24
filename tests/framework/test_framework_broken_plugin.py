"""A block plugin that fails to import hides none of the other blocks, and is named where its blocks are asked for."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from .conftest import write


@pytest.fixture(scope="module")
def broken_plugin_dir(tmp_path_factory) -> Path:
    """An installed distribution whose ``evsda.blocks`` entry point raises on import."""
    root = tmp_path_factory.mktemp("broken_plugin")
    (root / "evsda_broken.py").write_text("raise ImportError('needs libfoo 2.0')\n")
    dist = root / "evsda_broken-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evsda-broken\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[evsda.blocks]\nbroken = evsda_broken:BLOCKS\n")
    return root


def evsda(plugin_dir: Path, *args, cwd=None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plugin_dir), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "evsda.graph.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True)


def test_the_other_blocks_stay_listed(broken_plugin_dir):
    proc = evsda(broken_plugin_dir, "blocks")
    assert proc.returncode == 0, proc.stderr
    assert "dvs_pixel" in proc.stdout
    assert "block plugin 'broken' (evsda_broken:BLOCKS) failed to import: needs libfoo 2.0" in proc.stderr


def test_a_graph_asking_for_a_missing_block_names_the_broken_plugin(broken_plugin_dir, tmp_path):
    graph = write(tmp_path / "g.yaml", """\
        run: {start: "2024-03-01T02:15:00Z", duration_s: 0.05, window_s: 0.01, seed: 7}
        blocks:
          arbiter: {type: my_arbiter}
        """)
    proc = evsda(broken_plugin_dir, "validate", graph)
    assert proc.returncode == 2
    assert "unknown block type 'my_arbiter'" in proc.stderr
    assert "block plugin 'broken' (evsda_broken:BLOCKS) failed to import: needs libfoo 2.0" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_python_api_keeps_the_failure(broken_plugin_dir, monkeypatch):
    from evsda.graph import registry

    monkeypatch.syspath_prepend(str(broken_plugin_dir))
    registry.refresh()
    try:
        assert "dvs_pixel" in registry.available()
        assert any("needs libfoo 2.0" in line for line in registry.broken())
        assert registry.unknown_block("my_arbiter").startswith("unknown block type 'my_arbiter' (block plugin 'broken'")
    finally:
        monkeypatch.undo()
        registry.refresh()
    assert registry.broken() == []
