"""Event-file writers: recorded events to the formats event-camera tools read.

Every writer takes an iterable of event chunks (dicts of numpy arrays ``t_trigger_ns``,
``t_readout_ns``, ``x``, ``y``, ``p``, ``cause``, as :meth:`RunStore.iter_events` yields
them) and the sensor size, and streams: memory stays flat in the number of events.

Time. Every format carries integer microseconds since the run's start epoch
(``floor(t_ns / 1000)``), never shifted so that the first event is at zero:

* ``aedat4`` (iniVation AEDAT 4.0) and ``evt2`` / ``evt3`` (Prophesee EVT 2.0 / 3.0 raw)
  are camera formats; they carry the readout time ``t_a`` of paper Eq. 22, the time a real
  camera stamps (monotonic, as these formats require). They are written with the
  ``faery`` package with ``zero_t0=False``, so faery keeps absolute times: EVT 3.0's
  24-bit time base wraps every 2**24 µs (16.8 s) and faery writes the wraps, so a reader
  that counts them from the start of the file recovers the absolute time. EVT 2.0/3.0
  address at most 2048 x 2048 pixels.
* ``hdf5`` follows v2e's layout (dataset ``events``, one row ``[t, x, y, p]`` per event,
  ``p`` 1 for ON and 0 for OFF), in integer microseconds (v2e converts a float32 time that
  loses microseconds after ~17 s, 2**24 µs). The dtype is no wider than needed: v2e's uint32
  when every time of the run fits (runs shorter than 2**32 µs = 71.6 min, given by
  ``max_time_us``), else int64. Datasets are gzip-compressed with the byte shuffle filter by
  default (every HDF5 reader decodes gzip). Column ``t`` is the readout time by default; the
  parallel datasets ``t_trigger_us`` (or ``t_readout_us``) and ``cause``
  (:class:`~evsda.blocks.ports.EventCause`, the simulation's truth; uint8) keep the rest of
  the Eq. 22 record. Attributes give the sensor size and the time origin.
* ``npy`` is a numpy structured array with tonic's fields and types
  ``x`` int16, ``y`` int16, ``t`` int64 [µs], ``p`` bool (True = ON), readout time by
  default.

``time="trigger"`` writes the trigger time ``t_t`` instead (hdf5 and npy only: trigger
times are not monotonic in readout order, which the camera formats forbid).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np
from evsda.graph import UserError

Chunk = dict[str, np.ndarray]
NS_PER_US = 1000
TONIC_DTYPE = np.dtype([("x", np.int16), ("y", np.int16), ("t", np.int64), ("p", bool)])
EVT_MAX_SIZE_PX = 2048          # EVT 2.0 and 3.0 carry 11-bit addresses [pixel]
TIME_FIELDS = {"readout": "t_readout_ns", "trigger": "t_trigger_ns"}
HDF5_DISK_MARGIN = 8 << 20      # bytes kept free below an HDF5 export (its metadata and cache flushes)


def _micros(chunk: Chunk, time: str) -> np.ndarray:
    return np.asarray(chunk[TIME_FIELDS[time]], np.int64) // NS_PER_US


def _counted(chunks: Iterable[Chunk], counter: list[int]) -> Iterator[Chunk]:
    for chunk in chunks:
        n = len(chunk["x"])
        if n:
            counter[0] += n
            yield chunk


# -- camera formats, through faery ------------------------------------------------------------
def _faery_stream(chunks: Iterable[Chunk]) -> Iterator[np.ndarray]:
    import faery

    for chunk in chunks:
        out = np.empty(len(chunk["x"]), dtype=faery.EVENTS_DTYPE)
        out["t"] = _micros(chunk, "readout")
        out["x"] = chunk["x"]
        out["y"] = chunk["y"]
        out["p"] = np.asarray(chunk["p"]) > 0
        yield out


def _write_faery(chunks, path, width, height, file_type: str, version: str | None) -> int:
    from faery.file_encoder import events_to_file

    counter = [0]
    events_to_file(_faery_stream(_counted(chunks, counter)), Path(path), dimensions=(width, height),
                   version=version, zero_t0=False, file_type=file_type)
    return counter[0]


def write_aedat4(chunks: Iterable[Chunk], path, width: int, height: int, time: str = "readout", **_) -> int:
    """AEDAT 4.0 (one event stream, LZ4) with readout times [µs since the run epoch]; returns the count."""
    _camera_time(time, "aedat4")
    return _write_faery(chunks, path, width, height, "aedat", None)


def _evt_writer(version: str) -> Callable[..., int]:
    def write(chunks: Iterable[Chunk], path, width: int, height: int, time: str = "readout", **_) -> int:
        _camera_time(time, version)
        if width > EVT_MAX_SIZE_PX or height > EVT_MAX_SIZE_PX:
            raise UserError(f"{version} addresses at most {EVT_MAX_SIZE_PX} x {EVT_MAX_SIZE_PX} pixels; "
                            f"this sensor is {width} x {height}: export to aedat4, hdf5 or npy instead")
        return _write_faery(chunks, path, width, height, "evt", version)

    write.__name__ = f"write_{version}"
    write.__doc__ = f"Prophesee {version.upper()} raw with readout times [µs since the run epoch]; returns the count."
    return write


write_evt2 = _evt_writer("evt2")
write_evt3 = _evt_writer("evt3")


def _camera_time(time: str, fmt: str) -> None:
    if time != "readout":
        raise UserError(f"{fmt} files carry the readout time (camera formats need monotonic timestamps); "
                        f"use --time readout, or export to hdf5 or npy for trigger times")


# -- HDF5 in v2e's layout ---------------------------------------------------------------------------
#: HDF5 compression by default: gzip (deflate) at a moderate level, after the byte shuffle filter
HDF5_COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True}


def hdf5_time_dtype(max_time_us: int | None) -> np.dtype:
    """The narrowest dtype of the ``events`` rows: v2e's uint32 when every time fits, else int64."""
    if max_time_us is not None and 0 <= max_time_us < 2**32:
        return np.dtype(np.uint32)
    return np.dtype(np.int64)


