"""Runs ``evsda`` with a fault injected into the Zarr store's writes (used by the fault tests).

    python fault_driver.py PATTERN N MODE -- evsda arguments...

The N-th write (1-based) of a store key matching the regular expression PATTERN triggers
the fault. Modes:

* ``kill-before``: SIGKILL before the write;
* ``kill-partial``: leave half the bytes in the temporary file Zarr writes first, then SIGKILL
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


def install(pattern: str, nth: int, mode: str) -> None:
    original = local._put
    seen = {"count": 0, "full": False}
    regex = re.compile(pattern)

    def _put(path, value, exclusive=False):
        key = str(path)
        if seen["full"]:
            raise OSError(errno.ENOSPC, "No space left on device", key)
        if regex.search(key) and not (exclusive and path.exists()):    # not a create-if-absent no-op
            seen["count"] += 1
            if seen["count"] == nth:
                data = bytes(value.as_buffer_like())
                if mode == "kill-before":
                    os.kill(os.getpid(), signal.SIGKILL)
                if mode in ("kill-partial", "enospc"):
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.with_suffix(".0123456789abcdef0123456789abcdef.partial").write_bytes(data[: len(data) // 2])
                    if mode == "kill-partial":
                        os.kill(os.getpid(), signal.SIGKILL)
                    seen["full"] = True
                    raise OSError(errno.ENOSPC, "No space left on device", key)
                result = original(path, value, exclusive=exclusive)
                os.kill(os.getpid(), signal.SIGKILL)
                return result
        return original(path, value, exclusive=exclusive)

    local._put = _put


if __name__ == "__main__":
    pattern, nth, mode, sep, *args = sys.argv[1:]
    assert sep == "--" and mode in ("kill-before", "kill-partial", "kill-after", "enospc")
    install(pattern, int(nth), mode)
    from evsda.graph.cli import main

    sys.exit(main(args))
