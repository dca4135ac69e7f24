"""A space-time matched filter for events: counts along straight tracks over a grid of candidate velocities.

A point source moving at a constant apparent velocity ``v`` leaves its events on the line
``x = x0 + v (t - t_mid)`` in (x, y, t). Shifting every event of a look back to the look's middle
with a trial velocity, ``x' = x - v (t - t_mid)``, piles the source's events into one place
exactly when ``v`` is right: the motion-compensated event image of contrast maximisation
(Gallego, Rebecq & Scaramuzza 2018, CVPR, "A unifying contrast maximization framework for event
cameras"; used on noise-dominated space recordings by Arja et al. 2023, CVPR Workshops, "Density
invariant contrast maximization for neuromorphic Earth observations"), searched over a grid of
velocities as the velocity-matched filter or shift-and-stack of faint-streak detection
(Yanagisawa et al. 2005, PASJ 57, 399). Here the compensated image is counted in boxes of
``box x box`` pixels, and each box's count is tested against the Poisson background expected
there (:mod:`.significance`).

Velocities are spaced ``step_px / look`` apart, so a source between two trial velocities is
smeared by at most ``step_px / 2`` pixels at the ends of a look. Events are first thinned
(:func:`thin_events`) so that the background is close to Poisson: a pixel's events closer than
``dedup`` to its previous one are merged (the ON-then-OFF rebound of a shot-noise event, a burst
of events in one pixel), and optionally a pixel gives at most ``max_per_pixel`` events per look.
"""

from __future__ import annotations

import math

import numba
import numpy as np


def velocity_grid(max_rate_px_s: float, min_rate_px_s: float, look_s: float, step_px: float) -> np.ndarray:
    """Trial velocities ``(n, 2)`` [pixel s^-1] on a square grid ``step_px / look_s`` apart, with
    ``min_rate <= |v| <= max_rate`` (the origin included when ``min_rate`` is 0)."""
    dv = step_px / look_s
    n = int(math.floor(max_rate_px_s / dv + 1e-9))
    axis = np.arange(-n, n + 1) * dv
    vx, vy = np.meshgrid(axis, axis)
    speed = np.hypot(vx, vy)
    keep = (speed <= max_rate_px_s + 1e-9) & (speed >= min_rate_px_s - 1e-9)
    return np.stack([vx[keep], vy[keep]], axis=-1)


@numba.njit(cache=True, nogil=True)
def thin_events(t_ns, pixel, last_t_ns, look_counts, dedup_ns, max_per_pixel):
    """Keep-mask of events (time-ordered): merge a pixel's events within ``dedup_ns`` of its previous
    event and keep at most ``max_per_pixel`` per look (0: no limit). ``last_t_ns`` (per pixel, across looks) and
    ``look_counts`` (per pixel, this look) are updated in place."""
    keep = np.zeros(t_ns.size, np.bool_)
    for e in range(t_ns.size):
        p = pixel[e]
        if t_ns[e] - last_t_ns[p] >= dedup_ns and (max_per_pixel <= 0 or look_counts[p] < max_per_pixel):
            keep[e] = True
            look_counts[p] += 1
        last_t_ns[p] = t_ns[e]
    return keep


