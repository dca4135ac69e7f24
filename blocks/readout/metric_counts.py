"""The metrics block's per-window counts in compiled passes that leave the interpreter lock (issue 13).

:func:`count_recorded` counts a window's recorded events in one call: each event's pixel counted into the frame
and tested against the track marks (:func:`count_pixels`), their causes (:func:`count_causes`), their readout
delays ``t_a - t_t`` kept (with their maximum, the number of positive ones, their integer sum and the sum of their
magnitudes) and the events recorded out of trigger order counted (:func:`count_delays`). :func:`bin_delays` adds
the delays' logarithmic bins, from NumPy's ``log10`` (left to NumPy: a compiled logarithm need not round alike).
:func:`mark_paths` marks the sources' paths (the track) on the frame.
Every result is an integer, the same as the NumPy expressions they replace (``np.add.at``, ``np.bincount``,
running maxima; tests/readout/test_readout_metric_counts.py keeps those as the reference and compares).
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

SOURCE_MARK, SATELLITE_MARK = 1, 2       # the track bits of metrics.SOURCE_BIT, metrics.SATELLITE_BIT
INT64_MIN = np.iinfo(np.int64).min
FETCH_AHEAD = 16                         # events whose pixels are fetched ahead of their turn (alone: 16 ~0.7x of 0)


@intrinsic
def _fetch_for_write(typingctx, array, index):
    """Ask the CPU to bring ``array[index]`` (one dimension) into its caches to be written (LLVM's ``prefetch``;
    no effect on results)."""
    def codegen(context, builder, signature, args):
        values = context.make_array(signature.args[0])(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, signature.args[0], values, [args[1]], wraparound=False)
        byte_pointer, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        prefetch = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [byte_pointer, i32,
                                                                                                 i32, i32]),
                                                  "llvm.prefetch.p0i8")
        builder.call(prefetch, [builder.bitcast(pointer, byte_pointer), i32(1), i32(3), i32(1)])
        return context.get_dummy_value()
    return types.void(array, index), codegen


@numba.njit(cache=True, error_model="numpy", nogil=True)
def count_recorded(image, tracks, width, height, x, y, t_a, t_t, cause, by_cause, order, delays):
    """A window's recorded events counted: their pixels (:func:`count_pixels`), causes (:func:`count_causes`),
    delays and ordering errors (:func:`count_delays`), in one call.

    ``image`` (int64) and ``tracks`` (uint8): the frame's flat counts and track marks, counted into;
    ``by_cause`` (int64 [n_causes]): events per cause added (causes past its end not counted);
    ``order`` (int64 [3]): the readout time of the last event, the trigger-time maximum before its readout
    tick and over every event so far, carried from window to window and updated; ``delays`` (int64 [n]):
    filled with ``t_a - t_t`` [ns]. Returns (events near a source, near a satellite, recorded out of trigger
    order, the largest delay, positive delays, the delays' sum, the sum of their magnitudes, the first event
    outside the frame or -1: then nothing is counted)."""
    near_source, near_satellite, outside = count_pixels(image, tracks, width, height, x, y)
    if outside >= 0:
        return 0, 0, 0, 0, 0, 0, 0, outside
    count_causes(cause, by_cause)
    out_of_order, largest, positive, total, magnitude = count_delays(t_a, t_t, order, delays)
    return near_source, near_satellite, out_of_order, largest, positive, total, magnitude, -1


@numba.njit(cache=True, error_model="numpy", nogil=True)
def count_pixels(image, tracks, width, height, x, y):
    """Add each event to its pixel's count in ``image`` and count the events on pixels marked near a source
    and near a satellite in ``tracks`` (the pixels ``FETCH_AHEAD`` events on asked for ahead). Returns (near a source, near a satellite, the first event outside the
    frame or -1: then nothing is counted)."""
    for i in range(x.size):
        if np.int64(x[i]) >= width or np.int64(y[i]) >= height:
            return 0, 0, i
    near_source = near_satellite = 0
    for i in range(x.size):
        if i + FETCH_AHEAD < x.size:          # the frame is megabytes, the events' pixels scattered over it
            ahead = np.int64(y[i + FETCH_AHEAD]) * width + np.int64(x[i + FETCH_AHEAD])
            _fetch_for_write(image, ahead)
            _fetch_for_write(tracks, ahead)
        pixel = np.int64(y[i]) * width + np.int64(x[i])
        image[pixel] += 1
        mark = tracks[pixel]
        near_source += (mark & SOURCE_MARK) != 0
        near_satellite += (mark & SATELLITE_MARK) != 0
    return near_source, near_satellite, -1


@numba.njit(cache=True, error_model="numpy", nogil=True)
def count_delays(t_a, t_t, order, delays):
    """The readout delays ``t_a - t_t`` into ``delays`` and the events recorded out of trigger order (an
    event whose trigger time is before that of an event recorded at an earlier readout tick; ``order`` as in
    :func:`count_recorded`). Returns (out of order, the largest delay, positive delays, their sum, the sum of
    their magnitudes)."""
    out_of_order = positive = total = magnitude = 0
    largest = INT64_MIN
    last_t_a, max_before, max_all = order[0], order[1], order[2]
    for i in range(t_a.size):
        delay = t_a[i] - t_t[i]
        delays[i] = delay
        largest = max(largest, delay)
        positive += delay > 0
        total += delay
        magnitude += abs(delay)
        if t_a[i] != last_t_a:          # a new readout tick: every event before it was recorded strictly earlier
            max_before = max_all
            last_t_a = t_a[i]
        out_of_order += t_t[i] < max_before
        max_all = max(max_all, t_t[i])
    order[0], order[1], order[2] = last_t_a, max_before, max_all
    return out_of_order, largest, positive, total, magnitude


@numba.njit(cache=True, error_model="numpy", nogil=True)
def count_causes(cause, by_cause):
    """Add the events of each cause to ``by_cause`` (int64 [n_causes]; causes past its end not counted): one
    pass a cause (compares that vectorise, against one increment after another of the same few counters)."""
    for c in range(by_cause.size):
        n = 0
        for i in range(cause.size):
            n += cause[i] == c
        by_cause[c] += n


@numba.njit(cache=True, error_model="numpy", nogil=True)
def bin_delays(log10_delay, bins_per_decade, histogram):
    """Add each delay's bin ``1 + floor(log10(delay) * bins_per_decade)`` (the last bin for any above it) to
    ``histogram`` (int64), from the delays' ``log10`` as NumPy works them out (positive delays only)."""
    last = histogram.size - 1
    for i in range(log10_delay.size):
        histogram[min(1 + np.int64(np.floor(log10_delay[i] * bins_per_decade)), last)] += 1


