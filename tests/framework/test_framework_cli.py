"""The ``evsda`` command: exit codes, messages without tracebacks, plugin discovery, schema."""

from __future__ import annotations

import textwrap
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from evsda.graph import registry
from evsda.graph.schema import graph_schema
from evsda.graph.store import RunStore

GOOD = """\
evsda: 1
name: good
run: {start: "2024-03-01T02:15:00Z", duration_s: 0.03, window_s: 0.01, seed: 3}
blocks:
  ramp: {type: test_ramp}
  spikes: {type: test_spikes}
connections:
  - {from: ramp.samples, to: spikes.samples}
"""


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def test_version(evsda_cli):
    proc = evsda_cli("--version", check=True)
    assert proc.stdout.startswith("evsda ")


def test_plugin_blocks_are_found_through_their_entry_point(evsda_cli):
    listing = evsda_cli("blocks", check=True).stdout
    assert "test_ramp  —  A noisy ramp sampled on the run's global grid." in listing
    assert "in:  samples: Samples" in listing
    detail = evsda_cli("blocks", "test_ramp", check=True).stdout
    assert "cadence_s [s]: float, default 0.001, > 0" in detail
    assert "Sampling interval" in detail


def test_unknown_block_is_exit_2_without_traceback(evsda_cli):
    proc = evsda_cli("blocks", "nope")
    assert proc.returncode == 2
    assert proc.stderr.strip() == "evsda: error: unknown block type 'nope'; `evsda blocks` lists them"


def test_validate_reports_every_problem_and_exits_2(evsda_cli, tmp_path):
    bad = write(tmp_path / "bad.yaml", GOOD.replace("test_spikes}", "test_spikes, params: {step: -1}}")
                .replace("spikes.samples", "spikes.smples"))
    proc = evsda_cli("validate", bad)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert all(line.startswith(f"evsda: error: {bad}:") for line in lines)
    assert any("parameter 'step': Input should be greater than 0" in line for line in lines)
    assert any("has no input port 'smples'" in line for line in lines)
    good = write(tmp_path / "good.yaml", GOOD)
    assert "ok — 2 blocks, 1 connections" in evsda_cli("validate", good, check=True).stdout


def test_run_writes_a_store_refuses_to_overwrite_and_reruns_from_a_store(evsda_cli, tmp_path):
    good = write(tmp_path / "good.yaml", GOOD)
    proc = evsda_cli("run", good, "-o", tmp_path / "a.zarr", "--set", "spikes.step=2")
    assert proc.returncode == 0, proc.stderr
    assert "3 of 3 windows" in proc.stderr and "time per block" in proc.stderr
    again = evsda_cli("run", good, "-o", tmp_path / "a.zarr")
    assert again.returncode == 2 and "already exists" in again.stderr and "Traceback" not in again.stderr
    rerun = evsda_cli("run", tmp_path / "a.zarr", "-o", tmp_path / "b.zarr")
    assert rerun.returncode == 0, rerun.stderr
    a, b = RunStore.open(tmp_path / "a.zarr").read_events(), RunStore.open(tmp_path / "b.zarr").read_events()
    assert len(a["x"]) > 0 and all(np.array_equal(a[k], b[k]) for k in a)


def test_schema_is_written_checked_and_detects_staleness(evsda_cli, evsda_main, tmp_path):
    """Written by a new process; checked through main() in this one."""
    folder = tmp_path / "schema"
    assert evsda_cli("schema", "--dir", folder).returncode == 0
    assert evsda_main("schema", "--check", "--dir", folder).returncode == 0
    graph_file = folder / "graph.schema.json"
    graph_file.write_text(graph_file.read_text().replace('"title"', '"titel"', 1))
    proc = evsda_main("schema", "--check", "--dir", folder)
    assert proc.returncode == 1 and "graph.schema.json is out of date" in proc.stderr


