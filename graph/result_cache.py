"""Results kept on disk across runs, by a digest of everything they depend on (a sweep's points repeat conditions).

A :class:`ResultCache` maps a key (plain data: numbers, strings, lists, dicts) to a JSON value. What a value
depends on besides its key is folded into every key: the digest of the source files of the code that computes
it (a change of that code misses), the Python, library versions and CPU (compiled and vectorised code may
round differently on another processor). A caller gives everything else in the key, so that a value taken
from the disk is what computing it again would give, bit for bit (floats are written and read exactly).

Where: ``EVSDA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/evsda`` or ``~/.cache/evsda``; one folder per
cache name, one file per key. ``EVSDA_CACHE=off`` (or ``evsda run --no-cache``) switches every cache off.

* Writes go to a temporary file in the same folder, then :func:`os.replace`: a reader sees a whole entry or
  none, and concurrent writers of one key (sweep workers) write the same bytes.
* An entry that cannot be read, is not JSON or holds another key is a miss; a write that fails (read-only
  or full disk) is skipped. Neither stops the run.
* Bounded: once a folder holds more than :data:`MAX_BYTES`, its oldest entries (by last use: a hit touches its
  file) are deleted until it holds :data:`PRUNED_FRACTION` of that. A process lists the folder at its first
  write there and again only once what it found plus what it wrote since passes the bound (listing it at every
  write cost 54 ms a write at 4 400 entries): entries other processes write in between are counted at the next
  listing, so concurrent writers can hold the folder above the bound until then. The folders can be deleted
  at any time.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import logging
import os
import platform
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from functools import lru_cache
from pathlib import Path
from typing import Any

from .errors import UserError

LOG = logging.getLogger("evsda.cache")
#: the most bytes of entries one cache keeps (its oldest entries go first) [byte]
MAX_BYTES = 32 * 2**20
#: share of the bound a folder is pruned down to, so that the next listing is a quarter of the bound away
PRUNED_FRACTION = 0.75
#: age after which a temporary file is taken as left by a process killed while writing [s]
STALE_TEMPORARY_S = 3600.0
#: bytes of entries each cache folder held at this process's last listing of it, plus what it wrote there since
_FOLDER_BYTES: dict[Path, int] = {}
_FOLDER_BYTES_LOCK = threading.Lock()
#: values of ``EVSDA_CACHE`` that switch caches off and on
OFF, ON = ("off", "0", "no", "false"), ("on", "1", "yes", "true", "")


def cache_root() -> Path | None:
    """The folder that holds the caches, or None when ``EVSDA_CACHE`` switches them off."""
    switch = os.environ.get("EVSDA_CACHE", "").strip().lower()
    if switch in OFF:
        return None
    if switch not in ON:
        raise UserError(f"EVSDA_CACHE must be 'on' or 'off', got {os.environ['EVSDA_CACHE']!r}")
    folder = os.environ.get("EVSDA_CACHE_DIR", "").strip()
    if folder:
        return Path(folder).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(base) if base else Path.home() / ".cache") / "evsda"


@lru_cache(maxsize=None)
def code_digest(sources: tuple[str, ...]) -> str | None:
    """SHA-256 of the ``.py`` files at ``sources`` (files, or folders read without their subfolders), in name
    order; None if one cannot be read (then nothing is cached: a change could not be seen)."""
    digest = hashlib.sha256()
    try:
        for source in sources:
            path = Path(source)
            files = sorted(path.glob("*.py")) if path.is_dir() else [path]
            for file in files:
                digest.update(file.name.encode() + b"\0" + file.read_bytes() + b"\0")
    except OSError:
        return None
    return digest.hexdigest()


@lru_cache(maxsize=None)
def environment(libraries: tuple[str, ...]) -> dict:
    """What else the numbers may depend on: the Python, the versions of ``libraries`` and the CPU (its name and
    features as LLVM sees them, when llvmlite is installed: they pick compiled and vectorised code paths)."""
    versions = {}
    for name in libraries:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    try:
        import llvmlite.binding as llvm
        cpu = f"{llvm.get_host_cpu_name()} {llvm.get_host_cpu_features().flatten()}"
    except Exception:           # not installed, or no LLVM target here: the platform's name only (on Linux a
        cpu = platform.processor()                       # `uname -p` subprocess, hence only here)
    return {"python": sys.version, "machine": platform.machine(), "libraries": versions, "cpu": cpu}


def _plain(value: Any) -> Any:
    """A key's numpy scalars and arrays as Python numbers and lists (called by :func:`json.dumps`)."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"a cache key holds {type(value).__name__}, not plain data")