def write_hdf5(chunks: Iterable[Chunk], path, width: int, height: int, time: str = "readout",
               epoch: str | None = None, compression: bool = True, max_time_us: int | None = None, **_) -> int:
    """v2e-layout HDF5 in integer microseconds, as narrow as the run allows and compressed (see the module
    docstring); returns the count. ``max_time_us`` bounds every time in the file (the run's duration)."""
    import h5py

    other = "trigger" if time == "readout" else "readout"
    dtype = hdf5_time_dtype(max_time_us)
    if max(width, height) >= np.iinfo(dtype).max:
        dtype = np.dtype(np.int64)
    limits = np.iinfo(dtype)
    filters = HDF5_COMPRESSION if compression else {}
    rows = 1 << 16
    folder = Path(path).parent
    with h5py.File(path, "w") as f:
        events = f.create_dataset("events", shape=(0, 4), maxshape=(None, 4), dtype=dtype,
                                  chunks=(rows, 4), **filters)
        extra_t = f.create_dataset(f"t_{other}_us", shape=(0,), maxshape=(None,), dtype=dtype,
                                   chunks=(rows,), **filters)
        cause = f.create_dataset("cause", shape=(0,), maxshape=(None,), dtype=np.uint8,
                                 chunks=(rows,), **filters)
        f.attrs.update({
            "width": width, "height": height, "time_unit": "us", "time_origin_utc": epoch or "",
            "t_column": time, "columns": "t,x,y,p", "polarity": "1 ON, 0 OFF",
            "layout": f"v2e events (N, 4) of {dtype.name}", "source": "evsda",
        })
        n = 0
        for chunk in chunks:
            k = len(chunk["x"])
            if not k:
                continue
            _check_room(folder, path, 41 * k)
            t, t_other = _micros(chunk, time), _micros(chunk, other)
            if min(t.min(), t_other.min()) < limits.min or max(t.max(), t_other.max()) > limits.max:
                raise UserError(f"{path}: an event time lies outside the run ({max_time_us} µs); "
                                f"the store's events and duration disagree")
            block = np.empty((k, 4), dtype)
            block[:, 0] = t
            block[:, 1] = chunk["x"]
            block[:, 2] = chunk["y"]
            block[:, 3] = np.asarray(chunk["p"]) > 0
            for dataset in (events, extra_t, cause):
                dataset.resize(n + k, axis=0)
            events[n:n + k] = block
            extra_t[n:n + k] = t_other
            cause[n:n + k] = chunk["cause"]
            n += k
    return n


def _check_room(folder: Path, path, nbytes: int) -> None:
    """Stop before the disk fills up: HDF5 (1.14, through h5py 3) crashes the process at exit after a
    write has failed with ENOSPC, so an export must never let it reach that point."""
    free = shutil.disk_usage(folder).free
    if free < 2 * nbytes + HDF5_DISK_MARGIN:
        raise UserError(f"{path}: the disk is nearly full ({free / 1e6:.1f} MB free); stopped the HDF5 export "
                        f"before it runs out of space")


