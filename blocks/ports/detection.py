"""Port type of source detection: what a detector found in a sensor's output, without ground truth.

Conventions as in :mod:`evsda.blocks.ports.core` (times in integer nanoseconds since the run's
start, positions in pixels with pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evsda.graph.ports import PortValue

from .core import FocalPlane


@dataclass(frozen=True, eq=False)
class Detections(PortValue):
    """Sources a detector found in one or more looks (integration segments or frames).

    A look spans ``[t_start_ns, t_start_ns + look_ns)``; each detection gives the source's
    position at the look's reference time ``t_ns`` (its middle), the apparent velocity
    (NaN where the detector cannot measure one, e.g. a single frame), the counts it rests
    on and its significance. Every look that ended in the window is listed in
    ``look_start_ns``, with or without detections, so a scorer knows which looks took place.
    """

    unit = "detection"
    focal_plane: FocalPlane
    look_ns: int                               # duration of one look [ns]
    false_alarm_rate_per_hour_per_mpx: float   # the rate the detector's threshold was set for [h^-1 Mpixel^-1]
    look_start_ns: np.ndarray                  # int64 [n_looks] start of every look that ended in this window
    t_ns: np.ndarray                           # int64 [n] reference time of the detection's look (its middle)
    t_reported_ns: np.ndarray                  # int64 [n] when the detector could report it (the look's end)
    x_px: np.ndarray                           # float64 [n] column at t_ns [pixel]
    y_px: np.ndarray                           # float64 [n] row at t_ns [pixel]
    vx_px_s: np.ndarray                        # float64 [n] apparent velocity along x [pixel s^-1] (NaN: not measured)
    vy_px_s: np.ndarray                        # float64 [n] apparent velocity along y [pixel s^-1]
    counts: np.ndarray                         # float64 [n] events (or electrons) in the matched filter
    background: np.ndarray                     # float64 [n] expected from the background alone
    significance_sigma: np.ndarray             # float64 [n] one-sided Gaussian equivalent of the local p-value [1]
    false_alarm_probability: np.ndarray        # float64 [n] p-value times the look's trials (Bonferroni) [1]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @classmethod
    def none(cls, focal_plane: FocalPlane, look_ns: int, far: float, look_start_ns=()) -> "Detections":
        """No detection in the looks starting at ``look_start_ns``."""
        f, i = np.zeros(0), np.zeros(0, np.int64)
        return cls(focal_plane, int(look_ns), float(far), np.asarray(look_start_ns, np.int64), i, i.copy(),
                   f, f.copy(), f.copy(), f.copy(), f.copy(), f.copy(), f.copy(), f.copy())
