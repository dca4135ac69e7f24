"""The ground truth beside the events: a run store's ``truth`` rows as CSV or HDF5.

One row per source on the detector per optics render time (see :class:`~evsda.blocks.ports.Truth`),
sorted by time then source, with the columns

==============  ===================  =========================================================
column          unit                 meaning
==============  ===================  =========================================================
``t_us``        µs                   render time since the run's start epoch: the clock of the
                                     exported events (which carry ``floor(t_ns / 1000)``);
                                     written to the nanosecond
``source_id``   -                    NORAD number of a satellite; ``HIP n`` (Hipparcos) or ``BS n``
                                     (drawn from star counts) of a star
``kind``        -                    ``satellite`` or ``star`` (HDF5: int8 with CF flags)
``x_px, y_px``  pixel                column and row of the source, pixel centres at integers
                                     (the events' ``x, y`` convention)
``magnitude``   mag                  apparent magnitude in the band
``photon_flux`` photon s^-1 m^-2     at the aperture, after the atmosphere
``range_m``     m                    observer-source distance (``inf`` for stars)
==============  ===================  =========================================================
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from evsda.blocks.ports import SourceKind

FORMATS = {"csv": ".csv", "hdf5": ".h5"}
STATE = ("x_px", "y_px", "magnitude", "photon_flux", "range_m")


def truth_path(events_output: str | Path, fmt: str) -> Path:
    """Where the truth of an export to ``events_output`` goes: ``NAME.truth.csv`` (or ``.h5``) beside it."""
    path = Path(events_output)
    return path.with_name(f"{path.stem}.truth{FORMATS[fmt]}")


def write_truth_csv(rows: dict[str, np.ndarray], path) -> int:
    """Write the truth ``rows`` (as :meth:`RunStore.read_truth` returns them) as CSV; returns the row count."""
    names = {int(k): k.name.lower() for k in SourceKind}
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t_us", "source_id", "kind", *STATE])
        t_us = [f"{t // 1000}.{t % 1000:03d}" for t in np.asarray(rows["t_ns"], np.int64).tolist()]
        kinds = [names.get(k, str(k)) for k in np.asarray(rows["kind"]).tolist()]
        state = [[str(v) for v in np.asarray(rows[name], np.float32)] for name in STATE]   # shortest float32 text
        writer.writerows(zip(t_us, np.asarray(rows["source_id"]).tolist(), kinds, *state))
    return len(t_us)


def write_truth_hdf5(rows: dict[str, np.ndarray], path, attrs: dict[str, dict], epoch: str | None,
                     width: int, height: int) -> int:
    """Write the truth ``rows`` as HDF5 (one compressed dataset per column, with ``units``/``long_name``
    attributes from ``attrs``); returns the row count."""
    import h5py

    options = {"compression": "gzip", "shuffle": True} if len(rows["t_ns"]) else {}
    with h5py.File(path, "w") as f:
        f.attrs.update({"width": width, "height": height, "time_origin_utc": epoch or "", "source": "evsda truth",
                        "rows": "one per source on the detector per optics render time, by time then source"})
        t = f.create_dataset("t_us", data=np.asarray(rows["t_ns"], np.int64) / 1000.0, **options)
        t.attrs.update({"units": "us", "long_name": "render time since the run's start epoch"})
        ids = f.create_dataset("source_id", data=np.asarray(rows["source_id"]).astype(object),
                               dtype=h5py.string_dtype(), **options)
        ids.attrs.update(attrs.get("source_id", {}))
        kind = f.create_dataset("kind", data=np.asarray(rows["kind"], np.int8), **options)
        kind.attrs.update(attrs.get("kind", {}))
        for name in STATE:
            dataset = f.create_dataset(name, data=np.asarray(rows[name], np.float32), **options)
            dataset.attrs.update(attrs.get(name, {}))
    return len(rows["t_ns"])
