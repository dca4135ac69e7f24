"""The input changes of the pixels under stamps in one window, from the sparse stamp list (compiled)."""

from __future__ import annotations

import numba
import numpy as np

from evsda.blocks.pixel.pixel_loop import FLUX
from evsda.blocks.pixel.sampling import stable_order


@numba.njit(cache=True, nogil=True)      # runs beside other blocks' steps (pipelined windows)
def own_changes(held, background, row_of, sample, flux, lead):
    """Where the photon flux of each listed pixel changes in a window: ``(row, column, value, off)``.

    Pixel ``i`` (of ``held.size``, sorted; ``held[i]`` its flux before the window [photon s^-1])
    sees ``background[k]`` at sample ``k`` plus the stamp flux ``flux[e]`` of every entry ``e`` with
    ``row_of[e] == i`` and ``sample[e] == k`` (entries sorted by sample), added in the entries' order.
    Returns the (pixel, sample) pairs whose value differs from the pixel's previous one, sorted by
    pixel then sample, their values, and ``off``: whether each pixel's last value differs from the
    last background. The same values and order as filling the dense ``[pixel, sample]`` table and
    comparing each column with the one before, without the table. A pixel with ``lead[i]`` has a change
    to ``held[i]`` before them, at column -1 (a change from before the window it has still to take).
    """
    n, k_max, m = held.size, background.size, row_of.size
    start = np.zeros(n + 1, np.int64)                # the entries by pixel, then sample (stable counting sort)
    for e in range(m):
        start[row_of[e] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:-1].copy()
    samples, fluxes = np.empty_like(sample), np.empty_like(flux)     # the entries' samples and fluxes in that order,
    for e in range(m):                                               # read in turn below (not gathered through it)
        samples[fill[row_of[e]]], fluxes[fill[row_of[e]]] = sample[e], flux[e]
        fill[row_of[e]] += 1
    n_background = 0                                 # a pixel's value changes only at sample 0, at a change
    for k in range(1, k_max):                        # of the background, at its entries and after them
        n_background += background[k] != background[k - 1]
    moves = np.empty(n_background + 1, np.int64)     # the background's changes, then k_max
    b = 0
    for k in range(1, k_max):
        if background[k] != background[k - 1]:
            moves[b] = k
            b += 1
    moves[b] = k_max
    capacity = n * (2 + n_background) + 2 * m
    rows = np.empty(capacity, np.int64)
    columns = np.empty(capacity, np.int64)
    values = np.empty(capacity)
    off = np.zeros(n, np.bool_)
    out = 0
    for i in range(n):
        previous = held[i]
        if lead[i]:
            rows[out], columns[out], values[out] = i, -1, previous
            out += 1
        e, e_end = start[i], start[i + 1]
        value = previous
        k, b = 0, 0
        while k < k_max:                             # only the samples where the value can change (above)
            value = background[k]
            entries = e < e_end and samples[e] == k
            while e < e_end and samples[e] == k:
                value = value + fluxes[e]
                e += 1
            if value != previous:
                rows[out], columns[out], values[out] = i, k, value
                out += 1
            previous = value
            while moves[b] <= k:
                b += 1
            following = min(moves[b], samples[e] if e < e_end else k_max)
            k = k + 1 if entries else following      # elsewhere the value is the background's, unchanged
        off[i] = k_max > 0 and value != background[k_max - 1]
    return rows[:out].copy(), columns[:out].copy(), values[:out].copy(), off


