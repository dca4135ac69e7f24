"""A run store's Zarr 3 files written directly, byte for byte as Zarr 3.1 writes them, without importing Zarr.

:class:`~evsda.graph.store.RunStore` writes its groups' and arrays' documents (``zarr.json``) and its arrays' chunks
here; Zarr reads them, truncates a store being resumed and writes checkpoints. What Zarr writes, this module writes:

- a document is ``json.dumps(document, allow_nan=True, indent=2)`` (Zarr's ``json_indent`` 2), its keys in Zarr's
  order; an attribute update keeps the keys' order (a dictionary update); a missing parent group gets an empty one;
- an array's chunk grid is regular, its chunk key ``c/i/j...`` (the ``default`` encoding, separator ``/``);
- every chunk holds the whole chunk shape, the rows past the array's end at the fill value (0, 0.0, False, "");
  a chunk written in part takes the rest from the chunk already there (decoded), as Zarr does; an array whose
  rows hold no values (a trailing axis of length 0) has no chunks;
- numbers go through ``bytes`` (little-endian), ``blosc`` (LZ4 level 5, bit shuffle, the item size as type size)
  and ``crc32c`` (Castagnoli, 4 bytes little-endian after the data); strings through ``vlen-utf8``, ``zstd``
  (level 3) and ``crc32c``: numcodecs' and google-crc32c's calls, the ones Zarr's codecs make;
- each file is written to ``<name>.<32 hex>.partial`` beside it and renamed over it (a killed write leaves a
  ``.partial`` file, which ``RunStore.open`` clears when it resumes the store).

``tests/framework/test_framework_store_files.py`` writes stores both ways and compares every file's bytes.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

ZARR_JSON = "zarr.json"
#: Blosc's settings for numeric arrays (Zarr's ``BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle")``)
BLOSC = {"cname": "lz4", "clevel": 5, "shuffle": "bitshuffle", "blocksize": 0}
ZSTD_LEVEL = 3
_SHUFFLES = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}


def document_bytes(document: dict[str, Any]) -> bytes:
    """A ``zarr.json`` document's bytes, as Zarr encodes them."""
    return json.dumps(document, allow_nan=True, indent=2).encode()


def put(path: Path, data) -> None:
    """Write ``data`` to ``path`` atomically: a ``.partial`` file beside it, then renamed over it (Zarr's way)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(f".{os.urandom(16).hex()}.partial")
    try:
        with partial.open("wb") as stream:
            stream.write(data)
        partial.replace(path)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise


def group_document(attributes: dict[str, Any]) -> dict[str, Any]:
    return {"attributes": attributes, "zarr_format": 3, "node_type": "group"}


def _codecs():
    """numcodecs' Blosc, Zstd and VLenUTF8 and google-crc32c, imported at the first chunk (~10 ms, not Zarr's
    ~150 ms); Blosc without its own threads, as Zarr sets it."""
    import google_crc32c
    import numcodecs.blosc
    from numcodecs.vlen import VLenUTF8
    from numcodecs.zstd import Zstd

    numcodecs.blosc.use_threads = False
    return numcodecs.blosc.Blosc, Zstd, VLenUTF8, google_crc32c


class ChunkCodec:
    """One array's codec chain: its ``codecs`` document and each chunk's encoding and decoding."""

    def __init__(self, dtype: np.dtype):
        self.dtype = dtype
        self.strings = dtype.kind == "T"
        if self.strings:
            self.document = [{"name": "vlen-utf8", "configuration": {}},
                             {"name": "zstd", "configuration": {"level": ZSTD_LEVEL, "checksum": False}},
                             {"name": "crc32c"}]
            return
        blosc = {"typesize": dtype.itemsize, **BLOSC}
        endian = {"name": "bytes"} if dtype.itemsize == 1 else {"name": "bytes", "configuration": {"endian": "little"}}
        self.document = [endian, {"name": "blosc", "configuration": blosc}, {"name": "crc32c"}]

    @classmethod
    def from_document(cls, dtype: np.dtype, codecs: list[dict[str, Any]]) -> "ChunkCodec":
        """The chain an array's document names; ValueError for a chain this module does not write."""
        codec = cls(dtype)
        if codec.document != codecs:
            raise ValueError(f"codec chain {codecs} is not one a run store appends to")
        return codec

    def _compressor(self):
        if not hasattr(self, "_made"):
            blosc, zstd, vlen, crc = _codecs()
            if self.strings:
                self._made = (zstd(level=ZSTD_LEVEL, checksum=False), vlen(), crc)
            else:
                config = self.document[1]["configuration"]
                self._made = (blosc(cname=config["cname"], clevel=config["clevel"],
                                    shuffle=_SHUFFLES[config["shuffle"]], blocksize=config["blocksize"],
                                    typesize=config["typesize"]), None, crc)
        return self._made

    def encode(self, chunk: np.ndarray) -> bytes:
        """A whole chunk's stored bytes (CRC-32C last)."""
        compressor, vlen, crc = self._compressor()
        raw = vlen.encode(chunk) if self.strings else np.ascontiguousarray(chunk.astype("<" + chunk.dtype.str[1:],
                                                                                       copy=False))
        packed = compressor.encode(raw)
        return bytes(packed) + np.uint32(crc.value(packed)).tobytes()

    def decode(self, stored: bytes, shape: tuple[int, ...]) -> np.ndarray:
        """A chunk's values from its stored bytes; ValueError when its checksum does not match."""
        compressor, vlen, crc = self._compressor()
        body, checksum = stored[:-4], stored[-4:]
        if np.uint32(crc.value(body)).tobytes() != checksum:
            raise ValueError("stored and computed checksum do not match")
        raw = compressor.decode(body)
        if self.strings:
            return vlen.decode(raw).reshape(shape).astype(self.dtype)
        return np.frombuffer(raw, dtype=self.dtype.newbyteorder("<")).reshape(shape).astype(self.dtype)


