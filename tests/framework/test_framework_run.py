"""The executor and the run store: pruning, reproducibility, checkpoints, resume after SIGKILL, reuse."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from evsda.graph import RunInfo, SceneError, StoreError, Window, block_rng
from evsda.graph.executor import run_graph
from evsda.graph.graphfile import load_graph
from evsda.graph.store import RunStore


def write(path: Path, text: str) -> Path:
    path.write_text(textwrap.dedent(text))
    return path


def chain(tmp_path: Path, *, duration_s=0.05, window_s=0.01, seed=7, extra="", sleep_s=0.0, step=5.0,
          name="chain.yaml") -> Path:
    return write(tmp_path / name, f"""\
        evsda: 1
        name: chain
        run: {{start: "2024-03-01T02:15:00Z", duration_s: {duration_s}, window_s: {window_s}, seed: {seed}}}
        blocks:
          ramp: {{type: test_ramp}}
          spikes: {{type: test_spikes, params: {{sleep_s: {sleep_s}, step: {step}}}}}
          {extra}
        connections:
          - {{from: ramp.samples, to: spikes.samples}}
        outputs: [spikes.events]
        """)


def events_of(result_or_store) -> dict[str, np.ndarray]:
    store = result_or_store if isinstance(result_or_store, RunStore) else result_or_store.store
    return store.read_events()


def test_block_runs_standalone_without_a_graph(plugin):
    from evsda_testblocks import RampSource, SpikeEncoder

    ramp, spikes = RampSource(noise=0.0, seed=3), SpikeEncoder(step=1.0)
    window = Window.from_seconds(0.0, 0.01)
    samples = ramp.step(window)["samples"]
    assert samples.t_ns.tolist() == list(range(0, 10_000_000, 1_000_000))
    events = spikes.step(window, samples=samples)["events"]
    assert len(events) == int(np.floor(np.abs(samples.value).sum()))
    assert spikes.get_state()["emitted"] == len(events)


def test_block_rng_depends_on_seed_and_name_only():
    a = block_rng(1, "pixel").random(4)
    assert np.array_equal(a, block_rng(1, "pixel").random(4))
    assert not np.array_equal(a, block_rng(2, "pixel").random(4))
    assert not np.array_equal(a, block_rng(1, "pixel2").random(4))


def test_window_grid_does_not_depend_on_window_cuts():
    whole = Window(0, 0, 10_000_000).sample_times_ns(3_000_000)
    parts = [Window(i, a, b).sample_times_ns(3_000_000) for i, (a, b) in enumerate([(0, 4_000_000), (4_000_000, 10_000_000)])]
    assert np.array_equal(whole, np.concatenate(parts))
    assert RunInfo(duration_ns=25, window_ns=10).n_windows == 3


def test_in_memory_run_and_pruning(plugin, tmp_path):
    extra = "unused: {type: test_scale}\n          other: {type: test_ramp}"
    path = chain(tmp_path, extra=extra)
    text = path.read_text().replace("outputs: [spikes.events]",
                                    "  - {from: other.samples, to: unused.samples}\noutputs: [spikes.events]")
    path.write_text(text)
    result = run_graph(load_graph(path))
    assert set(result.timing_s) == {"ramp", "spikes", "(store)"}     # 'other' and 'unused' never ran
    assert len(result.outputs[("spikes", "events")]) == 5


def test_run_is_reproducible_and_blocks_are_independent(plugin, tmp_path):
    a = run_graph(load_graph(chain(tmp_path)), tmp_path / "a.zarr")
    b = run_graph(load_graph(chain(tmp_path)), tmp_path / "b.zarr")
    unrelated = chain(tmp_path, extra="bystander: {type: test_ramp}", name="with_bystander.yaml")
    c = run_graph(load_graph(unrelated), tmp_path / "c.zarr")
    d = run_graph(load_graph(chain(tmp_path, seed=8, name="seed8.yaml")), tmp_path / "d.zarr")
    ea, eb, ec, ed = (events_of(r) for r in (a, b, c, d))
    assert len(ea["x"]) > 10
    for key in ea:
        assert np.array_equal(ea[key], eb[key]) and np.array_equal(ea[key], ec[key])
    assert not np.array_equal(ea["x"], ed["x"])


def test_a_progress_bar_changes_nothing_recorded(plugin, tmp_path):
    """With a bar (tqdm) or without (a stand-in that shows nothing, tqdm not imported for it), the same events."""
    shown = run_graph(load_graph(chain(tmp_path)), tmp_path / "shown.zarr", progress=True)
    hidden = run_graph(load_graph(chain(tmp_path)), tmp_path / "hidden.zarr", progress=False)
    for key, values in events_of(shown).items():
        assert np.array_equal(values, events_of(hidden)[key])


def test_a_loaded_graph_runs_afresh_each_time(plugin, tmp_path):
    # the encoder keeps a running sum and draws pixels from its generator: a second run of the same loaded
    # graph must start from nothing, as a fresh process does, not from the first run's end
    graph = load_graph(chain(tmp_path))
    first = events_of(run_graph(graph, tmp_path / "first.zarr"))
    second = events_of(run_graph(graph, tmp_path / "second.zarr"))
    assert first and len(next(iter(first.values()))) > 0
    for key in first:
        np.testing.assert_array_equal(second[key], first[key])


def test_store_layout_and_attrs(plugin, tmp_path):
    result = run_graph(load_graph(chain(tmp_path)), tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    attrs = store.attrs
    assert attrs["seed"] == 7 and attrs["start_epoch"] == "2024-03-01T02:15:00Z"
    assert attrs["graph"]["blocks"]["spikes"]["params"]["step"] == 5.0
    assert attrs["evsda_version"] and set(attrs["timing"]) >= {"ramp", "spikes"}
    assert store.committed_windows == 5 and store.n_events == len(result.store.read_events()["x"])
    events = store.read_events()
    assert events["x"].dtype == np.uint16 and events["t_trigger_ns"].dtype == np.int64
    assert np.all(events["t_readout_ns"] - events["t_trigger_ns"] == 1000)
    assert store.focal_plane.width_px == 32
    samples = list(store.product_windows("ramp", "samples"))
    assert len(samples) == 5 and samples[1].t_ns[0] == 10_000_000


def test_store_is_never_overwritten_silently(plugin, tmp_path):
    graph = load_graph(chain(tmp_path))
    run_graph(graph, tmp_path / "run.zarr")
    with pytest.raises(StoreError, match="already exists"):
        run_graph(graph, tmp_path / "run.zarr")
    run_graph(graph, tmp_path / "run.zarr", overwrite=True)
    with pytest.raises(StoreError, match="not an evsda run store"):
        RunStore.open(tmp_path)


def test_resume_refuses_a_different_graph(plugin, tmp_path):
    run_graph(load_graph(chain(tmp_path)), tmp_path / "run.zarr", max_windows=2)
    with pytest.raises(StoreError, match="different graph"):
        run_graph(load_graph(chain(tmp_path, step=6.0)), tmp_path / "run.zarr", resume=True)


def test_stopped_run_resumes_to_identical_events(plugin, tmp_path):
    graph = load_graph(chain(tmp_path))
    full = events_of(run_graph(graph, tmp_path / "full.zarr"))
    run_graph(load_graph(chain(tmp_path)), tmp_path / "part.zarr", max_windows=2, checkpoint_every_s=0)
    assert RunStore.open(tmp_path / "part.zarr").committed_windows == 2
    resumed = events_of(run_graph(load_graph(chain(tmp_path)), tmp_path / "part.zarr", resume=True))
    for key in full:
        assert np.array_equal(full[key], resumed[key])


def _committed_windows(store: Path) -> int:
    try:
        return json.loads((store / "zarr.json").read_text())["attributes"]["committed"]["windows"]
    except (OSError, ValueError, KeyError):
        return 0


def test_sigkill_at_random_moments_then_resume_is_byte_identical(plugin, plugin_dir, tmp_path):
    """Kill the run with SIGKILL at random instants, resume each time, compare with an uninterrupted run."""
    path = chain(tmp_path, duration_s=0.4, window_s=0.01, sleep_s=0.01)
    env = dict(os.environ, PYTHONPATH=str(plugin_dir))
    cli = [sys.executable, "-m", "evsda.graph.cli", "run", str(path), "--checkpoint-every", "0", "-q"]
    reference = tmp_path / "reference.zarr"        # uninterrupted, in this process (the pause changes no event)
    run_graph(load_graph(path, {"spikes.sleep_s": 0.0}), reference, checkpoint_every_s=0, progress=False)

    killed = tmp_path / "killed.zarr"
    rng = random.Random(4)
    kills = 0
    args = [*cli, "-o", str(killed)]
    while True:
        before = _committed_windows(killed)
        proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        args = [*cli, "-o", str(killed), "--resume"]
        while proc.poll() is None and _committed_windows(killed) <= before:
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.15))   # anywhere inside a window, a write or a commit
        if proc.poll() is None and kills < 4:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            kills += 1
            continue
        proc.wait()
        assert proc.returncode == 0, proc.stderr.read().decode()
        break
    assert kills == 4
    assert _committed_windows(killed) == 40
    a, b = RunStore.open(reference).read_events(), RunStore.open(killed).read_events()
    assert len(a["x"]) > 100
    for key in a:
        assert a[key].tobytes() == b[key].tobytes()


def test_reuse_loads_upstream_products_and_matches_a_full_run(plugin, tmp_path):
    first = run_graph(load_graph(chain(tmp_path)), tmp_path / "first.zarr")
    assert first.reused == {}
    changed = chain(tmp_path, step=3.0, name="changed.yaml")
    reused = run_graph(load_graph(changed), tmp_path / "reused.zarr", reuse=[tmp_path / "first.zarr"])
    assert reused.reused == {"ramp": str(tmp_path / "first.zarr")}
    assert "ramp" not in reused.timing_s
    full = run_graph(load_graph(changed), tmp_path / "full.zarr")
    a, b = events_of(reused), events_of(full)
    for key in a:
        assert np.array_equal(a[key], b[key])
    # a different upstream parameter must not be reused
    other = chain(tmp_path, seed=9, name="seed9.yaml")
    assert run_graph(load_graph(other), tmp_path / "x.zarr", reuse=[tmp_path / "first.zarr"]).reused == {}


def test_a_scene_error_in_the_first_window_leaves_no_store(plugin, tmp_path):
    path = chain(tmp_path)
    path.write_text(path.read_text().replace("ramp: {type: test_ramp}", "ramp: {type: test_ramp, params: {fail_at_s: 0.0}}"))
    with pytest.raises(SceneError, match="cannot continue"):
        run_graph(load_graph(path), tmp_path / "run.zarr")
    assert not (tmp_path / "run.zarr").exists()


def test_an_error_mid_run_keeps_every_committed_window(plugin, tmp_path):
    path = chain(tmp_path)
    path.write_text(path.read_text().replace("ramp: {type: test_ramp}", "ramp: {type: test_ramp, params: {fail_at_s: 0.035}}"))
    with pytest.raises(SceneError):
        run_graph(load_graph(path), tmp_path / "run.zarr", checkpoint_every_s=0)
    store = RunStore.open(tmp_path / "run.zarr")
    assert store.committed_windows == 3
    assert len(list(store.product_windows("ramp", "samples"))) == 3


def test_a_finished_run_drops_its_checkpoint_unless_asked_to_keep_it(plugin, tmp_path):
    run_graph(load_graph(chain(tmp_path)), tmp_path / "dropped.zarr", checkpoint_every_s=0)
    dropped = RunStore.open(tmp_path / "dropped.zarr")
    assert dropped.complete and dropped.status().describe() == "complete: 5 of 5 windows"
    assert dropped.read_checkpoint() == {} and not list((tmp_path / "dropped.zarr").glob("checkpoint/w*"))
    run_graph(load_graph(chain(tmp_path)), tmp_path / "kept.zarr", keep_checkpoint=True)
    kept = RunStore.open(tmp_path / "kept.zarr").read_checkpoint()
    assert kept["spikes"]["emitted"] > 0 and "__rng__" in kept["spikes"]
    for key, values in RunStore.open(tmp_path / "kept.zarr").read_events().items():
        assert values.tobytes() == dropped.read_events()[key].tobytes()


def test_resume_of_a_complete_run_changes_nothing_and_of_a_missing_store_starts_it(plugin, tmp_path):
    first = run_graph(load_graph(chain(tmp_path)), tmp_path / "run.zarr")
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "run.zarr").rglob("*") if p.is_file()}
    again = run_graph(load_graph(chain(tmp_path)), tmp_path / "run.zarr", resume=True)
    assert again.windows_run == 0 and again.metrics == first.metrics
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "run.zarr").rglob("*") if p.is_file()} == before
    fresh = run_graph(load_graph(chain(tmp_path)), tmp_path / "new.zarr", resume=True)
    assert fresh.windows_run == 5 and events_of(fresh)["x"].tobytes() == events_of(first)["x"].tobytes()


def test_overwrite_replaces_only_run_stores(plugin, tmp_path):
    graph = load_graph(chain(tmp_path))
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"\xff\xd8")
    (tmp_path / "notes.txt").write_text("mine")
    for target in (folder, tmp_path / "notes.txt"):
        with pytest.raises(StoreError, match="not an evsda run store"):
            run_graph(graph, target, overwrite=True)
    assert (folder / "holiday.jpg").read_bytes() == b"\xff\xd8" and (tmp_path / "notes.txt").read_text() == "mine"
    with pytest.raises(StoreError, match="not an evsda run store"):
        run_graph(graph, folder, resume=True)
    run_graph(graph, tmp_path / "run.zarr")
    run_graph(load_graph(chain(tmp_path, seed=8)), tmp_path / "run.zarr", overwrite=True)
    assert RunStore.open(tmp_path / "run.zarr").attrs["seed"] == 8


def test_windows_and_seeds_are_checked_in_the_python_api():
    from evsda.graph import InputError, ParameterError

    with pytest.raises(InputError, match="stops .* before it starts"):
        Window(0, 10, 5)
    with pytest.raises(InputError, match="finite"):
        Window.from_seconds(0.0, float("inf"))
    with pytest.raises(ParameterError, match="non-negative"):
        RunInfo(seed=-1)
    windows = RunInfo(duration_ns=10**18, window_ns=1).windows(start=5)   # 10^18 windows, made one at a time
    assert [next(windows).index for _ in range(3)] == [5, 6, 7]


def test_run_graph_holds_blas_to_one_thread(plugin, tmp_path, monkeypatch):
    """The Python API limits BLAS threads as the CLI does (EVSDA_BLAS_THREADS, default 1): the limit
    in force during the run follows the variable, whatever the process had before."""
    from threadpoolctl import threadpool_info

    import evsda.graph.executor as executor_module
    seen = []
    real = executor_module.Executor.execute

    def spy(self):
        seen.append({info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"})
        return real(self)

    monkeypatch.setattr(executor_module.Executor, "execute", spy)
    run_graph(load_graph(chain(tmp_path)))
    monkeypatch.setenv("EVSDA_BLAS_THREADS", "2")
    run_graph(load_graph(chain(tmp_path)))
    assert seen[0] == {1} and seen[1] == {2}
    monkeypatch.setenv("EVSDA_BLAS_THREADS", "0")
    with pytest.raises(Exception, match="EVSDA_BLAS_THREADS"):
        run_graph(load_graph(chain(tmp_path)))
