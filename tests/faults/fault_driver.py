"""Runs ``evsda`` with a fault injected into the run store's writes (used by the fault tests).

    python fault_driver.py PATTERN N MODE -- evsda arguments...

The N-th write (1-based) of a store key matching the regular expression PATTERN triggers
the fault, counting the writes of :mod:`evsda.graph.store_files` (the store's documents and appended
chunks) and of Zarr (checkpoints) together. Modes:

* ``kill-before``: SIGKILL before the write;
* ``kill-partial``: leave half the bytes in the temporary file written first, then SIGKILL
  (a kill in the middle of writing that key);
* ``kill-after``: SIGKILL right after the write;
* ``enospc``: raise ``OSError(ENOSPC)`` from this write and from every later one (a disk
  that has filled up), leaving half the bytes in the temporary file as a real full disk does.
"""

from __future__ import annotations

import errno
import os
import re
import signal
import sys

import zarr.storage._local as local

from evsda.graph import store_files


def install(pattern: str, nth: int, mode: str) -> None:
    seen = {"count": 0, "full": False}
    regex = re.compile(pattern)

    def faulty(path, data: bytes | None, write):
        """``write()`` (the write of ``data`` to ``path``; None: a create-if-absent no-op), or the fault."""
        key = str(path)
        if seen["full"]:
            raise OSError(errno.ENOSPC, "No space left on device", key)
        if data is not None and regex.search(key):
            seen["count"] += 1
            if seen["count"] == nth:
                if mode == "kill-before":
                    os.kill(os.getpid(), signal.SIGKILL)
                if mode in ("kill-partial", "enospc"):
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.with_suffix(".0123456789abcdef0123456789abcdef.partial").write_bytes(data[: len(data) // 2])
                    if mode == "kill-partial":
                        os.kill(os.getpid(), signal.SIGKILL)
                    seen["full"] = True
                    raise OSError(errno.ENOSPC, "No space left on device", key)
                result = write()
                os.kill(os.getpid(), signal.SIGKILL)
                return result
        return write()

    zarr_put, own_put = local._put, store_files.put

    def zarr_write(path, value, exclusive=False):
        data = None if exclusive and path.exists() else bytes(value.as_buffer_like())
        return faulty(path, data, lambda: zarr_put(path, value, exclusive=exclusive))

    def own_write(path, data):
        return faulty(path, bytes(data), lambda: own_put(path, data))

    local._put, store_files.put = zarr_write, own_write


if __name__ == "__main__":
    pattern, nth, mode, sep, *args = sys.argv[1:]
    assert sep == "--" and mode in ("kill-before", "kill-partial", "kill-after", "enospc")
    install(pattern, int(nth), mode)
    from evsda.graph.cli import main

    sys.exit(main(args))
