"""A run's Zarr 3 store: events, products, metrics and crash-safe checkpoints.

Layout (every array carries Zarr 3 ``dimension_names`` and its units in ``attrs["units"]``, so
``xarray.open_zarr(path, group="events")`` and ``xarray.open_datatree(path, engine="zarr")`` read it)::

    root attrs      format, evsda_version, graph (resolved), graph_hash, seed, start_epoch,
                    window_ns, duration_ns, n_windows, timing, reused, committed
    events/         (event) the columns the event stream's port type declares (``stream_columns`` of the
                    port type whose ``record`` is EVENT_STREAM; :func:`event_fields`): t_trigger_ns,
                    t_readout_ns [ns since start_epoch] (int64), x, y [pixel] (uint16), p (int8, flag_values
                    -1 1 = OFF ON), cause (uint8, CF flag_values / flag_meanings: signal leak parasitic shot);
                    attrs: focal_plane (its ``stream_geometry``)
    products/<block>/<port>/<field>         (<field>_value) every window's value, flattened and appended
    products/<block>/<port>/<field>.shape   (window, <field>_axis) shape of each window's value
    products/<block>/<port>/_attrs          (window) one JSON document per window (scalars, strings)
    metrics/        (metric) metric [name], value (float64), unit; also attrs: values, units
    <table>/        (<dim>) columns appended with :meth:`RunStore.append_table` (e.g. truth/)
    truth/          (sample) t_ns, source_index, x_px, y_px, magnitude, photon_flux, range_m; (source) source_id,
                    kind, block: the sources' true state at the optics' render times (:meth:`RunStore.append_truth`)
    checkpoint/w<k>                         one uint8 array: an .npz archive of every block's state and RNG
                                            arrays after window k, the rest as JSON in attrs["states"]; only the
                                            last committed one is kept
    .evsda-lock     while a run writes: its pid and host (see :mod:`evsda.graph.lock`)

Writing: a run writes its store without Zarr (:mod:`evsda.graph.store_files`: the groups' and appended arrays'
documents and chunks, every file byte for byte as Zarr 3.1 writes it, so no Zarr import and no Zarr I/O thread in a
run); Zarr reads the store, truncates it on resume, and writes and drops checkpoints.

Crash safety: every chunk and metadata document is written atomically (temporary file + rename, as
zarr >= 3.1.3 does too), but an append resizes an array before its data lands.
So appended arrays are never trusted beyond the lengths recorded in
``attrs["committed"]``, which is written last, after the data and the checkpoint of
a window. On resume every array is truncated back to its committed length and the
checkpoint named in the commit record is loaded; anything written after it is
discarded. A run killed at any instruction therefore resumes from its last complete
window (or starts over when nothing was committed). A finished run's record says
``complete: true``; its last checkpoint is dropped unless asked to keep it.

Damage: every chunk carries a CRC-32C (Zarr 3's ``crc32c`` codec) and every chunk below
the committed length is written (``write_empty_chunks``), so a changed byte, a truncated
chunk or a deleted chunk is a :class:`StoreError` naming the array, never zeros or wrong
data; an array shorter than its committed length is refused rather than padded.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import warnings
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import registry
from .errors import StoreError
from .files import os_reason
from .lock import LOCK_NAME, describe_holder, read_holder
from .ports import EVENT_STREAM, PORT_TYPES, PortValue, from_json, jsonable
from .store_files import ZARR_JSON, ArrayFiles, GroupFiles, writes

if TYPE_CHECKING:
    import zarr

EVENT_CHUNK_BYTES = 4 << 20     # events/ arrays are chunked by size: few files, fast appends
PRODUCT_CHUNK_BYTES = 256 << 10
EVENT_CHUNK = 1 << 20           # default number of events per chunk yielded by iter_events
#: appended data waits in memory until a commit or until this many bytes are pending
FLUSH_BYTES = 64 << 20
#: whole chunks are written once this many bytes of them are pending (the tracked pass's 62 MB of events then
#: compress while the run goes on, in the cores' idle time, not all in the run's tail)
WHOLE_CHUNK_BYTES = EVENT_CHUNK_BYTES


def _zarr():
    """Zarr, imported where a store is first read, resumed or checkpointed: ~0.15 s of CPU that a run which only
    writes its store (:mod:`evsda.graph.store_files` writes Zarr's files without it) does without."""
    import zarr

    return zarr


def _checkpoint_codecs() -> list:
    """The checkpoints' codec chain: LZ4 at level 1 without shuffling (the archive's bytes), then the CRC-32C."""
    from zarr.codecs import BloscCodec, Crc32cCodec

    return [BloscCodec(cname="lz4", clevel=1, shuffle="noshuffle"), Crc32cCodec()]


CHECKPOINT_CHUNK_BYTES = 1 << 24   # checkpoint archives are written and read in chunks of this size
#: every chunk is written, even one of zeros, so that a missing chunk file means damage (store_files writes every
#: chunk too)
ARRAY_CONFIG = {"write_empty_chunks": True}
FORMAT = "evsda-run/1"

@dataclass
class StoreStatus:
    """Where a run store stands: complete, resumable, being written, or damaged."""

    path: Path
    windows: int                    # committed windows
    n_windows: int | None           # windows of the whole run (None: not recorded)
    complete: bool                  # the run finished (every window and the blocks' final outputs)
    has_checkpoint: bool
    writer: str | None = None       # the live run writing it now, if any
    problems: list[str] = field(default_factory=list)   # damage found (nothing here: none found)

    @property
    def resumable(self) -> bool:
        """``--resume`` would continue it: unfinished, undamaged, and a checkpoint or nothing to restore."""
        return not self.complete and not self.problems and (self.has_checkpoint or self.windows == 0)

    def describe(self) -> str:
        """One line, e.g. ``incomplete: 12 of 40 windows committed; resumable with --resume``."""
        if self.problems:
            return f"damaged: {self.problems[0]}" + (f" (and {len(self.problems) - 1} more)" if len(self.problems) > 1 else "")
        total = f" of {self.n_windows}" if self.n_windows is not None else ""
        if self.complete:
            return f"complete: {self.windows}{total} windows"
        state = f"incomplete: {self.windows}{total} windows committed"
        if self.writer:
            return f"{state}; being written by {self.writer}"
        return f"{state}; " + ("continue it with --resume" if self.resumable else "not resumable (no checkpoint)")


class RunStore:
    """A run store on disk. Create with :meth:`create`, open with :meth:`open`."""

    def __init__(self, path: Path, writable: bool, group: zarr.Group | None = None,
                 groups: GroupFiles | None = None):
        self.path = path
        self.writable = writable
        #: the groups' attributes, read and written here (Zarr's group is opened only to read arrays)
        self._groups = groups or GroupFiles(path)
        self._group = group
        self._group_version = self._groups.version
        self._lengths: dict[str, int] = dict(self._committed().get("lengths", {}))
        self._written: dict[str, int] = dict(self._lengths)
        self._pending: dict[str, list[np.ndarray]] = {}
        self._pending_bytes = 0
        self._whole_bytes: dict[str, int] = {}      # per array: bytes pending in whole chunks
        self._writer: ThreadPoolExecutor | None = None      # the thread that writes whole chunks behind the appends
        self._behind: list[Future] = []             # its batches not yet known to be written
        self._arrays: dict[str, ArrayFiles] = {}        # appendable arrays, written by store_files
        self._checked = False       # a read-only store's structure has been checked
        self._truth_sources: dict[tuple[str, str], int] | None = None   # (block, source_id) -> source number
        #: per block: its last window's source ids and their numbers (a block's sources are mostly the same every
        #: window, whose numbers are then taken again instead of looked up one by one)
        self._truth_ids: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._chunk_rows: dict[str, int] = {}        # per appendable array: its rows per chunk
        self._truth_cache: dict[str, np.ndarray] | None = None
        #: set_metrics' values not yet written: earlier calls' (merged, JSON form), the latest call's, units
        self._pending_metrics: tuple[dict, dict, dict] = ({}, {}, {})
        self._attrs_set: set[tuple[str, str]] = set()      # (group, attribute) known to be set (_set_attr_once)

    # -- opening ----------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, attrs: dict[str, Any] | None = None, overwrite: bool = False) -> "RunStore":
        """A new, empty store at ``path``; refuses to replace an existing one unless ``overwrite``."""
        path = Path(path)
        if path.exists() and not (overwrite and _is_empty(path)):
            if not overwrite:
                raise StoreError(f"{path} already exists; choose another output, pass --overwrite to replace it, "
                                 f"or --resume to continue the run it holds")
            check_replaceable(path)
            _clear(path)
        groups = GroupFiles(path)
        try:
            groups.create_root({"format": FORMAT, **(attrs or {}), "committed": {"windows": 0, "lengths": {}}})
        except OSError as exc:
            raise StoreError(f"cannot create run store {path}: {os_reason(exc)}") from None
        return cls(path, writable=True, groups=groups)

    @classmethod
    def open(cls, path: str | Path, mode: str = "r") -> "RunStore":
        """Open an existing store read-only (``mode="r"``) or to continue writing (``"r+"``)."""
        path = Path(path)
        if not path.exists():
            raise StoreError(f"{path} does not exist")
        if not is_run_store(path):
            raise StoreError(f"{path} is not an evsda run store (no zarr.json with format '{FORMAT}')")
        try:
            group = _zarr().open_group(str(path), mode=mode, zarr_format=3)
        except OSError as exc:
            raise StoreError(f"cannot open run store {path}: {os_reason(exc)}") from None
        except Exception as exc:  # zarr raises several kinds for a damaged store
            raise StoreError(f"{path} is not a readable evsda run store ({type(exc).__name__})") from None
        store = cls(path, writable=mode != "r", group=group)
        if store.writable:
            store._truncate_to_commit()
        return store

    @property
    def group(self) -> zarr.Group:
        """The store as a Zarr group (opened at first use, and again once this store has written a group's
        attributes since: a Zarr group keeps the attributes it read)."""
        if self._group is None or self._group_version != self._groups.version:
            try:
                self._group = _zarr().open_group(str(self.path), mode="r+" if self.writable else "r", zarr_format=3)
            except OSError as exc:
                raise StoreError(f"cannot open run store {self.path}: {os_reason(exc)}") from None
            self._group_version = self._groups.version
        return self._group

    # -- attributes ---------------------------------------------------------------------
    @property
    def attrs(self) -> dict[str, Any]:
        return dict(self._groups.attributes(""))

    def set_attrs(self, **values) -> None:
        self._groups.update("", values)

    def _group_attrs(self, group: str) -> dict[str, Any]:
        """The attributes of ``group`` ({} when there is no such group)."""
        try:
            return self._groups.attributes(group)
        except KeyError:
            return {}

    def _committed(self) -> dict[str, Any]:
        return dict(self._groups.attributes("").get("committed", {"windows": 0, "lengths": {}}))

    @property
    def committed_windows(self) -> int:
        return int(self._committed().get("windows", 0))

    @property
    def complete(self) -> bool:
        """The run finished: every window and the blocks' final outputs are committed."""
        record = self._committed()
        if "complete" in record:
            return bool(record["complete"])
        n_windows = self.attrs.get("n_windows")       # stores written before the flag existed
        return n_windows is None or self.committed_windows >= int(n_windows)

    def status(self) -> StoreStatus:
        """Complete or not, resumable or not, who writes it now, and any damage found without reading
        the data (arrays shorter than committed, missing chunks); :meth:`verify` also reads every chunk."""
        n_windows = self.attrs.get("n_windows")
        holder = read_holder(self.path)
        return StoreStatus(self.path, self.committed_windows, None if n_windows is None else int(n_windows),
                           self.complete, bool(self._committed().get("checkpoint")),
                           describe_holder(holder) if holder else None, self._structure_problems())

    def disk_bytes(self) -> int:
        """The size of the store's files [byte]."""
        total = 0
        for folder, _, names in os.walk(self.path):
            for name in names:
                try:
                    total += os.lstat(os.path.join(folder, name)).st_size
                except OSError:
                    pass
        return total

    def verify(self) -> list[str]:
        """Every problem found reading every committed chunk (checksums), plus :meth:`status`'s."""
        problems = self._structure_problems()
        if problems:
            return problems
        for key, length in self._lengths.items():
            array = self.group[key]
            step = array.chunks[0]
            for lo in range(0, length, step):
                try:
                    self._read(array, key, lo, min(lo + step, length))
                except StoreError as exc:
                    problems.append(str(exc).removeprefix(f"{self.path}: "))
        return problems

    def _structure_problems(self) -> list[str]:
        """Committed arrays that are missing, shorter than committed, or miss a chunk file."""
        problems = []
        files = _files_under(self.path)
        for key, length in sorted(self._lengths.items()):
            if key not in self.group:
                problems.append(f"array {key} is missing ({length} entries committed)")
                continue
            array = self.group[key]
            if array.shape[0] < length:
                problems.append(f"array {key} holds {array.shape[0]} of its {length} committed entries")
                continue
            chunk, rest = array.chunks[0], (0,) * (array.ndim - 1)
            missing = [i for i in range(-(-length // chunk))
                       if f"{key}/{array.metadata.encode_chunk_key((i, *rest))}" not in files]
            if missing:
                problems.append(f"array {key} has lost chunk {missing[0]}"
                                + (f" and {len(missing) - 1} more" if len(missing) > 1 else "")
                                + f" (entries {missing[0] * chunk}-{min((missing[0] + 1) * chunk, length) - 1})")
        return problems

    def check_readable(self) -> None:
        """Raise :class:`StoreError` if the committed data is damaged (cheap checks, no chunk read)."""
        if self._checked and not self.writable:
            return
        problems = self._structure_problems()
        if problems:
            raise StoreError(f"{self.path} is damaged: {problems[0]}"
                             + (f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""))
        self._checked = True

    def _read(self, array: zarr.Array, key: str, lo: int, hi: int) -> np.ndarray:
        """``array[lo:hi]``, with a damaged chunk (checksum, truncation) reported as a StoreError."""
        try:
            return array[lo:hi]
        except OSError as exc:
            raise StoreError(f"{self.path}: cannot read array {key}: {os_reason(exc)}") from None
        except Exception as exc:  # the codecs raise several kinds for damaged bytes
            chunk = array.chunks[0]
            where = f"chunk {lo // chunk}" if hi - lo <= chunk else f"chunks {lo // chunk}-{(hi - 1) // chunk}"
            raise StoreError(f"{self.path}: array {key} is damaged in {where} "
                             f"({_short(str(exc)) or type(exc).__name__})") from None

    # -- appendable arrays -----------------------------------------------------------------
    def _array(self, key: str, dtype: np.dtype, chunk: int, trailing: tuple[int, ...] = (),
               dims: tuple[str, ...] | None = None, attrs: dict[str, Any] | None = None) -> ArrayFiles:
        """The appendable array ``key``: the one on disk, or a new one of ``dtype`` in chunks of ``chunk`` rows."""
        array = self._arrays.get(key)
        if array is None:
            folder = self.path / key
            leaf = key.rsplit("/", 1)[-1]
            dims = dims or (f"{leaf}_index", *(f"{leaf}_axis{i}" for i in range(1, 1 + len(trailing))))
            if (folder / ZARR_JSON).is_file():
                array = ArrayFiles.open(folder) if writes(dtype) else _ZarrAppendable(self.group[key])
            elif writes(dtype):
                self._groups.require(key.rsplit("/", 1)[0] if "/" in key else "")
                array = ArrayFiles.create(folder, dtype, (0, *trailing), (chunk, *trailing), list(dims),
                                          dict(attrs or {}))
            else:
                array = _ZarrAppendable.create(self.group, key, dtype, (chunk, *trailing), list(dims), attrs or {})
            self._arrays[key] = array
        return array

    def _append(self, key: str, data: np.ndarray, chunk: int, dims: tuple[str, ...] | None = None,
                attrs: dict[str, Any] | None = None) -> None:
        """Queue ``data`` for appending to array ``key`` (written by :meth:`flush`); ``dims`` and ``attrs``
        name the array's dimensions and describe it when it is created."""
        rows = self._chunk_rows.get(key)
        if rows is None:
            rows = self._chunk_rows[key] = self._array(key, data.dtype, chunk, data.shape[1:], dims, attrs).chunks[0]
        self._pending.setdefault(key, []).append(data)
        self._lengths[key] = self._lengths.get(key, 0) + data.shape[0]
        self._pending_bytes += data.nbytes
        whole = self._lengths[key] // rows * rows - self._written.get(key, 0)
        if whole > 0 and data.shape[0]:
            self._whole_bytes[key] = whole * (data.nbytes // data.shape[0])

    def _appended(self) -> None:
        """After an append: write the whole chunks pending once there are :data:`WHOLE_CHUNK_BYTES` of them, or
        once :data:`FLUSH_BYTES` are pending in all."""
        if self._pending_bytes > FLUSH_BYTES or sum(self._whole_bytes.values()) >= WHOLE_CHUNK_BYTES:
            self.flush(whole_chunks_only=True)

    def flush(self, whole_chunks_only: bool = False) -> None:
        """Write queued appends to disk (durable only after :meth:`commit`).

        With ``whole_chunks_only`` (appends past :data:`FLUSH_BYTES`) each array writes up to its
        last chunk boundary and keeps the rest queued, so no chunk is compressed twice, and the
        writing goes on in the background (:meth:`_write_behind`) while the caller records the next
        windows; otherwise this returns once everything queued is on disk. The arrays are written
        concurrently (Blosc and Zstandard release the GIL).
        """
        jobs, remaining = [], {}
        for key, parts in self._pending.items():
            array = self._arrays[key]
            start = self._written.get(key, 0)
            stop = start + sum(part.shape[0] for part in parts)
            if whole_chunks_only:
                stop = max(start, stop - stop % array.chunks[0])
            head, tail = _split_rows(parts, stop - start)
            if tail:
                remaining[key] = tail
            if stop > start:
                jobs.append((array, start, stop, head))
                self._written[key] = stop
        self._pending = remaining
        self._pending_bytes = sum(part.nbytes for parts in remaining.values() for part in parts)
        self._whole_bytes.clear()
        if jobs:
            self._write_behind(jobs)
        if not whole_chunks_only:
            self._settle()

    def _write_behind(self, jobs: list) -> None:
        """Write ``jobs`` on the store's writing thread, after the jobs handed to it before (an array's slices land
        in order); at most one earlier batch is left unfinished, so what waits in memory stays bounded."""
        while len(self._behind) > 1:
            self._behind.pop(0).result()
        if self._writer is None:
            self._writer = ThreadPoolExecutor(1, thread_name_prefix="evsda-store")
        self._behind.append(self._writer.submit(_write_slices, jobs))

    def _settle(self) -> None:
        """Wait for the writes handed to the writing thread (raising the first error of theirs), then let it go."""
        behind, self._behind = self._behind, []
        try:
            for job in behind:
                job.result()
        finally:
            if self._writer is not None and not self._behind:
                self._writer.shutdown(wait=False)
                self._writer = None

    def _truncate_to_commit(self) -> None:
        """Cut every appendable array back to its committed length (see the module docstring)."""
        self.check_readable()           # never extend an array past its data, never resume over lost chunks
        _remove_partial_writes(self.path)
        lengths = self._lengths
        for key in _array_keys(self.group):
            if key.startswith(("checkpoint/", "metrics/")):     # written whole, never appended
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

    def _set_attr_once(self, group: str, name: str, make) -> None:
        """Set attribute ``name`` of ``group`` to ``make()`` unless it has one; each (group, name) is looked up on
        disk once per store object (appends come every window)."""
        if (group, name) in self._attrs_set:
            return
        if name not in self._group_attrs(group):
            self._groups.update(group, {name: make()})
        self._attrs_set.add((group, name))

    # -- events -----------------------------------------------------------------------------
    def append_events(self, events: dict[str, np.ndarray], focal_plane: PortValue | None = None) -> None:
        """Append recorded events (a dict with the :func:`event_fields`); durable after :meth:`commit`."""
        columns = event_stream_type().stream_columns
        sizes = {len(np.asarray(events[name])) for name in columns}
        if len(sizes) != 1:
            raise ValueError(f"event fields have different lengths: {sizes}")
        for name, (dtype, attrs) in columns.items():
            self._append(f"events/{name}", np.asarray(events[name]).astype(dtype, copy=False),
                         EVENT_CHUNK_BYTES // dtype.itemsize, ("event",), attrs)
        self._appended()
        if focal_plane is not None:
            self._set_attr_once("events", "focal_plane", lambda: focal_plane.to_arrays()[1])

    def append_table(self, group: str, columns: dict[str, np.ndarray], dim: str,
                     attrs: dict[str, dict[str, Any]] | None = None, chunk_bytes: int = PRODUCT_CHUNK_BYTES) -> None:
        """Append rows to the table ``group`` (e.g. ``truth``): 1-D columns of one length along dimension
        ``dim``, each column's ``attrs`` (units, long_name, flag_values...) set when it is created.
        Durable after :meth:`commit`, checksummed and cut back on resume like the events."""
        sizes = {len(np.asarray(values)) for values in columns.values()}
        if len(sizes) != 1:
            raise ValueError(f"columns of {group} have different lengths: {sizes}")
        for name, values in columns.items():
            values = np.asarray(values)
            if values.dtype.kind in "UO":
                values = values.astype(np.dtypes.StringDType())
            self._append(f"{group}/{name}", values, max(chunk_bytes // max(values.itemsize, 1), 1), (dim,),
                         (attrs or {}).get(name, {}))
        self._appended()

    def read_table(self, group: str) -> dict[str, np.ndarray]:
        """Every committed row of the table ``group`` (see :meth:`append_table`)."""
        if self.writable:
            self.flush()
        if group not in self.group:
            raise StoreError(f"{self.path} holds no table {group}")
        self.check_readable()
        out = {}
        for name in self.group[group].array_keys():
            key = f"{group}/{name}"
            out[name] = self._read(self.group[key], key, 0, self._lengths.get(key, 0))
        return out

    @property
    def n_events(self) -> int:
        return int(self._lengths.get("events/t_readout_ns", 0))

    @property
    def focal_plane(self):
        attrs = self._group_attrs("events")
        if "focal_plane" not in attrs:
            return None
        return event_stream_type().geometry_type().from_arrays({}, dict(attrs["focal_plane"]))

    def iter_events(self, chunk_size: int = EVENT_CHUNK, start: int = 0, stop: int | None = None
                    ) -> Iterator[dict[str, np.ndarray]]:
        """Committed events in chunks of at most ``chunk_size``, as dicts of numpy arrays."""
        if self.writable:
            self.flush()
        stop = self.n_events if stop is None else min(stop, self.n_events)
        if stop > start:
            self.check_readable()
        arrays = {name: self.group[f"events/{name}"] for name in event_fields()} if stop > start else {}
        for lo in range(start, stop, chunk_size):
            hi = min(lo + chunk_size, stop)
            yield {name: self._read(array, f"events/{name}", lo, hi) for name, array in arrays.items()}

    def read_events(self) -> dict[str, np.ndarray]:
        """All committed events at once (for small runs; prefer :meth:`iter_events`)."""
        chunks = list(self.iter_events())
        if not chunks:
            return {name: np.zeros(0, dtype) for name, dtype in event_fields().items()}
        return {name: np.concatenate([c[name] for c in chunks]) for name in chunks[0]}

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
            self._append(f"{base}/{name}", data.reshape(-1), max(PRODUCT_CHUNK_BYTES // max(data.itemsize, 1), 1),
                         (f"{name}_value",), _field_attrs(name, value.unit))
            self._append(f"{base}/{name}.shape", np.asarray([data.shape], dtype=np.int64), 1024,
                         ("window", f"{name}_axis"), {"units": "1"})
        self._append(f"{base}/_attrs", np.array([json.dumps(attrs)], dtype=np.dtypes.StringDType()), 1024,
                     ("window",), {"long_name": "each window's scalar fields (JSON)"})
        self._appended()
        self._set_attr_once(base, "type", lambda: type(value).type_name())

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
        self.check_readable()
        value_type = port_type(self._group_attrs(base)["type"])
        documents = self.group[f"{base}/_attrs"]
        n = min(self._lengths.get(f"{base}/_attrs", 0), documents.shape[0])
        stop = n if stop is None else min(stop, n)
        shapes, offsets = self._product_layout(base, stop)
        for w in range(start, stop):
            attrs = json.loads(str(self._read(documents, f"{base}/_attrs", w, w + 1)[0]))
            arrays = {f: self._read(self.group[f"{base}/{f}"], f"{base}/{f}", offsets[f][w], offsets[f][w + 1]
                                    ).reshape(tuple(shapes[f][w])) for f in shapes}
            yield value_type.from_arrays({**arrays, **_string_fields(attrs)}, attrs)

    def _product_layout(self, base: str, stop: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Each numeric field of the product ``base``: its values' shapes in windows ``[0, stop)`` and where each
        window's values start in the flattened array."""
        fields = sorted(k for k in self.group[base].array_keys() if not k.endswith(".shape") and k != "_attrs")
        shapes = {f: self._read(self.group[f"{base}/{f}.shape"], f"{base}/{f}.shape", 0, stop) for f in fields}
        offsets = {f: np.concatenate([[0], np.cumsum(np.prod(shapes[f], axis=1))]).astype(np.int64) for f in fields}
        return shapes, offsets

    def product_hash(self, block: str) -> str | None:
        return self._group_attrs(f"products/{block}").get("upstream_hash")

    def set_product_hash(self, block: str, digest: str) -> None:
        if self.product_hash(block) == digest:
            return
        self._groups.update(f"products/{block}", {"upstream_hash": digest})

    # -- ground truth ---------------------------------------------------------------------------
    def append_truth(self, block: str, value: PortValue) -> None:
        """Append one window's ground truth of ``block``: a port value whose ``table()`` gives per-source
        columns (``source_id``, ``kind``), per-row columns (``t_ns``, ``source_index`` and the state) and their
        attributes (:class:`evsda.blocks.ports.Truth`).

        Sources are numbered in the order they first appear in the run (dimension ``source``, with the
        ``block`` that rendered them); rows (dimension ``sample``) refer to them by that number.
        """
        sources, rows, attrs = value.table()
        self._append_truth_table(block, sources, rows, attrs)
        if isinstance(getattr(value, "focal_plane", None), PortValue):
            self._set_attr_once("truth", "focal_plane", lambda: value.focal_plane.to_arrays()[1])

    def _append_truth_table(self, block: str, sources: dict[str, np.ndarray], rows: dict[str, np.ndarray],
                            attrs: dict[str, dict]) -> None:
        ids = np.asarray(sources["source_id"]).astype(str)
        numbers, new = self._source_numbers(block, ids)
        per_source = {name: np.asarray(values)[new] for name, values in sources.items()}
        per_source["block"] = np.full(len(new), block)
        attrs = {**attrs, "block": {"long_name": "block that rendered the source"}}
        self.append_table("truth", per_source, "source", attrs, chunk_bytes=8 << 10)
        self.append_table("truth", {**rows, "source_index": numbers[np.asarray(rows["source_index"], np.int64)]},
                          "sample", attrs)
        self._truth_cache = None

    def _source_numbers(self, block: str, ids: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """The source numbers of ``block``'s sources ``ids`` (numbering those not seen before) and the positions of
        the new ones; the block's last numbers again when ``ids`` are its last window's."""
        last = self._truth_ids.get(block)
        if last is not None and np.array_equal(last[0], ids):
            return last[1], []
        numbering = self._truth_numbering()
        numbers = np.empty(len(ids), np.int32)
        new = []
        for k, source_id in enumerate(ids):
            key = (block, str(source_id))
            if key not in numbering:
                numbering[key] = len(numbering)
                new.append(k)
            numbers[k] = numbering[key]
        self._truth_ids[block] = (ids, numbers)
        return numbers, new

    def _truth_numbering(self) -> dict[tuple[str, str], int]:
        """(block, source_id) -> source number, of the committed sources (read once) and those appended since."""
        if self._truth_sources is None:
            self._truth_sources = {}
            n = self._lengths.get("truth/source_id", 0)
            if n:
                ids = self._read(self.group["truth/source_id"], "truth/source_id", 0, n)
                blocks = self._read(self.group["truth/block"], "truth/block", 0, n)
                self._truth_sources = {(str(b), str(i)): k for k, (b, i) in enumerate(zip(blocks, ids))}
        return self._truth_sources

    @property
    def has_truth(self) -> bool:
        return "truth" in self.group and "t_ns" in self.group["truth"]

    def read_truth(self) -> dict[str, np.ndarray]:
        """Every committed truth row, sorted by time then source: the per-row columns plus the row's
        ``source_id``, ``kind`` and ``block`` ({} when the store holds no truth)."""
        if self._truth_cache is not None:
            return self._truth_cache
        if not self.has_truth:
            return {}
        columns = self.read_table("truth")
        per_source = {name: columns.pop(name) for name in ("source_id", "kind", "block")}
        source = columns["source_index"].astype(np.int64)
        for name, values in per_source.items():
            columns[name] = (values if values.dtype.kind in "biuf" else np.array(values.tolist(), dtype=str))[source]
        order = np.lexsort((source, columns["t_ns"]))
        self._truth_cache = {name: values[order] for name, values in columns.items()}
        return self._truth_cache

    def truth_attrs(self) -> dict[str, dict]:
        """Each truth column's attributes (``units``, ``long_name``, flags)."""
        if not self.has_truth:
            return {}
        group = self.group["truth"]
        return {name: dict(group[name].attrs) for name in group.array_keys()}

    def copy_truth(self, other: "RunStore", block: str, start_ns: int, stop_ns: int) -> None:
        """Append ``other``'s truth rows of ``block`` in ``[start_ns, stop_ns)`` (a block reused from it)."""
        rows = other.read_truth()
        if not rows:
            return
        keep = (rows["block"] == block) & (rows["t_ns"] >= start_ns) & (rows["t_ns"] < stop_ns)
        ids, first, source = np.unique(rows["source_id"][keep], return_index=True, return_inverse=True)
        sources = {"source_id": ids, "kind": rows["kind"][keep][first]}
        state = {name: values[keep] for name, values in rows.items()
                 if name not in ("source_id", "kind", "block", "source_index")}
        self._append_truth_table(block, sources, {**state, "source_index": source}, other.truth_attrs())
        focal_plane = other._group_attrs("truth").get("focal_plane")
        if focal_plane is not None and "focal_plane" not in self._group_attrs("truth"):
            self._groups.update("truth", {"focal_plane": focal_plane})

    # -- metrics ------------------------------------------------------------------------------
    def set_metrics(self, values: dict[str, Any], units: dict[str, str]) -> None:
        """Record metrics, merged with those recorded before (a name's later value replaces its earlier one);
        written, like appended data, by the next :meth:`commit` (a run records its running figures every
        window: writing each time took ~45 ms per window of the tracked pass, under the GIL)."""
        earlier, latest, pending_units = self._pending_metrics
        earlier.update(jsonable(latest))       # as if written: earlier values merge in their JSON form
        self._pending_metrics = (earlier, dict(values), {**pending_units, **units})

    def _write_metrics(self) -> None:
        """Write the pending metrics merged with those on disk as attributes and as data: ``metrics/metric``
        (names), ``metrics/value`` (float64; NaN where a value is missing) and ``metrics/unit`` along
        dimension ``metric``, so ``xarray.open_zarr(path, group="metrics").value.sel(metric=NAME)`` works."""
        earlier, values, units = self._pending_metrics
        if not earlier and not values and not units:
            return
        self._pending_metrics = ({}, {}, {})
        stored = self._group_attrs("metrics")
        merged_values = {**stored.get("values", {}), **earlier, **values}
        merged_units = {**stored.get("units", {}), **units}
        self._groups.update("metrics", {"values": jsonable(merged_values), "units": merged_units})
        names = [k for k, v in merged_values.items() if isinstance(v, (int, float, np.number, type(None)))]
        numbers = np.array([np.nan if merged_values[k] is None else float(merged_values[k]) for k in names], np.float64)
        columns = {"metric": (np.array(names, dtype=np.dtypes.StringDType()), {"long_name": "metric name"}),
                   "value": (numbers, {"long_name": "metric value (units in unit)"}),
                   "unit": (np.array([merged_units.get(k, "") for k in names], dtype=np.dtypes.StringDType()),
                            {"long_name": "unit of each metric"})}
        for name, (data, attrs) in columns.items():
            array = ArrayFiles.create(self.path / "metrics" / name, data.dtype, data.shape, (max(1, data.size),),
                                      ["metric"], attrs)
            if data.size:
                array.write(0, data)

    @property
    def metrics(self) -> dict[str, Any]:
        """The recorded metrics (those not yet committed included)."""
        stored = dict(self._group_attrs("metrics").get("values", {}))
        return {**stored, **self._pending_metrics[0], **jsonable(self._pending_metrics[1])}

    @property
    def metric_units(self) -> dict[str, str]:
        stored = dict(self._group_attrs("metrics").get("units", {}))
        return {**stored, **self._pending_metrics[2]}

    # -- checkpoints and commits ---------------------------------------------------------------
    def write_checkpoint(self, window_index: int, states: dict[str, dict[str, Any]]) -> str:
        """Write every block's state after ``window_index``; returns the checkpoint's name.

        All states go into one array (an uncompressed ``.npz`` archive, read back without
        pickle) with the non-array entries as JSON in its attributes: one Zarr array per
        checkpoint instead of one per state entry keeps frequent checkpoints cheap. The archive
        is streamed into the array one chunk at a time, so writing it holds one chunk beside the
        states, not a copy of them (a 1280 x 720 sensor's pixel state is ~150 MB).
        """
        name = f"w{window_index}"
        arrays: dict[str, np.ndarray] = {}
        skeleton = {block: _encode_state(state, arrays) for block, state in states.items()}
        group = self.group.require_group("checkpoint")
        array = group.create_array(name, shape=(0,), dtype=np.uint8, chunks=(CHECKPOINT_CHUNK_BYTES,),
                                   compressors=_checkpoint_codecs(), overwrite=True, config=ARRAY_CONFIG,
                                   dimension_names=[f"{name}_byte"], attributes={"units": "byte"})
        with _ChunkedWriter(array, CHECKPOINT_CHUNK_BYTES) as stream:
            np.savez(stream, **arrays)
        array.attrs.update({"states": skeleton, "bytes": int(stream.size)})
        return name

    def read_checkpoint(self) -> dict[str, dict[str, Any]]:
        """The block states of the last committed checkpoint (block name -> state); {} when there is none."""
        name = self._committed().get("checkpoint")
        if not name:
            return {}
        key = f"checkpoint/{name}"
        if key not in self.group:
            raise StoreError(f"{self.path} is damaged: its committed checkpoint {name} is missing")
        array = self.group[key]
        files = _files_under(self.path / "checkpoint" / name, prefix=f"{key}/")
        chunk = array.chunks[0]
        expected = int(array.attrs.get("bytes", array.shape[0]))
        if array.shape[0] != expected or any(f"{key}/{array.metadata.encode_chunk_key((i,))}" not in files
                                             for i in range(-(-expected // chunk))):
            raise StoreError(f"{self.path} is damaged: its checkpoint {name} has lost data")
        packed = self._read(array, key, 0, expected)
        try:
            with np.load(io.BytesIO(packed.tobytes()), allow_pickle=False) as archive:
                arrays = {k: archive[k] for k in archive.files}
        except (ValueError, OSError, KeyError) as exc:
            raise StoreError(f"{self.path} is damaged: its checkpoint {name} cannot be read ({_short(str(exc))})") from None
        return {block: _decode_state(entry, arrays) for block, entry in dict(array.attrs["states"]).items()}

    def commit(self, windows: int | None = None, checkpoint: str | None = None, complete: bool | None = None,
               drop_checkpoint: bool = False) -> None:
        """Make everything appended so far durable: write the commit record, then drop old checkpoints.

        ``complete`` marks the run finished or not (None: unchanged; a store whose record has no flag
        is complete once ``windows`` reaches its ``n_windows`` attribute, or always if it has none);
        ``drop_checkpoint`` removes the last checkpoint.
        """
        self.flush()
        self._write_metrics()
        record = self._committed()
        record["lengths"] = dict(self._lengths)
        if windows is not None:
            record["windows"] = int(windows)
        old = record.get("checkpoint")
        if checkpoint is not None:
            record["checkpoint"] = checkpoint
        if drop_checkpoint:
            record["checkpoint"] = None
        if complete is not None:
            record["complete"] = bool(complete)
        self._groups.update("", {"committed": record})
        if old and old != record["checkpoint"] and "checkpoint" in self.group and old in self.group["checkpoint"]:
            del self.group["checkpoint"][old]


#: units that a field's name states by its suffix (the blocks' naming rule: ``aperture_m``, ``t_ns``)
_SUFFIX_UNITS = {"ns": "ns", "s": "s", "m": "m", "km": "km", "px": "pixel", "K": "K", "hz": "Hz", "rad": "rad",
                 "deg": "deg", "mag": "mag", "arcsec": "arcsec"}


def _field_attrs(name: str, port_unit: str) -> dict[str, str]:
    """Attributes of a product field: its unit when its name states one, else the unit of its port type."""
    suffix = name.rsplit("_", 1)[-1] if "_" in name else ""
    attrs = {"long_name": f"{name} of every window, flattened (shapes in {name}.shape)", "port_unit": port_unit}
    if suffix in _SUFFIX_UNITS:
        attrs["units"] = _SUFFIX_UNITS[suffix]
    return attrs


class _ZarrAppendable:
    """An appendable array of a kind :mod:`evsda.graph.store_files` does not write (:data:`~evsda.graph.store_files.KINDS`),
    written by Zarr with the numeric codec chain, as :class:`~evsda.graph.store_files.ArrayFiles` is written."""

    def __init__(self, array: zarr.Array):
        self.array = array.with_config(ARRAY_CONFIG)
        self.chunks = self.array.chunks

    @classmethod
    def create(cls, group: zarr.Group, key: str, dtype: np.dtype, chunks: tuple[int, ...], dims: list[str],
               attrs: dict[str, Any]) -> "_ZarrAppendable":
        from zarr.codecs import BloscCodec, Crc32cCodec

        codecs = [BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle"), Crc32cCodec()]
        return cls(group.create_array(key, shape=(0, *chunks[1:]), chunks=chunks, dtype=dtype, compressors=codecs,
                                      config=ARRAY_CONFIG, dimension_names=dims, attributes=dict(attrs)))

    @property
    def shape(self) -> tuple[int, ...]:
        return self.array.shape

    @property
    def dtype(self) -> np.dtype:
        return self.array.dtype

    def resize(self, rows: int) -> None:
        self.array.resize((rows, *self.array.shape[1:]))

    def write(self, start: int, data: np.ndarray) -> None:
        self.array[start:start + data.shape[0]] = data


def _split_rows(parts: list[np.ndarray], rows: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``parts`` (arrays of rows, in order) cut after their first ``rows`` rows: (the parts before, the parts after)."""
    head = []
    for k, part in enumerate(parts):
        if rows >= part.shape[0]:
            head.append(part)
            rows -= part.shape[0]
            continue
        if rows:
            head.append(part[:rows])
        return head, [part[rows:], *parts[k + 1:]]
    return head, []


def _write_slices(jobs: list[tuple[ArrayFiles, int, int, list[np.ndarray]]]) -> None:
    """Write each job's rows (one job an array), the arrays concurrently."""
    with ThreadPoolExecutor(len(jobs)) as pool:
        list(pool.map(_write_slice, jobs))


def _write_slice(job: tuple[ArrayFiles, int, int, list[np.ndarray]]) -> None:
    array, start, stop, parts = job
    data = parts[0] if len(parts) == 1 else np.concatenate(parts)
    if array.shape[0] != stop:
        array.resize(stop)
    array.write(start, data.astype(array.dtype, copy=False))


def is_run_store(path: str | Path) -> bool:
    """Whether ``path`` is an evsda run store (a folder whose zarr.json has the evsda format attribute)."""
    meta = Path(path) / "zarr.json"
    try:
        if not meta.is_file() or meta.stat().st_size > (16 << 20):
            return False
        document = json.loads(meta.read_bytes())
    except (OSError, ValueError):
        return False
    return isinstance(document, dict) and (document.get("attributes") or {}).get("format") == FORMAT


def _is_empty(path: Path) -> bool:
    """A folder holding nothing but, at most, a run's lock file (a run stopped before its first window)."""
    try:
        return path.is_dir() and all(entry.name == LOCK_NAME for entry in os.scandir(path))
    except OSError:
        return False


def check_replaceable(path: str | Path) -> None:
    """Refuse to replace ``path`` unless it is an evsda run store (or an empty folder)."""
    path = Path(path)
    if path.is_symlink() or not path.is_dir():
        raise StoreError(f"{path} is not an evsda run store; --overwrite replaces only run stores, "
                         f"so choose another output")
    if not (_is_empty(path) or is_run_store(path)):
        raise StoreError(f"{path} is a folder that is not an evsda run store; --overwrite replaces only run "
                         f"stores, so choose another output")


def _clear(path: Path) -> None:
    """Remove everything in the run store ``path`` but its lock file."""
    for entry in os.scandir(path):
        if entry.name == LOCK_NAME:
            continue
        target = Path(entry.path)
        if entry.is_dir(follow_symlinks=False):
            shutil.rmtree(target)
        else:
            target.unlink()


_PARTIAL_WRITE = re.compile(r"\.[0-9a-f]{32}\.partial$")


def _remove_partial_writes(root: Path) -> None:
    """Remove the temporary files of writes a killed run left unfinished (Zarr writes ``name.<uuid>.partial``
    then renames it)."""
    for folder, _, names in os.walk(root):
        for name in names:
            if _PARTIAL_WRITE.search(name):
                Path(folder, name).unlink(missing_ok=True)


def _files_under(root: Path, prefix: str = "") -> set[str]:
    """Paths of the files under ``root``, relative to it with ``/`` separators, each after ``prefix``."""
    found = set()
    for folder, _, names in os.walk(root):
        rel = os.path.relpath(folder, root)
        base = prefix if rel == "." else f"{prefix}{rel.replace(os.sep, '/')}/"
        found.update(base + name for name in names)
    return found


def _short(text: str, limit: int = 80) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _string_fields(attrs: dict[str, Any]) -> dict[str, np.ndarray]:
    """The string arrays a product's JSON document holds (taken out of ``attrs``), by field name."""
    keys = [k for k, v in attrs.items() if isinstance(v, dict) and "__strings__" in v]
    return {key: np.asarray(doc["__strings__"], dtype=str).reshape(doc["shape"])
            for key, doc in ((k, attrs.pop(k)) for k in keys)}


def event_stream_type() -> type[PortValue]:
    """The port type that declares itself the run's event stream (``record = EVENT_STREAM``): its
    ``stream_columns`` are the arrays of ``events/``, its ``stream_geometry`` the focal plane recorded with them."""
    if not any(t.record == EVENT_STREAM for t in PORT_TYPES.values()):
        registry.load_entry_points()
    for candidate in PORT_TYPES.values():
        if candidate.record == EVENT_STREAM:
            return candidate
    raise StoreError("no installed block defines an event stream port type")


def event_fields() -> dict[str, np.dtype]:
    """The columns of ``events/`` and their dtypes (those of :func:`event_stream_type`)."""
    return {name: dtype for name, (dtype, _) in event_stream_type().stream_columns.items()}


def port_type(name: str) -> type[PortValue]:
    """The port type called ``name``, loading the registered blocks' vocabulary if needed."""
    if name not in PORT_TYPES:
        registry.load_entry_points()
    try:
        return PORT_TYPES[name]
    except KeyError:
        raise StoreError(f"the store holds values of port type '{name}', which no installed block defines") from None


def _array_keys(group: zarr.Group, prefix: str = "") -> Iterator[str]:
    with warnings.catch_warnings():     # zarr notes the lock file, which is no array or group
        warnings.filterwarnings("ignore", message="Object at .* is not recognized", category=UserWarning)
        names = list(group.array_keys())
        subgroups = list(group.groups())
    for name in names:
        yield prefix + name
    for name, sub in subgroups:
        yield from _array_keys(sub, f"{prefix}{name}/")


# -- state (de)serialisation --------------------------------------------------------------------
class _ChunkedWriter(io.RawIOBase):
    """A write-only stream into a 1-D uint8 Zarr array, one full chunk at a time (the array grows as it goes)."""

    def __init__(self, array: zarr.Array, chunk_bytes: int):
        super().__init__()
        self.array, self.chunk, self.size = array, int(chunk_bytes), 0
        self._pending = bytearray()

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        size = view.nbytes
        if self._pending:                                  # complete the chunk begun before
            take = min(size, self.chunk - len(self._pending))
            self._pending += view[:take]
            view = view[take:]
            if len(self._pending) == self.chunk:
                self._store(self._pending)
                self._pending = bytearray()
        whole = len(view) // self.chunk * self.chunk
        if whole:                                          # whole chunks straight from the caller's buffer
            self._store(view[:whole])
        self._pending += view[whole:]
        return size

    def close(self) -> None:
        """Store the last partial chunk; closed even when that fails (a full disk), so that nothing retries the
        write later (Python closes unclosed streams when it collects them, at exit too, where Zarr hangs)."""
        pending, self._pending = self._pending, bytearray()
        try:
            if not self.closed and pending:
                self._store(pending)
        finally:
            super().close()

    def _store(self, data) -> None:
        start = self.size
        self.size += len(data)
        self.array.resize((self.size,))
        self.array[start:self.size] = np.frombuffer(data, dtype=np.uint8)


def _encode_state(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """JSON skeleton of a state value; its arrays go into ``arrays`` under fresh keys."""
    if isinstance(value, np.ndarray) and value.dtype.kind != "O":
        key = f"a{len(arrays)}"
        arrays[key] = np.ascontiguousarray(value)
        return {"__array__": key}
    if isinstance(value, PortValue):
        fields, attrs = value.to_arrays()
        return {"__port__": type(value).type_name(), "__attrs__": jsonable(attrs),
                "__fields__": {k: _encode_state(v, arrays) for k, v in fields.items()}}
    if isinstance(value, dict):
        return {"__dict__": {str(k): _encode_state(v, arrays) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return {"__list__": [_encode_state(v, arrays) for v in value]}
    return jsonable(value)


def _decode_state(entry: Any, arrays: dict[str, np.ndarray]) -> Any:
    """Inverse of :func:`_encode_state`."""
    if isinstance(entry, dict):
        if "__array__" in entry:
            return arrays[entry["__array__"]]
        if "__port__" in entry:
            fields = {k: _decode_state(v, arrays) for k, v in entry["__fields__"].items()}
            return port_type(entry["__port__"]).from_arrays(fields, from_json(entry["__attrs__"]))
        if "__dict__" in entry:
            return {k: _decode_state(v, arrays) for k, v in entry["__dict__"].items()}
        if "__list__" in entry:
            return [_decode_state(v, arrays) for v in entry["__list__"]]
    return from_json(entry)
