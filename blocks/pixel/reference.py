"""The reference implementation: every pixel, every time step, in the order the paper writes it.

One step ``n`` (time ``n dt``) of every pixel:

1. photoreceptor: ``L <- (1 - eps) L + eps Y`` (Eqs. 12-16, for the input held at ``n dt``), or in
   the large-signal form the same step on ``e^-L`` (:func:`.lowpass.large_signal_step`);
2. junction leak and parasitic photocurrent lower the memory ``M`` (Eqs. 18-19);
3. comparator (Eq. 17), for pixels not in their refractory period: at most one event,
   the rest of ``Ne_total`` owed; at a pixel's first comparison after an event, the owed
   events its new ``Ne_total`` no longer holds are counted as lost (:mod:`.comparator`);
4. shot noise (Eq. 20): a uniform number ``u`` per pixel; ``u < p`` is an OFF event,
   ``u > 1 - p`` an ON event; it leaves ``M`` where it is (:mod:`.noise`). A pixel that is
   refractory or has just fired cannot emit it: it is counted as lost;
5. refractory (Eq. 21): a pixel that fired at ``n`` may fire again at ``n + k``.

It costs a few dozen array operations per step for the whole array, so it is meant for
small sensors and short runs: it is the yardstick the event-driven implementation is
checked against.
"""

from __future__ import annotations

import numpy as np

from . import lowpass
from .comparator import charge_cause, events_possible, lost_owed
from .eventlog import EventLog
from .initial import initial_pixels
from .model import PixelModel

STATE_KEYS = ("flux", "filtered", "memorised", "ready", "theta_on", "theta_off", "credit", "owed", "noise_scale")


def new_state(model: PixelModel, photon_flux: np.ndarray, rng: np.random.Generator) -> dict:
    """State of a freshly started pixel array looking at ``photon_flux`` [photon s^-1 per pixel]."""
    init = initial_pixels(model, photon_flux, rng)
    return {"flux": photon_flux.astype(float).copy(), "filtered": init.filtered, "memorised": init.memorised,
            "ready": np.zeros(photon_flux.shape[0], np.int64), "theta_on": init.theta_on,
            "theta_off": init.theta_off, "credit": init.credit, "owed": np.zeros(photon_flux.shape[0], np.int64),
            "noise_scale": init.noise_scale}


def run(model: PixelModel, state: dict, n_start: int, n_end: int, change_steps: np.ndarray, frames: np.ndarray,
        rng: np.random.Generator, log: EventLog) -> None:
    """Advance ``state`` through steps ``[n_start, n_end)``; input ``frames[k]`` holds from ``change_steps[k]``."""
    p = model.params
    dt, k_refr = model.dt_s, model.refractory_steps
    flux, L, M = state["flux"], state["filtered"], state["memorised"]
    ready, th_on, th_off, credit = state["ready"], state["theta_on"], state["theta_off"], state["credit"]
    owed, scale = state["owed"], state["noise_scale"]
    drive = model.drive(flux)
    large = p.lowpass_form == "large_signal"
    next_change = 0
    for n in range(n_start, n_end):
        while next_change < len(change_steps) and change_steps[next_change] <= n:
            flux[:] = frames[next_change]
            drive = model.drive(flux)
            next_change += 1
        # 1. photoreceptor low-pass (Eq. 16)
        if large:
            L[:] = lowpass.large_signal_step(L, drive.y, drive.eps)
        else:
            L[:] = (1.0 - drive.eps) * L + drive.eps * drive.y
        # 2. junction leak (Eq. 18) and parasitic photocurrent (Eq. 19)
        leak = dt * p.leak_rate_hz * scale * th_on
        para = dt * drive.parasitic_hz * th_on
        M -= leak + para
        credit[0] += leak
        credit[1] += para
        # 3. comparator (Eq. 17), outside the refractory period (Eq. 21)
        awake = ready <= n
        delta = L - M
        total = events_possible(delta, th_on, th_off)
        fired = awake & (total != 0)
        settle = np.flatnonzero((ready == n) & (owed != 0))      # first comparison after an event
        if settle.size:
            log.lose(np.sum(lost_owed(owed[settle], total[settle])))
            owed[settle] = 0
        idx = np.flatnonzero(fired)
        if idx.size:
            sign = np.sign(total[idx]).astype(np.int8)
            owed[idx] = (total[idx] - sign).astype(np.int64)
            theta = np.where(sign > 0, th_on[idx], th_off[idx])
            cause = charge_cause(sign, delta[idx] - credit[:, idx].sum(axis=0), credit[:, idx])
            noise = cause > 0
            credit[cause[noise] - 1, idx[noise]] -= sign[noise] * theta[noise]
            M[idx] += sign * theta
            ready[idx] = n + k_refr
            log.add(n, idx, sign, cause)
            if p.threshold_redraw:
                _redraw(p, rng, idx, sign, th_on, th_off)
        # 4. shot noise (Eq. 20)
        u = rng.random(L.shape[0])
        shot_p = drive.shot_p * scale
        shot_on, shot_off = u > 1.0 - shot_p, u < shot_p
        candidate = shot_on | shot_off
        emitted = candidate & awake & ~fired
        log.lose(np.count_nonzero(candidate) - np.count_nonzero(emitted))
        idx = np.flatnonzero(emitted)
        if idx.size:
            sign = np.where(shot_on[idx], 1, -1).astype(np.int8)
            ready[idx] = n + k_refr
            log.add(n, idx, sign, 3)
            if p.threshold_redraw:
                _redraw(p, rng, idx, sign, th_on, th_off)


def _redraw(p, rng, idx, sign, th_on, th_off) -> None:
    """IEBCS: a new threshold of the polarity that fired."""
    new = rng.normal(0.0, 1.0, idx.size) * p.threshold_sigma
    on = sign > 0
    th_on[idx[on]] = np.maximum(p.threshold_on + new[on], p.threshold_floor)
    th_off[idx[~on]] = np.maximum(p.threshold_off + new[~on], p.threshold_floor)
