"""Visibility conditions: Earth's shadow, the observer's Sun elevation, the horizon, Earth occultation."""

from __future__ import annotations

import numpy as np

EARTH_RADIUS_M = 6_378_136.6        # equatorial radius, the sphere Skyfield's is_sunlit() uses [m]
SUN_RADIUS_M = 6.957e8              # IAU 2015 Resolution B3 nominal solar radius [m]


def lit_fraction(r_sat: np.ndarray, r_sun: np.ndarray) -> np.ndarray:
    """Fraction of the solar disc visible from ``r_sat`` past a spherical Earth (conical shadow).

    Montenbruck & Gill (2000), *Satellite Orbits*, Sec. 3.4.2, Eqs. (3.85)-(3.87): with
    the apparent radii ``a`` of the Sun and ``b`` of the Earth and the separation ``c``
    of their centres seen from the satellite, the occulted area of the solar disc is
    the lens-shaped overlap of two discs. 1 in sunlight, 0 in the umbra, in between in
    the penumbra. Geocentric GCRS positions in metres, ``[n, 3]``.
    """
    to_sun = r_sun - r_sat
    d_sun = np.linalg.norm(to_sun, axis=-1)
    d_earth = np.linalg.norm(r_sat, axis=-1)
    a = np.arcsin(SUN_RADIUS_M / d_sun)
    b = np.arcsin(np.clip(EARTH_RADIUS_M / d_earth, -1.0, 1.0))
    c = np.arccos(np.clip(-np.sum(r_sat * to_sun, axis=-1) / (d_earth * d_sun), -1.0, 1.0))
    fraction = np.ones_like(c)
    fraction[c < b - a] = 0.0
    partial = (c < a + b) & (c >= np.abs(b - a))
    if np.any(partial):
        ap, bp, cp = a[partial], b[partial], c[partial]
        x = (cp**2 + ap**2 - bp**2) / (2 * cp)
        y = np.sqrt(np.maximum(ap**2 - x**2, 0.0))
        overlap = ap**2 * np.arccos(np.clip(x / ap, -1, 1)) + bp**2 * np.arccos(np.clip((cp - x) / bp, -1, 1)) - cp * y
        fraction[partial] = 1.0 - overlap / (np.pi * ap**2)
    return np.clip(fraction, 0.0, 1.0)


def sun_centre_visible(r_sat: np.ndarray, r_sun: np.ndarray) -> np.ndarray:
    """Whether the line from ``r_sat`` to the Sun's centre misses the Earth's sphere.

    The same test as Skyfield's ``is_sunlit()``: the middle of the penumbra.
    """
    return ~segment_hits_sphere(r_sat, r_sun, EARTH_RADIUS_M)


def segment_hits_sphere(p0: np.ndarray, p1: np.ndarray, radius_m: float) -> np.ndarray:
    """Whether the segment ``p0 -> p1`` passes within ``radius_m`` of the origin."""
    d = p1 - p0
    t = np.clip(-np.sum(p0 * d, axis=-1) / np.sum(d * d, axis=-1), 0.0, 1.0)
    closest = p0 + t[..., None] * d
    return np.linalg.norm(closest, axis=-1) < radius_m


def elevation(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Elevation [rad] of ``direction`` above the plane normal to ``up`` (both ``[n, 3]``)."""
    d = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    return np.arcsin(np.clip(np.sum(d * up, axis=-1), -1.0, 1.0))
