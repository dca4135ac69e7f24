"""Timing jitter: a random delay between a pixel's comparator decision and its event's time stamp.

A real pixel reports a threshold crossing after a latency that varies from event to event:
the photoreceptor's noise moves the crossing, and the comparator and the request to the
read-out take a variable time (IEBCS models it as a Gaussian of the latency, after the
characterisation of Joubert et al. 2021). evsda adds to each event a delay ``sigma |z|``
(``z`` standard normal: half-normal, mean ``0.80 sigma``, standard deviation ``0.60 sigma``), so
no event is reported before its decision. ``z`` is addressed by (pixel, step) through the
counter RNG (:mod:`.counter_rng`), so the delays do not depend on the windows or on the
implementation. An event delayed past the end of its window is held and reported in the
next one; events delayed past the end of the run are not reported.
"""

from __future__ import annotations

import numpy as np

from evsda.blocks.ports import TriggeredEvents

from .counter_rng import normal

JITTER_STREAM = 7          # counter-RNG stream of the delays (normal() draws from streams 14 and 15)
FIELDS = ("t_ns", "x", "y", "p", "cause")


def delays_ns(key: int, pixel: np.ndarray, step: np.ndarray, sigma_s: float) -> np.ndarray:
    """Half-normal delays ``sigma |z|`` of the events of ``pixel`` decided at ``step`` [ns]."""
    z = normal(key, JITTER_STREAM, pixel, step)
    return np.round(np.abs(z) * sigma_s * 1e9).astype(np.int64)


def jittered(events: TriggeredEvents, held: dict | None, stop_ns: int, key: int, sigma_s: float,
             dt_ns: int) -> tuple[TriggeredEvents, dict]:
    """The events of a window with their delays, plus those held from before; returns ``(due, held)``.

    ``due`` holds every event whose delayed time is before ``stop_ns`` (sorted by time, row,
    column); the others are held for the next window.
    """
    width = events.focal_plane.width_px
    pixel = events.y.astype(np.int64) * width + events.x.astype(np.int64)
    new = {"t_ns": events.t_ns + delays_ns(key, pixel, events.t_ns // dt_ns, sigma_s), "x": events.x,
           "y": events.y, "p": events.p, "cause": events.cause}
    if held is not None:
        new = {name: np.concatenate([held[name], new[name]]) for name in FIELDS}
    due = new["t_ns"] < stop_ns
    order = np.lexsort((new["x"][due], new["y"][due], new["t_ns"][due]))
    out = {name: new[name][due][order] for name in FIELDS}
    counts = tuple(int(c) for c in np.bincount(out["cause"], minlength=4)[:4])
    port = TriggeredEvents(events.focal_plane, out["t_ns"], out["x"], out["y"], out["p"], out["cause"],
                           events.n_loss, counts)
    return port, {name: new[name][~due] for name in FIELDS}
