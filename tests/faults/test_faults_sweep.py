"""An interrupted sweep on a 2-worker Dask LocalCluster: killed (SIGKILL) or stopped (SIGINT) while points
run, its worker processes end with it, and re-running the same command finishes the sweep without
recomputing any point that had finished; every point's events equal those of the point run alone."""

from __future__ import annotations

import csv
import signal
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
from faultkit import graph_file

from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore

STEPS = "spikes.step=[2.0, 3.0, 4.0, 5.0, 6.0, 7.0]"


def finished_rows(out: Path) -> list[dict]:
    try:
        with open(out / "sweep.csv", newline="") as handle:
            return [row for row in csv.DictReader(handle) if row["status"] == "ok"]
    except OSError:
        return []


def wait_for(condition, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def gone(processes: list[psutil.Process]) -> bool:
    return all(not p.is_running() or p.status() == psutil.STATUS_ZOMBIE for p in processes)


@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGINT])
def test_an_interrupted_sweep_reruns_to_completion_and_its_workers_end(evsda, tmp_path, how):
    graph, out = graph_file(tmp_path, duration_s=0.1, sleep_s=0.15), tmp_path / "sweep"
    sweep = evsda.start("sweep", graph, "--vary", STEPS, "-j", "2", "-o", out)
    parent = psutil.Process(sweep.pid)
    workers = wait_for(lambda: [p for p in parent.children(recursive=True) if "python" in p.name().lower()]
                       if len(parent.children(recursive=True)) >= 2 else None, 120, "the workers to start")
    done_before = wait_for(lambda: finished_rows(out) if len(finished_rows(out)) >= 2 else None, 120,
                           "two points to finish")
    sweep.send_signal(how)
    sweep.wait(timeout=60)
    stderr = sweep.stderr.read()
    if how == signal.SIGINT:
        assert sweep.returncode == 130 and "Traceback" not in stderr and "Warning" not in stderr
        assert "sweep interrupted after" in stderr.splitlines()[-1] and "re-run the same command" in stderr
    else:
        assert sweep.returncode == -signal.SIGKILL
    wait_for(lambda: gone(workers), 30, "the workers to end with the sweep")
    from evsda.graph.store import is_run_store
    # every point whose store is complete, including those that finished while the sweep was stopping
    finished = {i for i in range(6) if is_run_store(out / f"point_00{i}.zarr")
                and RunStore.open(out / f"point_00{i}.zarr").complete}
    assert finished >= {int(row["point"]) for row in finished_rows(out)} >= {int(r["point"]) for r in done_before}
    assert len(finished) < 6
    stamps = {i: (out / f"point_00{i}.zarr" / "zarr.json").stat().st_mtime_ns for i in finished}

    again = evsda("sweep", graph, "--vary", STEPS, "-j", "2", "-o", out, timeout=300)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("already complete") == len(finished)
    assert {i: (out / f"point_00{i}.zarr" / "zarr.json").stat().st_mtime_ns for i in finished} == stamps
    for i, step in enumerate([2.0, 3.0, 4.0, 5.0, 6.0, 7.0]):
        store = RunStore.open(out / f"point_00{i}.zarr")
        assert store.complete
        if i not in finished:       # the interrupted and the never-started points: as if run alone
            # (without the wall-clock pause, which only slows a window down: same events and metrics)
            alone = run_graph(load_graph(graph, {"spikes.step": step, "spikes.sleep_s": 0.0}))
            events = np.concatenate([e.t_readout_ns for e in alone.outputs[("spikes", "events")]])
            assert np.array_equal(store.read_events()["t_readout_ns"], events)
            assert store.metrics == alone.metrics


def test_sigterm_while_points_run_is_one_line(evsda, tmp_path):
    """SIGTERM (as SIGINT) in the middle of long points: exit 143 and the sweep's one line, with nothing after
    it (the workers, ended mid-point, made Python's resource tracker warn about leaked semaphores)."""
    graph, out = graph_file(tmp_path, duration_s=2.0, sleep_s=0.1), tmp_path / "sweep"
    sweep = evsda.start("sweep", graph, "--vary", "spikes.step=[2.0, 3.0, 4.0]", "-j", "2", "-o", out)
    wait_for(lambda: (out / "point_000.zarr" / "zarr.json").exists(), 120, "the first point to start writing")
    time.sleep(1.0)
    sweep.send_signal(signal.SIGTERM)
    sweep.wait(timeout=60)
    lines = sweep.stderr.read().strip().splitlines()
    assert sweep.returncode == 143 and lines[0].startswith("sweep: 3 points into"), lines
    assert lines[1:] == ["evsda: sweep interrupted after 0 of 3 points; finished points are kept and unfinished ones "
                         "resume: re-run the same command"]
