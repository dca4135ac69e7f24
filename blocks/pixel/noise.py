"""Noise sources of the comparator: junction leak, parasitic photocurrent, shot noise (paper Eq. 18-20).

* Junction leak (Eq. 18): the memorised log current drifts down by ``R_leak theta_ON``
  per second, so a static pixel emits ON "leak" events at ``R_leak``. The paper prints
  ``delta = dt R_leak / theta_ON``; that has units of 1/threshold and would make the
  event rate ``R_leak / theta_ON^2``. The drift that gives the stated rate is
  ``dt R_leak theta_ON`` (v2e's ``subtract_leak_current``), used here. The leak does not
  depend on temperature in the paper's model (Sec. 2.4, after Nozaki & Delbruck 2017).
* Parasitic photocurrent (Eq. 19): a second leak whose rate is proportional to the pixel
  illuminance ``M_v = Phi eta_v / A`` (luminous efficacy ``eta_v``, 680 lm/W in the paper), up
  to one event per refractory period (with the junction leak).
* Shot noise (Eq. 20): at every step each pixel fires an OFF event with probability
  ``p = r dt`` (``u < p``) and an ON event with the same probability (``u > 1 - p``), with
  ``r = ((F - 1) I/I_max + 1) R_n``: ``R_n`` in the dark, ``F R_n`` at ``I = I_max``. ``I`` is the
  lin-log value of the total current and ``I/I_max`` is clipped to [0, 1] so the rate stays
  within ``[F R_n, R_n]`` (above ``I_max`` the printed formula would go negative). The total
  shot-noise rate is ``2 r``; v2e's ``shot_noise_rate_hz`` is that total (it uses ``R_n/2``
  per polarity).

  A shot-noise event leaves the memorised value where it is. The paper lets it reset ``M``
  "just as a legitimate event"; the comparator then answers one refractory period later with
  an opposite "rebound" event whenever the pixel's other contributions do not absorb the
  shift, so the sensor showed 1.5-2x the configured rate and a non-stationary first second
  (issue 11.2). ``R_n`` is set from a measured background-activity rate, which counts every
  event a still pixel emits; emitting each shot event once, without the rebound, is what
  makes the simulated rate the configured one: ON ``R_leak + R_para + r``, OFF ``r`` per pixel
  (less the trials that fall in a refractory period, ``~2 r T_refr``).
"""

from __future__ import annotations

import numpy as np


def leak_drift_per_s(rate_hz, theta_on):
    """Paper Eq. 18: downward drift of the memorised log current [s^-1 in log units]."""
    return np.asarray(rate_hz, dtype=float) * theta_on


def illuminance_lux(power_W, pixel_area_m2: float, luminous_efficacy_lm_per_W: float = 680.0):
    """Paper Eq. 19: pixel illuminance ``M_v = Phi eta_v / A`` [lx]."""
    return np.asarray(power_W, dtype=float) * luminous_efficacy_lm_per_W / pixel_area_m2


def parasitic_rate_hz(illuminance, rate_per_lux_hz: float, max_hz: float = np.inf):
    """Paper Eq. 19: leak-event rate of the parasitic photocurrent, ``R_para = M_v f_para``, at most ``max_hz`` [Hz].

    Eq. 19 grows without bound with the illuminance. A pixel emits at most one event per
    refractory period, so a faster drift would only pile up thresholds in ``L - M`` that no
    event can pay off (a memory running away from the input); the rate is capped where the
    drift equals one threshold per refractory period (:attr:`.model.PixelModel.parasitic_max_hz`).
    """
    return np.minimum(np.asarray(illuminance, dtype=float) * rate_per_lux_hz, max_hz)


def shot_noise_rate_hz(y, rate_hz: float, intensity_factor: float, y_max: float, y_floor: float = 0.0):
    """Paper Eq. 20: shot-noise event rate of EACH polarity at lin-log level ``y`` [Hz].

    ``I/I_max`` of the paper is ``(y - y_floor) / (y_max - y_floor)``, clipped to [0, 1]:
    ``y_floor`` = 0 is the paper's zero current; a photoreceptor logarithmic down to its dark
    current starts the scale at the dark pixel's level (:meth:`.model.PixelModel.shot_noise_floor`).
    A floor at or above ``y_max`` gives every pixel ``F R_n``.
    """
    span = y_max - y_floor
    if span <= 0:
        return np.full(np.shape(y), intensity_factor * rate_hz)
    level = np.clip((np.asarray(y, dtype=float) - y_floor) / span, 0.0, 1.0)
    return ((intensity_factor - 1.0) * level + 1.0) * rate_hz