class ResultCache:
    """Values of one kind computed by the code in ``sources`` (files or package folders) with ``libraries``,
    kept under the folder ``name`` of :func:`cache_root`."""

    def __init__(self, name: str, sources: Iterable[str | Path], libraries: Iterable[str] = ()):
        self.name = name
        self.sources = tuple(str(s) for s in sources)
        self.libraries = tuple(libraries)

    def folder(self) -> Path | None:
        """Where the entries are, or None when caching is off (or the code cannot be read)."""
        root = cache_root()
        return None if root is None or code_digest(self.sources) is None else root / self.name

    def _entry(self, key: Any) -> tuple[str, str]:
        """The key's text (with the code's digest and the environment) and its SHA-256, the entry's name."""
        text = json.dumps({"key": key, "code": code_digest(self.sources), "environment": environment(self.libraries)},
                          sort_keys=True, separators=(",", ":"), default=_plain)
        return text, hashlib.sha256(text.encode()).hexdigest()

    def get(self, key: Any) -> tuple[bool, Any]:
        """``(True, value)`` if the key's entry is on disk and whole, else ``(False, None)``."""
        folder = self.folder()
        if folder is None:
            return False, None
        text, name = self._entry(key)
        path = folder / name[:2] / f"{name}.json"
        try:
            entry = json.loads(path.read_text(encoding="utf-8"))
            if not isinstance(entry, dict) or entry.get("key") != text or "value" not in entry:
                raise ValueError("another key")
        except (OSError, ValueError, UnicodeDecodeError) as exc:
            if not isinstance(exc, FileNotFoundError):
                LOG.debug("cache %s: entry %s unreadable (%s): a miss", self.name, name, exc)
            return False, None
        try:
            os.utime(path)                   # its last use, for the size bound
        except OSError:                      # a cache read but not written by this user still answers
            pass
        LOG.debug("cache %s: hit %s", self.name, name)
        return True, entry["value"]

    def put(self, key: Any, value: Any) -> None:
        """Write the key's entry (a JSON value; NaN and infinities allowed) atomically; failures are skipped."""
        folder = self.folder()
        if folder is None:
            return
        text, name = self._entry(key)
        data = json.dumps({"key": text, "value": value})
        shard = folder / name[:2]
        try:
            shard.mkdir(parents=True, exist_ok=True)
            handle, temporary = tempfile.mkstemp(dir=shard, prefix=f".{name}.", suffix=".tmp")
            try:
                with os.fdopen(handle, "w", encoding="utf-8") as file:
                    file.write(data)
                os.replace(temporary, shard / f"{name}.json")
            except BaseException:
                Path(temporary).unlink(missing_ok=True)
                raise
        except OSError as exc:
            LOG.debug("cache %s: entry %s not written (%s)", self.name, name, exc)
            return
        self._counted(folder, len(data.encode("utf-8")))

    @classmethod
    def _counted(cls, folder: Path, written: int) -> None:
        """Count ``written`` bytes into ``folder``'s tally; :meth:`prune` it (a listing) at its first write in
        this process and whenever the tally passes :data:`MAX_BYTES`."""
        with _FOLDER_BYTES_LOCK:
            held = _FOLDER_BYTES.get(folder)
            if held is not None and held + written <= MAX_BYTES:
                _FOLDER_BYTES[folder] = held + written
                return
        left = cls.prune(folder)
        with _FOLDER_BYTES_LOCK:
            _FOLDER_BYTES[folder] = left

    @staticmethod
    def prune(folder: Path, max_bytes: int | None = None) -> int:
        """If the folder holds more than ``max_bytes`` (default :data:`MAX_BYTES`), delete its least recently used
        entries until it holds :data:`PRUNED_FRACTION` of that; delete temporary files older than
        :data:`STALE_TEMPORARY_S` (left by a process killed while writing). Returns the bytes of entries left
        [byte]."""
        max_bytes = MAX_BYTES if max_bytes is None else max_bytes
        entries, now = [], time.time()
        for path in folder.glob("*/*"):
            try:
                stat = path.stat()
                if path.suffix == ".tmp" and now - stat.st_mtime > STALE_TEMPORARY_S:
                    path.unlink()
            except OSError:                  # another worker deleted it first, or no right to
                continue
            if path.suffix == ".json":
                entries.append((stat.st_mtime, stat.st_size, path))
        total = sum(size for _, size, _ in entries)
        if total <= max_bytes:
            return total
        for _, size, path in sorted(entries, key=lambda e: e[0]):
            if total <= PRUNED_FRACTION * max_bytes:
                break
            try:
                path.unlink()
            except OSError:
                pass
            total -= size
        return total

    def remember(self, key: Any, compute: Callable[[], Any], encode: Callable[[Any], Any] = lambda v: v,
                 decode: Callable[[Any], Any] = lambda v: v) -> Any:
        """``compute()``'s value, taken from the disk when the key's entry is there (``decode`` of it), else
        computed and written (``encode``: the value as JSON data). An entry ``decode`` rejects is a miss."""
        found, stored = self.get(key)
        if found:
            try:
                return decode(stored)
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                LOG.debug("cache %s: entry not decoded (%s): a miss", self.name, exc)
        value = compute()
        self.put(key, encode(value))
        return value
