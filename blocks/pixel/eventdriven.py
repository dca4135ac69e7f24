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
from .crossing import NEVER, first_crossing
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
        while active.size:
            t_event = np.minimum(s["cmp_next"][active], s["shot_next"][active])
            pending = ptr < end
            t_change = np.full(active.size, NEVER)
            t_change[pending] = change_step[ptr[pending]]
            do_change = t_change <= t_event
            do_event = ~do_change & (t_event < n_end)
            if do_change.any():
                sel = np.flatnonzero(do_change)
                ptr[sel] += 1
                following = np.full(sel.size, NEVER)
                more = ptr[sel] < end[sel]
                following[more] = change_step[ptr[sel][more]]
                self._change(active[sel], t_change[sel], change_flux[ptr[sel] - 1], following)
            if do_event.any():
                sel = np.flatnonzero(do_event)
                self._event(active[sel], t_event[sel], t_change[sel], log)
            keep = (ptr < end) | (np.minimum(s["cmp_next"][active], s["shot_next"][active]) < n_end)
            active, ptr, end = active[keep], ptr[keep], end[keep]

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

    def _change(self, idx: np.ndarray, t: np.ndarray, flux: np.ndarray, next_change: np.ndarray) -> None:
        """A new input holds from step ``t`` on (until ``next_change``)."""
        self._advance(idx, t - 1)
        self.s["flux"][idx] = flux
        drive = self.model.drive(flux)
        self.y[idx], self.log_a[idx], self.para_hz[idx] = drive.y, drive.log_a, drive.parasitic_hz
        if self.model.shot_p_max > 0:
            self.accept[idx] = drive.shot_p / self.model.shot_p_max
        self._schedule(idx, next_change)

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
