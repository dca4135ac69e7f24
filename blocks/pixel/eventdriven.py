"""The fast implementation: event-driven, exact on the reference's time grid.

A pixel is only touched when something happens to it: an event, a shot-noise trial,
or a change of its input. In between, its state follows in closed form and the step at
which the comparator next fires is solved for instead of stepped to (:mod:`.crossing`).
Shot noise (Eq. 20), a Bernoulli trial per pixel and step in the reference, is drawn as
the exact geometric waiting time to the next trial, thinned to the input's probability
at that step: the same law as the reference, step by step, whatever the input does.

All times live on the grid ``n dt``, so the fast and reference implementations produce
the same process -- refractory period (Eq. 21), one event per step and the events lost
(Eq. 17's ``N_loss``, :mod:`.comparator`) included -- and differ only in their random numbers. Random numbers are
addressed by (pixel, per-pixel counter) (:mod:`.counter_rng`) and a pixel's state is only
ever advanced at its own events and input changes, in order, so the events do not
depend on how the run is cut into windows.

This module turns a window's irradiance into per-pixel input changes and hands the
pixels that have something to do to the compiled per-pixel loop (:mod:`.pixel_loop`).
Cost: proportional to the number of events plus the number of (pixel, input change)
pairs; quiet pixels cost nothing until their next noise event. A change of the uniform
background is one input change shared by every pixel away from the stamps. Input that changes
nearly every pixel at every sample (video) goes through :mod:`.dense_loop` instead, with
identical events.
"""

from __future__ import annotations

import math

import numpy as np

from evsda.blocks.threads import worker_threads
from evsda.graph.threads import parallel_map

from .eventlog import EventLog
from .initial import initial_draws
from .model import PixelModel
from .deferred import SharedChanges, select_pixels, take_and_run
from .dense_loop import run_dense_chunk
from .drive_kernel import drive_constants, drive_rows
from .own_changes import under_stamps, window_changes
from .pixel_loop import COUNT, PARA, REAL, Y, resolve_schedules, start_pixels

NAMES = {"flux": "flux", "filtered": "L", "memorised": "M", "theta_on": "th_on", "theta_off": "th_off",
         "step": "step", "ready": "ready"}                                     # public names of some fields
_CHUNKS_PER_THREAD = 8                 # a thread's share of the items over this is the threads' last chunk (x 1/4)
_FIRST_CAPACITY = 1024                 # room for events per chunk at the first try (at least 2 per pixel)
#: a dense chunk's room for events over the last dense window's events per pixel (rows under a bright feature make
#: more than the mean; room never written is never touched, so costs no memory) [1]
_DENSE_ROOM = 2.0
#: room the envelope of background changes leaves around those kept, in Y (plus their spread) [ln of current]
#: and in the parasitic rate [relative]: wider envelopes are renewed less often but show fewer pixels quiet
_ENVELOPE_Y, _ENVELOPE_PARA = 1e-3, 1e-2
_PRUNE_EVERY = 8                       # windows between forgetting the background changes every pixel has taken
_WAKE_RENEWED = 1 << 30                # steps after the wake codes' first step at which they are set again
_LINE = 64                             # bytes of a cache line: where the state tables start (:func:`_line_aligned`)


def _aligned_empty(shape: tuple, dtype) -> np.ndarray:
    """An uninitialised array whose data starts on a cache line (``_LINE`` bytes; NumPy's large arrays start 16
    bytes into one)."""
    nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    raw = np.empty(nbytes + _LINE, np.uint8)
    start = -raw.ctypes.data % _LINE
    return raw[start:start + nbytes].view(dtype).reshape(shape)


def _line_aligned(array: np.ndarray) -> np.ndarray:
    """``array``, or where its data does not start on a cache line, a copy that does.

    A state table's 96-byte rows (:data:`.pixel_loop.REAL`) at a start 16 bytes into a line span three lines in
    every other row, two where it starts on one: each pixel's turn reads fewer lines (the same values)."""
    if array.ctypes.data % _LINE == 0:
        return array
    out = _aligned_empty(array.shape, array.dtype)
    out[...] = array
    return out


