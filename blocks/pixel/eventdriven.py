"""The fast implementation: event-driven, exact on the reference's time grid.

A pixel is only touched when something happens to it: an event, a shot-noise arrival,
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
addressed by (pixel, per-pixel counter) (:mod:`.counter_rng`) and the state is only ever
advanced at a pixel's own events and input changes, so the events do not depend on how
the run is cut into windows.

Cost: proportional to the number of events plus the number of (pixel, input change)
pairs -- quiet pixels cost nothing until their next noise event. A change of the uniform
background touches every pixel.
"""

from __future__ import annotations

import numpy as np

from . import counter_rng
from .comparator import charge_cause
from .crossing import NEVER, first_crossing, may_cross
from .eventlog import EventLog
from .initial import initial_pixels
from .model import PixelModel

GAP, ACCEPT, THRESHOLD = 1, 2, 3          # counter-RNG streams


class EventDrivenPixels:
    """Event-driven pixel array over a state dict (see :func:`new_state`)."""

    def __init__(self, model: PixelModel, state: dict):
        self.model = model
        self.s = state
        p = model.params
        self._leak_dt = p.leak_rate_hz * model.dt_s
        self._q = 2.0 * model.shot_p_max                       # shot candidate probability per step
        self._log_1mq = np.log1p(-self._q) if self._q < 1 else -np.inf
        drive = model.drive(state["flux"])                     # caches derived from the state's input
        self.y, self.log_a, self.para_hz = drive.y, drive.log_a, drive.parasitic_hz
        self.accept = drive.shot_p / model.shot_p_max if model.shot_p_max > 0 else np.zeros_like(drive.y)

    # -- construction ---------------------------------------------------------------------
    @staticmethod
    def new_state(model: PixelModel, photon_flux: np.ndarray, rng: np.random.Generator, n_start: int) -> dict:
        """Fresh state looking at ``photon_flux``; the first step simulated is ``n_start``."""
        init = initial_pixels(model, photon_flux, rng)
        n = photon_flux.shape[0]
        state = {"flux": photon_flux.astype(float).copy(), "step": np.full(n, n_start - 1, np.int64),
                 "filtered": init.filtered, "memorised": init.memorised, "ready": np.full(n, n_start, np.int64),
                 "theta_on": init.theta_on, "theta_off": init.theta_off, "credit": init.credit,
                 "shot_next": np.zeros(n, np.int64), "shot_count": np.zeros(n, np.int64),
                 "cmp_next": np.zeros(n, np.int64), "event_count": np.zeros(n, np.int64),
                 "key": int(rng.integers(0, 2**63 - 1))}
        pixels = EventDrivenPixels(model, state)
        everyone = np.arange(n)
        pixels._draw_shot(everyone, state["step"])
        pixels._schedule(everyone)
        return state

    # -- the main loop ------------------------------------------------------------------------
    def run(self, n_end: int, change_pixel: np.ndarray, change_step: np.ndarray, change_flux: np.ndarray,
            log: EventLog) -> None:
        """Process every event before step ``n_end`` and the input changes (sorted by pixel, then step)."""
        s = self.s
        changed, first, counts = np.unique(change_pixel, return_index=True, return_counts=True)
        due = np.flatnonzero(np.minimum(s["cmp_next"], s["shot_next"]) < n_end)
        active = np.union1d(due, changed)
        ptr = np.zeros(active.size, np.int64)          # next change of each active pixel ...
        end = np.zeros(active.size, np.int64)          # ... and one past its last
        if changed.size:
            where = np.minimum(np.searchsorted(changed, active), changed.size - 1)
            has = changed[where] == active
            ptr[has] = first[where[has]]
            end[has] = ptr[has] + counts[where[has]]
        drive = self.model.drive(change_flux)            # every new input of this window, at once
        accept = drive.shot_p / self.model.shot_p_max if self.model.shot_p_max > 0 else np.zeros(change_flux.size)
        new_input = (change_flux, drive.y, drive.log_a, drive.parasitic_hz, accept)
        while active.size:
            t_event = np.minimum(s["cmp_next"][active], s["shot_next"][active])
            pending = ptr < end
            t_change = np.full(active.size, NEVER)
            t_change[pending] = change_step[ptr[pending]]
            do_change = t_change <= t_event
            do_event = ~do_change & (t_event < n_end)
            if do_change.any():
                self._changes(active, np.flatnonzero(do_change), ptr, end, change_step, new_input)
            if do_event.any():
                sel = np.flatnonzero(do_event)
                self._event(active[sel], t_event[sel], t_change[sel], log)
            keep = (ptr < end) | (np.minimum(s["cmp_next"][active], s["shot_next"][active]) < n_end)
            active, ptr, end = active[keep], ptr[keep], end[keep]

    def _changes(self, active, sel, ptr, end, change_step, new_input) -> None:
        """Apply the next input changes of ``active[sel]`` up to the first segment where something may happen.

        Looking ahead over all the pixel's remaining input segments at once
        (:meth:`_first_busy_segment`), changes are applied one by one, in order -- so the
        state is the same whatever the windows -- up to the first segment that may hold a
        comparator crossing or holds a shot-noise trial, which is then scheduled exactly.
        """
        s = self.s
        pix = active[sel]
        n_apply = self._first_busy_segment(pix, ptr[sel], end[sel], change_step, new_input) + 1
        todo = np.arange(sel.size)
        depth = 0
        while todo.size:
            p_sel, k = pix[todo], ptr[sel[todo]]
            self._advance(p_sel, change_step[k] - 1)
            s["flux"][p_sel], self.y[p_sel], self.log_a[p_sel], self.para_hz[p_sel], self.accept[p_sel] = (
                v[k] for v in new_input)
            ptr[sel[todo]] += 1
            depth += 1
            todo = todo[n_apply[todo] > depth]
        more = ptr[sel] < end[sel]
        following = np.full(sel.size, NEVER)
        following[more] = change_step[ptr[sel][more]]
        self._schedule(pix, following)

    def _first_busy_segment(self, pix, first, end, change_step, new_input) -> np.ndarray:
        """Index (0 = the segment starting at change ``first``) of the first input segment that may hold an event.

        The low-pass output at each segment start follows from the affine recursion
        ``L' = A L + (1 - A) Y`` (``A = a^length``), evaluated for all segments by a parallel
        prefix scan; the memory drifts linearly. A segment is quiet when
        :func:`.crossing.may_cross` proves, with a margin far above the rounding of this
        look-ahead, that the comparator cannot fire in it, and no shot-noise trial falls
        in it. The last segment of the window counts as busy.
        """
        s, dt = self.s, self.model.dt_s
        n_seg = end - first
        m = int(n_seg.max())
        col = np.arange(m)
        valid = col[None, :] < n_seg[:, None]
        k = np.where(valid, first[:, None] + col[None, :], first[:, None])
        start = change_step[k]                                            # [P, m] first step of each segment
        stop = np.where(col[None, :] + 1 < n_seg[:, None], change_step[np.minimum(k + 1, change_step.size - 1)],
                        NEVER)
        _, y, log_a, para, _ = (v[k] for v in new_input)
        length = np.where(stop < NEVER, stop - start, 0)
        theta_on = s["theta_on"][pix]
        drift = (self._leak_dt + para * dt) * theta_on[:, None]           # per step, per segment
        # state just before the first new segment, from the current one
        step = s["step"][pix]
        lead = start[:, 0] - 1 - step
        y_now = self.y[pix]
        l0 = y_now + (s["filtered"][pix] - y_now) * np.exp(np.where(lead > 0, lead * self.log_a[pix], 0.0))
        m0 = s["memorised"][pix] - (self._leak_dt + self.para_hz[pix] * dt) * theta_on * lead
        # affine prefix scan of x -> A x + B over the segments (Hillis-Steele)
        with np.errstate(invalid="ignore"):
            a = np.exp(np.where(length > 0, length * log_a, 0.0))
        b = y * (1.0 - a)
        shift = 1
        while shift < m:
            a_prev, b_prev = a[:, :-shift].copy(), b[:, :-shift].copy()
            b[:, shift:] = a[:, shift:] * b_prev + b[:, shift:]
            a[:, shift:] = a[:, shift:] * a_prev
            shift *= 2
        l_start = np.empty_like(a)
        l_start[:, 0] = l0
        l_start[:, 1:] = a[:, :-1] * l0[:, None] + b[:, :-1]
        m_start = m0[:, None] - np.concatenate([np.zeros((pix.size, 1)), np.cumsum(drift * length, axis=1)[:, :-1]],
                                               axis=1)
        ref = start - 1
        j0 = np.maximum(s["ready"][pix][:, None] - ref, 1)
        margin = 1e-9
        busy = may_cross(j0.ravel(), (stop - 1 - ref).ravel(), (y - m_start).ravel(), (l_start - y).ravel(),
                         log_a.ravel(), drift.ravel(), np.repeat(theta_on - margin, m),
                         np.repeat(s["theta_off"][pix] - margin, m)).reshape(pix.size, m)
        busy |= (s["shot_next"][pix][:, None] >= start) & (s["shot_next"][pix][:, None] < stop)
        busy |= col[None, :] + 1 >= n_seg[:, None]
        return np.argmax(busy & valid, axis=1)

    # -- pieces -------------------------------------------------------------------------------
    def _advance(self, idx: np.ndarray, t: np.ndarray) -> None:
        """Move the state of pixels ``idx`` from their last step to step ``t`` at constant input (Eqs. 16, 18, 19)."""
        s = self.s
        j = t - s["step"][idx]
        y = self.y[idx]
        with np.errstate(invalid="ignore"):
            decay = np.exp(np.where(j > 0, j * self.log_a[idx], 0.0))
        s["filtered"][idx] = y + (s["filtered"][idx] - y) * decay
        theta = s["theta_on"][idx]
        leak = self._leak_dt * theta * j
        para = self.para_hz[idx] * self.model.dt_s * theta * j
        s["memorised"][idx] -= leak + para
        s["credit"][0, idx] += leak
        s["credit"][1, idx] += para
        s["step"][idx] = t

    def _schedule(self, idx: np.ndarray, next_change: np.ndarray | None = None) -> None:
        """Next comparator event of pixels ``idx`` from their current state (:func:`.crossing.first_crossing`).

        Only crossings before ``next_change`` (the step of the pixel's next input change,
        where it is rescheduled anyway) are looked for.
        """
        s = self.s
        step = s["step"][idx]
        y = self.y[idx]
        theta_on = s["theta_on"][idx]
        drift = (self._leak_dt + self.para_hz[idx] * self.model.dt_s) * theta_on
        j0 = np.maximum(s["ready"][idx] - step, 1)
        horizon = None if next_change is None else np.where(next_change >= NEVER, NEVER, next_change - 1 - step)
        j, _ = first_crossing(j0, y - s["memorised"][idx], s["filtered"][idx] - y, self.log_a[idx], drift,
                              theta_on, s["theta_off"][idx], horizon)
        s["cmp_next"][idx] = np.where(j >= NEVER, NEVER, step + j)

    def _draw_shot(self, idx: np.ndarray, after: np.ndarray) -> None:
        """Step of the next shot-noise candidate of pixels ``idx`` after step ``after`` (geometric law)."""
        s = self.s
        if self._q <= 0:
            s["shot_next"][idx] = NEVER
            return
        u = counter_rng.uniform_open(s["key"], GAP, idx, s["shot_count"][idx])
        gap = np.floor(np.log(u) / self._log_1mq) + 1.0 if np.isfinite(self._log_1mq) else np.ones(idx.size)
        s["shot_next"][idx] = np.minimum(after + np.minimum(gap, float(NEVER)).astype(np.int64), NEVER)

    def _event(self, idx: np.ndarray, t: np.ndarray, next_change: np.ndarray, log: EventLog) -> None:
        """Comparator events and shot-noise arrivals of pixels ``idx`` at steps ``t`` (before ``next_change``)."""
        s = self.s
        p = self.model.params
        k_refr = self.model.refractory_steps
        self._advance(idx, t)
        comparator = s["cmp_next"][idx] == t
        # comparator (Eq. 17)
        sel = np.flatnonzero(comparator)
        if sel.size:
            pix, tt = idx[sel], t[sel]
            delta = s["filtered"][pix] - s["memorised"][pix]
            sign = np.where(delta >= 0, 1, -1).astype(np.int8)
            theta = np.where(sign > 0, s["theta_on"][pix], s["theta_off"][pix])
            total = np.maximum(np.trunc(np.abs(delta) / theta), 1.0)
            log.lose(np.sum(total - 1.0))
            credit = s["credit"][:, pix]
            cause = charge_cause(sign, delta - credit.sum(axis=0), credit)
            noise = cause > 0
            s["credit"][cause[noise] - 1, pix[noise]] -= sign[noise] * theta[noise]
            s["memorised"][pix] += sign * theta
            s["ready"][pix] = tt + k_refr
            log.add(tt, pix, sign, cause)
            if p.threshold_redraw:
                self._redraw(pix, sign)
        # shot noise (Eq. 20): candidates arriving now
        arrived = np.flatnonzero(s["shot_next"][idx] == t)
        if arrived.size:
            pix, tt = idx[arrived], t[arrived]
            bits = counter_rng.hash64(s["key"], ACCEPT, pix, s["shot_count"][pix])
            u = (bits >> np.uint64(11)).astype(np.float64) * 2.0**-53
            accepted = u < self.accept[pix]
            sign = np.where((bits & np.uint64(1)) == 1, 1, -1).astype(np.int8)
            emitted = accepted & (s["ready"][pix] <= tt)
            log.lose(np.count_nonzero(accepted) - np.count_nonzero(emitted))
            e = np.flatnonzero(emitted)
            if e.size:
                pe, te, se = pix[e], tt[e], sign[e]
                theta = np.where(se > 0, s["theta_on"][pe], s["theta_off"][pe])
                s["memorised"][pe] += se * theta
                s["credit"][2, pe] -= se * theta
                s["ready"][pe] = te + k_refr
                log.add(te, pe, se, 3)
                if p.threshold_redraw:
                    self._redraw(pe, se)
            s["shot_count"][pix] += 1
            self._draw_shot(pix, tt)
        self._schedule(idx, next_change)

    def _redraw(self, pix: np.ndarray, sign: np.ndarray) -> None:
        """IEBCS: a new threshold of the polarity that fired, addressed by the pixel's event count."""
        s, p = self.s, self.model.params
        z = counter_rng.normal(s["key"], THRESHOLD, pix, s["event_count"][pix])
        on = sign > 0
        s["theta_on"][pix[on]] = np.maximum(p.threshold_on + p.threshold_sigma * z[on], p.threshold_floor)
        s["theta_off"][pix[~on]] = np.maximum(p.threshold_off + p.threshold_sigma * z[~on], p.threshold_floor)
        s["event_count"][pix] += 1
