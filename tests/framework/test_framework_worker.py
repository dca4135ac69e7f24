"""A block stepped in a worker process of its own (issue 13): the same bytes as in the run's process, resume from
a worker's checkpoint, its errors raised as the serial loop raises them, a killed worker one clear error that
keeps what was committed, and no process left behind."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import pytest

from evsda.graph import ParameterError, SceneError, registry
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import graph_from_dict
from evsda.graph.store import RunStore
from evsda.graph.worker import WorkerDied, workers_pay

sys.path.insert(0, str(Path(__file__).parents[1]))
from test_examples_identical import store_digest  # noqa: E402

pytestmark = pytest.mark.usefixtures("plugin")


def graph(windows: int = 8, **gain) -> dict:
    """ramp -> noisy gain (worth a process) -> spikes -> counter."""
    return {
        "evsda": 1, "name": "worker",
        "run": {"start": "2024-01-01T00:00:00Z", "duration_s": windows * 0.01, "window_s": 0.01, "seed": 5,
                "store_products": True},
        "blocks": {"ramp": {"type": "test_ramp", "params": {"cadence_s": 1e-4}},
                   "gain": {"type": "test_noisy_gain", "params": gain},
                   "spikes": {"type": "test_spikes", "params": {"step": 2.0}},
                   "count": {"type": "test_counter"}},
        "connections": [{"from": "ramp.samples", "to": "gain.samples"}, {"from": "gain.samples", "to": "spikes.samples"},
                        {"from": "spikes.events", "to": "count.events"}],
    }


def workers_here() -> list[int]:
    """The worker processes this process started that still exist (zombies included)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        parent = int(stat.rpartition(")")[2].split()[1])
        if parent == os.getpid() and b"evsda.graph.worker" in cmdline:
            found.append(int(entry.name))
    return found


def run(tmp_path: Path, name: str, g: dict, **options) -> Path:
    out = tmp_path / f"{name}.zarr"
    run_graph(graph_from_dict(g), out, progress=False, **options)
    return out


needs_proc = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="looks for processes in /proc")


@needs_proc
def test_a_worker_records_the_serial_bytes_and_leaves_no_process(tmp_path, caplog):
    serial = store_digest(run(tmp_path, "serial", graph(), pipeline=False))
    caplog.clear()
    with caplog.at_level(logging.INFO):
        worker = store_digest(run(tmp_path, "worker", graph(), pipeline=True, workers=True))
    assert worker == serial
    assert "test_noisy_gain 'gain' steps in a worker process" in caplog.text
    stepped = [r for r in caplog.records if r.name == "evsda_testblocks"]     # its log records reach this process
    assert len(stepped) == 8 and all(str(os.getpid()) not in r.getMessage() for r in stepped)
    assert store_digest(run(tmp_path, "threads", graph(), pipeline=True, workers=False)) == serial
    assert not workers_here()


@needs_proc
def test_a_run_resumes_from_a_checkpoint_a_worker_wrote(tmp_path):
    serial = store_digest(run(tmp_path, "serial", graph(), pipeline=False))
    out = run(tmp_path, "resumed", graph(), workers=True, max_windows=3, checkpoint_every_s=0)
    assert RunStore.open(out).committed_windows == 3
    run_graph(graph_from_dict(graph()), out, resume=True, progress=False, workers=True)
    assert store_digest(out) == serial
    out = run(tmp_path, "in-process", graph(), workers=True, max_windows=5, checkpoint_every_s=0)
    run_graph(graph_from_dict(graph()), out, resume=True, progress=False, workers=False)   # and back in-process
    assert store_digest(out) == serial
    assert not workers_here()


@needs_proc
def test_an_error_in_the_worker_is_the_serial_loops_and_keeps_its_windows(tmp_path):
    caught = {}
    for mode, options in (("serial", {"pipeline": False}), ("worker", {"workers": True})):
        with pytest.raises(SceneError) as caught[mode]:
            run(tmp_path, mode, graph(fail_at_window=4), checkpoint_every_s=0, **options)
    assert str(caught["worker"].value) == str(caught["serial"].value) == "test_noisy_gain 'gain' fails in window 4"
    assert any("raised in the worker process" in note for note in caught["worker"].value.__notes__)
    kept = {mode: RunStore.open(tmp_path / f"{mode}.zarr").committed_windows for mode in caught}
    assert kept == {"serial": 4, "worker": 4}
    assert not workers_here()


@needs_proc
def test_a_set_up_error_in_the_worker_comes_first_as_in_the_serial_loop(tmp_path):
    """Every block is set up before any steps: the worker's set-up error wins over a step's error in window 0."""
    g = graph(fail_in_setup=True)
    g["blocks"]["ramp"]["params"]["fail_at_s"] = 0.005
    for options in ({"pipeline": False}, {"workers": True}):
        with pytest.raises(ParameterError) as caught:
            run(tmp_path, "setup", g, **options)
        assert str(caught.value) == "test_noisy_gain 'gain' cannot be set up"
        assert not (tmp_path / "setup.zarr").exists()
    assert not workers_here()