def test_graph_schema_validates_block_params(plugin):
    schema = graph_schema(["test_ramp", "test_spikes"])
    good = {"evsda": 1, "blocks": {"r": {"type": "test_ramp", "params": {"cadence_s": 0.01}}}}
    jsonschema.validate(good, schema)
    for bad_params in ({"cadence_s": -1}, {"cadense_s": 1.0}):
        bad = {"evsda": 1, "blocks": {"r": {"type": "test_ramp", "params": bad_params}}}
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"evsda": 1, "blocks": {"r": {"type": "no_such_block"}}}, schema)


def test_registry_rejects_a_clashing_type_name(plugin):
    from evsda_testblocks import RampSource

    clash = type("Clash", (RampSource,), {"__doc__": "another"})
    try:
        registry.register(clash, "test")
    except Exception as exc:  # UserError
        assert "clashes" in str(exc)
    else:
        raise AssertionError("clash accepted")


def test_sweep_runs_the_grid_reuses_upstream_and_writes_a_table(evsda_cli, tmp_path):
    good = write(tmp_path / "good.yaml", GOOD)
    grid = write(tmp_path / "grid.yaml", "spikes.step: [2, 3]\n")
    proc = evsda_cli("sweep", good, "--grid", grid, "--vary", "spikes.latency_s=[1.0e-6]", "-o", tmp_path / "sw",
                     "-j", "1")
    assert proc.returncode == 0, proc.stderr
    assert "point 0: {'spikes.step': 2, 'spikes.latency_s': 1e-06} -> point_000.zarr (computed in full" in proc.stderr
    assert "point 1: {'spikes.step': 3, 'spikes.latency_s': 1e-06} -> point_001.zarr (reused ramp" in proc.stderr
    rows = (tmp_path / "sw" / "sweep.csv").read_text().splitlines()
    assert rows[0].startswith("point,status,spikes.step,spikes.latency_s,wall_s,cpu_s") and len(rows) == 3
    n2 = RunStore.open(tmp_path / "sw" / "point_000.zarr").n_events
    n3 = RunStore.open(tmp_path / "sw" / "point_001.zarr").n_events
    assert n2 > n3 > 0
    again = evsda_cli("sweep", good, "--grid", grid, "--vary", "spikes.latency_s=[1.0e-6]", "-o", tmp_path / "sw",
                      "-j", "1")
    assert again.stderr.count("already complete") == 2
    bad = evsda_cli("sweep", good, "--vary", "spikes.step=[2, -1]", "-o", tmp_path / "bad")
    assert bad.returncode == 2 and "parameter 'step': Input should be greater than 0" in bad.stderr


def test_verbose_and_quiet_go_before_or_after_the_command(evsda_cli, tmp_path):
    good = write(tmp_path / "good.yaml", GOOD)
    loud = evsda_cli("run", good, "-o", tmp_path / "a.zarr", "--no-progress", "-v", check=True)
    assert "time per block" in loud.stderr
    for args in (("-q", "run", good), ("run", "-q", good), ("run", good, "--quiet")):
        out = tmp_path / f"q{len(list(tmp_path.iterdir()))}.zarr"
        quiet = evsda_cli(*args, "-o", out, "--no-progress", check=True)
        assert quiet.stderr == "" and RunStore.open(out).complete
    assert evsda_cli("blocks", "-v", check=True).stdout == evsda_cli("-v", "blocks", check=True).stdout


