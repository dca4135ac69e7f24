"""From a pupil field to a focal-plane PSF, and the analytic long-exposure PSF.

The telescope's focal plane holds the Fraunhofer pattern of the pupil field ``P(r)``
(Goodman 2005 Eq. 5-19): ``E(theta) = (1/lambda) int P(r) exp(-2 pi i r . theta / lambda) dr``,
whose squared modulus is the intensity per steradian [sr^-1] for a unit incident
irradiance; ``integral |E|^2 dOmega = integral |P|^2 dA`` (Parseval). ``E`` is evaluated
either by FFT (samples ``lambda / (N delta)`` apart) or by the matrix Fourier transform
(Soummer et al. 2007, Opt. Express 15, 15935) on any grid of angles, which the renderer
uses to sample exactly the sub-pixels of a stamp.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from scipy.special import j0, j1

from .kolmogorov import atmospheric_mtf
from .telescope import Telescope


def mft_matrix(theta: np.ndarray, x: np.ndarray, wavelength: float, dtype=np.complex128) -> np.ndarray:
    """``exp(-2 pi i theta_a x_j / lambda)``: rows are angles [rad], columns pupil coordinates [m]."""
    return np.exp(-2j * np.pi / wavelength * np.outer(theta, x)).astype(dtype)


def focal_field_mft(pupil_field: np.ndarray, delta: float, wavelength: float,
                    theta_x: np.ndarray, theta_y: np.ndarray) -> np.ndarray:
    """``E`` [sr^-1/2] at the angles ``theta_y`` (rows) x ``theta_x`` (columns) [rad].

    ``pupil_field`` is ``(..., n, n)`` sampled every ``delta`` [m] with its origin at ``n // 2``.
    """
    n = pupil_field.shape[-1]
    x = (np.arange(n) - n // 2) * delta
    wy = mft_matrix(theta_y, x, wavelength, pupil_field.dtype if np.iscomplexobj(pupil_field) else np.complex128)
    wx = mft_matrix(theta_x, x, wavelength, wy.dtype)
    return (delta**2 / wavelength) * (wy @ pupil_field @ wx.T)


def psf_fft(pupil_field: np.ndarray, delta: float, wavelength: float, n_fft: int,
            workers: int = -1) -> tuple[np.ndarray, float]:
    """PSF [sr^-1] on an ``n_fft x n_fft`` grid by zero-padded FFT, and its sample spacing [rad].

    The PSF is centred at ``n_fft // 2``; its spacing is ``lambda / (n_fft delta)``.
    """
    n = pupil_field.shape[-1]
    padded = np.zeros((*pupil_field.shape[:-2], n_fft, n_fft), dtype=np.result_type(pupil_field, np.complex64))
    start = n_fft // 2 - n // 2
    padded[..., start:start + n, start:start + n] = pupil_field
    field = sfft.fftshift(sfft.fft2(sfft.ifftshift(padded, axes=(-2, -1)), workers=workers), axes=(-2, -1))
    return np.abs(field) ** 2 * (delta**2 / wavelength) ** 2, wavelength / (n_fft * delta)


def long_exposure_profile(telescope: Telescope, wavelength: float, r0: float, L0: float,
                          theta: np.ndarray, n_frequencies: int = 4096,
                          kernel: HankelKernel | None = None) -> np.ndarray:
    """Long-exposure seeing PSF [sr^-1] at radii ``theta`` [rad]: the inverse Hankel transform of
    ``OTF_telescope(f) exp(-D_phi(lambda f) / 2)`` (Fried 1966, JOSA 56, 1372, Eq. 4.8; Roddier 1981).

    ``r0 = inf`` gives the diffraction-limited (Airy) profile through the same transform. ``kernel``: where the
    transform's Bessel functions are kept between tables of the same radii and frequencies (the same numbers).
    """
    f, transfer, df = long_exposure_transfer(telescope, wavelength, r0, L0, n_frequencies)
    theta = np.asarray(theta, dtype=float)
    out = np.empty(theta.shape)
    flat = theta.ravel()
    for start in range(0, flat.size, 512):                       # bounded memory
        chunk = flat[start:start + 512]
        bessel = hankel_block(chunk, f) if kernel is None else kernel.block(chunk, f)
        out.ravel()[start:start + 512] = 2 * np.pi * (bessel @ (transfer * f)) * df
    return out


def hankel_block(theta: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``J0(2 pi theta f)`` [1], radii ``theta`` [rad] (rows) by frequencies ``f`` [rad^-1] (columns)."""
    return j0(2 * np.pi * np.outer(theta, f))