@needs_proc
def test_a_killed_worker_is_one_error_and_the_store_keeps_what_was_committed(tmp_path, monkeypatch):
    monkeypatch.setenv("EVSDA_TEST_DIE_AT_WINDOW", "5")
    with pytest.raises(WorkerDied) as caught:
        run(tmp_path, "killed", graph(), workers=True, checkpoint_every_s=0)
    monkeypatch.delenv("EVSDA_TEST_DIE_AT_WINDOW")
    assert str(caught.value) == ("test_noisy_gain 'gain': its worker process ended while stepping a window "
                                 f"(killed by SIGKILL); 5 of 8 windows are committed in {tmp_path / 'killed.zarr'}; "
                                 "continue with --resume")
    assert not workers_here()
    out = tmp_path / "killed.zarr"
    assert RunStore.open(out).committed_windows == 5
    run_graph(graph_from_dict(graph()), out, resume=True, progress=False, workers=False)
    assert store_digest(out) == store_digest(run(tmp_path, "serial", graph(), pipeline=False))


def test_where_a_worker_may_pay(tmp_path, caplog, monkeypatch):
    """Workers are off by default; EVSDA_WORKERS=auto takes one on two cores or more, for 16 windows or more; never
    with --no-pipeline."""
    serial = store_digest(run(tmp_path, "serial", graph(windows=16), pipeline=False))
    caplog.clear()
    monkeypatch.delenv("EVSDA_WORKERS", raising=False)
    with caplog.at_level(logging.INFO):
        run(tmp_path, "default", graph(windows=16))
        monkeypatch.setenv("EVSDA_WORKERS", "auto")
        monkeypatch.setenv("EVSDA_THREADS", "1")
        assert store_digest(run(tmp_path, "one-core", graph(windows=16))) == serial
        monkeypatch.delenv("EVSDA_THREADS")
        run(tmp_path, "short", graph(windows=15))
        run(tmp_path, "not-pipelined", graph(windows=16), pipeline=False, workers=True)
    assert "worker process" not in caplog.text
    assert all(str(os.getpid()) in r.getMessage() for r in caplog.records if r.name == "evsda_testblocks")
    if workers_pay(16):
        monkeypatch.setenv("EVSDA_WORKERS", "auto")
        caplog.clear()
        with caplog.at_level(logging.INFO):
            assert store_digest(run(tmp_path, "auto", graph(windows=16))) == serial
        assert "steps in a worker process" in caplog.text


@needs_proc
def test_a_worker_that_cannot_start_leaves_the_block_here(tmp_path, caplog, monkeypatch):
    serial = store_digest(run(tmp_path, "serial", graph(), pipeline=False))
    monkeypatch.setattr(sys, "executable", str(tmp_path / "no-such-python"))
    with caplog.at_level(logging.INFO):
        assert store_digest(run(tmp_path, "fallback", graph(), workers=True)) == serial
    assert "test_noisy_gain 'gain' steps in this process: its worker process could not start" in caplog.text


@needs_proc
def test_a_block_a_fresh_interpreter_cannot_import_steps_here(tmp_path, caplog, monkeypatch):
    """A block class that exists only in this process (no module file): the worker says so, the block runs here."""
    import evsda_testblocks

    phantom = types.ModuleType("evsda_phantom_blocks")
    phantom.Gain = type("Gain", (evsda_testblocks.NoisyGain,), {"__module__": "evsda_phantom_blocks",
                                                                 "type_name": "test_phantom_gain"})
    monkeypatch.setitem(sys.modules, "evsda_phantom_blocks", phantom)
    registry.register(phantom.Gain, "test")
    try:
        g = graph()
        g["blocks"]["gain"]["type"] = "test_phantom_gain"
        serial = store_digest(run(tmp_path, "serial", g, pipeline=False))
        with caplog.at_level(logging.INFO):
            assert store_digest(run(tmp_path, "here", g, workers=True)) == serial
    finally:
        registry.unregister("test_phantom_gain")
    assert "steps in this process: its worker process could not start (ModuleNotFoundError" in caplog.text
    assert not workers_here()


@needs_proc
def test_ctrl_c_stops_the_run_and_its_worker(tmp_path, plugin_dir):
    """SIGINT to the terminal's process group (the run and its worker): one line, the worker gone."""
    g = tmp_path / "g.yaml"
    import yaml
    g.write_text(yaml.safe_dump(graph(windows=200, sleep_s=0.02)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(plugin_dir), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "evsda.graph.cli", "run", str(g), "-o", str(tmp_path / "r.zarr"),
                             "-q", "--checkpoint-every", "0", "--workers"], env=env, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 30
    while _committed(tmp_path / "r.zarr") < 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    children = [p for p in Path("/proc").iterdir() if p.name.isdigit() and _parent(p) == proc.pid]
    assert children, "the run started no worker"
    os.killpg(proc.pid, signal.SIGINT)
    proc.wait(timeout=30)
    lines = proc.stderr.read().strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1 and "--resume" in lines[0], lines
    time.sleep(0.1)
    assert not any(p.exists() and _state(p) != "Z" for p in children)


def _committed(store: Path) -> int:
    try:
        return RunStore.open(store).committed_windows
    except Exception:                       # noqa: BLE001 -- not there yet, or being written
        return 0


def _parent(proc_dir: Path) -> int:
    try:
        return int((proc_dir / "stat").read_text().rpartition(")")[2].split()[1])
    except (OSError, ValueError, IndexError):
        return -1


def _state(proc_dir: Path) -> str:
    try:
        return (proc_dir / "stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return "gone"
