"""Synthetic event streams for the detection tests: Poisson background and sources on straight tracks."""

import numpy as np
import pytest

from evsda.blocks.ports import EventCause, Events, FocalPlane
from evsda.graph import NS_PER_S


def focal_plane(width: int = 64, height: int = 64) -> FocalPlane:
    return FocalPlane(width, height, 15e-6, 0.085)


def synthetic_events(rng, fp: FocalPlane, duration_s: float, background_hz: float,
                     tracks=(), start_s: float = 0.0) -> Events:
    """Background events (Poisson, ``background_hz`` per pixel) and, for every track
    ``(x0, y0, vx, vy, rate_hz)``, events at ``rate_hz`` in the pixel under ``(x0 + vx t, y0 + vy t)``."""
    n_bg = rng.poisson(background_hz * duration_s * fp.width_px * fp.height_px)
    t = [rng.uniform(0, duration_s, n_bg)]
    x = [rng.integers(0, fp.width_px, n_bg).astype(float)]
    y = [rng.integers(0, fp.height_px, n_bg).astype(float)]
    cause = [np.full(n_bg, EventCause.SHOT)]
    for x0, y0, vx, vy, rate in tracks:
        n = rng.poisson(rate * duration_s)
        ts = rng.uniform(0, duration_s, n)
        t.append(ts)
        x.append(np.rint(x0 + vx * (ts + start_s)))
        y.append(np.rint(y0 + vy * (ts + start_s)))
        cause.append(np.full(n, EventCause.SIGNAL))
    t, x, y, cause = (np.concatenate(a) for a in (t, x, y, cause))
    inside = (x >= 0) & (x < fp.width_px) & (y >= 0) & (y < fp.height_px)
    order = np.argsort(t[inside], kind="stable")
    t_ns = (np.round((t[inside][order] + start_s) * NS_PER_S)).astype(np.int64)
    n = t_ns.size
    return Events(fp, t_ns, t_ns.copy(), x[inside][order].astype(np.uint16), y[inside][order].astype(np.uint16),
                  np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8), cause[inside][order].astype(np.uint8))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