@numba.njit(cache=True, error_model="numpy", nogil=True)
def mark_paths(seen, satellite, box, radius_sq, step_px, tracks, image, added):
    """Mark every source's path in ``tracks`` (uint8 [height, width]): ``SOURCE_MARK`` on every pixel whose
    centre is within ``sqrt(radius_sq)`` of a point of the path, ``SATELLITE_MARK`` too for a satellite.

    ``seen``: float64 [n_t, n_src, 2] the sources' (x, y) samples [pixel], NaN in both where not seen; the path
    is straight between consecutive seen samples, a point every ``step_px`` or less (:func:`path_points`, as
    :func:`.metrics.densify`); ``satellite``: bool [n_src]; ``box``: int64 [n_box, 2] offsets from
    ``floor(point)`` covering the disc; ``added`` (int64 [4]): the pixels newly marked near a source, the recorded
    events (``image``) on them, and the same for a satellite, added to."""
    height, width = tracks.shape
    for s in range(seen.shape[1]):
        bit = SOURCE_MARK | (SATELLITE_MARK if satellite[s] else 0)
        for point in path_points(seen[:, s], step_px):
            fx, fy = np.int64(np.floor(point[0])), np.int64(np.floor(point[1]))
            for k in range(box.shape[0]):
                px, py = fx + box[k, 0], fy + box[k, 1]
                dx, dy = px - point[0], py - point[1]
                if dx * dx + dy * dy <= radius_sq and 0 <= px < width and 0 <= py < height:
                    mark = tracks[py, px]
                    if mark & SOURCE_MARK == 0:
                        added[0] += 1
                        added[1] += image[py, px]
                    if bit & SATELLITE_MARK and mark & SATELLITE_MARK == 0:
                        added[2] += 1
                        added[3] += image[py, px]
                    tracks[py, px] = mark | bit


@numba.njit(cache=True, error_model="numpy", nogil=True)
def path_points(xy, step_px):
    """Points every ``step_px`` or less along the straight segments between consecutive finite samples of
    ``xy`` [n, 2], then the samples themselves: the points of :func:`.metrics.densify`, the same arithmetic
    (``a + (b - a) * (j / n)``), in another order."""
    finite = np.empty(xy.shape[0], np.bool_)
    for i in range(xy.shape[0]):
        finite[i] = np.isfinite(xy[i, 0]) and np.isfinite(xy[i, 1])
    points = []
    for i in range(xy.shape[0] - 1):
        if finite[i] and finite[i + 1]:
            ax, ay, bx, by = xy[i, 0], xy[i, 1], xy[i + 1, 0], xy[i + 1, 1]
            n = max(1, np.int64(np.ceil(max(abs(bx - ax), abs(by - ay)) / step_px)))
            for j in range(n):
                frac = j / n
                points.append((ax + (bx - ax) * frac, ay + (by - ay) * frac))
    for i in range(xy.shape[0]):
        if finite[i]:
            points.append((xy[i, 0], xy[i, 1]))
    return points