class HankelKernel:
    """:func:`hankel_block`'s blocks, each made once and kept: a long-exposure table's Bessel functions depend on
    its radii and frequencies only (``r0`` and ``L0`` enter through the transfer function), so every table of one
    stamp sampling and wavelength shares them (2048 x 2048 of them: 32 MB, ~0.13 s of ``j0`` on one core)."""

    def __init__(self):
        self._blocks: dict[tuple[bytes, bytes], np.ndarray] = {}

    def block(self, theta: np.ndarray, f: np.ndarray) -> np.ndarray:
        """:func:`hankel_block` of these radii and frequencies, made at the first call (thread-safe: a block made
        twice at once is the same numbers)."""
        key = (theta.tobytes(), f.tobytes())
        if key not in self._blocks:
            self._blocks[key] = hankel_block(theta, f)
        return self._blocks[key]


def long_exposure_transfer(telescope: Telescope, wavelength: float, r0: float, L0: float,
                           n_frequencies: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The long-exposure OTF ``OTF_telescope(f) exp(-D_phi(lambda f) / 2)`` [1] (Fried 1966, JOSA 56, 1372; the
    telescope's alone for ``r0 = inf``) at the centres ``f`` [cycles rad^-1] of ``n_frequencies`` equal cells from 0
    to ``D / lambda``: ``(f, OTF(f), the cells' width)``."""
    cutoff = telescope.diameter_m / wavelength
    f = (np.arange(n_frequencies) + 0.5) * cutoff / n_frequencies
    transfer = telescope.otf(f, wavelength)
    if np.isfinite(r0):
        transfer = transfer * atmospheric_mtf(f, wavelength, r0, L0)
    return f, transfer, cutoff / n_frequencies


#: frequencies of :func:`long_exposure_encircled_energy`'s sum [1]
ENCIRCLED_FREQUENCIES = 8192


def long_exposure_encircled_energy(telescope: Telescope, wavelength: float, r0: float, L0: float,
                                   theta: np.ndarray, n_frequencies: int = ENCIRCLED_FREQUENCIES) -> np.ndarray:
    """Fraction [1] of the long-exposure PSF's power within radius ``theta`` [rad]:
    ``EE(theta) = 2 pi theta int OTF(f) J1(2 pi f theta) df`` (the Hankel pair of :func:`long_exposure_profile`)."""
    return encircled_energy(long_exposure_transfer(telescope, wavelength, r0, L0, n_frequencies), theta)


def encircled_energy(transfer: tuple[np.ndarray, np.ndarray, float], theta: np.ndarray) -> np.ndarray:
    """:func:`long_exposure_encircled_energy` [1] at radii ``theta`` [rad] from its transfer function
    (:func:`long_exposure_transfer`'s ``(f, OTF(f), df)``), made once for many radii (the same numbers)."""
    f, values, df = transfer
    theta = np.asarray(theta, dtype=float)
    return 2 * np.pi * theta * (j1(2 * np.pi * np.outer(theta, f)) @ values) * df


def fwhm(profile_theta: np.ndarray, profile: np.ndarray) -> float:
    """Full width at half maximum [rad] of a monotonically decreasing radial profile sampled at ``profile_theta``."""
    half = profile[0] / 2
    below = np.nonzero(profile < half)[0]
    if below.size == 0:
        return np.nan
    i = below[0]
    t0, t1, p0, p1 = profile_theta[i - 1], profile_theta[i], profile[i - 1], profile[i]
    return 2 * (t0 + (half - p0) * (t1 - t0) / (p1 - p0))
