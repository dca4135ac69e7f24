"""The optics block's ground truth: where every source was, and how bright, at each render time.

The optics draws each source at its render times from the sample-and-hold of its
:class:`~evsda.blocks.ports.PointSources` input; this module lists those same held samples
as a :class:`~evsda.blocks.ports.Truth` table, one row per source on the detector per
render time, so the truth and the rendered irradiance (hence the events) agree exactly.
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import FocalPlane, Truth


def truth_table(focal_plane: FocalPlane, t_ns: np.ndarray, ids: list[str], kinds: list[int],
                tracks: list[dict[str, np.ndarray]]) -> Truth:
    """The rows of the sources ``ids`` (kinds ``kinds``) whose held samples ``tracks`` (``x``, ``y``,
    ``flux``, ``magnitude``, ``range``, each ``[n_t]`` at ``t_ns``) put them on the detector."""
    names = ("x", "y", "flux", "magnitude", "range")
    columns = {name: np.stack([tr[name] for tr in tracks], axis=1) if tracks else np.zeros((len(t_ns), 0))
               for name in names}
    return truth_rows(focal_plane, t_ns, ids, kinds, columns)


def truth_rows(focal_plane: FocalPlane, t_ns: np.ndarray, ids: list[str], kinds: list[int],
               columns: dict[str, np.ndarray], sources: np.ndarray | None = None) -> Truth:
    """:func:`truth_table` from the sources' held samples side by side: ``columns[name]`` (n_t, tracks), track ``j``
    the source ``sources[j]`` (increasing; None: every source, track ``j`` source ``j``)."""
    t_ns = np.asarray(t_ns, np.int64)
    on_detector = np.isfinite(columns["x"]) & np.isfinite(columns["y"])
    time_index, track = np.nonzero(on_detector)          # row-major: sorted by time, then source
    source = track if sources is None else np.asarray(sources)[track]

    def column(name: str) -> np.ndarray:           # the boolean mask reads them in the same row-major order
        return np.asarray(columns[name])[on_detector].astype(np.float32)

    return Truth(focal_plane, np.asarray(ids, dtype=str), np.asarray(kinds, dtype=np.int8), t_ns[time_index],
                 source.astype(np.int32), column("x"), column("y"), column("magnitude"), column("flux"),
                 column("range"))
