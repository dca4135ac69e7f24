"""Zernike polynomials in Noll's ordering (paper Eq. 5-6; Noll 1976, J. Opt. Soc. Am. 66, 207).

Modes are orthonormal over the unit disk: the mean of ``Z_j**2`` over the disk is 1,
so a coefficient is the rms phase [rad] that mode contributes. ``j`` starts at 1
(piston); even ``j`` carry ``cos(m theta)``, odd ``j`` carry ``sin(m theta)``.

>>> noll_to_nm(4)        # defocus
(2, 0)
>>> [noll_to_nm(j) for j in (2, 3)]   # tip and tilt
[(1, 1), (1, 1)]
"""

from __future__ import annotations

from functools import lru_cache
from math import factorial

import numpy as np

#: Noll 1976 Table IV: residual phase variance after removing the first J modes,
#: Delta_J in units of (D/r0)^(5/3) [rad^2], for a Kolmogorov screen, J = 1..21.
NOLL_1976_RESIDUALS = {
    1: 1.0299, 2: 0.582, 3: 0.134, 4: 0.111, 5: 0.0880, 6: 0.0648, 7: 0.0587,
    8: 0.0525, 9: 0.0463, 10: 0.0401, 11: 0.0377, 12: 0.0352, 13: 0.0328, 14: 0.0304,
    15: 0.0279, 16: 0.0267, 17: 0.0255, 18: 0.0243, 19: 0.0232, 20: 0.0220, 21: 0.0208,
}


@lru_cache(maxsize=None)
def noll_to_nm(j: int) -> tuple[int, int]:
    """Radial degree ``n`` and azimuthal frequency ``m >= 0`` of Noll mode ``j`` (Noll 1976 Table I)."""
    if j < 1:
        raise ValueError(f"Noll index starts at 1, got {j}")
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    position = j - n * (n + 1) // 2 - 1           # 0-based place of j within radial order n
    m = 2 * ((position + 1) // 2) if n % 2 == 0 else 2 * (position // 2) + 1
    return n, m


def radial_polynomial(n: int, m: int, rho: np.ndarray) -> np.ndarray:
    """``R_n^m(rho)`` of paper Eq. 6 (Noll 1976 Eq. 2), evaluated by Horner's rule in ``rho**2``."""
    rho = np.asarray(rho, dtype=float)
    coefficients = [(-1) ** s * factorial(n - s)
                    / (factorial(s) * factorial((n + m) // 2 - s) * factorial((n - m) // 2 - s))
                    for s in range((n - m) // 2 + 1)]       # multiplies rho**(n - 2 s)
    rho2 = rho * rho
    result = np.zeros_like(rho)
    for c in coefficients:                                 # highest power first
        result = result * rho2 + c
    return result * rho**m


def zernike(j: int, rho: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Noll mode ``Z_j`` at polar coordinates on the unit disk (paper Eq. 5), zero outside it."""
    n, m = noll_to_nm(j)
    rho = np.asarray(rho, dtype=float)
    radial = np.sqrt(n + 1) * radial_polynomial(n, m, rho)
    if m != 0:
        radial = radial * np.sqrt(2) * (np.cos(m * theta) if j % 2 == 0 else np.sin(m * theta))
    return np.where(rho <= 1.0, radial, 0.0)


def zernike_basis(n_modes: int, x: np.ndarray, y: np.ndarray, radius: float, first: int = 1) -> np.ndarray:
    """Modes ``first .. first + n_modes - 1`` at Cartesian points (``x``, ``y``) [m] of a disk of ``radius`` [m].

    Returns an array of shape ``(n_modes, *x.shape)`` [1].
    """
    rho = np.hypot(x, y) / radius
    theta = np.arctan2(y, x)
    return np.stack([zernike(j, rho, theta) for j in range(first, first + n_modes)])


def n_modes_up_to_order(n_max: int) -> int:
    """Number of Noll modes with radial degree ``n <= n_max`` (a complete set of orders)."""
    return (n_max + 1) * (n_max + 2) // 2
