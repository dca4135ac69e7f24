"""Twilight: sunlight scattered by the upper atmosphere after sunset and before sunrise.

Patat, Ugolnikov & Postylyakov (2006, A&A 455, 385), Table 1: the zenith V-band sky at
ESO-Paranal (2635 m) measured on FORS1 images, fitted for Sun zenith distances
95-105 deg (Sun depression 5-15 deg) by

    mu_V = 11.84 + 1.518 x - 0.057 x**2  [mag/arcsec^2],  x = zeta - 95 deg.

The fit is the *total* sky, twilight plus the night sky, which at Paranal is
V = 21.6 mag/arcsec^2 at the zenith (Patat 2003, A&A 400, 1183). The twilight term is
the difference of the two in flux; it reaches zero at a depression of 15.85 deg (the
fit meets the night sky; the paper notes the night level is reached near
zeta = 105-106 deg) and stays zero below. Above 5 deg of depression the fit does not
apply (it is not extrapolated).

The measurement is near the zenith and at a high, dry site: Patat et al. find the
twilight of a low-altitude site (Crimea) about 30 % brighter in V, and the twilight
sky is brighter towards the Sun's azimuth and the horizon. evsda applies the zenith
value to the whole field.
"""

from __future__ import annotations

import numpy as np

PATAT_V_COEFFICIENTS = (11.84, 1.518, -0.057)     # Patat et al. (2006) Table 1, V [mag/arcsec^2, /deg, /deg^2]
PATAT_REFERENCE_ZENITH_DISTANCE_DEG = 95.0        # x = zeta - 95 deg [deg]
PARANAL_NIGHT_SKY_V = 21.6                        # zenith V night sky at Paranal (Patat 2003) [mag/arcsec^2]
MIN_SUN_DEPRESSION_DEG = 5.0                      # the fit's lower limit (Sun zenith distance 95 deg) [deg]


def total_zenith_sky_v(sun_depression_deg) -> np.ndarray:
    """Patat et al. (2006) fit of the total zenith V sky [mag/arcsec^2] at a Sun depression [deg]."""
    a0, a1, a2 = PATAT_V_COEFFICIENTS
    x = 90.0 + np.asarray(sun_depression_deg, dtype=np.float64) - PATAT_REFERENCE_ZENITH_DISTANCE_DEG
    return a0 + a1 * x + a2 * x * x


def _last_depression_deg() -> float:
    """Depression at which the fit meets the night sky (its first root past 5 deg) [deg]."""
    a0, a1, a2 = PATAT_V_COEFFICIENTS
    x = (-a1 + np.sqrt(a1 * a1 - 4 * a2 * (a0 - PARANAL_NIGHT_SKY_V))) / (2 * a2)
    return float(x + PATAT_REFERENCE_ZENITH_DISTANCE_DEG - 90.0)


#: Sun depression beyond which the twilight adds nothing in V (15.85 deg) [deg]
END_OF_TWILIGHT_DEPRESSION_DEG = _last_depression_deg()


def twilight_flux_relative(sun_depression_deg) -> np.ndarray:
    """Twilight at the zenith as a V flux per arcsec^2 relative to a 0 mag/arcsec^2 sky, ``10**(-0.4 mu)`` [1].

    Zero past the end of twilight; NaN where the Sun is less than 5 deg below the
    horizon (outside the measurement).
    """
    depression = np.asarray(sun_depression_deg, dtype=np.float64)
    excess = 10.0 ** (-0.4 * total_zenith_sky_v(depression)) - 10.0 ** (-0.4 * PARANAL_NIGHT_SKY_V)
    excess = np.where(depression < END_OF_TWILIGHT_DEPRESSION_DEG, np.maximum(excess, 0.0), 0.0)
    return np.where(depression >= MIN_SUN_DEPRESSION_DEG, excess, np.nan)


def twilight_surface_brightness(sun_depression_deg) -> np.ndarray:
    """Twilight alone at the zenith [V mag/arcsec^2]: inf past the end of twilight, NaN above 5 deg of depression."""
    with np.errstate(divide="ignore"):
        return -2.5 * np.log10(twilight_flux_relative(sun_depression_deg))
