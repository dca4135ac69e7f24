"""The fast implementation: event-driven, exact on the reference's time grid.

A pixel is only touched when something happens to it: an event, a shot-noise trial,
or a change of its input. In between, its state follows in closed form (see
:mod:`.crossing`): the low-pass output relaxes geometrically, the memory drifts with the
leak currents, and the first step at which the comparator fires is solved for instead of
stepped to. Shot noise (Eq. 20), a Bernoulli trial per pixel and step in the reference,
is drawn as the exact geometric waiting time to the next trial that succeeds at the
largest probability ``p_max`` over all inputs, thinned to the probability ``p`` of the input
at that step (accepted with ``p / p_max``; Lewis & Shedler 1979 thinning, in discrete
time): the same law as the reference, step by step, whatever the input does.

All times live on the grid ``n dt``, so the fast and reference implementations produce
the same process -- refractory period (Eq. 21), one event per step and ``N_loss``
(Eq. 17) included -- and differ only in their random numbers. Random numbers are
addressed by (pixel, per-pixel counter) (:mod:`.counter_rng`) and a pixel's state is only
ever advanced at its own events and input changes, one at a time and in order, so the
events do not depend on how the run is cut into windows.

Cost: proportional to the number of events plus the number of (pixel, input change)
pairs; quiet pixels cost nothing until their next noise event. The pixels handled in a
window are copied into a compact working set (:class:`_Work`) and written back when done.
A change of the uniform background touches every pixel.
"""

from __future__ import annotations

import numpy as np

from . import counter_rng
from .comparator import TOLERANCE, charge_cause, reach
from .crossing import NEVER, comparator_input, first_crossing
from .eventlog import EventLog
from .initial import initial_pixels
from .model import PixelModel

GAP, ACCEPT, THRESHOLD = 1, 2, 3          # counter-RNG streams

# The per-pixel state is kept as two row-per-pixel tables, so that gathering the pixels of a
# window and writing them back are one fancy-indexing operation each, not one per field.
REAL = ("flux", "L", "M", "th_on", "th_off", "c_leak", "c_para", "c_shot",   # input, filter, memory, thresholds, causes
        "y", "log_a", "para", "accept")                                        # derived from the input (Eqs. 14-16, 19-20)
COUNT = ("step", "ready", "shot_next", "shot_count", "cmp_next", "event_count")
NAMES = {"flux": "flux", "filtered": "L", "memorised": "M", "theta_on": "th_on", "theta_off": "th_off",
         "step": "step", "ready": "ready"}                                     # public names of some fields
_LOOK_AHEAD = 8                              # input segments examined at once when skipping quiet ones


def _no_changes():
    return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)


class _Work:
    """The pixels handled in one window, as compact arrays (a struct of arrays)."""

    def __init__(self, **arrays):
        self.__dict__.update(arrays)

    def take(self, keep: np.ndarray) -> "_Work":
        return _Work(**{k: v[keep] for k, v in self.__dict__.items()})


