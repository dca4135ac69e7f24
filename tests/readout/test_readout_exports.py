"""Exports read back with independent readers: `aedat` (AEDAT 4.0), `expelliarmus` (EVT 2.0,
and EVT 3.0 addresses), a decoder written here from Prophesee's published EVT 3.0 word
layout (EVT 3.0 times: expelliarmus 1.1 mis-decodes EVT 3.0 time-high words, see its
issue #20), h5py and numpy. Also: empty exports, absolute times past 2**24 µs, and memory
that stays flat in the number of exported events.
"""

import tracemalloc

import aedat
import h5py
import numpy as np
import pytest
from expelliarmus import Wizard

from evsda.blocks.readout.exporters import TONIC_DTYPE, export_events, extension_warning, infer_format
from evsda.graph import UserError

W, H = 1280, 720


def synthetic_chunks(n, chunk=50_000, seed=0, t0_ns=16_000_000_000):
    """Recorded events sorted by readout time, from 16 s on (past EVT 3.0's 2**24 µs wrap and
    float32's 2**24 µs precision limit), with sub-microsecond parts and the last row and column."""
    rng = np.random.default_rng(seed)
    t = t0_ns
    for lo in range(0, n, chunk):
        k = min(chunk, n - lo)
        readout = t + np.cumsum(rng.integers(0, 3_000, k))
        t = int(readout[-1])
        x = rng.integers(0, W, k)
        y = rng.integers(0, H, k)
        x[:2], y[:2] = W - 1, H - 1
        yield {"t_trigger_ns": readout - rng.integers(0, 50_000, k), "t_readout_ns": readout,
               "x": x.astype(np.uint16), "y": y.astype(np.uint16),
               "p": rng.choice(np.array([-1, 1], np.int8), k), "cause": rng.integers(0, 4, k).astype(np.uint8)}


def expected(n, **kw):
    chunks = list(synthetic_chunks(n, **kw))
    return {name: np.concatenate([c[name] for c in chunks]) for name in chunks[0]}


def multiset(*columns):
    order = np.lexsort(columns[::-1])
    return [np.asarray(c)[order].astype(np.int64) for c in columns]


N = 120_000
SUFFIX = {"aedat4": ".aedat4", "evt2": ".raw", "evt3": ".raw", "hdf5": ".h5", "npy": ".npy"}