def background_density(x: np.ndarray, y: np.ndarray, width: int, height: int, tile_px: int) -> float:
    """Events per pixel in a look, robust to sources: the mean over tiles of ``tile_px`` pixels,
    leaving out tiles whose count is improbably high for the median tile (p < 1e-3, Poisson)."""
    from scipy import stats

    nx, ny = max(1, width // tile_px), max(1, height // tile_px)
    tx = np.minimum(x.astype(np.int64) * nx // width, nx - 1)
    ty = np.minimum(y.astype(np.int64) * ny // height, ny - 1)
    counts = np.bincount(ty * nx + tx, minlength=nx * ny).astype(float)
    area = np.bincount((np.arange(height)[:, None] * ny // height * nx
                        + np.arange(width)[None, :] * nx // width).ravel(), minlength=nx * ny).astype(float)
    typical = np.median(counts / area) * area
    quiet = counts <= stats.poisson.isf(1e-3, np.maximum(typical, 1e-9))
    return float(counts[quiet].sum() / area[quiet].sum())


@numba.njit(cache=True, nogil=True)
def _box_sum(counts, i0, j0, box):
    s = 0
    for jj in range(j0, j0 + box):
        for ii in range(i0, i0 + box):
            s += counts[jj, ii]
    return s


@numba.njit(cache=True, nogil=True)
def candidate_boxes(t_s, x, y, velocities, box, pad, width, height, k_min, capacity):
    """Boxes whose motion-compensated count reaches ``k_min`` and is a local maximum, for every trial velocity.

    ``t_s`` are event times from the look's middle [s], ``x``, ``y`` pixel coordinates. A box is
    ``box x box`` cells of the compensated image, indexed by its first cell ``(i0, j0)`` in a map
    padded by ``pad`` cells on each side. A box is reported once per velocity, when no box shifted by
    one cell holds more events (a bright source at a nearly right velocity fills a line of boxes above
    ``k_min``: only its peaks are candidates). Returns ``(velocity index, i0, j0, count)`` rows and their
    number; ``-1`` when more than ``capacity`` were found.
    """
    n = t_s.size
    map_w, map_h = width + 2 * pad, height + 2 * pad
    counts = np.zeros((map_h, map_w), np.int32)
    seen = np.full((map_h, map_w), -1, np.int32)      # last velocity at which a box was examined
    ci = np.empty(n, np.int64)
    cj = np.empty(n, np.int64)
    out = np.empty((capacity, 4), np.int64)
    found = 0
    # a box of box^2 cells holding k_min events has a cell holding at least k_min / box^2 of them: only boxes
    # around such cells need their sums
    cell_min = max(1, -(-k_min // (box * box)))
    for k in range(velocities.shape[0]):
        vx, vy = velocities[k, 0], velocities[k, 1]
        for e in range(n):
            i = int(math.floor(x[e] - vx * t_s[e] + 0.5)) + pad
            j = int(math.floor(y[e] - vy * t_s[e] + 0.5)) + pad
            if i < 0 or j < 0 or i >= map_w or j >= map_h:
                i = -1
            ci[e], cj[e] = i, j
            if i >= 0:
                counts[j, i] += 1
        for e in range(n):
            if ci[e] < 0 or counts[cj[e], ci[e]] < cell_min:
                continue
            for j0 in range(max(0, cj[e] - box + 1), min(cj[e], map_h - box) + 1):
                for i0 in range(max(0, ci[e] - box + 1), min(ci[e], map_w - box) + 1):
                    if seen[j0, i0] == k:
                        continue
                    seen[j0, i0] = k
                    s = _box_sum(counts, i0, j0, box)
                    if s < k_min:
                        continue
                    peak = True
                    for dj in range(-1, 2):
                        for di in range(-1, 2):
                            jn, i_n = j0 + dj, i0 + di
                            if (di != 0 or dj != 0) and 0 <= jn <= map_h - box and 0 <= i_n <= map_w - box:
                                if _box_sum(counts, i_n, jn, box) > s:
                                    peak = False
                    if not peak:
                        continue
                    if found >= capacity:
                        return out, -1
                    out[found, 0], out[found, 1], out[found, 2], out[found, 3] = k, i0, j0, s
                    found += 1
        for e in range(n):
            if ci[e] >= 0:
                counts[cj[e], ci[e]] = 0
    return out, found


def exposure_fraction(cx, cy, vx, vy, look_s: float, width: int, height: int) -> np.ndarray:
    """Fraction of the look during which a box centred at ``(cx, cy)`` at the look's middle, moving at
    ``(vx, vy)``, lies on the detector ``[-0.5, width - 0.5) x [-0.5, height - 0.5)`` [1]."""
    half = look_s / 2
    lo = np.full(np.shape(cx), -half)
    hi = np.full(np.shape(cx), half)
    for c, v, size in ((np.asarray(cx, float), np.asarray(vx, float), width),
                       (np.asarray(cy, float), np.asarray(vy, float), height)):
        moving = np.abs(v) > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(moving, (-0.5 - c) / np.where(moving, v, 1.0), -np.inf)
            b = np.where(moving, (size - 0.5 - c) / np.where(moving, v, 1.0), np.inf)
        enter, leave = np.minimum(a, b), np.maximum(a, b)
        inside = moving | ((c >= -0.5) & (c < size - 0.5))
        lo = np.where(inside, np.maximum(lo, enter), half)
        hi = np.minimum(hi, leave)
    return np.clip((hi - lo) / look_s, 0.0, 1.0)


def refine(t_s: np.ndarray, x: np.ndarray, y: np.ndarray, centre: np.ndarray, velocity: np.ndarray,
           radius_px: float, max_change_px_s: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Position at the look's middle and velocity of a detection by least squares on its events.

    The events whose compensated position (at ``velocity``) lies within ``radius_px`` of ``centre``
    are fitted with ``x = x0 + v t`` along each axis. The fitted velocity replaces the trial one when it
    differs by at most ``max_change_px_s`` (the trial grid's spacing) and the events span enough time;
    otherwise the position is their compensated mean at the trial velocity. Returns
    ``(position, velocity, n_events)``.
    """
    u = x - velocity[0] * t_s
    w = y - velocity[1] * t_s
    near = (u - centre[0]) ** 2 + (w - centre[1]) ** 2 <= radius_px**2
    n = int(near.sum())
    if n == 0:
        return centre.astype(float), velocity.astype(float), 0
    t, xs, ys = t_s[near], x[near], y[near]
    position = np.array([u[near].mean(), w[near].mean()])
    if n >= 4 and np.ptp(t) > 0:
        design = np.stack([np.ones(n), t], axis=1)
        (x0, fvx), *_ = np.linalg.lstsq(design, xs, rcond=None)
        (y0, fvy), *_ = np.linalg.lstsq(design, ys, rcond=None)
        fitted = np.array([fvx, fvy])
        if np.all(np.abs(fitted - velocity) <= max_change_px_s):
            return np.array([x0, y0]), fitted, n
    return position, velocity.astype(float), n
