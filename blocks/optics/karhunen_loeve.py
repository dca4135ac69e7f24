"""Kolmogorov phase screens from Zernike modes: Noll's covariance and its Karhunen-Loeve basis.

* Covariance of Zernike coefficients (paper Eq. 8-10; Noll 1976 Eq. 25, Roddier 1990,
  Opt. Eng. 29, 1174, Eq. 5-6), in rad^2 for an aperture of diameter ``D`` and Fried
  parameter ``r0``.
* Karhunen-Loeve coefficients (paper Eq. 11): ``C = U diag(s) U^T`` and ``a = U (sqrt(s) n)``
  with ``n`` independent standard normal draws, so that ``E[a a^T] = C``.
* Phase screen (paper Eq. 7): ``phi = sum_j a_j Z_j``.

Piston (``j = 1``) has infinite variance for Kolmogorov turbulence and carries no image
information; modes start at ``j = 2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import gammaln

from .zernike import noll_to_nm, zernike_basis

#: Constant factor of K_zz' (paper Eq. 9) [1]. The paper (like Roddier 1990) prints
#: Gamma(14/3) [(24/5) Gamma(6/5)]^(5/6) Gamma(11/6)^2 / (2 pi^2) = 2.2698. Evaluating Noll's
#: integral (Noll 1976 Eq. 23 with the exact Kolmogorov PSD, see kolmogorov.PSD_COEFFICIENT) in
#: closed form with Gradshteyn & Ryzhik 6.574.2 gives 1/(2 pi^2) -> 4 / (pi 2^(14/3)), i.e. 2.2461,
#: which reproduces Noll's own Table IV (tilt 0.4489 per axis, table 0.448); the printed value
#: is 1.05 % high. We use the exact one.
_K0 = np.exp(gammaln(14 / 3) + 5 / 6 * np.log(24 / 5 * np.exp(gammaln(6 / 5))) + 2 * gammaln(11 / 6)) \
    * 4 / (np.pi * 2 ** (14 / 3))


def _covariance(j: np.ndarray, jp: np.ndarray) -> np.ndarray:
    """``E[a_j a_j']`` for ``D/r0 = 1`` [rad^2] (paper Eq. 8-10, Noll 1976 Eq. 25), broadcasting."""
    nm = np.array([noll_to_nm(int(i)) for i in range(1, int(max(j.max(), jp.max())) + 1)])
    n, m = nm[j - 1, 0], nm[j - 1, 1]
    n_, m_ = nm[jp - 1, 0], nm[jp - 1, 1]
    # paper Eq. 10: same azimuthal frequency, and the same parity of j (both cos or both sin) unless m = 0
    delta = (m == m_) & ((m == 0) | ((j - jp) % 2 == 0))
    sign = np.where(((n + n_ - 2 * m) // 2) % 2 == 0, 1.0, -1.0)
    k = _K0 * sign * np.sqrt((n + 1) * (n_ + 1))                                    # paper Eq. 9
    log_ratio = (gammaln((n + n_ - 5 / 3) / 2) - gammaln((n - n_ + 17 / 3) / 2)
                 - gammaln((n_ - n + 17 / 3) / 2) - gammaln((n + n_ + 23 / 3) / 2))
    return np.where(delta, k * np.exp(log_ratio), 0.0)                              # paper Eq. 8


def noll_covariance_element(j: int, jp: int) -> float:
    """``E[a_j a_j']`` for ``D/r0 = 1`` [rad^2] (paper Eq. 8-10)."""
    return float(_covariance(np.array([j]), np.array([jp]))[0])


@lru_cache(maxsize=32)
def _unit_covariance(n_modes: int) -> np.ndarray:
    modes = np.arange(2, 2 + n_modes)
    covariance = _covariance(modes[:, None], modes[None, :])
    covariance.flags.writeable = False
    return covariance


def noll_covariance(n_modes: int, d_over_r0: float = 1.0) -> np.ndarray:
    """Covariance of Zernike coefficients ``j = 2 .. n_modes + 1`` [rad^2] (paper Eq. 8)."""
    return _unit_covariance(n_modes) * d_over_r0 ** (5 / 3)


def noll_residual_variance(n_removed: int, n_modes: int, d_over_r0: float = 1.0) -> float:
    """Phase variance [rad^2] in modes ``n_removed + 1 .. n_modes + 1`` of a screen of ``n_modes`` modes.

    With ``n_modes`` large this tends to Noll's ``Delta_J`` (Noll 1976 Table IV).
    """
    diagonal = np.diag(noll_covariance(n_modes, d_over_r0))
    return float(diagonal[max(n_removed - 1, 0):].sum())


@dataclass(frozen=True)
class KarhunenLoeve:
    """The Karhunen-Loeve basis of the first ``n_modes`` Zernike modes (paper Eq. 11).

    ``vectors[:, i]`` is the i-th KL function expressed on Zernike modes ``j = 2 ..``;
    ``variances[i]`` its variance for ``D/r0 = 1`` [rad^2].
    """

    n_modes: int
    vectors: np.ndarray
    variances: np.ndarray

    @classmethod
    def of(cls, n_modes: int) -> "KarhunenLoeve":
        return _karhunen_loeve(n_modes)

    def sample_coefficients(self, rng: np.random.Generator, d_over_r0: float, size: int | None = None) -> np.ndarray:
        """Zernike coefficients ``a_j`` [rad] with covariance ``noll_covariance`` (paper Eq. 11).

        Shape ``(n_modes,)`` or ``(size, n_modes)``.
        """
        shape = (self.n_modes,) if size is None else (size, self.n_modes)
        independent = rng.standard_normal(shape) * np.sqrt(self.variances) * d_over_r0 ** (5 / 6)
        return independent @ self.vectors.T


@lru_cache(maxsize=16)
def _karhunen_loeve(n_modes: int) -> KarhunenLoeve:
    covariance = _unit_covariance(n_modes)
    variances, vectors = np.linalg.eigh(covariance)     # symmetric: U^T C U diagonal (paper Eq. 11)
    variances = np.clip(variances, 0.0, None)
    return KarhunenLoeve(n_modes, vectors, variances)


def zernike_phase_screen(coefficients: np.ndarray, x: np.ndarray, y: np.ndarray, radius: float) -> np.ndarray:
    """Phase [rad] ``sum_j a_j Z_j`` at points (``x``, ``y``) [m] of a disk of ``radius`` [m] (paper Eq. 7).

    ``coefficients`` are for modes ``j = 2, 3, ...``; shape ``(n,)`` or ``(batch, n)``.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    basis = zernike_basis(coefficients.shape[-1], x, y, radius, first=2)
    return np.tensordot(coefficients, basis, axes=(-1, 0))
