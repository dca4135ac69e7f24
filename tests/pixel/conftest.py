"""Synthetic irradiance for the pixel tests: core ``Irradiance`` objects built directly."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from evsda.blocks.pixel import DvsPixel
from evsda.blocks.ports import FocalPlane, Irradiance
from evsda.graph import Window

WAVELENGTH_M = 550e-9
PITCH_M = 5e-6


CROSSING_HORIZON_STEPS = 400      # the longest search horizon of :func:`crossing_cases` [steps]


def crossing_cases(seed: int, n: int, offset_sigma: float, relax_sigma: float, relax_share: float):
    """Random inputs of :func:`crossing.first_crossing`: ``(c, d, log_a, delta, theta_on, theta_off, j0, horizon)``,
    offsets ``c`` and relaxations ``d`` normal with the given spreads (``d`` zero outside ``relax_share`` of the
    cases), filter gains from none to instant, leak drifts, thresholds 0.05-0.3 and horizons of 7-400 steps."""
    rng = np.random.default_rng(seed)
    c = rng.normal(0, offset_sigma, n)
    d = rng.normal(0, relax_sigma, n) * (rng.random(n) < relax_share)
    eps = rng.choice([0.0, 1e-3, 0.05, 0.5, 1.0], n)
    with np.errstate(divide="ignore"):
        log_a = np.log1p(-eps)
    delta = rng.choice([0.0, 1e-4, 1e-3, 3e-2], n)
    th_on, th_off = rng.uniform(0.05, 0.3, n), rng.uniform(0.05, 0.3, n)
    j0 = rng.integers(1, 5, n)
    horizon = rng.choice([CROSSING_HORIZON_STEPS, 50, 7], n)
    return c, d, log_a, delta, th_on, th_off, j0, horizon


def first_hits(g, th_on, th_off, j0, horizon):
    """Stepping's answer for :func:`crossing_cases`: whether and at which step (1-based) ``g`` (n, steps) first
    leaves the band ``(-theta_off, theta_on)`` within ``[j0, max(horizon, j0)]``."""
    steps = np.arange(1, g.shape[1] + 1)
    hit = ((g >= th_on[:, None]) | (g <= -th_off[:, None])) & (steps[None] >= j0[:, None]) \
        & (steps[None] <= np.maximum(horizon, j0)[:, None])
    return hit.any(axis=1), steps[np.argmax(hit, axis=1)]


def focal_plane(width: int, height: int) -> FocalPlane:
    return FocalPlane(width, height, PITCH_M, 1.0)


def uniform(fp: FocalPlane, t_ns, background) -> Irradiance:
    """Uniform photon flux ``background[k]`` (or a constant) from each sample time ``t_ns[k]``."""
    t = np.asarray(t_ns, dtype=np.int64)
    bg = np.broadcast_to(np.asarray(background, dtype=float), t.shape).copy()
    return Irradiance(fp, WAVELENGTH_M, t, bg, np.zeros((t.size, 0, 2), np.int32), np.zeros((t.size, 0, 1, 1)))


def with_stamp(fp: FocalPlane, t_ns, background, origin, stamp) -> Irradiance:
    """Uniform background plus one stamp per sample: ``origin[k] = (x0, y0)``, ``stamp[k]`` is ``[h, w]``."""
    t = np.asarray(t_ns, dtype=np.int64)
    bg = np.broadcast_to(np.asarray(background, dtype=float), t.shape).copy()
    origin = np.asarray(origin, dtype=np.int32).reshape(t.size, 1, 2)
    stamp = np.asarray(stamp, dtype=float)
    return Irradiance(fp, WAVELENGTH_M, t, bg, origin, stamp[:, None])


def moving_spot(fp: FocalPlane, t_ns, background=2e3, peak=2e6, start=(2.0, 6.0), velocity=(100.0, 0.0),
                size=9, sigma=1.2) -> Irradiance:
    """A Gaussian spot moving at ``velocity`` [pixel/s] over a uniform background [photon/s]."""
    t = np.asarray(t_ns, dtype=np.int64)
    xc = start[0] + velocity[0] * t * 1e-9
    yc = start[1] + velocity[1] * t * 1e-9
    x0 = np.floor(xc).astype(int) - size // 2
    y0 = np.floor(yc).astype(int) - size // 2
    gy, gx = np.mgrid[0:size, 0:size]
    stamp = peak * np.exp(-((gx[None] + x0[:, None, None] - xc[:, None, None]) ** 2
                            + (gy[None] + y0[:, None, None] - yc[:, None, None]) ** 2) / (2 * sigma**2))
    return with_stamp(fp, t, background, np.stack([x0, y0], -1), stamp)


def grid(start_ns: int, stop_ns: int, cadence_ns: int) -> np.ndarray:
    """Sample times ``k cadence`` inside ``[start, stop)`` (one global grid)."""
    first = -(-start_ns // cadence_ns)
    return np.arange(first * cadence_ns, stop_ns, cadence_ns, dtype=np.int64)


def simulate(block: DvsPixel, irradiance_of, duration_s: float, window_s: float):
    """Run ``block`` over consecutive windows; ``irradiance_of(start_ns, stop_ns)`` gives each window's input."""
    outs = []
    n = int(round(duration_s / window_s))
    for w in range(n):
        win = Window.from_seconds(w * window_s, min((w + 1) * window_s, duration_s), index=w)
        outs.append(block.step(win, irradiance=irradiance_of(win.start_ns, win.stop_ns))["events"])
    return outs


def concat(outs) -> dict:
    """All events of a run as arrays, plus totals."""
    return {
        "t": np.concatenate([o.t_ns for o in outs]), "x": np.concatenate([o.x for o in outs]),
        "y": np.concatenate([o.y for o in outs]), "p": np.concatenate([o.p for o in outs]),
        "cause": np.concatenate([o.cause for o in outs]), "n_loss": sum(o.n_loss for o in outs),
        "counts": np.sum([o.counts_by_cause for o in outs], axis=0),
    }


def counts_image(events: dict, fp: FocalPlane, mask=None) -> np.ndarray:
    img = np.zeros(fp.shape, dtype=np.int64)
    sel = slice(None) if mask is None else mask
    np.add.at(img, (events["y"][sel].astype(int), events["x"][sel].astype(int)), 1)
    return img


@pytest.fixture
def scenes():
    """The scene helpers of this module."""
    return sys.modules[__name__]
