"""Sweeps: grids and seeded sampling, per-value checks, reuse planning, failure-tolerant streamed results,
re-runs that skip finished points, and points run as Dask tasks on a 2-worker LocalCluster."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from evsda.graph import GraphError, UserError
from evsda.graph import sweep as sweep_module
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore
from evsda.graph.sweep import Range, read_grid, read_results, reuse_plan, run_sweep, sample

from .conftest import write

GRAPH = """\
evsda: 1
name: chain
run: {start: "2024-03-01T02:15:00Z", duration_s: 0.03, window_s: 0.01, seed: 3, store_products: false}
blocks:
  ramp: {type: test_ramp}
  double: {type: test_scale}
  spikes: {type: test_spikes}
  count: {type: test_counter}
connections:
  - {from: ramp.samples, to: double.samples}
  - {from: double.samples, to: spikes.samples}
  - {from: spikes.events, to: count.events}
"""


def chain(tmp_path):
    return write(tmp_path / "chain.yaml", GRAPH)


def test_lists_make_a_grid_and_ranges_need_sampling(tmp_path):
    grid_file = write(tmp_path / "grid.yaml", "a.x: [1, 2]\nb.y: {min: 1e-3, max: 1, log: true}\n")
    grid = read_grid(grid_file, ["c.z=[5e-1, 7]"])
    assert grid == {"a.x": [1, 2], "b.y": Range(1e-3, 1.0, log=True), "c.z": [0.5, 7]}
    assert sample({"a.x": [1, 2], "c.z": [0.5, 7]}) == [{"a.x": 1, "c.z": 0.5}, {"a.x": 1, "c.z": 7},
                                                       {"a.x": 2, "c.z": 0.5}, {"a.x": 2, "c.z": 7}]
    with pytest.raises(UserError, match="b.y is a range"):
        sample(grid)
    with pytest.raises(UserError, match="needs --points"):
        sample(grid, "lhs")
    with pytest.raises(GraphError) as info:
        read_grid(None, ["a.x={min: 2, max: 1}", "b.y={min: 0, max: 1, log: true}", "c.z=[]"])
    assert len(info.value.problems) == 3


def test_random_and_latin_hypercube_draws_are_seeded_and_lhs_stratifies():
    grid = {"a.x": Range(0.0, 10.0), "b.y": Range(1.0, 1e4, log=True), "c.n": Range(1, 5, integer=True),
            "d.k": ["p", "q"]}
    for method in ("random", "lhs"):
        first, again = sample(grid, method, 20, seed=4), sample(grid, method, 20, seed=4)
        assert first == again and first != sample(grid, method, 20, seed=5)
        assert all(0 <= p["a.x"] < 10 and 1 <= p["b.y"] < 1e4 and p["c.n"] in range(1, 6) and p["d.k"] in "pq"
                   for p in first)
        assert all(isinstance(p["c.n"], int) for p in first)
    lhs = sample(grid, "lhs", 20, seed=4)
    # every tenth of... every 1/20 of each axis holds exactly one point (McKay et al. 1979), in log for b.y
    assert sorted(int(p["a.x"] / 10 * 20) for p in lhs) == list(range(20))
    assert sorted(int(np.log10(p["b.y"]) / 4 * 20) for p in lhs) == list(range(20))
    assert sorted(p["d.k"] for p in lhs) == ["p"] * 10 + ["q"] * 10


def test_planning_checks_each_distinct_value_once(plugin, tmp_path, monkeypatch):
    calls = []
    real = sweep_module.check_override
    monkeypatch.setattr(sweep_module, "check_override", lambda g, k, v: calls.append((k, v)) or real(g, k, v))
    values = sample({"spikes.step": [1, 2, 3], "ramp.noise": [0.0, 0.1]}, "random", 300, seed=1)
    points = sweep_module.plan(str(chain(tmp_path)), values, tmp_path / "out")
    assert len(points) == 300 and points[0].store.name == "point_000.zarr" and len(calls) == 5
    with pytest.raises(GraphError) as info:
        sweep_module.plan(str(chain(tmp_path)), sample({"spikes.step": [1, -1, -1], "nope.x": [1]}), tmp_path)
    messages = sorted(str(p) for p in info.value.problems)
    assert len(messages) == 2, messages
    assert "no block named 'nope'" in messages[0] and "'step': Input should be greater than 0" in messages[1]


def test_points_reuse_the_earliest_point_sharing_their_upstream_values(plugin, tmp_path):
    values = sample({"double.gain": [1.0, 2.0], "spikes.step": [2.0, 3.0]})
    points = sweep_module.plan(str(chain(tmp_path)), values, tmp_path)
    providers, stored = reuse_plan(str(chain(tmp_path)), points)
    # 0 (g1,s2) computes all; 1 (g1,s3) reuses double from 0; 2 (g2,s2) reuses ramp from 0; 3 reuses double from 2
    assert providers == {1: 0, 2: 0, 3: 2}
    assert stored == {0: ["double", "ramp"], 2: ["double"]}


def test_a_sweep_records_failures_streams_rows_and_a_rerun_skips_finished_points(plugin, tmp_path):
    out = tmp_path / "sweep"
    lines = []
    # run.window_s = 1e-9 passes the run section's own check but the point's graph exceeds the window limit
    grid = {"double.gain": [1.0, 2.0], "run.window_s": [0.01, 1e-9]}
    result = run_sweep(str(chain(tmp_path)), grid, out, jobs=1, report=lines.append)
    assert result.failed == 2 and len(result.rows) == 4
    assert lines[-1].startswith("sweep: 2 of 4 points failed")
    table = read_results(out)
    assert list(table.columns[:4]) == ["point", "status", "double.gain", "run.window_s"]
    failed = table[table.status == "failed"]
    assert list(failed["run.window_s"]) == [1e-9, 1e-9] and all("\n" not in e and "windows" in e for e in failed.error)
    ok = table[table.status == "ok"]
    assert (ok.wall_s > 0).all() and (ok.cpu_s > 0).all() and list(ok.reused) == ["", "ramp"]
    assert all(row.events_counted == RunStore.open(row.store).n_events > 0 for row in ok.itertuples())
    csv_table = pd.read_csv(result.csv)
    assert sorted(csv_table.point) == [0, 1, 2, 3] and set(csv_table.status) == {"ok", "failed"}
    # the reused point holds the same events as a point computed alone
    alone = run_graph(load_graph(chain(tmp_path), {"double.gain": 2.0, "run.window_s": 0.01}), tmp_path / "alone.zarr")
    assert np.array_equal(RunStore.open(ok.store.iloc[1]).read_events()["t_readout_ns"],
                          alone.store.read_events()["t_readout_ns"])
    lines.clear()
    again = run_sweep(str(chain(tmp_path)), grid, out, jobs=1, report=lines.append)
    assert [r["status"] for r in again.rows] == ["done", "failed", "done", "failed"]
    assert [r["wall_s"] for r in again.rows if r["status"] == "done"] == list(ok.wall_s)
    # values YAML reads as dates are compared as they read back from the plan file
    dated = {"run.start": read_grid(None, ["run.start=[2024-03-01 02:15:00Z]"])["run.start"]}
    assert run_sweep(str(chain(tmp_path)), dated, tmp_path / "dated", jobs=1, report=lines.append).ok
    assert [r["status"] for r in run_sweep(str(chain(tmp_path)), dated, tmp_path / "dated", jobs=1,
                                           report=lines.append).rows] == ["done"]
    with pytest.raises(UserError, match="URLs such as s3:// are not supported"):
        run_sweep(str(chain(tmp_path)), grid, "s3://bucket/study", jobs=1, report=lines.append)
    with pytest.raises(UserError, match="holds another sweep"):
        run_sweep(str(chain(tmp_path)), {"double.gain": [3.0]}, out, jobs=1, report=lines.append)


def test_cli_sweep_exit_status_counts_failures(evsda_cli, tmp_path):
    proc = evsda_cli("sweep", chain(tmp_path), "--vary", "run.window_s=[0.01, 1e-9]", "-j", "1", "-o", tmp_path / "s")
    assert proc.returncode == 3 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("sweep: 1 of 2 points failed")
    lhs = evsda_cli("sweep", chain(tmp_path), "--vary", "spikes.step={min: 1, max: 4}", "--sample", "lhs",
                    "--points", "3", "--seed", "2", "-j", "1", "-q", "-o", tmp_path / "l")
    assert lhs.returncode == 0 and lhs.stderr == ""
    assert len(pd.read_parquet(tmp_path / "l" / "sweep.parquet")) == 3


def test_points_run_as_dask_tasks_on_two_workers_and_reuse_across_them(plugin, tmp_path):
    """Two workers; points sharing upstream values wait for the point that computes them and load its
    outputs from its store; a failing point does not stop the others."""
    out = tmp_path / "dask"
    grid = {"double.gain": [1.0, 2.0], "spikes.step": [2.0, 3.0], "run.window_s": [0.01]}
    bad = {"double.gain": [1.0], "spikes.step": [2.0], "run.window_s": [1e-9]}
    result = run_sweep(str(chain(tmp_path)), grid, out, jobs=2, report=lambda line: None)
    assert result.ok and [r["reused"] for r in result.rows] == ["", "double", "ramp", "double"]
    for row in result.rows:
        values = {k: row[k] for k in grid}
        alone = run_graph(load_graph(chain(tmp_path), values), tmp_path / f"alone{row['point']}.zarr")
        stored = RunStore.open(row["store"]).read_events()
        assert np.array_equal(stored["t_readout_ns"], alone.store.read_events()["t_readout_ns"])
        assert row["events_counted"] == alone.metrics["events_counted"]
    # a running cluster (--scheduler): stores go where its workers can reach them (absolute paths)
    import logging

    from distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=":0", silence_logs=logging.ERROR) as cluster:
        failing = run_sweep(str(chain(tmp_path)), {**bad, "run.window_s": [0.01, 1e-9]}, tmp_path / "bad",
                            scheduler=cluster.scheduler_address, report=lambda line: None)
    assert failing.failed == 1 and "windows" in failing.rows[1]["error"] and failing.rows[0]["status"] == "ok"
    assert Path(failing.rows[0]["store"]).is_absolute() and RunStore.open(failing.rows[0]["store"]).complete


def test_sweep_plot_shows_the_metric_against_the_parameters_and_marks_failures(plugin, tmp_path, evsda_cli):
    from evsda.graph.sweep_plot import plot_sweep

    out = tmp_path / "plotted"
    grid = {"double.gain": [1.0, 2.0, 4.0], "run.window_s": [0.01, 1e-9]}   # the 1e-9 points fail
    run_sweep(str(chain(tmp_path)), grid, out, jobs=1, report=lambda line: None)
    table = read_results(out)
    ok = table[table.status == "ok"].sort_values("double.gain")
    figure = plot_sweep(table, "events_counted", x="double.gain")
    axes = figure.axes[0]
    line, crosses = axes.lines[0], axes.lines[-1]
    assert list(line.get_xdata()) == [1.0, 2.0, 4.0] and list(line.get_ydata()) == list(ok.events_counted)
    assert list(crosses.get_xdata()) == [1.0, 2.0, 4.0] and crosses.get_marker() == "x"
    assert axes.get_ylabel() == "events_counted [event]" and "3 failed" in axes.get_title()
    plane = plot_sweep(table, "events_counted", x="double.gain", y="run.window_s")
    points = plane.axes[0].collections[0]
    assert np.array_equal(points.get_offsets()[:, 0], table[table.status == "ok"]["double.gain"])
    assert np.array_equal(points.get_array(), table[table.status == "ok"].events_counted)
    assert plane.axes[0].get_yscale() == "log"          # 1e-9 .. 1e-2: seven decades
    with pytest.raises(UserError, match="choose the x axis"):
        plot_sweep(table, "events_counted")
    with pytest.raises(UserError, match="not a metric"):
        plot_sweep(table, "nope", x="double.gain")
    proc = evsda_cli("sweep-plot", out, "events_counted", "--x", "double.gain", "-o", tmp_path / "p.png")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_the_sweep_size_and_each_points_size_are_limited_and_the_limits_can_be_raised(plugin, tmp_path, capsys):
    """100^4 grid points or 10^8 drawn points are refused before any is built (they exhausted memory);
    ``--limit`` on sweep reaches every point's graph, as its failure message says it does."""
    from evsda.graph.cli import main

    def sweep(*args):
        capsys.readouterr()
        status = main(["sweep", str(chain(tmp_path)), "-j", "1", "-q", *map(str, args)])
        return status, [line for line in capsys.readouterr().err.splitlines() if line.strip()]

    hundred = "[" + ", ".join(str(v) for v in range(1, 101)) + "]"
    status, lines = sweep(*[a for k in ("ramp.slope_per_s", "double.gain", "spikes.step", "spikes.latency_s")
                            for a in ("--vary", f"{k}={hundred}")], "-o", tmp_path / "grid")
    assert status == 2 and lines == ["evsda: error: the sweep has 1e+08 points (100 x 100 x 100 x 100 values), more "
                                     "than the limit of 1e+04; vary fewer values, draw fewer with --sample lhs "
                                     "--points N, or raise the limit with --limit points=1e+08"]
    status, lines = sweep("--vary", "spikes.step={min: 1, max: 2}", "--sample", "lhs", "--points", "100000000",
                          "-o", tmp_path / "lhs")
    assert status == 2 and len(lines) == 1 and "(--points 100000000), more than the limit of 1e+04" in lines[0]
    with pytest.raises(UserError, match="more than the limit of 3"):
        sample({"a.x": [1, 2], "b.y": [1, 2]}, max_points=3)
    assert len(sample({"a.x": [1, 2], "b.y": [1, 2]}, max_points=4)) == 4
    assert not (tmp_path / "grid").exists() and not (tmp_path / "lhs").exists()
    # a point of 3 windows passes a limit of 5 windows, one of 30 does not; the message names the flag
    status, lines = sweep("--vary", "run.window_s=[0.01, 0.001]", "--limit", "windows=5", "-o", tmp_path / "w")
    error = read_results(tmp_path / "w").set_index("point").error
    assert status == 3 and lines[-1].startswith("evsda: sweep: 1 of 2 points failed")
    assert "30 windows (duration_s / window_s) is more than the limit of 5" in error[1]
    assert "--limit windows=30" in error[1]
    status, lines = sweep("--vary", "run.window_s=[0.01, 0.001]", "--limit", "windows=30", "-o", tmp_path / "w")
    assert status == 0 and lines == []
    assert sweep("--vary", "spikes.step=[1]", "--limit", "points=0", "-o", tmp_path / "p")[1] == [
        "evsda: error: --limit points: expected a finite number >= 1, got 0"]


