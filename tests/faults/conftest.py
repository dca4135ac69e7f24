"""Fixtures of the fault-injection suite: the framework's test blocks as an installed plugin, a
reference run, and a runner of ``evsda`` in a subprocess (optionally through :mod:`fault_driver`,
which injects kills and a full disk into the store's writes). Helpers are in :mod:`faultkit`."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))       # faultkit, for the tests (pytest runs with --import-mode=importlib)

# A shell that starts pytest as an asynchronous command without job control (`cmd &` in a script, nohup) has
# it ignore SIGINT, and an ignored signal stays ignored in every child: the runs these tests interrupt with
# SIGINT would then not see it. A handled signal is reset to its default in a child, so handle it here.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

PLUGIN = HERE.parent / "framework" / "plugin" / "evsda_testblocks.py"
DRIVER = HERE / "fault_driver.py"


@pytest.fixture(scope="session")
def plugin_path(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("faults_plugin")
    shutil.copy(PLUGIN, root / PLUGIN.name)
    dist = root / "evsda_testblocks-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evsda-testblocks\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[evsda.blocks]\ntestblocks = evsda_testblocks:BLOCKS\n")
    return root


@pytest.fixture(scope="session", autouse=True)
def registered(plugin_path):
    """The test blocks registered in this process too (stores holding their port types are read here)."""
    from evsda.graph import registry

    sys.path.insert(0, str(plugin_path))
    registry.refresh()
    yield
    sys.path.remove(str(plugin_path))
    registry.refresh()


@pytest.fixture(scope="session")
def env(plugin_path) -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(plugin_path), os.environ.get("PYTHONPATH", "")]),
                OPENBLAS_NUM_THREADS="1")


@pytest.fixture
def evsda(env):
    """``evsda(*args)``: the command in a subprocess; ``evsda.fault(pattern, n, mode, *args)`` through the driver."""

    class Runner:
        def __call__(self, *args, timeout=60, **kwargs):
            return subprocess.run([sys.executable, "-m", "evsda.graph.cli", *map(str, args)], env=env,
                                  capture_output=True, text=True, timeout=timeout, **kwargs)

        def fault(self, pattern, n, mode, *args, timeout=60):
            return subprocess.run([sys.executable, str(DRIVER), pattern, str(n), mode, "--", *map(str, args)],
                                  env=env, capture_output=True, text=True, timeout=timeout)

        def start(self, *args, **kwargs):
            return subprocess.Popen([sys.executable, "-m", "evsda.graph.cli", *map(str, args)], env=env,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kwargs)

    return Runner()


@pytest.fixture(scope="session")
def reference(tmp_path_factory, registered):
    """An uninterrupted run of the fault graph (events, products and metrics to compare with), in this process:
    the command's runs are compared with it, so it also checks that they equal the library's."""
    from faultkit import run_in_process

    return run_in_process(tmp_path_factory.mktemp("reference"), "ref.zarr")