def test_aedat4_read_by_aedat(tmp_path):
    path = tmp_path / "run.aedat4"
    assert export_events(synthetic_chunks(N), path, "aedat4", W, H) == N
    decoder = aedat.Decoder(str(path))
    assert decoder.id_to_stream()[0]["width"] == W and decoder.id_to_stream()[0]["height"] == H
    got = np.concatenate([packet["events"] for packet in decoder if "events" in packet])
    want = expected(N)
    np.testing.assert_array_equal(got["t"].astype(np.int64), want["t_readout_ns"] // 1000)
    np.testing.assert_array_equal(got["x"], want["x"])
    np.testing.assert_array_equal(got["y"], want["y"])
    np.testing.assert_array_equal(got["on"], want["p"] > 0)


def test_evt2_read_by_expelliarmus(tmp_path):
    path = tmp_path / "run.raw"
    assert export_events(synthetic_chunks(N), path, "evt2", W, H) == N
    got = Wizard(encoding="evt2", fpath=str(path)).read()
    want = expected(N)
    np.testing.assert_array_equal(got["t"], want["t_readout_ns"] // 1000)
    np.testing.assert_array_equal(got["x"], want["x"])
    np.testing.assert_array_equal(got["y"], want["y"])
    np.testing.assert_array_equal(got["p"], (want["p"] > 0).astype(np.uint8))


def read_evt3_words(path):
    """Decode EVT 3.0 from its published word layout (docs.prophesee.ai, "EVT 3.0 Format"):
    16-bit little-endian words, type in bits 15-12; ADDR_Y 0x0 (y in 10-0), ADDR_X 0x2
    (polarity 11, x 10-0), VECT_BASE_X 0x3 (polarity 11, x 10-0), VECT_12 0x4 / VECT_8 0x5
    (valid-pixel bits from the base x, which then advances by 12 / 8), TIME_LOW 0x6 and
    TIME_HIGH 0x8 (the low and high 12 bits of a 24-bit µs time base; a decreasing
    TIME_HIGH is a wrap of 2**24 µs)."""
    data = path.read_bytes()
    pos = 0
    while data[pos:pos + 1] == b"%":
        pos = data.index(b"\n", pos) + 1
    words = np.frombuffer(data[pos:], "<u2").tolist()
    out, y, base, pol, low, high, wraps = [], 0, 0, 0, 0, None, 0
    for w in words:
        kind, v = w >> 12, w & 0xFFF
        if kind == 0x0:
            y = v & 0x7FF
        elif kind == 0x2:
            out.append(((wraps << 24) | (high << 12) | low, v & 0x7FF, y, v >> 11))
        elif kind == 0x3:
            base, pol = v & 0x7FF, v >> 11
        elif kind in (0x4, 0x5):
            size = 12 if kind == 0x4 else 8
            out.extend(((wraps << 24) | (high << 12) | low, base + i, y, pol) for i in range(size) if v >> i & 1)
            base += size
        elif kind == 0x6:
            low = v
        elif kind == 0x8:
            wraps += high is not None and v < high
            high = v
    return np.array(out, np.int64).reshape(-1, 4)


def test_evt3_read_by_spec_decoder_and_expelliarmus(tmp_path):
    path = tmp_path / "run.raw"
    assert export_events(synthetic_chunks(N), path, "evt3", W, H) == N
    want = expected(N)
    t_us, x, y, p = want["t_readout_ns"] // 1000, want["x"], want["y"], (want["p"] > 0).astype(np.int64)
    got = read_evt3_words(path)
    # EVT 3.0 groups events of one time and row into vectors, so compare as multisets
    for a, b in zip(multiset(*got.T), multiset(t_us, x, y, p)):
        np.testing.assert_array_equal(a, b)
    other = Wizard(encoding="evt3", fpath=str(path)).read()
    for a, b in zip(multiset(other["x"], other["y"], other["p"]), multiset(x, y, p)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("time", ["readout", "trigger"])
def test_hdf5_keeps_integer_microseconds(tmp_path, time):
    path = tmp_path / "run.h5"
    assert export_events(synthetic_chunks(N), path, "hdf5", W, H, time=time, epoch="2024-03-01T02:15:00Z") == N
    want = expected(N)
    other = "trigger" if time == "readout" else "readout"
    with h5py.File(path, "r") as f:
        events = f["events"][:].astype(np.int64)
        assert f["events"].dtype == np.int64 and events.shape == (N, 4)      # no max_time_us: the widest
        assert f["events"].compression == "gzip" and f["events"].shuffle and f["cause"].dtype == np.uint8
        np.testing.assert_array_equal(events[:, 0], want[f"t_{time}_ns"] // 1000)
        np.testing.assert_array_equal(events[:, 1], want["x"])
        np.testing.assert_array_equal(events[:, 2], want["y"])
        np.testing.assert_array_equal(events[:, 3], want["p"] > 0)
        np.testing.assert_array_equal(f[f"t_{other}_us"][:], want[f"t_{other}_ns"] // 1000)
        np.testing.assert_array_equal(f["cause"][:], want["cause"])
        assert f.attrs["width"] == W and f.attrs["height"] == H and f.attrs["time_unit"] == "us"
        assert f.attrs["time_origin_utc"] == "2024-03-01T02:15:00Z" and f.attrs["t_column"] == time
    # the point of integers: v2e's float32 seconds cannot hold these microseconds
    assert np.any(np.float32(events[:, 0] / 1e6).astype(np.float64) * 1e6 != events[:, 0])


def test_hdf5_is_as_narrow_as_the_run_allows_and_compressed(tmp_path):
    want = expected(N)
    longest = int(max(want["t_readout_ns"].max(), want["t_trigger_ns"].max()) // 1000) + 1
    narrow, wide, raw = tmp_path / "narrow.h5", tmp_path / "wide.h5", tmp_path / "raw.h5"
    export_events(synthetic_chunks(N), narrow, "hdf5", W, H, max_time_us=longest)
    export_events(synthetic_chunks(N), wide, "hdf5", W, H, max_time_us=2**32)          # a run past 71.6 min
    export_events(synthetic_chunks(N), raw, "hdf5", W, H, max_time_us=longest, compression=False)
    with h5py.File(narrow, "r") as f, h5py.File(wide, "r") as g:
        assert f["events"].dtype == np.uint32 and f["t_trigger_us"].dtype == np.uint32   # v2e's dtype
        assert g["events"].dtype == np.int64
        np.testing.assert_array_equal(f["events"][:], g["events"][:])
        np.testing.assert_array_equal(f["t_trigger_us"][:], want["t_trigger_ns"] // 1000)
    assert narrow.stat().st_size < 0.6 * raw.stat().st_size
    late = {k: v[:1].copy() for k, v in next(iter(synthetic_chunks(N))).items()}
    late["t_readout_ns"][:] = 2**33 * 1000          # past what the stated duration allows in uint32
    with pytest.raises(UserError, match="outside the run"):
        export_events(iter([late]), tmp_path / "late.h5", "hdf5", W, H, max_time_us=longest)


def test_the_format_follows_the_extension_and_odd_extensions_are_warned_about():
    assert [infer_format(f"a{ext}") for ext in (".aedat4", ".raw", ".h5", ".HDF5", ".npy")] == \
        ["aedat4", "evt3", "hdf5", "hdf5", "npy"]
    with pytest.raises(UserError, match="give --format"):
        infer_format("a.raw2")
    assert extension_warning("a.raw", "evt2") is None and extension_warning("a.h5", "hdf5") is None
    assert ".raw" in extension_warning("a.raw2", "evt2") and ".aedat4" in extension_warning("a.aedat", "aedat4")


def test_npy_has_tonic_fields(tmp_path):
    path = tmp_path / "run.npy"
    assert export_events(synthetic_chunks(N), path, "npy", W, H) == N
    got = np.load(path)
    want = expected(N)
    assert got.dtype == TONIC_DTYPE and got.dtype.names == ("x", "y", "t", "p")
    np.testing.assert_array_equal(got["t"], want["t_readout_ns"] // 1000)
    np.testing.assert_array_equal(got["x"], want["x"])
    np.testing.assert_array_equal(got["p"], want["p"] > 0)
    assert np.load(path, mmap_mode="r").shape == (N,)


def test_empty_exports_are_valid_files(tmp_path):
    for fmt in ("aedat4", "evt2", "evt3", "hdf5", "npy"):
        path = tmp_path / f"empty_{fmt}{SUFFIX[fmt]}"
        assert export_events(iter([]), path, fmt, W, H) == 0
    assert [p for p in aedat.Decoder(str(tmp_path / "empty_aedat4.aedat4")) if "events" in p] == []
    for version in ("evt2", "evt3"):
        got = Wizard(encoding=version, fpath=str(tmp_path / f"empty_{version}.raw")).read()
        assert got is None or len(got) == 0
    assert read_evt3_words(tmp_path / "empty_evt3.raw").shape == (0, 4)
    with h5py.File(tmp_path / "empty_hdf5.h5", "r") as f:
        assert f["events"].shape == (0, 4)
    assert np.load(tmp_path / "empty_npy.npy").shape == (0,)


@pytest.mark.parametrize("fmt", ["aedat4", "evt2", "evt3", "hdf5", "npy"])
def test_memory_stays_flat_in_the_number_of_events(tmp_path, fmt):
    """Peak Python/numpy memory while exporting 20 chunks is that of exporting 2: the writers
    hold one chunk at a time (the 10**8-event export is in benchmarks/readout_throughput.py)."""
    peaks = []
    for n in (100_000, 1_000_000):
        tracemalloc.start()
        export_events(synthetic_chunks(n, chunk=50_000), tmp_path / f"m{n}{SUFFIX[fmt]}", fmt, W, H)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    chunk_bytes = 50_000 * 40       # one chunk of the generator's fields
    assert peaks[1] < peaks[0] + chunk_bytes, peaks


def test_user_mistakes_are_one_clear_sentence(tmp_path):
    with pytest.raises(UserError, match="readout time"):
        export_events(synthetic_chunks(10), tmp_path / "a.aedat4", "aedat4", W, H, time="trigger")
    with pytest.raises(UserError, match="2048"):
        export_events(synthetic_chunks(10), tmp_path / "a.raw", "evt3", 4096, 3072)
    with pytest.raises(UserError, match="unknown export format"):
        export_events(synthetic_chunks(10), tmp_path / "a.x", "mp4", W, H)