class EventDrivenPixels:
    """Event-driven pixel array over a state dict (see :meth:`new_state`)."""

    def __init__(self, model: PixelModel, state: dict):
        self.model = model
        self.s = state
        self._leak_dt = model.params.leak_rate_hz * model.dt_s
        self._q = 2.0 * model.shot_p_max                       # shot-trial probability per step
        self._log_1mq = np.log1p(-self._q) if self._q < 1 else -np.inf

    def _derive(self, flux):
        """Input-derived quantities: lin-log target, ln(1 - eps), parasitic rate, shot acceptance."""
        drive = self.model.drive(flux)
        accept = drive.shot_p / self.model.shot_p_max if self.model.shot_p_max > 0 else np.zeros_like(drive.y)
        return drive.y, drive.log_a, drive.parasitic_hz, accept

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
        init = initial_pixels(model, photon_flux, rng)
        n = photon_flux.shape[0]
        state = {"real": np.zeros((n, len(REAL))), "count": np.zeros((n, len(COUNT)), np.int64),
                 "next": np.zeros(n, np.int64),                           # min(cmp_next, shot_next)
                 "off_background": np.flatnonzero(photon_flux != background),   # pixels under stamps
                 "key": int(rng.integers(0, 2**63 - 1))}
        pixels = EventDrivenPixels(model, state)
        w = _Work(pix=np.arange(n), **{name: np.zeros(n) for name in REAL},
                  **{name: np.zeros(n, np.int64) for name in COUNT})
        w.flux[:] = photon_flux
        w.y[:], w.log_a[:], w.para[:], w.accept[:] = pixels._derive(photon_flux)
        w.L[:], w.M[:], w.th_on[:], w.th_off[:] = init.filtered, init.memorised, init.theta_on, init.theta_off
        w.c_leak[:], w.c_para[:], w.c_shot[:] = init.credit
        w.step[:], w.ready[:] = n_start - 1, n_start
        w.shot_next[:] = pixels._shot_gap(w.pix, w.shot_count) + w.step
        pixels._schedule(w, np.arange(n), np.full(n, NEVER))
        pixels._scatter(w)
        return state

    # -- working set --------------------------------------------------------------------------
    def _gather(self, pix: np.ndarray) -> _Work:
        real = np.ascontiguousarray(self.s["real"].take(pix, axis=0).T)      # take: faster than fancy indexing
        count = np.ascontiguousarray(self.s["count"].take(pix, axis=0).T)
        return _Work(pix=pix, **dict(zip(REAL, real)), **dict(zip(COUNT, count)))

    def _scatter(self, w: _Work) -> None:
        for table, names in ((self.s["real"], REAL), (self.s["count"], COUNT)):
            rows = np.empty((w.pix.size, len(names)), table.dtype)
            for k, name in enumerate(names):
                rows[:, k] = getattr(w, name)
            table[w.pix] = rows
        self.s["next"][w.pix] = np.minimum(w.cmp_next, w.shot_next)

    # -- one window ---------------------------------------------------------------------------
    def run_window(self, held_background: float, background: np.ndarray, steps: np.ndarray, stamps,
                   n_end: int, log: EventLog) -> None:
        """Process a window whose samples (uniform ``background[k]`` plus ``stamps``) hold from ``steps[k]``.

        ``held_background`` is the uniform flux of the input held before the window. When
        only stamps change, only the pixels under them (now or before) see new inputs;
        a change of the background is a new input for every pixel.
        """
        s = self.s
        if np.all(background == held_background):
            touched = np.union1d(s["off_background"], stamps.pixel)
            if touched.size == 0 or steps.size == 0:
                self.run(n_end, *_no_changes(), log)
                return
            values = np.repeat(background[None, :], touched.size, axis=0)          # [pixel, sample]
            np.add.at(values, (np.searchsorted(touched, stamps.pixel), stamps.sample), stamps.flux)
            before = np.concatenate([s["real"][touched, REAL.index("flux"), None], values[:, :-1]], axis=1)
            row, col = np.nonzero(values != before)
            s["off_background"] = touched[values[:, -1] != background[-1]]
            self.run(n_end, touched[row], steps[col].astype(np.int64), values[row, col], log)
            return
        flux = s["real"][:, REAL.index("flux")].copy()
        bounds = np.r_[steps[1:], n_end]
        self.run(int(steps[0]), *_no_changes(), log)
        for k in range(steps.size):
            frame = np.full(flux.shape[0], background[k])
            mine = stamps.sample == k
            np.add.at(frame, stamps.pixel[mine], stamps.flux[mine])
            pixel = np.flatnonzero(frame != flux)
            self.run(int(bounds[k]), pixel, np.full(pixel.size, steps[k], np.int64), frame[pixel], log)
            flux = frame
        s["off_background"] = np.flatnonzero(flux != background[-1])

    # -- the main loop ------------------------------------------------------------------------
    def run(self, n_end: int, change_pixel: np.ndarray, change_step: np.ndarray, change_flux: np.ndarray,
            log: EventLog) -> None:
        """Process every event before step ``n_end`` and the input changes (sorted by pixel, then step)."""
        due = np.flatnonzero(self.s["next"] < n_end)
        if change_pixel.size:
            changed, first, counts = np.unique(change_pixel, return_index=True, return_counts=True)
            active = np.union1d(due, changed)
        else:
            active = due
        if active.size == 0:
            return
        w = self._gather(active)
        w.ptr = np.zeros(active.size, np.int64)           # next change of each pixel ...
        w.end = np.zeros(active.size, np.int64)           # ... and one past its last
        new_input = None
        if change_pixel.size:
            where = np.minimum(np.searchsorted(changed, active), changed.size - 1)
            has = changed[where] == active
            w.ptr[has] = first[where[has]]
            w.end[has] = w.ptr[has] + counts[where[has]]
            new_input = (change_flux, *self._derive(change_flux))
        if change_pixel.size:                             # schedule again with the window's changes in view
            self._search(w, np.flatnonzero(w.ptr < w.end), change_step, new_input)
        while w.pix.size:
            t_change = self._next_change(w, change_step)
            t_event = np.minimum(w.cmp_next, w.shot_next)
            fire = (t_event < t_change) & (t_event < n_end)
            if fire.any():
                i = np.flatnonzero(fire)
                self._event(w, i, t_event[i], np.minimum(t_change[i], n_end), log)
            # after an event, or where the look-ahead reached a change with nothing before it
            again = fire | ((t_change <= t_event) & (w.ptr < w.end))
            if again.any():
                self._search(w, np.flatnonzero(again), change_step, new_input)
            done = (w.ptr >= w.end) & (np.minimum(w.cmp_next, w.shot_next) >= n_end)
            n_done = np.count_nonzero(done)
            if n_done == w.pix.size:
                self._scatter(w)
                break
            if n_done > w.pix.size // 4 or (n_done and w.pix.size < 4096):    # compact now and then
                self._scatter(w.take(done))
                w = w.take(~done)

    @staticmethod
    def _next_change(w: _Work, change_step) -> np.ndarray:
        """Step of each item's next input change (``NEVER`` if none is left)."""
        pending = w.ptr < w.end
        t_change = np.full(w.pix.size, NEVER)
        t_change[pending] = change_step[w.ptr[pending]]
        return t_change

    # -- pieces (all act on items ``i`` of the working set) -----------------------------------
    def _advance(self, w: _Work, i, t) -> None:
        """Move items ``i`` from their last step to step ``t`` at constant input (Eqs. 16, 18, 19)."""
        j = t - w.step[i]
        y = w.y[i]
        with np.errstate(invalid="ignore"):                 # 0 * ln(0) where the filter is off
            decay = np.where(j > 0, np.exp(j * w.log_a[i]), 1.0)
        w.L[i] = y + (w.L[i] - y) * decay
        scale = w.th_on[i] * j * self.model.dt_s
        leak = self.model.params.leak_rate_hz * scale
        para = w.para[i] * scale
        w.M[i] -= leak + para
        w.c_leak[i] += leak
        w.c_para[i] += para
        w.step[i] = t

    def _schedule(self, w: _Work, i, next_change) -> None:
        """Next comparator event of items ``i`` (:func:`.crossing.first_crossing`), looked for before ``next_change``."""
        step, y, th_on = w.step[i], w.y[i], w.th_on[i]
        drift = (self._leak_dt + w.para[i] * self.model.dt_s) * th_on
        j0 = np.maximum(w.ready[i] - step, 1)
        horizon = np.where(next_change >= NEVER, NEVER, next_change - 1 - step)
        j, _ = first_crossing(j0, y - w.M[i], w.L[i] - y, w.log_a[i], drift, reach(th_on), reach(w.th_off[i]),
                              horizon)
        w.cmp_next[i] = np.where(j >= NEVER, NEVER, step + j)

    def _shot_gap(self, pix, count) -> np.ndarray:
        """Steps to the next shot-noise trial (geometric with success probability ``2 p_max`` per step)."""
        if self._q <= 0:
            return np.full(pix.size, NEVER)
        if not np.isfinite(self._log_1mq):
            return np.ones(pix.size, np.int64)
        u = counter_rng.uniform_open(self.s["key"], GAP, pix, count)
        gap = np.floor(np.log(u) / self._log_1mq) + 1.0
        return np.minimum(gap, float(NEVER // 2)).astype(np.int64)

    def _search(self, w: _Work, i, change_step, new_input) -> None:
        """Schedule items ``i`` from their present state, through their next input changes.

        The state at the start of the present input segment and of up to
        ``_LOOK_AHEAD`` following ones follows in closed form: the low-pass output from the
        affine recursion ``L' = A L + (1 - A) Y`` (``A = a^length``), evaluated for all
        segments at once by a parallel prefix scan (Hillis & Steele 1986), the memory and
        the leak contributions from the linear drift. The comparator's first crossing
        (:func:`.crossing.first_crossing`) is solved in every segment at once; the state
        jumps to the start of the first segment with a crossing, a shot-noise trial, or the
        pixel's last change in the window, and that segment's crossing becomes the item's
        next comparator event. When none of the segments examined holds anything, the
        state stops at the start of the last of them.
        """
        remaining = w.end[i] - w.ptr[i]
        if change_step.size == 0 or not np.all(remaining > 0):    # no change left: to the end, in one batch
            self._schedule(w, i[remaining == 0], np.full(np.count_nonzero(remaining == 0), NEVER))
            i, remaining = i[remaining > 0], remaining[remaining > 0]
            if not i.size:
                return
        dt = self.model.dt_s
        first = w.ptr[i]
        n_new = np.minimum(remaining, _LOOK_AHEAD)          # new segments examined; column 0 is the present one
        m = int(n_new.max()) + 1
        col = np.arange(m)
        valid = col[None, :] <= n_new[:, None]
        top = change_step.size - 1
        k = np.minimum(first[:, None] + col[None, 1:] - 1, top)                  # change index of columns 1..
        last = col[None, :] >= remaining[:, None]                                   # the pixel's last segment
        start = np.concatenate([w.step[i][:, None] + 1, change_step[k]], axis=1)   # first step of each segment
        after = np.concatenate([change_step[first][:, None], change_step[np.minimum(k + 1, top)]], axis=1)
        stop = np.where(last, NEVER, after)
        ref = start - 1                                      # the step whose state each segment starts from
        flux, y, log_a, para, accept = (np.concatenate([now[i][:, None], new[k]], axis=1) for now, new in
                                        zip((w.flux, w.y, w.log_a, w.para, w.accept), new_input))
        length = np.where(last, 0, stop - start)
        length[:, 0] = stop[:, 0] - 1 - ref[:, 0]
        th_on = w.th_on[i]
        drift = (self._leak_dt + para * dt) * th_on[:, None]                       # per step, per segment
        leak = self._leak_dt * th_on[:, None] * length
        parasitic = para * dt * th_on[:, None] * length
        with np.errstate(invalid="ignore"):                 # 0 * ln(0) where the filter is off
            a = np.where(length > 0, np.exp(length * log_a), 1.0)
        # affine prefix scan of x -> A x + B over the segments
        b = y * (1.0 - a)
        shift = 1
        while shift < m:
            a_prev, b_prev = a[:, :-shift].copy(), b[:, :-shift].copy()
            b[:, shift:] = a[:, shift:] * b_prev + b[:, shift:]
            a[:, shift:] = a[:, shift:] * a_prev
            shift *= 2
        l_now = w.L[i]
        l_start = np.empty_like(a)
        l_start[:, 0] = l_now
        l_start[:, 1:] = a[:, :-1] * l_now[:, None] + b[:, :-1]
        leak_start, para_start = (np.concatenate([np.zeros((i.size, 1)), np.cumsum(v, axis=1)[:, :-1]], axis=1)
                                  for v in (leak, parasitic))
        m_start = w.M[i][:, None] - leak_start - para_start
        j0 = np.maximum(w.ready[i][:, None] - ref, 1)
        horizon = np.where(last, NEVER, stop - 1 - ref)
        j, _ = first_crossing(j0.ravel(), (y - m_start).ravel(), (l_start - y).ravel(), log_a.ravel(), drift.ravel(),
                              np.repeat(reach(th_on), m), np.repeat(reach(w.th_off[i]), m), horizon.ravel())
        j = j.reshape(i.size, m)
        cross = (j < NEVER) & (j <= horizon)              # a refractory pixel may report its first step after the segment
        shot = w.shot_next[i][:, None]
        busy = cross | ((shot >= start) & (shot < stop)) | last | (col[None, :] == n_new[:, None])
        target = np.argmax(busy & valid, axis=1)
        at = (np.arange(i.size), target)
        w.L[i], w.M[i] = l_start[at], m_start[at]
        w.c_leak[i] += leak_start[at]
        w.c_para[i] += para_start[at]
        w.step[i] = ref[at]
        w.flux[i], w.y[i], w.log_a[i], w.para[i], w.accept[i] = flux[at], y[at], log_a[at], para[at], accept[at]
        w.ptr[i] = first + target
        w.cmp_next[i] = np.where(cross[at], ref[at] + j[at], NEVER)

    def _event(self, w: _Work, i, t, limit, log: EventLog) -> None:
        """Comparator events and shot-noise trials of items ``i`` at steps ``t`` (to be rescheduled after).

        A comparator event that leaves a backlog (Eq. 17) is followed by the next one as
        soon as the refractory period ends if the input is still beyond a threshold then:
        those follow-ups are fired here, in a loop over the few items still firing, up to
        each item's ``limit`` (its next input change or the window's end) and its next
        shot-noise trial. They are exactly the events the main loop would find one round
        at a time, with the same arithmetic.
        """
        self._advance(w, i, t)
        fired = i[w.cmp_next[i] == t]
        if fired.size:
            self._fire(w, fired, log)
        self._shot(w, i, t, log)
        bound = limit[np.searchsorted(i, fired)] if fired.size else limit[:0]
        while fired.size:
            nxt = w.ready[fired]
            keep = (nxt < bound) & (nxt < w.shot_next[fired])
            fired, bound, nxt = fired[keep], bound[keep], nxt[keep]
            if not fired.size:
                break
            y, th_on = w.y[fired], w.th_on[fired]
            drift = (self._leak_dt + w.para[fired] * self.model.dt_s) * th_on
            g = comparator_input(nxt - w.step[fired], y - w.M[fired], w.L[fired] - y, w.log_a[fired], drift)
            keep = (g >= reach(th_on)) | (g <= -reach(w.th_off[fired]))
            fired, bound, nxt = fired[keep], bound[keep], nxt[keep]
            if fired.size:
                self._advance(w, fired, nxt)
                self._fire(w, fired, log)

    def _fire(self, w: _Work, c, log: EventLog) -> None:
        """Comparator events (Eq. 17) of items ``c``, whose state is at the event step."""
        p = self.model.params
        tt = w.step[c]
        delta = w.L[c] - w.M[c]
        sign = np.where(delta >= 0, 1, -1).astype(np.int8)
        theta = np.where(sign > 0, w.th_on[c], w.th_off[c])
        total = np.maximum(np.trunc((np.abs(delta) + TOLERANCE) / theta), 1.0)
        log.lose(np.sum(total - 1.0))
        credit = np.vstack([w.c_leak[c], w.c_para[c], w.c_shot[c]])
        cause = charge_cause(sign, delta - credit.sum(axis=0), credit)
        moved = sign * theta
        w.c_leak[c] -= np.where(cause == 1, moved, 0.0)
        w.c_para[c] -= np.where(cause == 2, moved, 0.0)
        w.c_shot[c] -= np.where(cause == 3, moved, 0.0)
        w.M[c] += moved
        w.ready[c] = tt + self.model.refractory_steps
        log.add(tt, w.pix[c], sign, cause)
        if p.threshold_redraw:
            self._redraw(w, c, sign)

    def _shot(self, w: _Work, i, t, log: EventLog) -> None:
        """Shot-noise trials (Eq. 20) of items ``i`` arriving at steps ``t``."""
        p = self.model.params
        k_refr = self.model.refractory_steps
        # shot noise (Eq. 20): trials arriving now
        a = i[w.shot_next[i] == t]
        if a.size:
            tt = w.step[a]
            bits = counter_rng.hash64(self.s["key"], ACCEPT, w.pix[a], w.shot_count[a])
            u = (bits >> np.uint64(11)).astype(np.float64) * 2.0**-53
            accepted = u < w.accept[a]
            emitted = accepted & (w.ready[a] <= tt)
            log.lose(np.count_nonzero(accepted) - np.count_nonzero(emitted))
            e = a[emitted]
            if e.size:
                sign = np.where((bits[emitted] & np.uint64(1)) == 1, 1, -1).astype(np.int8)
                moved = sign * np.where(sign > 0, w.th_on[e], w.th_off[e])
                w.M[e] += moved
                w.c_shot[e] -= moved
                w.ready[e] = w.step[e] + k_refr
                log.add(w.step[e], w.pix[e], sign, 3)
                if p.threshold_redraw:
                    self._redraw(w, e, sign)
            w.shot_count[a] += 1
            w.shot_next[a] = tt + self._shot_gap(w.pix[a], w.shot_count[a])

    def _redraw(self, w: _Work, e, sign) -> None:
        """IEBCS: a new threshold of the polarity that fired, addressed by the pixel's event count."""
        p = self.model.params
        z = counter_rng.normal(self.s["key"], THRESHOLD, w.pix[e], w.event_count[e])
        on = sign > 0
        w.th_on[e[on]] = np.maximum(p.threshold_on + p.threshold_sigma * z[on], p.threshold_floor)
        w.th_off[e[~on]] = np.maximum(p.threshold_off + p.threshold_sigma * z[~on], p.threshold_floor)
        w.event_count[e] += 1