def test_a_second_sweep_into_the_same_folder_is_refused_naming_the_first(plugin, tmp_path):
    """Two sweeps into one folder failed each other's points and truncated each other's results table;
    the folder's lock refuses the second with one line, and the first's table stays whole."""
    from evsda.graph.lock import StoreLock

    out = tmp_path / "s"
    out.mkdir()
    grid = {"spikes.step": [2.0, 3.0]}
    with StoreLock(out):            # as a running sweep holds it
        with pytest.raises(UserError, match=rf"{out} is being written by another evsda sweep \(pid \d+ on host"):
            run_sweep(str(chain(tmp_path)), grid, out, jobs=1, report=lambda line: None)
    assert not (out / "sweep.csv").exists() and not (out / "sweep-plan.json").exists()
    result = run_sweep(str(chain(tmp_path)), grid, out, jobs=1, report=lambda line: None)
    assert result.ok and not (out / ".evsda-lock").exists()


def test_a_scheduler_address_that_is_no_address_is_one_line(plugin, tmp_path):
    with pytest.raises(UserError, match="cannot reach the Dask scheduler at not an address: missing port number"):
        run_sweep(str(chain(tmp_path)), {"spikes.step": [2.0]}, tmp_path / "s", scheduler="not an address",
                  report=lambda line: None)


