"""The ground truth in the run store (``truth`` group) and its export beside the events (CSV, HDF5),
on synthetic truth written through the store's own API and read back with csv and h5py.

End to end (the optics block's truth against the satellite block and the events):
``tests/test_end_to_end_scenes.py``.
"""

import csv

import h5py
import numpy as np
import pytest

from evsda.blocks.optics.truth import truth_table
from evsda.blocks.ports import FocalPlane, SourceKind
from evsda.graph.cli import main
from evsda.graph.store import RunStore

FP = FocalPlane(64, 48, 10e-6, 0.5)


def window_truth(t_ns, ids, kinds, x):
    """Truth of sources ``ids`` with columns ``x[n_t, n_src]`` (NaN: off the detector)."""
    x = np.asarray(x, float)
    tracks = [{"x": x[:, j], "y": x[:, j] / 2, "flux": np.full(len(t_ns), 1e6 * (j + 1)),
               "magnitude": np.full(len(t_ns), 9.0 + j), "range": np.full(len(t_ns), 1e6 if kinds[j] == 0 else np.inf)}
              for j in range(len(ids))]
    return truth_table(FP, np.asarray(t_ns), ids, kinds, tracks)


@pytest.fixture
def store(tmp_path):
    s = RunStore.create(tmp_path / "run.zarr", attrs={"start_epoch": "2024-01-01T00:00:00Z"})
    s.append_events({"t_trigger_ns": [5], "t_readout_ns": [6], "x": [1], "y": [2], "p": [1], "cause": [0]},
                    focal_plane=FP)
    nan = np.nan
    # window 0: a satellite (on the detector at its second sample only) and a star
    s.append_truth("optics", window_truth([0, 1000], ["25544", "HIP 7"], [0, 1], [[nan, 5.0], [10.5, 6.0]]))
    # window 1: a new satellite appears first in the list; the star is still there
    s.append_truth("optics", window_truth([2000, 3000], ["99999", "25544", "HIP 7"], [0, 0, 1],
                                          [[1.0, 11.0, 7.0], [2.0, 11.5, nan]]))
    s.commit(windows=2, complete=True)
    return s


def test_rows_are_the_on_detector_samples_numbered_by_source(store):
    rows = RunStore.open(store.path).read_truth()
    assert rows["t_ns"].tolist() == [0, 1000, 1000, 2000, 2000, 2000, 3000, 3000]
    assert rows["source_id"].tolist() == ["HIP 7", "25544", "HIP 7", "25544", "HIP 7", "99999", "25544", "99999"]
    assert rows["x_px"].tolist() == [5.0, 10.5, 6.0, 11.0, 7.0, 1.0, 11.5, 2.0]
    assert rows["kind"].tolist() == [1, 0, 1, 0, 1, 0, 0, 0]
    assert np.isinf(rows["range_m"][rows["kind"] == SourceKind.STAR]).all()
    # each (block, source) is numbered once, in order of first appearance
    group = RunStore.open(store.path).group["truth"]
    assert group["source_id"][:].tolist() == ["25544", "HIP 7", "99999"]
    assert group["source_id"].metadata.dimension_names == ("source",)
    assert group["x_px"].metadata.dimension_names == ("sample",)
    assert group["photon_flux"].attrs["units"] == "photon s^-1 m^-2"