class EventDrivenPixels:
    """Event-driven pixel array over a state dict (see :meth:`new_state`)."""

    #: leave background changes out of pixels they cannot make fire (:mod:`.deferred`); False: the reference
    defer_background = True

    def __init__(self, model: PixelModel, state: dict):
        self.model = model
        self.s = state
        state["real"], state["count"] = _line_aligned(state["real"]), _line_aligned(state["count"])   # a restored state
        # each pixel's wake step (:func:`.deferred.select_pixels`) under the envelope (y_high, y_low, para_high) of
        # the background changes; derived from the state, not part of it: renewed from it when not fresh
        self._wake = np.empty(state["real"].shape[0], np.int32)      # as pixel_loop.wake_code from _envelope[3]
        self._envelope = np.array([-np.inf, np.inf, 0.0, 0.0])
        self._fresh = False
        self._windows = 0
        self._slot = np.full(state["real"].shape[0], -1, np.int32)    # scratch of :func:`.own_changes.under_stamps`
        self._rows = np.empty((0, len(REAL)))                         # scratch of the window's input changes
        self._dense_rate = 0.0                        # events per pixel of the last dense window (room for events)
        p = model.params
        q = 2.0 * model.shot_p_max                       # shot-trial probability per step
        self._drive = drive_constants(model)
        self._constants = (p.leak_rate_hz, model.dt_s, p.lowpass_form == "large_signal",
                           np.int64(model.refractory_steps), q,
                           np.int64(state["key"]), p.threshold_redraw,
                           p.threshold_on, p.threshold_off, p.threshold_sigma, p.threshold_floor)

    def _inputs(self, flux: np.ndarray) -> np.ndarray:
        """Rows of the state table's input columns for photon fluxes ``flux`` (Eqs. 12-16, 19-20).

        Only the input columns (``FLUX``, ``Y``, ``LOG_A``, ``PARA``, ``ACCEPT``), all the compiled
        loop reads, are set (:func:`.drive_kernel.drive_rows`, shared with the dense path).
        """
        flux = np.ascontiguousarray(flux, dtype=float)
        rows = np.empty((flux.size, len(REAL)))
        drive_rows(flux, self._drive, rows)
        return rows

    @staticmethod
    def field(state: dict, name: str) -> np.ndarray:
        """A copy of one per-pixel field (``memorised``, ``theta_on``, ...) of a state dict."""
        key = NAMES.get(name, name)
        if key in REAL:
            return state["real"][:, REAL.index(key)].copy()
        return state["count"][:, COUNT.index(key)].copy()

    # -- construction ---------------------------------------------------------------------
    @staticmethod
    def new_state(model: PixelModel, photon_flux: np.ndarray, rng: np.random.Generator, n_start: int,
                  background: float) -> dict:
        """Fresh state looking at ``photon_flux`` (``background`` plus stamps); the first step is ``n_start``."""
        draws = initial_draws(model, photon_flux.shape[0], rng)
        fluxes, drive, inverse = model.distinct_drive(photon_flux)
        n = photon_flux.shape[0]
        state = {"real": _aligned_empty((n, len(REAL)), float), "count": _aligned_empty((n, len(COUNT)), np.int64),
                 "next": np.empty(n, np.int64),                           # each pixel's next event step
                 "off_background": np.flatnonzero(photon_flux != background),   # pixels under stamps
                 "key": int(rng.integers(0, 2**63 - 1))}
        pixels = EventDrivenPixels(model, state)
        # the input columns of the distinct fluxes; where every pixel has its own (video), straight into the state
        # table, which start_pixels reads each row of before it writes the row's other columns
        rows = state["real"] if fluxes.size == n else np.empty((fluxes.size, len(REAL)))
        drive_rows(fluxes, pixels._drive, rows)
        leak_hz, dt, large, _, q, key, *_ = pixels._constants
        start_pixels(state["real"], state["count"], state["next"], inverse, rows, drive.y, drive.parasitic_hz,
                     draws.theta_on, draws.theta_off, draws.phase, draws.noise_scale, np.int64(n_start), leak_hz, dt,
                     large, key, q)
        return state

    # -- one window ---------------------------------------------------------------------------
    def run_window(self, held_background: float, background: np.ndarray, steps: np.ndarray, stamps,
                   n_end: int, log: EventLog) -> None:
        """Process a window whose samples (uniform ``background[k]`` plus ``stamps``) hold from ``steps[k]``.

        ``held_background`` is the uniform flux of the input held before the window. The
        pixels under stamps (now or before) get their own input changes; every other pixel
        shares the changes of the background, if any, and takes them only when they can
        matter (:mod:`.deferred`): when it is due for an event, or its comparator could reach
        a threshold under them before the window's end. A pixel under a stamp with background changes it was
        left out of takes them in the same turn as its own changes: those before the last quietly, the last as the
        first of its own changes (the row driven from its flux: the same bits as the background's row).
        """
        s = self.s
        history = SharedChanges(s, len(REAL))
        touched, stamp_row = under_stamps(s["off_background"], stamps.pixel, self._slot)   # under stamps, now or before
        kept = s["shared_step"].size                          # changes from before this window
        if steps.size:
            shared, own_step, own_flux, s["off_background"], changed, first, counts, quiet_from = window_changes(
                touched, stamp_row, stamps.sample, stamps.flux, s["real"], s["applied"], np.int64(s["shared_base"]),
                s["shared_step"], s["shared_input"], float(held_background), background, steps)
        else:                         # no samples: those behind take the earlier background changes now
            self._catch_up(history, history.behind(touched))
            shared = own_step = changed = first = counts = quiet_from = np.zeros(0, np.int64)
            own_flux = np.zeros(0)
        if shared.size:
            rows = self._inputs(background[shared])
            history.append(steps[shared], rows)
            self._fresh = self._fresh and self._holds(rows)
        refresh = not self._fresh or n_end - self._envelope[3] >= _WAKE_RENEWED
        if refresh:
            self._renew_envelope(n_end)
        leak_hz, dt = self._constants[:2]
        suffix = history.suffix_bounds(Y, PARA)
        base, end = np.int64(s["shared_base"]), np.int64(history.end)

        def select(span):             # the pixels of span to process and their changes (marks those taking them)
            return select_pixels(s["real"], s["count"], s["next"], self._wake, s["applied"], touched, changed,
                                 np.int64(n_end), base, end, *suffix, self._envelope, leak_hz * dt, dt,
                                 self.defer_background, refresh, np.int64(kept), np.int64(own_step.size),
                                 np.int64(s["shared_step"].size), first, counts, quiet_from, *span)

        n, parts = s["next"].size, worker_threads()     # the sensor in parts, in threads: the same lists
        spans = [(np.int64(n * i // parts), np.int64(n * (i + 1) // parts)) for i in range(parts)]
        selected = parallel_map(select, spans, parts)
        pixels, lo, hi, quiet_lo = selected[0] if parts == 1 else (np.concatenate(v) for v in zip(*selected))
        change_step = np.concatenate([own_step, s["shared_step"]])
        change_input = self._change_rows(own_flux.size + s["shared_input"].shape[0])      # own rows, then kept
        change_input[own_flux.size:] = s["shared_input"]     # the own rows: driven from own_flux by take_and_run
        self._run_changes(pixels, lo, hi, change_step, change_input, n_end, log, quiet_lo, kept - 1,
                          np.ascontiguousarray(own_flux, dtype=float))
        history.taken(touched)
        self._windows += 1
        if self._windows % _PRUNE_EVERY == 0:                # a sweep of every pixel's count, for memory only
            history.prune()

    def _change_rows(self, n: int) -> np.ndarray:
        """``n`` rows of the state table's width for a window's input changes, from a buffer kept across windows:
        a new array of ~10 MB each window was written through fresh pages (the kernel zeroing each on its first
        touch)."""
        if self._rows.shape[0] < n:
            self._rows = np.empty((max(n, 2 * self._rows.shape[0]), len(REAL)))
        return self._rows[:n]

    def _holds(self, rows: np.ndarray) -> bool:
        """Whether the envelope holds the background changes ``rows`` (their ``Y`` and parasitic rates)."""
        y_high, y_low, para_high = self._envelope[:3]
        return bool(np.all((rows[:, Y] <= y_high) & (rows[:, Y] >= y_low) & (rows[:, PARA] <= para_high)))

    def _renew_envelope(self, n_end: int) -> None:
        """An envelope around the kept background changes (none: the empty one, which any change leaves), for
        every pixel's wake to be set under it (:func:`.deferred.select_pixels` with ``refresh``), its wake codes
        from ``n_end`` (the envelope's last entry: :func:`.pixel_loop.wake_code`)."""
        rows = self.s["shared_input"]
        if rows.shape[0]:
            y_high, y_low = rows[:, Y].max(), rows[:, Y].min()
            room = _ENVELOPE_Y + (y_high - y_low)
            self._envelope = np.array([y_high + room, y_low - room, rows[:, PARA].max() * (1.0 + _ENVELOPE_PARA),
                                       float(n_end)])
        else:
            self._envelope = np.array([-np.inf, np.inf, 0.0, float(n_end)])
        self._fresh = True

    def take_pending(self) -> None:
        """Give every pixel the background changes it was left out of (its state then reads as if it took each
        at once; events are unaffected either way)."""
        history = SharedChanges(self.s, len(REAL))
        self._catch_up(history, history.behind(np.arange(self.s["real"].shape[0])))
        history.prune()

    def _catch_up(self, history: SharedChanges, pixels: np.ndarray) -> None:
        """Give ``pixels`` the background changes they have not taken (all before the present window).

        They were left out only while they provably could not fire (:func:`.deferred.select_pixels`),
        so this makes no events; one would mean the bound is wrong, which is raised, not hidden.
        """
        if not pixels.size:
            return
        kept = self.s["shared_step"].size
        lo, hi, quiet_lo = history.quiet_ranges(pixels, kept, 0)
        steps = self.s["shared_step"]
        scratch = EventLog()
        self._run_changes(pixels, lo, hi, steps, self.s["shared_input"], int(steps[-1]) + 1, scratch, quiet_lo,
                          kept - 1, np.zeros(0))
        if scratch._chunks or scratch.n_loss:
            raise RuntimeError("a pixel left out of a background change would have fired (deferral bound violated)")
        history.taken(pixels)

    def run_dense_window(self, background: np.ndarray, steps: np.ndarray, stamps_of, block_rows: int, n_end: int,
                         log: EventLog, height: int, width: int) -> None:
        """Process a window whose input changes almost everywhere each sample (video frames, noise upstream).

        ``stamps_of(row0, row1)`` gives the summed stamp flux ``[sample, pixel]`` of image rows
        ``row0 .. row1 - 1`` (:func:`.sampling.dense_stamps`), to which ``background[k]`` adds.
        Rows are taken ``block_rows`` at a time (the whole sensor at once when the frames are a
        view); each pixel reads its own samples off them in the compiled loop (:mod:`.dense_loop`) and
        goes through the same per-pixel event loop as :meth:`run_window`, so the events are
        exactly those :meth:`run_window` makes from the same input (tested). A chunk's pixels first have their
        kept schedules made the searches' crossings (:func:`.pixel_loop.resolve_schedules`, which the loop reads them
        as), on the chunk's thread; the items of a chunk run again (:meth:`_run`) were all in first chunks, which are
        runs of items, and are put back as they were after it.
        """
        s = self.s
        self.take_pending()                                   # background changes left out before
        background = np.ascontiguousarray(background, dtype=float)
        steps = np.ascontiguousarray(steps, dtype=np.int64)
        off_background = np.zeros(height * width, np.uint8)
        for row0 in range(0, height, block_rows):
            row1 = min(height, row0 + block_rows)
            stamps = stamps_of(row0, row1)
            first, off = row0 * width, off_background[row0 * width:row1 * width]

            def kernel(index, buffers):
                a, b = first + index[0], first + index[-1] + 1
                if b - a == index.size:       # a chunk's pixels first: their searches, as the kernel reads them
                    resolve_schedules(s["real"][a:b], s["count"][a:b], s["next"][a:b], *self._constants[:3])
                return run_dense_chunk(s["real"], s["count"], s["next"], np.int64(first), index, stamps, background,
                                       steps, self._drive, np.int64(n_end), *self._constants, *buffers, off)

            written = self._run(off.size, kernel, log, _DENSE_ROOM * self._dense_rate)
            self._dense_rate = written / off.size
        s["off_background"] = np.flatnonzero(off_background)
        self._fresh = False                                   # the wake steps are those of the states before

    def _run_changes(self, pixels, lo, hi, change_step, change_input, n_end: int, log: EventLog, quiet_lo,
                     quiet_end: int, own_flux: np.ndarray) -> None:
        """The event-driven loop (:func:`.pixel_loop.run_pixels`) over ``pixels``, pixel ``pixels[i]`` with the
        changes ``lo[i]:hi[i]`` of ``change_step``/``change_input``, after the kept background changes
        ``quiet_lo[i] .. quiet_end - 1`` (none where -1) taken quietly (:func:`.deferred.take_and_run`)."""
        s = self.s
        quiet_lo, lo = quiet_lo.copy(), lo.copy()

        def kernel(index, buffers):
            if index.size and index[-1] - index[0] + 1 == index.size:    # a run of items (ascending): views
                index = slice(index[0], index[-1] + 1)
            chunk_lo = lo[index]
            out = take_and_run(s["real"], s["count"], s["next"], self._wake, self._envelope, pixels[index],
                               quiet_lo[index], np.int64(quiet_end), s["shared_step"], s["shared_input"], chunk_lo,
                               hi[index], change_step, change_input, np.int64(own_flux.size), own_flux, self._drive,
                               np.int64(n_end), *self._constants, *buffers)
            quiet_lo[index] = -1             # taken: a chunk run again with more room for events takes them once
            lo[index] = chunk_lo             # past the changes swept (take_own): taken once too
            return out

        self._run(pixels.size, kernel, log)

    def _run(self, n_items: int, kernel, log: EventLog, room: float = 0.0) -> int:
        """``kernel(index, buffers)`` over chunks of the items ``0 .. n_items - 1``, in threads; returns the events
        written.

        ``kernel`` is a compiled loop (:func:`.deferred.take_and_run`, :func:`.dense_loop.run_dense_chunk`)
        over the pixels of ``index``, writing events into the buffers (step, pixel, polarity,
        cause) and returning ``(events written, items done, events lost)``. Pixels are
        independent, so chunks run concurrently (:func:`worker_threads` of them), the threads taking the next
        chunk as they come free; the chunks shrink towards the end (:func:`chunk_bounds`), so the threads end
        close together. A chunk has room for ``room`` events per item (at least 2, and ``_FIRST_CAPACITY``); one
        that runs out of room leaves its remaining items untouched, and those run again with twice the room.
        """
        room = max(2.0, room)
        first_capacity = _FIRST_CAPACITY
        threads = worker_threads()
        items = np.arange(n_items, dtype=np.int64)
        written = 0
        while items.size:
            bounds = chunk_bounds(items.size, threads)

            def chunk(span):
                a, b = span
                capacity = max(first_capacity, math.ceil(room * (b - a)))
                buffers = (np.empty(capacity, np.int64), np.empty(capacity, np.int64), np.empty(capacity, np.int8),
                           np.empty(capacity, np.uint8))
                n_events, n_done, lost = kernel(items[a:b], buffers)
                return [v[:n_events] for v in buffers], a + n_done, b, lost

            done = parallel_map(chunk, zip(bounds[:-1], bounds[1:]), threads)
            for events, *_ in done:
                log.add(*events)
                written += events[0].size
            log.lose(sum(lost for *_, lost in done))
            left = [np.arange(a, b) for _, a, b, _ in done if a < b]
            items = items[np.concatenate(left)] if left else items[:0]
            room, first_capacity = 2 * room, 2 * first_capacity
        return written


def chunk_bounds(n_items: int, threads: int) -> np.ndarray:
    """Bounds of the chunks that ``threads`` threads take ``n_items`` items in, each taking the next as it comes free.

    Guided self-scheduling (Polychronopoulos and Kuck, IEEE Trans. Comput. C-36, 1987), halved: each chunk is a
    ``1 / (2 threads)`` share of the items left, down to a ``1 / (4 _CHUNKS_PER_THREAD)`` share of a thread's
    items. Early chunks are long (few calls), and when the last chunk is taken the others are at most that short, so
    the threads end within a short chunk of each other where items differ in cost (the dense path's rows under a
    bright bar: several times the events of others). Equal chunks (``_CHUNKS_PER_THREAD`` per thread) left a thread
    idle up to a whole chunk, ~6 % of a window."""
    smallest = max(1, n_items // (4 * _CHUNKS_PER_THREAD * threads))
    bounds = [0]
    while bounds[-1] < n_items:
        left = n_items - bounds[-1]
        bounds.append(bounds[-1] + min(left, max(smallest, -(-left // (2 * threads)))))
    return np.array(bounds, np.int64)
