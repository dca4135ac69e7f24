"""One writer per run store: a lock file inside the store naming its holder.

A run, a resume or an overwrite holds ``<store>/.evsda-lock`` for as long as it writes.
The file says who holds it (pid, host, start time); the lock itself is a POSIX
``flock`` on the open file, which the kernel drops when the holder exits in any way
(even SIGKILL). A lock file left by a dead run is therefore stale by construction:
the next writer takes it over. A second writer while the holder lives is refused
with one line naming the holder.

Forked children (worker processes) close their copy of the descriptor, so a child that
outlives its parent does not keep the parent's store locked.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import time
from pathlib import Path

from .errors import StoreError

LOCK_NAME = ".evsda-lock"
log = logging.getLogger("evsda.lock")
_HELD: dict[int, Path] = {}     # descriptors of the locks this process holds


def _close_in_child() -> None:
    for fd in list(_HELD):
        try:
            os.close(fd)
        except OSError:
            pass
    _HELD.clear()


os.register_at_fork(after_in_child=_close_in_child)


def read_holder(directory: str | Path) -> dict | None:
    """Who holds the lock of the store in ``directory`` now (pid, host, since), or None if nobody."""
    path = Path(directory) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _parse(os.pread(fd, 4096, 0)) or {"pid": "?", "host": "?"}
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def describe_holder(holder: dict) -> str:
    since = holder.get("since")
    when = time.strftime(" since %Y-%m-%d %H:%M:%S", time.localtime(since)) if isinstance(since, (int, float)) else ""
    return f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')}{when}"


def _parse(data: bytes) -> dict | None:
    try:
        value = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None
    return value if isinstance(value, dict) else None


class StoreLock:
    """The write lock of the run store in ``directory`` (which must exist); a context manager."""

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self.path = self.directory / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> "StoreLock":
        """Take the lock, or raise :class:`StoreError` naming the process that holds it."""
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
            except OSError as exc:
                raise StoreError(f"cannot lock run store {self.directory}: {exc.strerror}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _parse(os.pread(fd, 4096, 0)) or {}
                os.close(fd)
                raise StoreError(f"{self.directory} is being written by another evsda run "
                                 f"({describe_holder(holder)}); wait for it to end or stop it") from None
            # the previous holder may have removed the file between our open and our flock
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            previous = _parse(os.pread(fd, 4096, 0))
            if previous:
                log.info("%s: took over the lock left by %s, which has ended", self.directory,
                         describe_holder(previous))
            record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()})
            os.ftruncate(fd, 0)
            os.pwrite(fd, record.encode(), 0)
            self._fd = fd
            _HELD[fd] = self.path
            return self

    def release(self) -> None:
        """Remove the lock file and drop the lock (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        _HELD.pop(fd, None)
        try:
            self.path.unlink()
        except OSError:
            pass    # the store went away, or a read-only folder: the flock still ends below
        os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> "StoreLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
