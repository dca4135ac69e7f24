"""A run's Zarr 3 store: events, products, metrics and crash-safe checkpoints.

Layout::

    root attrs      evsda_version, graph (resolved), graph_hash, seed, start_epoch,
                    window_ns, duration_ns, n_windows, timing, committed
    events/         t_trigger_ns, t_readout_ns (int64), x, y (uint16), p (int8), cause (uint8)
    products/<block>/<port>/<field>         every window's value, flattened and appended
    products/<block>/<port>/<field>.shape   [n_windows, ndim] shape of each window's value
    products/<block>/<port>/_attrs          one JSON document per window (scalars, strings)
    metrics/        attrs: values, units
    checkpoint/w<k>/<block>/                block state and RNG state after window k

Crash safety: zarr >= 3.1.3 writes every chunk and metadata document atomically
(temporary file + rename), but ``append`` resizes an array before its data lands.
So appended arrays are never trusted beyond the lengths recorded in
``attrs["committed"]``, which is written last, after the data and the checkpoint of
a window. On resume every array is truncated back to its committed length and the
checkpoint named in the commit record is loaded; anything written after it is
discarded. A run killed at any instruction therefore resumes from its last complete
window.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import zarr
from zarr.codecs import BloscCodec

from . import registry
from .errors import StoreError
from .ports import PORT_TYPES, PortValue

EVENT_FIELDS: dict[str, np.dtype] = {
    "t_trigger_ns": np.dtype(np.int64),
    "t_readout_ns": np.dtype(np.int64),
    "x": np.dtype(np.uint16),
    "y": np.dtype(np.uint16),
    "p": np.dtype(np.int8),
    "cause": np.dtype(np.uint8),
}
EVENT_CHUNK_BYTES = 4 << 20     # events/ arrays are chunked by size: few files, fast appends
PRODUCT_CHUNK_BYTES = 256 << 10
EVENT_CHUNK = 1 << 20           # default number of events per chunk yielded by iter_events
#: appended data waits in memory until a commit or until this many bytes are pending
FLUSH_BYTES = 64 << 20
#: fast, multithreaded compression: bit-shuffled LZ4 suits sorted timestamps and small integers
COMPRESSOR = BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle")
FORMAT = "evsda-run/1"


class RunStore:
    """A run store on disk. Create with :meth:`create`, open with :meth:`open`."""

    def __init__(self, group: zarr.Group, path: Path, writable: bool):
        self.group = group
        self.path = path
        self.writable = writable
        self._lengths: dict[str, int] = dict(self._committed().get("lengths", {}))
        self._written: dict[str, int] = dict(self._lengths)
        self._pending: dict[str, list[np.ndarray]] = {}
        self._pending_bytes = 0
        self._arrays: dict[str, zarr.Array] = {}

    # -- opening ----------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, attrs: dict[str, Any] | None = None, overwrite: bool = False) -> "RunStore":
        """A new, empty store at ``path``; refuses to replace an existing one unless ``overwrite``."""
        path = Path(path)
        if path.exists() and not overwrite:
            raise StoreError(f"{path} already exists; choose another output, pass --overwrite to replace it, "
                             f"or --resume to continue the run it holds")
        try:
            group = zarr.open_group(str(path), mode="w", zarr_format=3)
        except OSError as exc:
            raise StoreError(f"cannot create run store {path}: {exc}") from None
        group.attrs.update({"format": FORMAT, **(attrs or {}), "committed": {"windows": 0, "lengths": {}}})
        return cls(group, path, writable=True)

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> "RunStore":
        """Open an existing store read-only (``mode="r"``) or to continue writing (``"r+"``)."""
        path = Path(path)
        if not path.exists():
            raise StoreError(f"{path} does not exist")
        try:
            group = zarr.open_group(str(path), mode=mode, zarr_format=3)
        except Exception as exc:  # zarr raises several kinds for a non-store path
            raise StoreError(f"{path} is not an evsda run store ({exc})") from None
        if group.attrs.get("format") != FORMAT:
            raise StoreError(f"{path} is not an evsda run store (no '{FORMAT}' format attribute)")
        store = cls(group, path, writable=mode != "r")
        if store.writable:
            store._truncate_to_commit()
        return store

    # -- attributes ---------------------------------------------------------------------
    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self.group.attrs)

    def set_attrs(self, **values) -> None:
        self.group.attrs.update(values)

    def _committed(self) -> dict[str, Any]:
        return dict(self.group.attrs.get("committed", {"windows": 0, "lengths": {}}))

    @property
    def committed_windows(self) -> int:
        return int(self._committed().get("windows", 0))

    # -- appendable arrays -----------------------------------------------------------------
    def _array(self, key: str, dtype: np.dtype, chunk: int, trailing: tuple[int, ...] = ()) -> zarr.Array:
        array = self._arrays.get(key)
        if array is None:
            if key in self.group:
                array = self.group[key]
            else:
                compressors = [COMPRESSOR] if dtype.kind in "biuf" else "auto"
                array = self.group.create_array(key, shape=(0, *trailing), chunks=(chunk, *trailing), dtype=dtype,
                                                compressors=compressors)
            self._arrays[key] = array
        return array

    def _append(self, key: str, data: np.ndarray, chunk: int) -> None:
        """Queue ``data`` for appending to array ``key`` (written by :meth:`flush`)."""
        self._array(key, data.dtype, chunk, data.shape[1:])
        self._pending.setdefault(key, []).append(data)
        self._lengths[key] = self._lengths.get(key, 0) + data.shape[0]
        self._pending_bytes += data.nbytes
        if self._pending_bytes > FLUSH_BYTES:
            self.flush(whole_chunks_only=True)

    def flush(self, whole_chunks_only: bool = False) -> None:
        """Write queued appends to disk (durable only after :meth:`commit`).

        With ``whole_chunks_only`` (appends past :data:`FLUSH_BYTES`) each array writes up to its
        last chunk boundary and keeps the rest queued, so no chunk is compressed twice; the
        arrays are written concurrently (Zarr's codecs release the GIL).
        """
        jobs, remaining = [], {}
        for key, parts in self._pending.items():
            array = self._arrays[key]
            start = self._written.get(key, 0)
            data = parts[0] if len(parts) == 1 else np.concatenate(parts)
            stop = start + data.shape[0]
            if whole_chunks_only:
                stop = max(start, stop - stop % array.chunks[0])
            if stop - start < data.shape[0]:
                remaining[key] = [data[stop - start:]]
            if stop > start:
                jobs.append((array, start, stop, data[: stop - start]))
                self._written[key] = stop
        self._pending = remaining
        self._pending_bytes = sum(parts[0].nbytes for parts in remaining.values())
        with ThreadPoolExecutor(max(1, len(jobs))) as pool:
            list(pool.map(_write_slice, jobs))

    def _truncate_to_commit(self) -> None:
        """Cut every appendable array back to its committed length (see the module docstring)."""
        lengths = self._lengths
        for key in _array_keys(self.group):
            if key.startswith("checkpoint/"):
                continue
            array = self.group[key]
            committed = lengths.get(key, 0)
            if array.shape[0] != committed:
                array.resize((committed, *array.shape[1:]))
        name = self._committed().get("checkpoint")
        if "checkpoint" in self.group:
            for stale in list(self.group["checkpoint"].array_keys()):
                if stale != name:
                    del self.group["checkpoint"][stale]

    # -- events -----------------------------------------------------------------------------
    def append_events(self, events: dict[str, np.ndarray], focal_plane: PortValue | None = None) -> None:
        """Append recorded events (a dict with the :data:`EVENT_FIELDS`); durable after :meth:`commit`."""
        sizes = {len(np.asarray(events[name])) for name in EVENT_FIELDS}
        if len(sizes) != 1:
            raise ValueError(f"event fields have different lengths: {sizes}")
        for name, dtype in EVENT_FIELDS.items():
            self._append(f"events/{name}", np.asarray(events[name]).astype(dtype, copy=False),
                         EVENT_CHUNK_BYTES // dtype.itemsize)
        if focal_plane is not None and "focal_plane" not in self.group["events"].attrs:
            self.group["events"].attrs["focal_plane"] = focal_plane.to_arrays()[1]

    @property
    def n_events(self) -> int:
        return int(self._lengths.get("events/t_readout_ns", 0))

    @property
    def focal_plane(self):
        if "events" not in self.group or "focal_plane" not in self.group["events"].attrs:
            return None
        return port_type("FocalPlane")(**self.group["events"].attrs["focal_plane"])

    def iter_events(self, chunk_size: int = EVENT_CHUNK, start: int = 0, stop: int | None = None
                    ) -> Iterator[dict[str, np.ndarray]]:
        """Committed events in chunks of at most ``chunk_size``, as dicts of numpy arrays."""
        if self.writable:
            self.flush()
        stop = self.n_events if stop is None else min(stop, self.n_events)
        arrays = {name: self.group[f"events/{name}"] for name in EVENT_FIELDS} if stop > start else {}
        for lo in range(start, stop, chunk_size):
            hi = min(lo + chunk_size, stop)
            yield {name: array[lo:hi] for name, array in arrays.items()}

    def read_events(self) -> dict[str, np.ndarray]:
        """All committed events at once (for small runs; prefer :meth:`iter_events`)."""
        chunks = list(self.iter_events())
        if not chunks:
            return {name: np.zeros(0, dtype) for name, dtype in EVENT_FIELDS.items()}
        return {name: np.concatenate([c[name] for c in chunks]) for name in EVENT_FIELDS}

    # -- products -------------------------------------------------------------------------
    def append_product(self, block: str, port: str, value: PortValue) -> None:
        """Append one window's value of ``block.port``."""
        base = f"products/{block}/{port}"
        arrays, attrs = value.to_arrays()
        for name, data in arrays.items():
            data = np.asarray(data)
            if data.dtype.kind in "USO":  # strings travel in the JSON document
                attrs[name] = {"__strings__": data.tolist(), "shape": list(data.shape)}
                continue
            self._append(f"{base}/{name}", data.reshape(-1), max(PRODUCT_CHUNK_BYTES // max(data.itemsize, 1), 1))
            self._append(f"{base}/{name}.shape", np.asarray([data.shape], dtype=np.int64), 1024)
        self._append(f"{base}/_attrs", np.array([json.dumps(attrs)], dtype=np.dtypes.StringDType()), 1024)
        group = self.group[base]
        if "type" not in group.attrs:
            group.attrs["type"] = type(value).type_name()

    def has_product(self, block: str, port: str) -> bool:
        return f"products/{block}/{port}/_attrs" in self.group

    def product_windows(self, block: str, port: str, start: int = 0, stop: int | None = None
                        ) -> Iterator[PortValue]:
        """The stored value of ``block.port`` for each window in ``[start, stop)``."""
        base = f"products/{block}/{port}"
        if self.writable:
            self.flush()
        if not self.has_product(block, port):
            raise StoreError(f"{self.path} holds no products of {block}.{port}")
        value_type = port_type(self.group[base].attrs["type"])
        documents = self.group[f"{base}/_attrs"]
        n = min(self._lengths.get(f"{base}/_attrs", 0), documents.shape[0])
        stop = n if stop is None else min(stop, n)
        fields = sorted(k for k in self.group[base].array_keys() if not k.endswith(".shape") and k != "_attrs")
        shapes = {f: self.group[f"{base}/{f}.shape"][:stop] for f in fields}
        offsets = {f: np.concatenate([[0], np.cumsum(np.prod(shapes[f], axis=1))]).astype(np.int64) for f in fields}
        for w in range(start, stop):
            attrs = json.loads(str(documents[w]))
            arrays = {}
            for f in fields:
                flat = self.group[f"{base}/{f}"][offsets[f][w]:offsets[f][w + 1]]
                arrays[f] = flat.reshape(tuple(shapes[f][w]))
            for key in [k for k, v in attrs.items() if isinstance(v, dict) and "__strings__" in v]:
                doc = attrs.pop(key)
                arrays[key] = np.asarray(doc["__strings__"], dtype=str).reshape(doc["shape"])
            yield value_type.from_arrays(arrays, attrs)

    def product_hash(self, block: str) -> str | None:
        key = f"products/{block}"
        return self.group[key].attrs.get("upstream_hash") if key in self.group else None

    def set_product_hash(self, block: str, digest: str) -> None:
        group = self.group.require_group(f"products/{block}")
        group.attrs["upstream_hash"] = digest

    # -- metrics ------------------------------------------------------------------------------
    def set_metrics(self, values: dict[str, Any], units: dict[str, str]) -> None:
        group = self.group.require_group("metrics")
        merged_values = {**group.attrs.get("values", {}), **values}
        merged_units = {**group.attrs.get("units", {}), **units}
        group.attrs.update({"values": _jsonable(merged_values), "units": merged_units})

    @property
    def metrics(self) -> dict[str, Any]:
        return dict(self.group["metrics"].attrs.get("values", {})) if "metrics" in self.group else {}

    @property
    def metric_units(self) -> dict[str, str]:
        return dict(self.group["metrics"].attrs.get("units", {})) if "metrics" in self.group else {}

    # -- checkpoints and commits ---------------------------------------------------------------
    def write_checkpoint(self, window_index: int, states: dict[str, dict[str, Any]]) -> str:
        """Write every block's state after ``window_index``; returns the checkpoint's name.

        All states go into one array (an uncompressed ``.npz`` archive, read back without
        pickle) with the non-array entries as JSON in its attributes: one Zarr array per
        checkpoint instead of one per state entry keeps frequent checkpoints cheap.
        """
        name = f"w{window_index}"
        arrays: dict[str, np.ndarray] = {}
        skeleton = {block: _encode_state(state, arrays) for block, state in states.items()}
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        packed = np.frombuffer(buffer.getbuffer(), dtype=np.uint8)
        group = self.group.require_group("checkpoint")
        array = group.create_array(name, shape=packed.shape, dtype=np.uint8, chunks=(max(1, min(packed.size, 1 << 24)),),
                                   compressors=BloscCodec(cname="lz4", clevel=1, shuffle="noshuffle"), overwrite=True)
        array[...] = packed
        array.attrs["states"] = skeleton
        return name

    def read_checkpoint(self) -> dict[str, dict[str, Any]]:
        """The block states of the last committed checkpoint (block name -> state)."""
        name = self._committed().get("checkpoint")
        if not name:
            return {}
        array = self.group["checkpoint"][name]
        with np.load(io.BytesIO(array[...].tobytes()), allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
        return {block: _decode_state(entry, arrays) for block, entry in dict(array.attrs["states"]).items()}

    def commit(self, windows: int | None = None, checkpoint: str | None = None) -> None:
        """Make everything appended so far durable: write the commit record, then drop old checkpoints."""
        self.flush()
        record = self._committed()
        record["lengths"] = dict(self._lengths)
        if windows is not None:
            record["windows"] = int(windows)
        old = record.get("checkpoint")
        if checkpoint is not None:
            record["checkpoint"] = checkpoint
        self.group.attrs["committed"] = record
        if checkpoint is not None and old and old != checkpoint and old in self.group["checkpoint"]:
            del self.group["checkpoint"][old]


def _write_slice(job: tuple[zarr.Array, int, int, np.ndarray]) -> None:
    array, start, stop, data = job
    if array.shape[0] != stop:
        array.resize((stop, *array.shape[1:]))
    array[start:stop] = data.astype(array.dtype, copy=False)


def port_type(name: str) -> type[PortValue]:
    """The port type called ``name``, loading the registered blocks' vocabulary if needed."""
    if name not in PORT_TYPES:
        registry.load_entry_points()
    try:
        return PORT_TYPES[name]
    except KeyError:
        raise StoreError(f"the store holds values of port type '{name}', which no installed block defines") from None


def _array_keys(group: zarr.Group, prefix: str = "") -> Iterator[str]:
    for name in group.array_keys():
        yield prefix + name
    for name, sub in group.groups():
        yield from _array_keys(sub, f"{prefix}{name}/")


# -- state (de)serialisation --------------------------------------------------------------------
def _encode_state(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """JSON skeleton of a state value; its arrays go into ``arrays`` under fresh keys."""
    if isinstance(value, np.ndarray) and value.dtype.kind != "O":
        key = f"a{len(arrays)}"
        arrays[key] = np.ascontiguousarray(value)
        return {"__array__": key}
    if isinstance(value, PortValue):
        fields, attrs = value.to_arrays()
        return {"__port__": type(value).type_name(), "__attrs__": _jsonable(attrs),
                "__fields__": {k: _encode_state(v, arrays) for k, v in fields.items()}}
    if isinstance(value, dict):
        return {"__dict__": {str(k): _encode_state(v, arrays) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return {"__list__": [_encode_state(v, arrays) for v in value]}
    return _jsonable(value)


def _decode_state(entry: Any, arrays: dict[str, np.ndarray]) -> Any:
    """Inverse of :func:`_encode_state`."""
    if isinstance(entry, dict):
        if "__array__" in entry:
            return arrays[entry["__array__"]]
        if "__port__" in entry:
            fields = {k: _decode_state(v, arrays) for k, v in entry["__fields__"].items()}
            return port_type(entry["__port__"]).from_arrays(fields, _from_json(entry["__attrs__"]))
        if "__dict__" in entry:
            return {k: _decode_state(v, arrays) for k, v in entry["__dict__"].items()}
        if "__list__" in entry:
            return [_decode_state(v, arrays) for v in entry["__list__"]]
    return _from_json(entry)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "USO":
            return {"__strarray__": value.tolist()}
        return value.tolist()
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, float) and not np.isfinite(value):
        return {"__float__": repr(value)}
    return value


def _from_json(value):
    """Inverse of :func:`_jsonable` for the markers it writes."""
    if isinstance(value, dict):
        if "__strarray__" in value:
            return np.asarray(value["__strarray__"], dtype=str)
        if "__float__" in value:
            return float(value["__float__"])
        return {k: _from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value
