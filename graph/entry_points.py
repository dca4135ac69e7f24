"""The installed distributions' entry points read once a process, not at every library's call (issue 13: the
one-core start).

``importlib.metadata.entry_points`` reads every installed distribution's ``entry_points.txt`` afresh at each call
(~100 distributions, ~17 M instructions, 5-9 ms of CPU at load 6). A run of the tracked pass calls it nine times on
one core: pydantic's plugins, our commands and blocks (:mod:`evsda.graph.commands`, :mod:`evsda.graph.registry`),
networkx's backends (twice), Zarr, numcodecs and fsspec (at the first record). :func:`cache_entry_points` (called
where :mod:`evsda.graph` is first imported, before pydantic, which takes the function at its import) has it read
them once and answer later calls from what it read while the import path, the finders that find distributions and
the modification times of the path's folders (where an installed or removed package shows) are as they were; else
it reads them again. The same entry points, in the same order, as Python's function (its answer is built from
them); ``EVSDA_ENTRY_POINTS_CACHE=off`` leaves Python's function in place. Only on Python 3.11's function (whose
answer without a selection is ``SelectableGroups``).
"""

from __future__ import annotations

import importlib.metadata as metadata
import os
import sys

_SWITCH = "EVSDA_ENTRY_POINTS_CACHE"


def cache_entry_points() -> bool:
    """Have ``importlib.metadata.entry_points`` read the installed distributions once (the module docstring);
    whether it now does."""
    if os.environ.get(_SWITCH, "").strip().lower() in ("off", "0", "no", "false"):
        return False
    if not isinstance(metadata.entry_points, _ReadOnce):
        if not hasattr(metadata, "SelectableGroups"):      # the Python (3.11) whose function was checked
            return False
        metadata.entry_points = _ReadOnce(metadata.entry_points)
    return True


class _ReadOnce:
    """``importlib.metadata.entry_points`` (Python 3.11's) answered from one reading of the distributions."""

    def __init__(self, original):
        self.original = original
        self.__doc__ = original.__doc__
        self.state: tuple | None = None
        self.points: tuple = ()
        self.selected: dict[tuple, metadata.EntryPoints] = {}     # by selection: immutable, handed out again

    def __call__(self, **params):
        state = _installed_state()
        if state != self.state:
            groups = self.original()                               # every distribution's, grouped as Python does
            self.points = tuple(point for group in dict.values(groups) for point in group)   # no deprecation notice
            self.state, self.selected = state, {}
        if not params:                                             # a dictionary of groups: a fresh one each call
            return metadata.SelectableGroups.load(self.points)
        key = tuple(sorted(params.items()))
        if key not in self.selected:
            self.selected[key] = metadata.SelectableGroups.load(self.points).select(**params)
        return self.selected[key]


def _installed_state() -> tuple:
    """What the installed distributions follow from: the import path, the finders that find distributions, the
    path's folders' modification times [ns] (a package installed or removed changes its folder's)."""
    finders = tuple(id(finder) for finder in sys.meta_path if hasattr(finder, "find_distributions"))
    return tuple(sys.path), finders, tuple(map(_modified_ns, sys.path))


def _modified_ns(folder: str) -> int | None:
    try:
        return os.stat(folder or ".").st_mtime_ns
    except OSError:
        return None
