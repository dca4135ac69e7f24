"""The telescope: an annular aperture, its diffraction-limited PSF and OTF.

Angles are in radians on the sky; the focal plane maps an angle ``theta`` to
``f theta`` [m] for a focal length ``f``. PSFs are normalised to unit total power:
``integral PSF dOmega = 1`` [sr^-1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import j0, j1


@dataclass(frozen=True)
class Telescope:
    """Circular aperture of ``diameter_m`` with a central obscuration of ``obscuration`` x diameter."""

    diameter_m: float
    obscuration: float = 0.0          # linear ratio of the central obscuration's diameter [1]
    throughput: float = 1.0           # optical transmission [1]

    @property
    def collecting_area_m2(self) -> float:
        """``pi D^2 (1 - eps^2) / 4`` [m^2]."""
        return np.pi / 4 * self.diameter_m**2 * (1 - self.obscuration**2)

    def pupil(self, n: int, delta: float, supersample: int = 8) -> np.ndarray:
        """Transmission [1] on an ``n x n`` grid spaced ``delta`` [m] centred at ``n // 2``.

        Edge cells get their open fraction (``supersample^2`` points per cell), so the
        sampled area matches the analytic one to ~1e-4 even on coarse grids.
        """
        s = (np.arange(supersample) + 0.5) / supersample - 0.5
        x = ((np.arange(n) - n // 2)[:, None] + s[None, :]).ravel() * delta
        r2 = x[:, None] ** 2 + x[None, :] ** 2
        outer, inner = (self.diameter_m / 2) ** 2, (self.obscuration * self.diameter_m / 2) ** 2
        open_ = ((r2 <= outer) & (r2 >= inner)).astype(float)
        return open_.reshape(n, supersample, n, supersample).mean(axis=(1, 3))

    def airy(self, theta: np.ndarray, wavelength: float) -> np.ndarray:
        """Diffraction-limited PSF [sr^-1] of the annular aperture (Born & Wolf 1999 Sec. 8.5.2;
        Mahajan 1986, JOSA A 3, 470, Eq. 1): ``(A/lambda^2) [(2J1(v)/v - eps^2 2J1(eps v)/(eps v)) / (1 - eps^2)]^2``,
        ``v = pi D theta / lambda``.
        """
        eps = self.obscuration
        v = np.pi * self.diameter_m * np.asarray(theta, dtype=float) / wavelength
        amplitude = (_jinc(v) - eps**2 * _jinc(eps * v)) / (1 - eps**2)
        return self.collecting_area_m2 / wavelength**2 * amplitude**2

    def otf(self, f_angular: np.ndarray, wavelength: float) -> np.ndarray:
        """Diffraction-limited OTF [1] at angular frequency ``f`` [cycles rad^-1] (O'Neill 1956,
        J. Opt. Soc. Am. 46, 285; Mahajan 1998, *Optical Imaging and Aberrations* I, Eq. 2-123)."""
        return annular_otf(np.asarray(f_angular, dtype=float) * wavelength / self.diameter_m, self.obscuration)


def _jinc(v: np.ndarray) -> np.ndarray:
    """``2 J1(v) / v`` with its limit 1 at 0."""
    v = np.asarray(v, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.abs(v) < 1e-8, 1.0 - v**2 / 8, 2 * j1(v) / v)


def airy_encircled_energy(theta: np.ndarray, diameter: float, wavelength: float) -> np.ndarray:
    """Fraction of power within radius ``theta`` [rad] of an unobstructed Airy pattern [1]:
    ``1 - J0(v)^2 - J1(v)^2`` (Lord Rayleigh; Born & Wolf 1999 Eq. 8.5.36)."""
    v = np.pi * diameter * np.asarray(theta, dtype=float) / wavelength
    return 1.0 - j0(v) ** 2 - j1(v) ** 2


def annular_otf(nu: np.ndarray, eps: float) -> np.ndarray:
    """OTF of an annulus vs frequency ``nu`` normalised to the cutoff ``D / lambda`` [1] (O'Neill 1956)."""
    nu = np.abs(np.asarray(nu, dtype=float))

    def disk(x):
        x = np.clip(x, 0.0, 1.0)
        return 2 / np.pi * (np.arccos(x) - x * np.sqrt(1 - x * x))

    a = np.where(nu <= 1, disk(nu), 0.0)
    if eps == 0:
        return a
    b = np.where(nu <= eps, eps**2 * disk(nu / eps), 0.0)
    low, high = (1 - eps) / 2, (1 + eps) / 2
    cos_phi = np.clip((1 + eps**2 - 4 * nu**2) / (2 * eps), -1.0, 1.0)
    phi = np.arccos(cos_phi)
    overlap = (-2 * eps**2 + 2 * eps / np.pi * np.sin(phi) + (1 + eps**2) / np.pi * phi
               - 2 * (1 - eps**2) / np.pi * np.arctan((1 + eps) / (1 - eps) * np.tan(phi / 2)))
    c = np.where(nu <= low, -2 * eps**2, np.where(nu <= high, overlap, 0.0))
    return (a + b + c) / (1 - eps**2)
