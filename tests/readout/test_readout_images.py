"""Fig. 6 images and animations, and the `export` / `render` commands on a real run store."""

import argparse

import h5py
import numpy as np
import pytest
from PIL import Image

from evsda.blocks.ports import FocalPlane
from evsda.blocks.readout.commands import COMMANDS
from evsda.blocks.readout.render import accumulate, event_rgb, render_gif, render_png
from evsda.graph import UserError
from evsda.graph.store import RunStore

W, H = 96, 64


def chunks_of(events, size):
    n = len(events["x"])
    for lo in range(0, n, size):
        yield {k: v[lo:lo + size] for k, v in events.items()}


def random_events(n=5000, seed=0, duration_ns=1_000_000_000):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, duration_ns, n))
    return {"t_trigger_ns": t - 10, "t_readout_ns": t, "x": rng.integers(0, W, n).astype(np.uint16),
            "y": rng.integers(0, H, n).astype(np.uint16), "p": rng.choice(np.array([-1, 1], np.int8), n),
            "cause": np.zeros(n, np.uint8)}


def test_accumulate_counts_each_polarity_in_the_time_slice():
    ev = random_events()
    on, off = accumulate(chunks_of(ev, 777), W, H, 200_000_000, 700_000_000)
    sel = (ev["t_readout_ns"] >= 200_000_000) & (ev["t_readout_ns"] < 700_000_000)
    want_on, want_off = np.zeros((H, W), int), np.zeros((H, W), int)
    np.add.at(want_on, (ev["y"][sel & (ev["p"] > 0)], ev["x"][sel & (ev["p"] > 0)]), 1)
    np.add.at(want_off, (ev["y"][sel & (ev["p"] < 0)], ev["x"][sel & (ev["p"] < 0)]), 1)
    np.testing.assert_array_equal(on, want_on)
    np.testing.assert_array_equal(off, want_off)


def test_on_is_green_and_off_is_red():
    on = np.array([[3, 0], [0, 0]])
    off = np.array([[0, 3], [0, 0]])
    rgb = event_rgb(on, off)
    np.testing.assert_array_equal(rgb[0, 0], [0, 1, 0])
    np.testing.assert_array_equal(rgb[0, 1], [1, 0, 0])
    np.testing.assert_array_equal(rgb[1, 1], [0, 0, 0])