# -- numpy structured array (tonic's fields) ---------------------------------------------------------
def write_npy(chunks: Iterable[Chunk], path, width: int, height: int, time: str = "readout", **_) -> int:
    """A ``.npy`` of tonic's ``x, y, t, p`` structured dtype, streamed; returns the count.

    The header is written first with room for any length and rewritten with the final
    length at the end (numpy pads headers with spaces, so the size stays fixed).
    """
    if max(width, height) > np.iinfo(np.int16).max:
        raise UserError(f"npy (tonic) stores x and y as int16; this sensor is {width} x {height}")
    with open(path, "wb") as f:
        f.write(_npy_header(0))
        n = 0
        for chunk in chunks:
            k = len(chunk["x"])
            if not k:
                continue
            out = np.empty(k, TONIC_DTYPE)
            out["x"], out["y"] = chunk["x"], chunk["y"]
            out["t"] = _micros(chunk, time)
            out["p"] = np.asarray(chunk["p"]) > 0
            f.write(out.tobytes())
            n += k
        f.seek(0)
        f.write(_npy_header(n))
    return n


def _npy_header(n: int) -> bytes:
    """A version 1.0 ``.npy`` header of fixed size for a 1-D array of ``n`` TONIC_DTYPE records."""
    fields = {"descr": np.lib.format.dtype_to_descr(TONIC_DTYPE), "fortran_order": False, "shape": (n,)}
    text = repr(fields)
    room = len(repr({**fields, "shape": (2**63 - 1,)}))
    body = text + " " * (room - len(text))
    total = 10 + len(body) + 1                    # magic (6) + version (2) + length (2) + body + "\n"
    body += " " * (-total % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(body).to_bytes(2, "little") + body.encode("latin1")


#: upper estimates of the bytes a file takes per event, to check the disk has room before writing
#: (aedat4: LZ4-compressed records, measured 7.9 B/event on noise; the rest are fixed-size records)
BYTES_PER_EVENT = {"aedat4": 16, "evt2": 4, "evt3": 6, "hdf5": 41, "npy": TONIC_DTYPE.itemsize}

WRITERS: dict[str, Callable[..., int]] = {
    "aedat4": write_aedat4,
    "evt2": write_evt2,
    "evt3": write_evt3,
    "hdf5": write_hdf5,
    "npy": write_npy,
}


#: the file extensions readers expect for each format (the first is the one a format is inferred from):
#: Metavision opens EVT 2.0/3.0 only as ``.raw`` (the header names the version), dv / aedat as ``.aedat4``
EXTENSIONS: dict[str, tuple[str, ...]] = {
    "aedat4": (".aedat4",),
    "evt3": (".raw",),          # Gen4's native encoding: what a bare .raw is taken to be
    "evt2": (".raw",),
    "hdf5": (".h5", ".hdf5"),
    "npy": (".npy",),
}


def infer_format(path) -> str:
    """The export format of ``path`` from its extension (``.raw`` is EVT 3.0); a UserError if none fits."""
    suffix = Path(path).suffix.lower()
    for fmt, suffixes in EXTENSIONS.items():
        if suffix in suffixes:
            return fmt
    known = ", ".join(sorted({s for suffixes in EXTENSIONS.values() for s in suffixes}))
    raise UserError(f"cannot tell the export format from the extension of {path} (known: {known}); "
                    f"give --format")


def extension_warning(path, fmt: str) -> str | None:
    """A warning when ``path``'s extension is one readers of ``fmt`` refuse or take for another format."""
    suffix = Path(path).suffix.lower()
    expected = EXTENSIONS[fmt]
    if suffix in expected:
        return None
    return (f"{path}: readers of {fmt} files expect the extension {' or '.join(expected)}; "
            f"{suffix or 'no extension'} may be refused or taken for another format")


def export_events(chunks: Iterable[Chunk], path, fmt: str, width: int, height: int, **options) -> int:
    """Write ``chunks`` to ``path`` in format ``fmt`` (one of :data:`WRITERS`); returns the count."""
    try:
        writer = WRITERS[fmt]
    except KeyError:
        raise UserError(f"unknown export format {fmt!r}; choose one of {', '.join(WRITERS)}") from None
    if options.get("time", "readout") not in TIME_FIELDS:
        raise UserError(f"--time must be 'readout' or 'trigger', got {options['time']!r}")
    return writer(chunks, path, width, height, **options)