def test_sources_repeated_window_after_window_keep_their_numbers(tmp_path):
    """A block's sources are mostly the same every window (the store then takes their last numbers again): the same
    truth as numbering every source one by one each window (the last numbers dropped before each append)."""
    windows = [(["25544", "HIP 7"], [0, 1]), (["25544", "HIP 7"], [0, 1]), (["99999", "25544", "HIP 7"], [0, 0, 1]),
               (["25544", "HIP 7"], [0, 1]), (["25544", "HIP 7"], [0, 1])]
    written = {}
    for label in ("kept", "looked up"):
        s = RunStore.create(tmp_path / f"{label}.zarr")
        for k, (ids, kinds) in enumerate(windows):
            if label == "looked up":
                s._truth_ids.clear()
            x = np.arange(2 * len(ids), dtype=float).reshape(2, len(ids)) + k
            s.append_truth("optics", window_truth([2 * k, 2 * k + 1], ids, kinds, x))
        s.commit(windows=len(windows), complete=True)
        written[label] = RunStore.open(s.path).read_truth()
    assert written["kept"]["source_id"].tolist() == written["looked up"]["source_id"].tolist()
    for name, values in written["looked up"].items():
        assert np.array_equal(written["kept"][name], values), name
    group = RunStore.open(tmp_path / "kept.zarr").group["truth"]
    assert group["source_id"][:].tolist() == ["25544", "HIP 7", "99999"]


def test_export_writes_the_truth_beside_the_events_as_csv_and_hdf5(store, tmp_path, capsys):
    out = tmp_path / "events.h5"
    assert main(["export", str(store.path), "--format", "hdf5", "-o", str(out), "--truth"]) == 0
    assert "8 truth rows (3 sources)" in capsys.readouterr().out
    with open(tmp_path / "events.truth.csv") as f:
        table = list(csv.DictReader(f))
    rows = store.read_truth()
    assert [r["t_us"] for r in table][:3] == ["0.000", "1.000", "1.000"]
    assert [r["source_id"] for r in table] == rows["source_id"].tolist()
    assert [r["kind"] for r in table][:2] == ["star", "satellite"]
    np.testing.assert_array_equal([float(r["x_px"]) for r in table], rows["x_px"])
    np.testing.assert_array_equal([float(r["photon_flux"]) for r in table], rows["photon_flux"])

    assert main(["export", str(store.path), "--format", "npy", "-o", str(tmp_path / "events.npy"),
                 "--truth", "hdf5"]) == 0
    with h5py.File(tmp_path / "events.truth.h5") as f:
        np.testing.assert_array_equal(f["t_us"][:], rows["t_ns"] / 1000)
        assert [s.decode() for s in f["source_id"][:]] == rows["source_id"].tolist()
        np.testing.assert_array_equal(f["y_px"][:], rows["y_px"])
        assert f["kind"].attrs["flag_meanings"] == "satellite star" and f["range_m"].attrs["units"] == "m"
        assert f.attrs["width"] == 64 and f.attrs["time_origin_utc"] == "2024-01-01T00:00:00Z"


def test_export_truth_refuses_a_store_without_truth_and_an_existing_file(store, tmp_path, capsys):
    bare = RunStore.create(tmp_path / "bare.zarr")
    bare.append_events({"t_trigger_ns": [5], "t_readout_ns": [6], "x": [1], "y": [2], "p": [1], "cause": [0]},
                       focal_plane=FP)
    bare.commit(windows=1, complete=True)
    assert main(["export", str(bare.path), "--format", "npy", "-o", str(tmp_path / "a.npy"), "--truth"]) == 2
    assert "holds no ground truth" in capsys.readouterr().err
    assert not (tmp_path / "a.npy").exists()
    (tmp_path / "b.truth.csv").write_text("keep")
    assert main(["export", str(store.path), "--format", "npy", "-o", str(tmp_path / "b.npy"), "--truth"]) == 2
    assert "b.truth.csv" in capsys.readouterr().err
    assert (tmp_path / "b.truth.csv").read_text() == "keep" and not (tmp_path / "b.npy").exists()


def test_info_lists_the_truth_by_dimension(store):
    from evsda.graph.report import describe_store, store_info

    info = store_info(RunStore.open(store.path))
    assert info["tables"]["truth"]["source_id"] == 3 and info["tables"]["truth"]["x_px"] == 8
    assert "table        truth: 8 rows of " in describe_store(info) and "; 3 rows of block, kind, source_id" in \
        describe_store(info)