def test_a_sweep_is_never_written_inside_a_run_store(plugin, tmp_path):
    """A sweep folder inside a run store (or the store itself) is refused before anything is written."""
    store = tmp_path / "run.zarr"
    run_graph(load_graph(chain(tmp_path)), store, progress=False)
    before = sorted(p.relative_to(store) for p in store.rglob("*"))
    for out in (store, store / "events" / "study"):
        with pytest.raises(UserError, match=f"cannot write a sweep inside the run store {store}"):
            run_sweep(str(chain(tmp_path)), {"spikes.step": [2.0]}, out, jobs=1, report=lambda line: None)
    assert sorted(p.relative_to(store) for p in store.rglob("*")) == before


def test_damaged_results_tables_are_one_line_or_read_from_the_other_copy(plugin, tmp_path):
    """A damaged sweep.parquet or a sweep.csv that is not UTF-8 was a pyarrow/pandas traceback in sweep-plot."""
    out = tmp_path / "s"
    assert run_sweep(str(chain(tmp_path)), {"spikes.step": [2.0, 3.0]}, out, jobs=1, report=lambda line: None).ok
    whole = read_results(out)
    (out / "sweep.parquet").write_bytes(b"PAR1 not really")
    with pytest.warns(UserWarning, match="sweep.parquet cannot be read .* the results come from sweep.csv"):
        assert list(read_results(out)["point"]) == list(whole["point"])
    (out / "sweep.csv").write_bytes(b"point,status\n\xff\xfe,1\n")
    with pytest.raises(UserError, match=r"the sweep results \(sweep.parquet and sweep.csv\) cannot be read"):
        read_results(out)


def test_a_parameter_varied_twice_is_refused(tmp_path):
    """``--vary a.x=[1,2] --vary a.x=[3]`` ran one point: the second list replaced the first without a word."""
    grid_file = write(tmp_path / "grid.yaml", "a.x: [1, 2]\n")
    for args in ((None, ["a.x=[1, 2]", "a.x=[3]"]), (grid_file, ["a.x=[3]"])):
        with pytest.raises(GraphError, match=r"'a.x': is varied twice \(also in"):
            read_grid(*args)