def test_png_shows_an_on_track_in_green(tmp_path):
    """A horizontal track of ON events across the middle rows: green pixels, no red ones."""
    n = 4000
    x = np.repeat(np.arange(W), n // W + 1)[:n]
    ev = {"t_trigger_ns": np.arange(n), "t_readout_ns": np.arange(n), "x": x.astype(np.uint16),
          "y": np.full(n, H // 2, np.uint16), "p": np.ones(n, np.int8), "cause": np.zeros(n, np.uint8)}
    on, off = render_png(chunks_of(ev, 1000), tmp_path / "fig6.png", W, H)
    assert (on, off) == (n, 0)
    image = np.asarray(Image.open(tmp_path / "fig6.png").convert("RGB")).astype(int)
    green = (image[..., 1] > 200) & (image[..., 0] < 60) & (image[..., 2] < 60)
    red = (image[..., 0] > 200) & (image[..., 1] < 60) & (image[..., 2] < 60)
    band = np.flatnonzero(green.sum(axis=1) > 0.5 * image.shape[1])   # rows crossed by the track
    assert 3 <= band.size <= 12 and np.all(np.diff(band) == 1)
    assert not red[band].any()


def test_gif_has_one_frame_per_slice_and_moves(tmp_path):
    """An event walks one column per 10 ms: frame k of 10 (100 ms slices) holds columns 10k..10k+9."""
    t = np.arange(W) * 10_000_000
    ev = {"t_trigger_ns": t, "t_readout_ns": t, "x": np.arange(W).astype(np.uint16),
          "y": np.full(W, H - 5, np.uint16), "p": np.ones(W, np.int8), "cause": np.zeros(W, np.uint8)}
    n = render_gif(chunks_of(ev, 7), tmp_path / "a.gif", W, H, 0, 1_000_000_000, n_frames=10, fps=5)
    assert n == 10
    gif = Image.open(tmp_path / "a.gif")
    assert gif.n_frames == 10
    centroids = []
    for k in range(gif.n_frames):
        gif.seek(k)
        frame = np.asarray(gif.convert("RGB")).astype(int)
        green = (frame[..., 1] > 150) & (frame[..., 0] < 80)
        green[: frame.shape[0] // 2] = False                  # the track is low; the legend is high
        cols = np.flatnonzero(green.any(axis=0))
        centroids.append(cols.mean() if cols.size else np.nan)
    assert np.all(np.diff(centroids[:9]) > 0)                # the track moves right frame by frame


# -- commands on a run store ---------------------------------------------------------------------------
def make_store(path, events, fp=FocalPlane(W, H, 10e-6, 1.0)):
    store = RunStore.create(path, attrs={"start_epoch": "2024-03-01T02:15:00Z", "duration_ns": 1_000_000_000})
    store.append_events(events, focal_plane=fp)
    store.commit(windows=1)
    return path


def run_command(name, argv):
    command = next(c for c in COMMANDS if c.name == name)
    parser = argparse.ArgumentParser(prog=f"evsda {name}")
    command.configure(parser)
    return command.run(parser.parse_args(argv))


def test_export_and_render_commands(tmp_path):
    ev = random_events(20_000)
    store = make_store(tmp_path / "run.zarr", ev)
    assert run_command("export", [str(store), "--format", "hdf5", "-o", str(tmp_path / "e.h5"),
                                  "--chunk-size", "3000"]) == 0
    with h5py.File(tmp_path / "e.h5", "r") as f:
        np.testing.assert_array_equal(f["events"][:, 0], ev["t_readout_ns"] // 1000)
        assert f.attrs["time_origin_utc"] == "2024-03-01T02:15:00Z"
    assert run_command("render", [str(store), "--png", str(tmp_path / "f.png"), "--gif", str(tmp_path / "f.gif"),
                                  "--frames", "4", "--start-s", "0.25"]) == 0
    assert Image.open(tmp_path / "f.gif").n_frames == 4
    assert Image.open(tmp_path / "f.png").size[0] > 100


def test_export_of_a_run_without_events(tmp_path):
    empty = {k: v[:0] for k, v in random_events(1).items()}
    store = make_store(tmp_path / "empty.zarr", empty)
    assert run_command("export", [str(store), "--format", "npy", "-o", str(tmp_path / "e.npy")]) == 0
    assert np.load(tmp_path / "e.npy").shape == (0,)
    assert run_command("render", [str(store), "--png", str(tmp_path / "e.png")]) == 0


def test_command_mistakes_are_user_errors(tmp_path):
    store = make_store(tmp_path / "run.zarr", random_events(10))
    with pytest.raises(UserError, match="--png"):
        run_command("render", [str(store)])
    with pytest.raises(UserError, match="after --start-s"):
        run_command("render", [str(store), "--png", "x.png", "--start-s", "0.5", "--stop-s", "0.1"])
    with pytest.raises(UserError):
        run_command("export", [str(tmp_path / "missing.zarr"), "--format", "npy", "-o", "x.npy"])


def test_export_infers_the_format_and_warns_about_odd_extensions(tmp_path, capsys):
    ev = random_events(2000)
    store = make_store(tmp_path / "run.zarr", ev)
    assert run_command("export", [str(store), "-o", str(tmp_path / "e.h5")]) == 0
    with h5py.File(tmp_path / "e.h5", "r") as f:       # a 1 s run: v2e's uint32 microseconds, compressed
        assert f["events"].dtype == np.uint32 and f["events"].compression == "gzip"
        np.testing.assert_array_equal(f["events"][:, 0], ev["t_readout_ns"] // 1000)
    assert capsys.readouterr().err == ""
    assert run_command("export", [str(store), "--format", "evt2", "-o", str(tmp_path / "e.raw2")]) == 0
    assert "evsda: warning:" in capsys.readouterr().err and (tmp_path / "e.raw2").stat().st_size > 0
    with pytest.raises(UserError, match="give --format"):
        run_command("export", [str(store), "-o", str(tmp_path / "e.dat")])
