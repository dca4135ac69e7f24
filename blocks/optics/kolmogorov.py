"""Second-order statistics of Kolmogorov / von Karman turbulent phase.

Conventions: spatial frequency ``f`` in cycles per metre, separations ``r`` in metres,
Fried parameter ``r0`` [m], outer scale ``L0`` [m] (``inf`` = Kolmogorov).

* Phase power spectral density (Schmidt 2010, *Numerical Simulation of Optical Wave
  Propagation*, Eq. 9.52 with no inner scale):
  ``PSD(f) = 0.0229 r0^(-5/3) (f^2 + 1/L0^2)^(-11/6)`` [rad^2 m^2].
* Phase structure function, Kolmogorov (Fried 1965): ``D(r) = 6.88 (r/r0)^(5/3)`` [rad^2].
* Von Karman phase covariance (the Hankel transform of the PSD, Gradshteyn & Ryzhik
  6.565.4; same form as Assemat et al. 2006, Opt. Express 14, 988, Eq. 5):
  ``B(r) = 2 pi c 2^(-5/6) / Gamma(11/6) (L0/r0)^(5/3) u^(5/6) K_5/6(u)`` with ``u = 2 pi r / L0``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gamma, kv

#: Exact coefficient of the phase PSD in cycles per metre, ``0.0229`` (Schmidt 2010 Eq. 9.42) [1]
PSD_COEFFICIENT = gamma(11 / 6) ** 2 / (2 * np.pi ** (11 / 3)) * (24 / 5 * gamma(6 / 5)) ** (5 / 6)
#: Exact Kolmogorov structure-function coefficient, ``6.88`` (Fried 1965) [1]
STRUCTURE_COEFFICIENT = 2 * (24 / 5 * gamma(6 / 5)) ** (5 / 6)


def phase_psd(f: np.ndarray, r0: float, L0: float = np.inf) -> np.ndarray:
    """Von Karman phase PSD at spatial frequency ``f`` [cycles m^-1] -> [rad^2 m^2] (Schmidt 2010 Eq. 9.52)."""
    f = np.asarray(f, dtype=float)
    f0_sq = 0.0 if np.isinf(L0) else 1.0 / L0**2
    with np.errstate(divide="ignore"):
        return PSD_COEFFICIENT * r0 ** (-5 / 3) * (f * f + f0_sq) ** (-11 / 6)


def kolmogorov_structure_function(r: np.ndarray, r0: float) -> np.ndarray:
    """``6.88 (r/r0)^(5/3)`` [rad^2] (Fried 1965)."""
    return STRUCTURE_COEFFICIENT * (np.asarray(r, dtype=float) / r0) ** (5 / 3)


def von_karman_covariance(r: np.ndarray, r0: float, L0: float) -> np.ndarray:
    """Phase covariance ``B(r)`` [rad^2] of von Karman turbulence with finite outer scale ``L0`` [m]."""
    if not np.isfinite(L0):
        raise ValueError("the phase covariance needs a finite outer scale L0")
    r = np.asarray(r, dtype=float)
    scale = 2 * np.pi * PSD_COEFFICIENT * 2 ** (-5 / 6) / gamma(11 / 6) * (L0 / r0) ** (5 / 3)
    u = 2 * np.pi * r / L0
    with np.errstate(invalid="ignore", divide="ignore"):
        value = scale * u ** (5 / 6) * kv(5 / 6, u)
    at_zero = scale * 2 ** (-1 / 6) * gamma(5 / 6)            # lim u^nu K_nu(u) = 2^(nu-1) Gamma(nu)
    return np.where(u < 1e-10, at_zero, value)


def structure_function(r: np.ndarray, r0: float, L0: float = np.inf) -> np.ndarray:
    """Phase structure function [rad^2]: Kolmogorov for ``L0 = inf``, else ``2 (B(0) - B(r))``.

    Below ``u = 2 pi r / L0 = 1`` the difference is summed from the power series of
    ``u^nu K_nu(u) = pi / (2 sin nu pi) u^nu (I_-nu(u) - I_nu(u))`` (Abramowitz & Stegun 9.6.2,
    9.6.10), which avoids cancelling ``B(0) ~ (L0/r0)^(5/3)`` against ``B(r)``.
    """
    if not np.isfinite(L0):
        return kolmogorov_structure_function(r, r0)
    r = np.asarray(r, dtype=float)
    u = 2 * np.pi * r / L0
    nu = 5 / 6
    scale = 2 * np.pi * PSD_COEFFICIENT * 2 ** (-5 / 6) / gamma(11 / 6) * (L0 / r0) ** (5 / 3)
    half = np.minimum(u, 1.0) / 2
    series = np.zeros_like(u)
    power = np.ones_like(u)                          # (u/2)^(2k) / k!
    for k in range(0, 30):
        if k > 0:
            power = power * half**2 / k
            series -= power / gamma(k - nu + 1)
        series += power * half ** (2 * nu) / gamma(k + nu + 1)
    small = 2 * scale * np.pi * 2**nu / (2 * np.sin(nu * np.pi)) * series
    large = 2 * (von_karman_covariance(0.0, r0, L0) - von_karman_covariance(np.maximum(r, L0 / (2 * np.pi)), r0, L0))
    return np.where(u < 1.0, small, large)


def atmospheric_mtf(f_angular: np.ndarray, wavelength: float, r0: float, L0: float = np.inf) -> np.ndarray:
    """Long-exposure atmospheric transfer function ``exp(-D(lambda f) / 2)`` [1] (Fried 1966, JOSA 56, 1372).

    ``f_angular`` is the angular frequency on the sky [cycles rad^-1]; ``lambda f`` is the
    matching baseline in the pupil [m].
    """
    return np.exp(-0.5 * structure_function(wavelength * np.asarray(f_angular, dtype=float), r0, L0))


def tilt_variance_one_axis(wavelength: float, diameter: float, r0: float) -> float:
    """Variance of the Zernike (Z-) tilt angle along one axis [rad^2], from Noll 1976.

    Noll's tilt-mode variance is ``(Delta_1 - Delta_3) / 2 = 0.448 (D/r0)^(5/3)`` rad^2 per axis;
    ``Z_2 = 2 rho cos(theta)`` converts a coefficient ``a`` to the angle ``2 a lambda / (pi D)``,
    giving ``0.182 lambda^2 D^(-1/3) r0^(-5/3)`` (Tyler 1994, JOSA A 11, 358, Eq. 4).
    """
    return (1.0299 - 0.134) / 2 * (diameter / r0) ** (5 / 3) * (2 * wavelength / (np.pi * diameter)) ** 2