def test_run_json_and_info_say_what_the_store_holds(evsda_cli, evsda_main, tmp_path):
    """The run in a new process; `evsda info` on its store through main() in this one."""
    import json
    good = write(tmp_path / "good.yaml", GOOD)
    out = tmp_path / "a.zarr"
    report = json.loads(evsda_cli("run", good, "-o", out, "-q", "--json", check=True).stdout)
    store = RunStore.open(out)
    assert report["store"] == str(out) and report["events"] == store.n_events > 0 and report["windows"] == 3
    info = json.loads(evsda_main("info", out, "--json", check=True).stdout)
    assert info["complete"] and not info["resumable"] and info["seed"] == 3 and info["graph"] == "good"
    assert info["duration_s"] == pytest.approx(0.03) and info["n_windows"] == 3
    causes = np.bincount(store.read_events()["cause"], minlength=4)
    assert info["events_by_cause"] == {name: int(causes[i]) for i, name in
                                       enumerate(["signal", "leak", "parasitic", "shot"]) if causes[i]}
    assert sum(info["events_by_cause"].values()) == info["events"] == store.n_events
    assert "ramp.samples" in info["products"] and info["products"]["ramp.samples"] == 3
    text = evsda_main("info", out, check=True).stdout
    assert f"{out}: complete: 3 of 3 windows" in text and "seed         3" in text
    from evsda.graph.executor import run_graph
    from evsda.graph.graphfile import load_graph
    partial = tmp_path / "p.zarr"
    run_graph(load_graph(good), partial, max_windows=1, checkpoint_every_s=0, progress=False)
    info = json.loads(evsda_main("info", partial, "--json", check=True).stdout)
    assert not info["complete"] and info["resumable"] and info["windows"] == 1 and info["checkpoint"]
    missing = evsda_main("info", tmp_path / "nope.zarr")
    assert missing.returncode == 2 and missing.stderr.startswith("evsda: error:") and "Traceback" not in missing.stderr


def test_a_closed_pipe_ends_quietly(plugin_dir):
    import os
    import subprocess
    import sys
    env = dict(os.environ, PYTHONPATH=str(plugin_dir))
    proc = subprocess.Popen([sys.executable, "-m", "evsda.graph.cli", "blocks"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    proc.stdout.close()                     # the reader is gone before the listing is printed
    stderr = proc.communicate(timeout=120)[1].decode()
    assert stderr == "" and proc.returncode == 141


def test_example_scenes_ship_in_the_library():
    """``library:examples/NAME.yaml`` is each example scene (installed inside evsda.library by the wheel)."""
    from evsda import library
    from evsda.graph.graphfile import load_graph

    root = Path(__file__).parents[2] / "examples"
    scenes = sorted(p.name for p in root.glob("*.yaml"))
    assert "iss_pass.yaml" in scenes
    for name in scenes:
        # the same scene, whether evsda is installed from a wheel or from this checkout
        assert library.resolve(f"library:examples/{name}").read_bytes() == (root / name).read_bytes()
    graph = load_graph("library:examples/iss_pass_low_noise.yaml")      # its include is relative to it
    assert graph.name == "iss_pass_low_noise" and "scene/iss" in graph.nodes


def test_cache_flags_set_the_switch_for_the_command_only(evsda_main, tmp_path, monkeypatch):
    import os

    from evsda.graph import cli

    seen = []
    real = cli.run_graph

    def run_graph(*args, **kwargs):
        seen.append(os.environ.get("EVSDA_CACHE"))
        return real(*args, **kwargs)

    monkeypatch.setattr(cli, "run_graph", run_graph)
    monkeypatch.setenv("EVSDA_CACHE", "off")
    good = write(tmp_path / "good.yaml", GOOD)
    for n, flags in enumerate((["--cache"], ["--no-cache"], [])):
        evsda_main("run", good, "-o", tmp_path / f"{n}.zarr", "-q", *flags, check=True)
    assert seen == ["on", "off", "off"] and os.environ["EVSDA_CACHE"] == "off"
    monkeypatch.setenv("EVSDA_CACHE", "maybe")
    bad = evsda_main("run", good, "-o", tmp_path / "bad.zarr")
    assert bad.returncode == 2 and "EVSDA_CACHE must be 'on' or 'off', got 'maybe'" in bad.stderr
    assert not (tmp_path / "bad.zarr").exists() and len(seen) == 3
