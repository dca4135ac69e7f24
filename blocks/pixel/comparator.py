"""The change-detection comparator (paper Eq. 17) and the ground truth of why it fired.

Eq. 17: with ``dI = L - M`` (filtered log current minus memorised value),

    theta = theta_ON if dI >= 0 else theta_OFF
    Ne_total = dI / theta rounded towards zero
    Ne = sign(Ne_total) (one event per pixel per step), N_loss = Ne_total - Ne
    M <- M + Ne theta

so a change of ``k`` thresholds is emitted one event per step (or per refractory
period), the remainder staying in ``dI`` until the next comparison; ``|N_loss|`` is the
backlog of possible-but-not-emitted events at that comparison (the paper's
"potential data loss").

Thresholds are per pixel and drawn from a Gaussian (paper: 0.2 +- 0.03, after v2e),
frozen for the run; ``redraw`` draws a new threshold of the polarity that fired after
every event, as IEBCS does (Joubert et al. 2021, Front. Neurosci. 15:702765). A floor keeps
the extreme tail positive (v2e clamps at 0.01).

Cause attribution (simulation ground truth, not in the paper): ``dI`` is split into the
contributions that built it since the last events -- signal (changes of ``L``), junction
leak, parasitic leak and shot noise (the threshold-sized shifts of ``M`` that shot events
make, which the comparator later undoes with an opposite "rebound" event). An event is
charged to the contribution pushing hardest in its direction, which then gives up one
threshold. Over a long run each cause is charged its share of events: a static pixel
gets ``R_leak : R_para`` leak to parasitic events, and rebounds go to SHOT.

Rounding: a shot-noise event moves ``M`` by exactly one threshold, and the comparator
must undo it at ``|dI| = theta``; whether ``L - M`` then lands on the threshold or one ulp
short of it is an accident of floating point (v2e rounds its lin-log values to 1e-8 for
the same reason). A change within ``TOLERANCE`` of a threshold therefore counts as
reaching it, in both implementations.
"""

from __future__ import annotations

import numpy as np

TOLERANCE = 1e-9        # a change this close to a threshold reaches it (ln of current) [1]


def draw_thresholds(rng: np.random.Generator, size, mean: float, sigma: float, floor: float):
    """Per-pixel thresholds from ``N(mean, sigma)``, floored at ``floor`` [log units]."""
    return np.maximum(rng.normal(mean, sigma, size) if sigma > 0 else np.full(size, float(mean)), floor)


def events_possible(delta, theta_on, theta_off):
    """Paper Eq. 17: ``Ne_total``, the signed number of thresholds in ``delta`` (rounded towards 0)."""
    theta = np.where(delta >= 0, theta_on, theta_off)
    return np.sign(delta) * np.trunc((np.abs(delta) + TOLERANCE) / theta)


def reach(theta):
    """The comparator input at which a threshold ``theta`` fires (``theta`` less the rounding tolerance)."""
    return theta - TOLERANCE


def charge_cause(polarity, signal, credits):
    """Index (0 = SIGNAL, 1 = LEAK, 2 = PARASITIC, 3 = SHOT) of the contribution charged with an event.

    ``signal`` is the signal contribution ``[n]`` and ``credits`` the noise
    contributions ``[3, n]`` (leak, parasitic, shot), all in log units.
    """
    stacked = np.vstack([signal[None, :], credits]) * polarity[None, :]
    return np.argmax(stacked, axis=0)
