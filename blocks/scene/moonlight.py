"""Moonlight scattered by the atmosphere: Krisciunas & Schaefer (1991, PASP 103, 1033).

V-band surface brightness of the sky at zenith angle ``Z``, a separation ``rho`` from a
Moon at zenith angle ``Z_m`` and phase angle ``alpha``, for extinction ``k`` [mag/airmass]:

* Eq. 8: the Moon's illuminance outside the atmosphere [foot-candles]
  ``I* = 10**(-0.4 (3.84 + 0.026 |alpha| + 4e-9 alpha**4))`` (alpha in degrees), at the
  mean Earth-Moon distance; evsda scales it by ``(d_mean / d)**2`` with the ephemeris
  distance (perigee to apogee is a +-12 % change in illuminance);
* Eq. 3: the scattering path ``X(Z) = (1 - 0.96 sin^2 Z)**-0.5``;
* the scattering function ``f(rho) = 10**5.36 (1.06 + cos^2 rho)`` (Rayleigh) plus
  ``10**(6.15 - rho/40)`` (Mie, Eq. 21) for rho >= 10 deg or ``6.2e7 rho**-2`` (the
  aureole, Eq. 19) below;
* Eq. 15: ``B_moon = f(rho) I* 10**(-0.4 k X(Z_m)) (1 - 10**(-0.4 k X(Z)))`` [nanoLamberts];
* Eq. 1 (Garstang 1986): ``B [nL] = 34.08 exp(20.7233 - 0.92104 V)`` with V in
  mag/arcsec^2; since 0.92104 = 0.4 ln 10 it is a linear flux scale, so sky components
  add in nanoLamberts.

The authors quote 8-23 % agreement with their Mauna Kea data. Eq. 8 has no opposition
surge, so within a few degrees of full Moon it underestimates the Moon (and its light).
"""

from __future__ import annotations

import numpy as np

def nanolamberts_of_magnitude(mag_arcsec2) -> np.ndarray:
    """K&S Eq. 1: sky surface brightness in nanoLamberts of a V brightness [mag/arcsec^2]."""
    return 34.08 * np.exp(20.7233 - 0.92104 * np.asarray(mag_arcsec2, dtype=np.float64))


def magnitude_of_nanolamberts(nanolamberts) -> np.ndarray:
    """Inverse of K&S Eq. 1: V surface brightness [mag/arcsec^2] of ``B`` nanoLamberts (inf for 0)."""
    with np.errstate(divide="ignore"):
        return (20.7233 - np.log(np.asarray(nanolamberts, dtype=np.float64) / 34.08)) / 0.92104


def scattering_airmass(zenith_angle_rad) -> np.ndarray:
    """K&S Eq. 3: optical path through a scattering atmosphere, ``(1 - 0.96 sin^2 Z)**-0.5`` [1]."""
    return 1.0 / np.sqrt(1.0 - 0.96 * np.sin(np.asarray(zenith_angle_rad, dtype=np.float64)) ** 2)


def moon_magnitude(phase_angle_deg) -> np.ndarray:
    """K&S Eq. 9: the Moon's V magnitude at mean distance, ``-12.73 + 0.026 |alpha| + 4e-9 alpha^4`` [mag]."""
    alpha = np.abs(np.asarray(phase_angle_deg, dtype=np.float64))
    return -12.73 + 0.026 * alpha + 4e-9 * alpha**4


def moon_illuminance_fc(phase_angle_deg) -> np.ndarray:
    """K&S Eq. 8: the Moon's illuminance outside the atmosphere at mean distance [foot-candles]."""
    return 10.0 ** (-0.4 * (moon_magnitude(phase_angle_deg) + 16.57))


def scattering_function(separation_deg) -> np.ndarray:
    """K&S scattering function f(rho) [nL per foot-candle]: Rayleigh plus Mie (Eq. 21) or the aureole (Eq. 19)."""
    rho = np.asarray(separation_deg, dtype=np.float64)
    rayleigh = 10.0**5.36 * (1.06 + np.cos(np.radians(rho)) ** 2)
    with np.errstate(divide="ignore"):
        mie = np.where(rho >= 10.0, 10.0 ** (6.15 - rho / 40.0), 6.2e7 / rho**2)
    return rayleigh + mie


def moonlight_nanolamberts(phase_angle_deg, separation_deg, moon_zenith_angle_rad, zenith_angle_rad,
                           extinction_mag_per_airmass: float, distance_ratio=1.0) -> np.ndarray:
    """K&S Eq. 15: scattered moonlight [nL]; 0 while the Moon is below the horizon.

    ``distance_ratio`` is the Earth-Moon distance over its mean (illuminance ``~ 1/d^2``).
    """
    k = extinction_mag_per_airmass
    moon_z = np.asarray(moon_zenith_angle_rad, dtype=np.float64)
    illuminance = moon_illuminance_fc(phase_angle_deg) / np.asarray(distance_ratio, dtype=np.float64) ** 2
    brightness = (scattering_function(separation_deg) * illuminance
                  * 10.0 ** (-0.4 * k * scattering_airmass(np.minimum(moon_z, np.pi / 2)))
                  * (1.0 - 10.0 ** (-0.4 * k * scattering_airmass(zenith_angle_rad))))
    return np.where(moon_z < np.pi / 2, brightness, 0.0)
