"""Collects the events of one window and turns them into the ``TriggeredEvents`` port."""

from __future__ import annotations

import numba
import numpy as np

from evsda.blocks.ports import FocalPlane, TriggeredEvents

_DIGIT_BITS = 11               # the radix sort's widest digit: 2048 counters (16 KB, in L1) a pass
_PAYLOAD_BITS = 16             # a key's low bits that carry its event's polarity (int8) and cause (uint8)


class EventLog:
    """Events as (step, pixel, polarity, cause) chunks, plus the window's lost-event count."""

    def __init__(self):
        self._chunks: list[tuple[np.ndarray, ...]] = []
        self.n_loss = 0

    def add(self, step, pixel, polarity, cause) -> None:
        shape = np.shape(pixel)
        if np.size(pixel):
            parts = (np.asarray(v, dtype) for v, dtype in ((step, np.int64), (pixel, np.int64), (polarity, np.int8),
                                                           (cause, np.uint8)))
            self._chunks.append(tuple(v if v.shape == shape else np.broadcast_to(v, shape) for v in parts))

    def lose(self, count) -> None:
        self.n_loss += int(count)

    def to_port(self, focal_plane: FocalPlane, dt_ns: int) -> TriggeredEvents:
        """Events sorted by time, then row, then column, with times ``step dt`` [ns]."""
        if not self._chunks:
            out = TriggeredEvents.empty(focal_plane)
            return TriggeredEvents(focal_plane, out.t_ns, out.x, out.y, out.p, out.cause, self.n_loss, (0, 0, 0, 0))
        step, pixel, polarity, cause = (np.concatenate(parts) for parts in zip(*self._chunks))
        n = step.size
        t_ns, x, y, p, c = (np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16), np.empty(n, np.int8),
                            np.empty(n, np.uint8))
        counts = np.zeros(4, np.int64)
        scratch = [np.empty(n, np.int64) for _ in range(4)]
        time_ordered(step, pixel, polarity, cause, np.int64(focal_plane.width_px),
                     np.int64(focal_plane.width_px * focal_plane.height_px), np.int64(dt_ns), t_ns, x, y, p, c, counts,
                     *scratch)
        return TriggeredEvents(focal_plane, t_ns, x, y, p, c, self.n_loss, tuple(int(k) for k in counts))


@numba.njit(cache=True, nogil=True)      # runs beside other blocks' steps (pipelined windows)
def time_ordered(step, pixel, polarity, cause, width, n_pixels, dt_ns, t_ns, x, y, p, c, counts, keys, order,
                 other_keys, other_order):
    """The events sorted by step, then pixel (row, then column) into ``t_ns``, ``x``, ``y``, ``p``, ``c``: times
    ``step dt_ns`` [ns], columns and rows (``uint16``), polarities and causes; ``counts[c]`` adds the events of cause
    ``c`` (0-3). ``keys``, ``order`` and ``other_*``: scratch of the events' size.

    The keys ``(step, pixel)`` are unique (one event per pixel per step, Eqs. 17 and 20), so this is the order of any
    sort of them: NumPy's ``argsort`` of ``step * n_pixels + pixel`` under the GIL before, here a radix sort
    (:func:`_key_order`) in one call that releases it. Where a key has room, it carries the event's polarity and cause
    in ``_PAYLOAD_BITS`` low bits below it (the same order: the keys above them are unique), and the events are read
    off the sorted keys in turn, not gathered through their order."""
    keys, order, first, pixel_bits, payload = _key_order(step, pixel, polarity, cause, n_pixels, keys, order,
                                                         other_keys, other_order)
    pixel_mask = (np.int64(1) << pixel_bits) - 1
    for i in range(keys.size):
        if payload:
            key = keys[i]
            at, where = (key >> (payload + pixel_bits)) + first, (key >> payload) & pixel_mask
            sign, kind = (key >> 8) & 0xFF, key & 0xFF
            sign -= (sign & 0x80) << 1                # the polarity's int8 bits, signed again
        else:
            e = order[i]
            at, where, sign, kind = step[e], pixel[e], polarity[e], cause[e]
        row = where // width
        t_ns[i] = at * dt_ns
        x[i], y[i] = where - row * width, row
        p[i], c[i] = sign, kind
        if kind < 4:
            counts[kind] += 1


@numba.njit(cache=True, inline="always")
def _key_order(step, pixel, polarity, cause, n_pixels, keys, order, other_keys, other_order):
    """The keys ``(step, pixel)`` in their stable order, ``(keys, order, first step, pixel bits b, payload bits)``: a
    least-significant-digit radix sort (Knuth, TAOCP vol. 3, Sec. 5.2.5) of ``(step - first step) 2^b + pixel``
    (``2^b >= n_pixels``), in passes of at most ``_DIGIT_BITS`` bits. Where they fit in 62 bits with
    ``_PAYLOAD_BITS`` more, each key carries its event's polarity and cause below it (payload ``_PAYLOAD_BITS``) and
    ``order`` is not made; else (payload 0) ``order`` is the events' order. Where the events come in pixel order
    (the compiled loops' chunks, in turn), the passes over the pixel's bits would leave them as they are and are not
    made: the steps' ~17 bits a window on the tracked pass take two."""
    n = step.size
    first = step[0] if n else 0
    last = first
    for i in range(n):
        first = min(first, step[i])
        last = max(last, step[i])
    pixel_bits = 0
    while (n_pixels - 1) >> pixel_bits:
        pixel_bits += 1
    span_bits = 0
    while (last - first) >> span_bits:
        span_bits += 1
    payload = _PAYLOAD_BITS if span_bits + pixel_bits + _PAYLOAD_BITS <= 62 else 0
    top, by_pixel = 0, True
    for i in range(n):
        keys[i] = ((step[i] - first) << pixel_bits) | pixel[i]
        if payload:
            keys[i] = (keys[i] << payload) | ((polarity[i] & 0xFF) << 8) | cause[i]
        else:
            order[i] = i
        top = max(top, keys[i])
        if i and pixel[i] < pixel[i - 1]:
            by_pixel = False
    low = payload + (pixel_bits if by_pixel else 0)
    bits = low
    while top >> bits:
        bits += 1
    passes = -(-(bits - low) // _DIGIT_BITS)
    if passes == 0:
        return keys, order, first, pixel_bits, payload
    digit = -(-(bits - low) // passes)
    mask = (1 << digit) - 1
    start = np.empty((1 << digit) + 1, np.int64)
    for shift in range(low, low + passes * digit, digit):
        for d in range(start.size):
            start[d] = 0
        for i in range(n):
            start[((keys[i] >> shift) & mask) + 1] += 1
        for d in range(1 << digit):
            start[d + 1] += start[d]
        for i in range(n):
            d = (keys[i] >> shift) & mask
            other_keys[start[d]] = keys[i]
            if not payload:
                other_order[start[d]] = order[i]
            start[d] += 1
        keys, other_keys = other_keys, keys
        order, other_order = other_order, order
    return keys, order, first, pixel_bits, payload
