"""The change-detection comparator (paper Eq. 17) and the ground truth of why it fired.

Eq. 17: with ``dI = L - M`` (filtered log current minus memorised value),

    theta = theta_ON if dI >= 0 else theta_OFF
    Ne_total = dI / theta rounded towards zero
    Ne = sign(Ne_total) (one event per pixel per step), N_loss = Ne_total - Ne
    M <- M + Ne theta

so a change of ``k`` thresholds is emitted one event per step (or per refractory
period), the remainder staying in ``dI`` until the next comparison.

Lost events. The paper records ``N_loss = Ne_total - Ne`` "to capture the potential data
loss" (Sec. 2.3). Summed at every comparison that counts the same event again at each
comparison it waits through: a step of 5 thresholds reports 4 + 3 + 2 + 1 = 10 although all
5 are emitted. evsda counts what the paper's wording means, events a pixel could not emit:
after an event the pixel owes ``N_loss`` events; at its next comparison (the first step
after its refractory period) it could now emit ``Ne_total'``, and the owed events that
``Ne_total'`` no longer holds (the input went back, or moved less) are lost:
``lost = |N_loss| - clip(sign(N_loss) Ne_total', 0, |N_loss|)``. A 5-threshold step loses
nothing; a pulse of 5 thresholds that ends after 2 events loses 3. Shot-noise events that
arrive while a pixel is blind are lost too (:mod:`.reference`).

Thresholds are per pixel and drawn from a Gaussian (paper: 0.2 +- 0.03, after v2e),
frozen for the run; ``redraw`` draws a new threshold of the polarity that fired after
every event, as IEBCS does (Joubert et al. 2021, Front. Neurosci. 15:702765). A floor keeps
the extreme tail positive (v2e clamps at 0.01).

Cause attribution (simulation ground truth, not in the paper): ``dI`` is split into the
contributions that built it since the last events -- signal (changes of ``L``), junction
leak and parasitic leak. A comparator event is charged to the contribution pushing hardest
in its direction, which then gives up one threshold. Over a long run each cause is charged
its share of events: a static pixel gets ``R_leak : R_para`` leak to parasitic events.
Shot-noise events do not pass through the comparator (:mod:`.noise`) and are SHOT.

Rounding: an input that moves by exactly ``k`` thresholds (a contrast step, the leak's
drift of exactly ``theta`` per period) must give ``k`` events whether ``L - M`` lands on the
threshold or one ulp short of it, an accident of floating point (v2e rounds its lin-log
values to 1e-8 for the same reason). A change within ``TOLERANCE`` of a threshold
therefore counts as reaching it, in both implementations.
"""

from __future__ import annotations

import numpy as np

TOLERANCE = 1e-9        # a change this close to a threshold reaches it (ln of current) [1]
#: margin for rounding in the bounds that show a pixel cannot fire (:mod:`.deferred`); values are O(10), their
#: rounding ~1e-14 [ln of current]
ROUNDING_MARGIN = 1e-9


def draw_thresholds(rng: np.random.Generator, size, mean: float, sigma: float, floor: float):
    """Per-pixel thresholds from ``N(mean, sigma)``, floored at ``floor`` [log units]."""
    drawn = rng.normal(mean, sigma, size) if sigma > 0 else np.full(size, float(mean))
    return np.maximum(drawn, floor, out=drawn)


def events_possible(delta, theta_on, theta_off):
    """Paper Eq. 17: ``Ne_total``, the signed number of thresholds in ``delta`` (rounded towards 0)."""
    theta = np.where(delta >= 0, theta_on, theta_off)
    return np.sign(delta) * np.trunc((np.abs(delta) + TOLERANCE) / theta)


def reach(theta):
    """The comparator input at which a threshold ``theta`` fires (``theta`` less the rounding tolerance)."""
    return theta - TOLERANCE


def lost_owed(owed, total):
    """Events lost at a pixel's first comparison after an event: ``|owed|`` less what ``Ne_total`` still holds.

    ``owed`` is the signed ``N_loss`` of the last event, ``total`` the signed ``Ne_total``
    now; only events of the owed polarity count as kept.
    """
    owed = np.asarray(owed, dtype=np.int64)
    total = np.asarray(total)
    kept = np.clip(np.sign(owed) * total, 0, np.abs(owed))
    return np.abs(owed) - kept.astype(np.int64)


def charge_cause(polarity, signal, credits):
    """Index (0 = SIGNAL, 1 = LEAK, 2 = PARASITIC) of the contribution charged with a comparator event.

    ``signal`` is the signal contribution ``[n]`` and ``credits`` the noise
    contributions ``[2, n]`` (leak, parasitic), all in log units.
    """
    stacked = np.vstack([signal[None, :], credits]) * polarity[None, :]
    return np.argmax(stacked, axis=0)