#: the kinds of NumPy dtype written here (booleans, integers, floats, NumPy's variable-width strings); an array of
#: another kind (complex numbers, dates: none of evsda's own port types) is left to Zarr, whose documents for them
#: are not compared with this module's
KINDS = "biufT"


def writes(dtype: np.dtype) -> bool:
    """Whether arrays of ``dtype`` are written here (:data:`KINDS`)."""
    return dtype.kind in KINDS


def data_type(dtype: np.dtype) -> tuple[str, Any]:
    """Zarr 3's name of ``dtype`` and its fill value (the default, zero); TypeError for a kind not written here."""
    if dtype.kind == "T":
        return "string", ""
    if dtype.kind in "biu":
        return dtype.name, False if dtype.kind == "b" else 0
    if dtype.kind == "f":
        return dtype.name, 0.0
    raise TypeError(f"a run store does not write arrays of {dtype} without Zarr")


def native_dtype(name: str) -> np.dtype:
    """The NumPy dtype of Zarr 3's data type ``name``."""
    return np.dtypes.StringDType() if name == "string" else np.dtype(name)


class ArrayFiles:
    """One array's document and chunks on disk (``folder``), written as Zarr writes them."""

    def __init__(self, folder: Path, document: dict[str, Any]):
        self.folder = folder
        self.document = document
        self.dtype = native_dtype(document["data_type"])
        self.chunks = tuple(document["chunk_grid"]["configuration"]["chunk_shape"])
        self.codec = ChunkCodec.from_document(self.dtype, document["codecs"])
        self._last: tuple[int, np.ndarray] | None = None   # (index, values) of the last chunk written in part

    @classmethod
    def create(cls, folder: Path, dtype: np.dtype, shape: tuple[int, ...], chunks: tuple[int, ...],
               dims: list[str], attributes: dict[str, Any]) -> "ArrayFiles":
        """A new array (its document written; any array there before removed, as Zarr's ``overwrite``)."""
        name, fill = data_type(dtype)
        document = {"shape": list(shape), "data_type": name,
                    "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": list(chunks)}},
                    "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
                    "fill_value": fill, "codecs": ChunkCodec(dtype).document,
                    "attributes": attributes, "dimension_names": list(dims),
                    "zarr_format": 3, "node_type": "array", "storage_transformers": []}
        if folder.exists():
            shutil.rmtree(folder)
        array = cls(folder, document)
        array.save()
        return array

    @classmethod
    def open(cls, folder: Path) -> "ArrayFiles":
        return cls(folder, json.loads((folder / ZARR_JSON).read_bytes()))

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.document["shape"])

    def save(self) -> None:
        put(self.folder / ZARR_JSON, document_bytes(self.document))

    def resize(self, rows: int) -> None:
        """Set the array's length (its first axis) to ``rows``."""
        self.document["shape"] = [rows, *self.document["shape"][1:]]
        self.save()

    def chunk_path(self, index: int) -> Path:
        return self.folder.joinpath("c", str(index), *("0",) * (len(self.chunks) - 1))

    def write(self, start: int, data: np.ndarray) -> None:
        """Rows ``[start, start + len(data))`` (inside the array's shape), chunk by chunk (none when a row holds
        no values: Zarr's grid then has no chunks)."""
        if 0 in self.chunks:
            return
        step = self.chunks[0]
        stop = start + data.shape[0]
        for index in range(start // step, -(-stop // step)):
            lo, hi = max(start, index * step), min(stop, (index + 1) * step)
            part = data[lo - start: hi - start]
            if hi - lo == step:
                self._store(index, part)
                continue
            values = self._chunk_values(index)
            values[lo - index * step: hi - index * step] = part
            self._store(index, values)
            self._last = (index, values)

    def _chunk_values(self, index: int) -> np.ndarray:
        """Chunk ``index``'s values as they stand: kept from its last write, read from disk, or the fill value."""
        if self._last is not None and self._last[0] == index:
            return self._last[1]
        path = self.chunk_path(index)
        if path.exists():
            return self.codec.decode(path.read_bytes(), self.chunks).copy()
        fill = self.document["fill_value"]
        return np.full(self.chunks, fill, dtype=self.dtype) if self.codec.strings else np.zeros(self.chunks, self.dtype)

    def _store(self, index: int, values: np.ndarray) -> None:
        put(self.chunk_path(index), self.codec.encode(values))


class GroupFiles:
    """The groups' documents of one store (``root``): their attributes, read once, written on every change."""

    def __init__(self, root: Path):
        self.root = root
        self._attributes: dict[str, dict[str, Any]] = {}     # group path ("" the root) -> its attributes
        self.version = 0        # counts documents written (a reader's cached view of them is stale once it moves)

    def create_root(self, attributes: dict[str, Any]) -> None:
        self._attributes[""] = dict(attributes)
        self._save("")

    def exists(self, group: str) -> bool:
        return group in self._attributes or (self._folder(group) / ZARR_JSON).is_file()

    def attributes(self, group: str) -> dict[str, Any]:
        """A group's attributes (read from disk once); KeyError when it has none."""
        if group not in self._attributes:
            try:
                document = json.loads((self._folder(group) / ZARR_JSON).read_bytes())
            except FileNotFoundError:
                raise KeyError(group) from None
            self._attributes[group] = dict(document.get("attributes") or {})
        return self._attributes[group]

    def update(self, group: str, values: dict[str, Any]) -> None:
        """Set attributes of ``group`` (made first if missing), keeping the others and their order."""
        self.require(group)
        self._attributes[group].update(values)
        self._save(group)

    def require(self, group: str) -> None:
        """Make ``group`` and its parents where they are missing (empty attributes), as Zarr does."""
        parts = group.split("/") if group else []
        for k in range(len(parts) + 1):
            path = "/".join(parts[:k])
            if path in self._attributes:
                continue
            try:
                self.attributes(path)
            except KeyError:
                self._attributes[path] = {}
                self._save(path)

    def forget(self, group: str) -> None:
        """Drop what is known of ``group`` and the groups under it (Zarr changed or removed them)."""
        for path in [p for p in self._attributes if p == group or p.startswith(f"{group}/")]:
            del self._attributes[path]

    def _folder(self, group: str) -> Path:
        return self.root / group if group else self.root

    def _save(self, group: str) -> None:
        put(self._folder(group) / ZARR_JSON, document_bytes(group_document(self._attributes[group])))
        self.version += 1