@numba.njit(cache=True, nogil=True)      # runs beside other blocks' steps (pipelined windows)
def window_changes(touched, stamp_row, sample, flux, real, applied, base, shared_step, shared_input, held_background,
                   background, steps):
    """A window's input changes, for a window with samples (``background[k]`` from ``steps[k]``; ``held_background``
    before them): ``(shared, own_step, own_flux, off_background, changed, first, counts, quiet_from)``.

    ``shared`` are the samples where the uniform background changes. The pixels under stamps (``touched``, sorted;
    ``stamp_row``, ``sample``, ``flux``: the stamp entries as :func:`own_changes` takes them) get their own changes,
    sorted by pixel then step (``own_step``, ``own_flux``), from their flux in the state table ``real`` or, where they
    have not taken every background change kept (``applied`` below ``base`` + the ``shared_step.size`` kept; rows
    ``shared_input``), from the last kept change's, which then leads their changes (at its step); ``off_background``
    are those whose last value is not the background's. ``changed`` are the pixels with own changes,
    ``first`` and ``counts`` where each one's changes start and how many, and ``quiet_from`` the first kept change
    each has not taken where the ones before the last kept change are left to take quietly (-1: none). The NumPy
    bookkeeping of :meth:`.eventdriven.EventDrivenPixels.run_window` under the GIL before, in one call that
    releases it (the same arrays).
    """
    k_max, kept, n = background.size, shared_step.size, touched.size
    shared = np.empty(k_max, np.int64)
    n_shared = 0
    for k in range(k_max):
        if background[k] != (background[k - 1] if k else held_background):
            shared[n_shared] = k
            n_shared += 1
    held, behind = np.empty(n), np.empty(n, np.bool_)
    for i in range(n):
        behind[i] = applied[touched[i]] < base + kept
        held[i] = shared_input[kept - 1, FLUX] if behind[i] and kept > 0 else real[touched[i], FLUX]
    row, column, own_flux, off = own_changes(held, background, stamp_row, sample, flux, behind)
    n_own = row.size
    own_step, first = np.empty(n_own, np.int64), np.empty(n_own, np.int64)
    changed, counts, quiet_from = np.empty(n_own, np.int64), np.empty(n_own, np.int64), np.empty(n_own, np.int64)
    c = -1
    for j in range(n_own):
        own_step[j] = steps[column[j]] if column[j] >= 0 else (shared_step[kept - 1] if kept > 0 else 0)
        if j == 0 or row[j] != row[j - 1]:              # a pixel's first change
            c += 1
            first[c], changed[c], counts[c] = j, touched[row[j]], 0
            pending = applied[changed[c]] - base
            quiet_from[c] = pending if pending < kept - 1 else -1
        counts[c] += 1
    off_background = np.empty(n, np.int64)
    n_off = 0
    for i in range(n):
        if off[i]:
            off_background[n_off] = touched[i]
            n_off += 1
    return (shared[:n_shared], own_step, own_flux, off_background[:n_off], changed[:c + 1], first[:c + 1],
            counts[:c + 1], quiet_from[:c + 1])


@numba.njit(cache=True, nogil=True)
def under_stamps(before, pixel, slot):
    """The pixels under stamps now or before, sorted, and the row of each stamp entry's pixel among them.

    ``before`` (sorted, unique): the pixels whose input differed from the background at the last
    window's end; ``pixel``: the stamp entries' pixels; ``slot``: a per-pixel scratch row of -1, left
    as found. The same as marking both in a sensor-sized mask, listing it and looking each entry's pixel
    up in the list, at a cost in the stamps' pixels, not the sensor's.
    """
    touched = np.empty(before.size + pixel.size, np.int64)
    m = 0
    for p in before:
        slot[p] = 0
        touched[m] = p
        m += 1
    for p in pixel:
        if slot[p] < 0:
            slot[p] = 0
            touched[m] = p
            m += 1
    touched = _sorted_runs(touched[:m])
    for i in range(m):
        slot[touched[i]] = i
    rows = np.empty(pixel.size, np.int64)
    for e in range(pixel.size):
        rows[e] = slot[pixel[e]]
    for i in range(m):
        slot[touched[i]] = -1
    return touched, rows


@numba.njit(cache=True, nogil=True)
def _sorted_runs(values):
    """``values`` in ascending order, by :func:`.sampling.stable_order` (a natural merge sort of rising runs).

    :func:`under_stamps`' pixels are a few rising runs (the pixels before, sorted, then the stamps' new pixels,
    sorted within each sample), so this takes a few passes; NumPy's sort, compiled on a first run, took ~1 s of
    compiling there (its quicksort's pieces).
    """
    order = stable_order(values)
    out = np.empty_like(values)
    for i in range(values.size):
        out[i] = values[order[i]]
    return out
