"""From the ``Irradiance`` port to the pixel time grid: sample-and-hold inputs and their changes.

Pixel step ``n`` sits at ``t = n dt`` on one global grid. An irradiance sample taken at
``t_k`` holds from the first step at or after ``t_k`` until the next sample (the
``Irradiance`` convention); steps of a window before its first sample keep the input held
from the previous window.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from evsda.blocks.ports import Irradiance


def window_steps(start_ns: int, stop_ns: int, dt_ns: int) -> tuple[int, int]:
    """``(n_start, n_end)``: the steps ``n`` with ``start_ns <= n dt < stop_ns``."""
    return -(-start_ns // dt_ns), -(-stop_ns // dt_ns)


def sample_steps(irradiance: Irradiance, dt_ns: int, n_start: int, n_end: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the samples that take effect in ``[n_start, n_end)`` and the step at which each does.

    Samples before the window take effect at ``n_start`` (only the last of them counts);
    when several samples fall on one step the last one wins.
    """
    t = np.asarray(irradiance.t_ns, dtype=np.int64)
    steps = np.maximum(-(-t // dt_ns), n_start)
    keep = steps < n_end
    index = np.flatnonzero(keep)
    steps = steps[keep]
    if index.size:
        last_of_step = np.r_[steps[1:] != steps[:-1], True]
        index, steps = index[last_of_step], steps[last_of_step]
    return index, steps


@dataclass(frozen=True)
class StampPixels:
    """Stamp flux summed per (sample, pixel): ``flux[i]`` is added to the background at sample ``sample[i]``."""

    sample: np.ndarray   # int64 position in the list of samples
    pixel: np.ndarray    # int64 flat pixel index (row * width + column)
    flux: np.ndarray     # float64 [photon s^-1]


def live_stamps(irradiance: Irradiance, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k, s)``: the stamps ``s`` that add any flux at sample ``samples[k]`` (row-major: by sample, then stamp).

    A source off the detector at a sample, or at every sample of the window, keeps its slot in the
    ``Irradiance`` with zero flux (the optics keeps one slot per source it is given, and a star field gives
    every star the pointing sweeps over in the run); such a stamp adds nothing, so it is left out here, and a
    window's work and memory follow the sources on the detector in it, not those of the whole run.
    """
    flux = np.asarray(irradiance.stamp_flux)
    adds = np.zeros((samples.size, flux.shape[1]), np.bool_)
    _adds_flux(flux.reshape(*flux.shape[:2], -1), np.asarray(samples, dtype=np.int64), adds)
    return np.nonzero(adds)


@numba.njit(cache=True, nogil=True)
def _adds_flux(flux, samples, out):
    """``out[i, s]``: stamp ``s`` has a non-zero (or NaN) value at sample ``samples[i]`` (``flux`` [n_t, S, pixels])."""
    for i in range(samples.size):
        for s in range(flux.shape[1]):
            for value in flux[samples[i], s]:
                if value != 0:
                    out[i, s] = True
                    break


def has_stamps(irradiance: Irradiance, samples: np.ndarray) -> bool:
    """Whether ``samples`` is not empty and the irradiance carries stamps of at least one pixel."""
    flux = np.asarray(irradiance.stamp_flux)
    return samples.size > 0 and flux.ndim == 4 and flux.shape[1] * flux.shape[2] * flux.shape[3] > 0


def stamp_pixels(irradiance: Irradiance, samples: np.ndarray, live=None) -> StampPixels:
    """The stamps of ``samples`` as sparse (sample, pixel, flux) triples, clipped to the sensor and summed.

    Only the stamps that add flux (:func:`live_stamps`; ``live``: its result when the caller has it) are
    listed; each pixel's flux is summed from 0 in the stamps' order.
    """
    height, width = irradiance.focal_plane.shape
    flux = np.asarray(irradiance.stamp_flux)
    empty = np.zeros(0, np.int64)
    if not has_stamps(irradiance, samples):
        return StampPixels(empty, empty, np.zeros(0))
    which, stamp = live_stamps(irradiance, samples) if live is None else live
    if which.size == 0:
        return StampPixels(empty, empty, np.zeros(0))
    key, summed = _summed_stamps(flux, np.asarray(irradiance.stamp_origin), np.asarray(samples, dtype=np.int64),
                                 which.astype(np.int64), stamp.astype(np.int64), height, width)
    sample = key // (height * width)                 # the remainder as key - sample h w: NumPy's % is ~3x slower
    return StampPixels(sample, key - sample * (height * width), summed)


@numba.njit(cache=True, nogil=True)      # runs beside other blocks' steps (pipelined windows)
def _summed_stamps(flux, origin, samples, which, stamp, height, width):
    """``(key, flux)`` of :func:`stamp_pixels`: keys ``which * height * width + pixel`` of the live stamps' pixels
    on the sensor (``which``, ``stamp``: :func:`live_stamps`, sorted by sample), sorted and unique, and each key's
    flux summed from 0 in the stamps' order (``flux`` [n_t, S, h, w], ``origin`` [n_t, S, 2] column, row)."""
    h, w = flux.shape[2], flux.shape[3]
    keys = np.empty(which.size * h * w, np.int64)
    values = np.empty(which.size * h * w)
    unique = np.empty(which.size * h * w, np.int64)
    summed = np.zeros(which.size * h * w)
    runs = np.empty(which.size * h, np.int64)        # a stamp row's first key, its place in keys, its length
    run_at, run_size = np.empty(which.size * h, np.int64), np.empty(which.size * h, np.int64)
    order = np.empty(which.size * h * w, np.int64)
    m, u, i = 0, 0, 0
    while i < which.size:                            # the stamps of one sample at a time: its keys sort alone
        first, n_runs = m, 0
        sample = which[i]
        while i < which.size and which[i] == sample:
            k, s = samples[which[i]], stamp[i]
            col0, row0 = np.int64(origin[k, s, 0]), np.int64(origin[k, s, 1])
            for a in range(h):
                row = row0 + a
                if 0 <= row < height:
                    start = m
                    for b in range(w):
                        col = col0 + b
                        if 0 <= col < width:
                            keys[m] = sample * np.int64(height * width) + row * width + col
                            values[m] = flux[k, s, a, b]
                            m += 1
                    if m > start:
                        runs[n_runs], run_at[n_runs], run_size[n_runs] = keys[start], start - first, m - start
                        n_runs += 1
            i += 1
        # A stamp row's keys rise one by one: where no two rows overlap, the rows ordered by their first keys
        # give the keys in order, each once, which is the stable sort's order (a few rows to sort, not every key)
        by_row = stable_order(runs[:n_runs])
        apart, n = True, 0
        for r in range(n_runs):
            rank = by_row[r]
            if r > 0 and runs[rank] <= runs[by_row[r - 1]] + run_size[by_row[r - 1]] - 1:
                apart = False
                break
            for j in range(run_size[rank]):
                order[n] = run_at[rank] + j
                n += 1
        if apart:
            ordered = order[:m - first]
        else:
            ordered = stable_order(keys[first:m])   # stable: a key's additions keep the stamps' order
        for j in ordered:
            if u == 0 or keys[first + j] != unique[u - 1]:
                unique[u] = keys[first + j]
                u += 1
            summed[u - 1] += values[first + j]
    return unique[:u].copy(), summed[:u].copy()


@numba.njit(cache=True, nogil=True)
def stable_order(keys):
    """The indices that sort ``keys`` ascending, equal keys in index order: ``np.argsort(keys, kind="stable")``.

    A natural merge sort of the indices: the rising runs of ``keys`` (a stamp's rows' keys rise), merged pairwise
    until one is left, the left run's index first on a tie; also :func:`.own_changes.under_stamps`' sort. NumPy's
    argsort (its merge sort's pieces) took 1.2-1.9 s of a first run's compiling here; this takes ~0.4 s
    (``benchmarks/optics_compile.py``).
    """
    n = keys.size
    a, b = np.empty(n, np.int64), np.empty(n, np.int64)
    bounds = np.empty(n + 1, np.int64)               # where the runs start, then n
    runs = 0
    for i in range(n):
        a[i] = i
        if i == 0 or keys[i] < keys[i - 1]:
            bounds[runs] = i
            runs += 1
    bounds[runs] = n
    while runs > 1:
        merged = 0
        for r in range(0, runs, 2):
            lo, mid = bounds[r], bounds[r + 1]
            hi = bounds[r + 2] if r + 1 < runs else mid
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if keys[a[j]] < keys[a[i]]:
                    b[k] = a[j]
                    j += 1
                else:
                    b[k] = a[i]
                    i += 1
                k += 1
            while i < mid:
                b[k] = a[i]
                i += 1
                k += 1
            while j < hi:
                b[k] = a[j]
                j += 1
                k += 1
            bounds[merged] = lo
            merged += 1
        bounds[merged] = n
        runs = merged
        a, b = b, a
    return a


def dense_frames(irradiance: Irradiance, samples: np.ndarray) -> np.ndarray:
    """Full ``[K, height * width]`` photon-flux frames of ``samples`` [photon s^-1 per pixel]."""
    height, width = irradiance.focal_plane.shape
    frames = np.repeat(np.asarray(irradiance.background, dtype=float)[samples, None], height * width, axis=1)
    video = video_frames(irradiance, samples)
    if video is not None:       # one stamp on every pixel: the additions below, a frame at a time (~20x quicker)
        live = np.unique(live_stamps(irradiance, samples)[0])
        frames[live] += 0.0 + video[live]
        return frames
    sparse = stamp_pixels(irradiance, samples)
    np.add.at(frames, (sparse.sample, sparse.pixel), sparse.flux)     # each flux summed from 0 (stamp_pixels)
    return frames


#: stamps covering at least this fraction of the sensor per sample, on average, make the input dense
DENSE_FRACTION = 0.25


def stamp_coverage(irradiance: Irradiance, samples: np.ndarray, live=None) -> float:
    """Mean fraction of the sensor's pixels that the stamps adding flux at ``samples`` (:func:`live_stamps`;
    ``live``: its result when the caller has it) cover per sample (overlaps counted twice)."""
    height, width = irradiance.focal_plane.shape
    flux = np.asarray(irradiance.stamp_flux)
    if samples.size == 0 or flux.ndim != 4 or flux.shape[1] == 0:
        return 0.0
    h, w = flux.shape[2:]
    which, stamp = live_stamps(irradiance, samples) if live is None else live
    origin = np.asarray(irradiance.stamp_origin)[samples[which], stamp].astype(np.int64)      # [P, (x0, y0)]
    cols = np.clip(origin[:, 0] + w, 0, width) - np.clip(origin[:, 0], 0, width)
    rows = np.clip(origin[:, 1] + h, 0, height) - np.clip(origin[:, 1], 0, height)
    return float((cols * rows).sum() / (samples.size * height * width))


#: (sample, pixel) values per block of rows the dense path sums its stamps into (8 MB)
DENSE_BLOCK_VALUES = 1 << 20


def video_frames(irradiance: Irradiance, samples: np.ndarray) -> np.ndarray | None:
    """The frames ``[sample, pixel]`` as a view, without a copy, where the input is a video: a single stamp
    covering the sensor at every sample of a contiguous run of ``samples``; else ``None``."""
    height, width = irradiance.focal_plane.shape
    flux = np.asarray(irradiance.stamp_flux)
    if samples.size == 0 or flux.ndim != 4 or flux.shape[1:] != (1, height, width):
        return None
    first, last = int(samples[0]), int(samples[-1])
    if last - first != samples.size - 1 or np.any(np.asarray(irradiance.stamp_origin)[first:last + 1]):
        return None
    return flux[first:last + 1, 0].reshape(samples.size, height * width)


def dense_block_rows(irradiance: Irradiance, samples: np.ndarray) -> int:
    """Image rows per block of :func:`dense_stamps`: the whole sensor for a video (a view), else ~8 MB of sums."""
    height, width = irradiance.focal_plane.shape
    if video_frames(irradiance, samples) is not None:
        return height
    return max(1, DENSE_BLOCK_VALUES // max(1, samples.size * width))


def dense_stamps(irradiance: Irradiance, samples: np.ndarray, row0: int, row1: int) -> np.ndarray:
    """Summed stamp flux ``[sample, pixel]`` of image rows ``row0 .. row1 - 1`` (pixels in row-major order).

    Frame-major, as the frames come. The stamps of a pixel are summed from 0 in their order:
    the additions, in the same order, that :func:`stamp_pixels` makes, so that the background
    added to it gives the event-driven path's input bit for bit (a video's single stamp plus 0
    is itself, so :func:`video_frames` serves it without a copy).
    """
    width = irradiance.focal_plane.width_px
    video = video_frames(irradiance, samples)
    if video is not None:
        return video[:, row0 * width:row1 * width]
    summed = np.zeros((samples.size, (row1 - row0) * width))
    flux = np.asarray(irradiance.stamp_flux)
    if has_stamps(irradiance, samples):
        _sum_stamps(flux, np.asarray(irradiance.stamp_origin, dtype=np.int64), np.asarray(samples, dtype=np.int64),
                    row0, row1, width, summed)
    return summed


@numba.njit(cache=True, nogil=True)      # runs beside other blocks' steps (pipelined windows)
def _sum_stamps(flux, origin, samples, row0, row1, width, out):
    """Add the stamps of ``samples`` (clipped to rows ``row0 .. row1 - 1`` and the sensor) into ``out[sample, pixel]``."""
    h, w = flux.shape[2], flux.shape[3]
    for i in range(samples.size):
        k = samples[i]
        for s in range(flux.shape[1]):
            x0, y0 = origin[k, s, 0], origin[k, s, 1]
            for row in range(max(y0, row0), min(y0 + h, row1)):
                base = (row - row0) * width
                for column in range(max(x0, 0), min(x0 + w, width)):
                    out[i, base + column] += flux[k, s, row - y0, column - x0]
