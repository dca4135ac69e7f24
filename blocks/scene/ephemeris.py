"""Offline access to Skyfield: time scale, JPL ephemeris, and run time -> Skyfield time.

Nothing here downloads: the time scale uses the leap-second and Earth-orientation tables
built into Skyfield, and the planetary ephemeris is JPL DE421 as shipped by the
``skyfield-data`` package.
"""

from __future__ import annotations

import functools
import os
from datetime import datetime

import numpy as np
import skyfield_data
from skyfield.api import Loader

NS_PER_DAY = 86_400 * 1_000_000_000


@functools.cache
def loader() -> Loader:
    """A Skyfield loader reading the files shipped by ``skyfield-data`` (never the network)."""
    return Loader(data_folder(), verbose=False)


def data_folder() -> str:
    """The folder of ``skyfield-data``'s files: its package's ``data`` folder.

    ``skyfield_data.get_skyfield_data_path()`` returns this folder after warning when its copy of
    ``finals2000A.all`` is past its date. evsda does not read that file (UT1 comes from Skyfield's built-in
    tables), so the folder is taken directly rather than the warning silenced: ``warnings.catch_warnings`` swaps
    the process's filter list and is not thread-safe, and in a pipelined run another thread leaving its own
    (the store's) let the warning through.
    """
    folder = os.path.join(os.path.dirname(skyfield_data.__file__), "data")
    if not os.path.isfile(os.path.join(folder, "de421.bsp")):
        raise RuntimeError(f"skyfield-data's de421.bsp is not in {folder}: reinstall skyfield-data")
    return folder


@functools.cache
def timescale():
    """Skyfield's time scale from its built-in leap-second and UT1 tables."""
    return loader().timescale(builtin=True)


@functools.cache
def planets():
    """JPL DE421 (1900-2050) from ``skyfield-data``."""
    return loader()("de421.bsp")


def skyfield_time(epoch: datetime, t_ns):
    """Skyfield ``Time`` of ``t_ns`` nanoseconds (scalar or array) after ``epoch`` (UTC).

    Offsets are SI seconds, i.e. added on the TT scale, so no leap second is ever skipped.
    """
    t0 = _epoch_time(epoch)
    offset_days = np.asarray(t_ns, dtype=np.float64) / NS_PER_DAY
    return timescale().tt_jd(t0.whole, t0.tt_fraction + offset_days)


@functools.lru_cache(maxsize=64)
def _epoch_time(epoch: datetime):
    return timescale().from_datetime(epoch)
