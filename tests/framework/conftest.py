"""Fixtures for the framework tests: a plugin package installed in a temporary folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

HERE = Path(__file__).parent


@pytest.fixture(scope="session")
def plugin_dir(tmp_path_factory) -> Path:
    """A folder holding the test plugin as an installed distribution with an evsda.blocks entry point."""
    root = tmp_path_factory.mktemp("plugin")
    shutil.copy(HERE / "plugin" / "evsda_testblocks.py", root / "evsda_testblocks.py")
    dist = root / "evsda_testblocks-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evsda-testblocks\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(textwrap.dedent("""\
        [evsda.blocks]
        testblocks = evsda_testblocks:BLOCKS
    """))
    return root


@pytest.fixture(scope="session")
def plugin(plugin_dir):
    """The test plugin, importable and registered in this process through its entry point."""
    from evsda.graph import registry

    sys.path.insert(0, str(plugin_dir))
    registry.refresh()
    yield plugin_dir
    sys.path.remove(str(plugin_dir))


@pytest.fixture
def evsda_cli(plugin_dir):
    """Run the ``evsda`` command in a subprocess that sees the test plugin."""

    def run(*args, cwd=None, check=False, **kwargs):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plugin_dir), os.environ.get("PYTHONPATH", "")]))
        proc = subprocess.run([sys.executable, "-m", "evsda.graph.cli", *map(str, args)], cwd=cwd, env=env,
                              capture_output=True, text=True, **kwargs)
        if check and proc.returncode != 0:
            raise AssertionError(f"evsda {' '.join(map(str, args))} failed:\n{proc.stderr}")
        return proc

    return run


@pytest.fixture
def evsda_main(plugin, capsys):
    """Run ``evsda`` through its ``main()`` in this process (the test plugin registered), for follow-up commands
    whose process start (~1.5 s CPU) checks nothing new: returns a CompletedProcess (returncode, stdout, stderr)."""
    from evsda.graph.cli import main

    def run(*args, check=False):
        capsys.readouterr()
        status = main([str(a) for a in args])
        out, err = capsys.readouterr()
        if check and status != 0:
            raise AssertionError(f"evsda {' '.join(map(str, args))} failed:\n{err}")
        return subprocess.CompletedProcess(args, status, out, err)

    return run


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


@pytest.fixture
def fresh_numba(tmp_path):
    """``fresh_numba(script, switch)``: a runner of ``script`` in fresh interpreters with their own Numba cache folder in
    ``tmp_path`` (its modules importable), ``switch`` unset unless given, and PYTHONHASHSEED fixed, so that hashes
    compare across processes; each run returns the JSON of the script's last line."""
    def bind(script: str, switch: str):
        def run(**env) -> dict:
            environ = {name: value for name, value in os.environ.items() if name != switch}
            environ.update(NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONHASHSEED="11",
                           PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]), **env)
            out = subprocess.run([sys.executable, "-c", script], env=environ, capture_output=True, text=True,
                                 check=True)
            return json.loads(out.stdout.splitlines()[-1])
        return run
    return bind
