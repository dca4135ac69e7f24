"""PSF to detector pixels: stamps integrated over pixels at sub-pixel source positions.

A stamp is ``size x size`` pixels around a source at column ``x``, row ``y`` (pixel
centres at integers, :mod:`evsda.blocks.ports.core`). Its first pixel is at
``(round(x) - size//2, round(y) - size//2)`` and the source sits at the sub-pixel offset
``x - round(x)`` from the stamp's central pixel. Each pixel's energy is the PSF
integrated over the pixel by the midpoint rule on ``oversample x oversample``
sub-pixels. With sub-pixels no wider than ``lambda / 2D`` (the Nyquist interval of the
band-limited intensity) the sum over all sub-pixels equals the PSF's integral exactly
(Poisson summation), so flux is conserved; within a pixel the rule's error is tested
against a much finer integration.

Values are fractions of the power incident on the collecting area [1]; multiply by the
photon flux [photon s^-1 m^-2], the collecting area [m^2] and the throughput to get
[photon s^-1 pixel^-1].
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .psf import mft_matrix


@dataclass(frozen=True)
class StampSampler:
    """Stamp size [pixel], pixel scale [rad] and sub-pixels per pixel along each axis."""

    size: int
    pixel_scale_rad: float
    oversample: int

    @cached_property
    def angles(self) -> np.ndarray:
        """Sub-pixel centre angles [rad] along one axis, relative to the central pixel's centre."""
        q = self.oversample
        sub = (np.arange(self.size * q) + 0.5) / q - 0.5 - self.size // 2
        return sub * self.pixel_scale_rad

    def bin(self, intensity: np.ndarray) -> np.ndarray:
        """Pixel energies [1] from intensities [sr^-1] at the sub-pixels, ``(..., Mq, Mq) -> (..., M, M)``."""
        m, q = self.size, self.oversample
        shape = intensity.shape[:-2]
        summed = intensity.reshape(*shape, m, q, m, q).sum(axis=(-3, -1))
        return summed * (self.pixel_scale_rad / q) ** 2


def oversampling_for(pixel_scale_rad: float, diameter_m: float, wavelength_m: float) -> int:
    """Sub-pixels per pixel so that they are at most ``lambda / 2D`` apart (Nyquist for the intensity)."""
    return max(1, int(np.ceil(pixel_scale_rad / (wavelength_m / (2 * diameter_m)) - 1e-9)))


def stamp_placement(x_px: np.ndarray, y_px: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Stamp origins ``(x0, y0)`` [pixel, int32] and source offsets from the central pixel [pixel].

    Returns ``origin`` of shape ``(..., 2)`` and ``offset`` of shape ``(..., 2)``, both (x, y).
    NaN positions give origin ``(0, 0)`` and offset 0 (their stamps are left empty).
    """
    xy = np.stack([np.asarray(x_px, dtype=float), np.asarray(y_px, dtype=float)], axis=-1)
    finite = np.isfinite(xy)
    centre = np.round(np.where(finite, xy, 0.0))
    origin = (centre - size // 2).astype(np.int32)
    return origin, np.where(finite, xy - centre, 0.0)


class PupilRenderer:
    """Stamps from pupil fields (far-field Fraunhofer pattern, :mod:`.psf`) by matrix Fourier transform.

    The source's sub-pixel offset becomes a tilt across the pupil, so the transform
    matrices are fixed and frames are processed in batches.
    """

    def __init__(self, sampler: StampSampler, n_pupil: int, delta_m: float, wavelength_m: float,
                 area_m2: float, dtype=np.complex64):
        self.sampler, self.n, self.delta, self.wavelength, self.area = sampler, n_pupil, delta_m, wavelength_m, area_m2
        self.x = (np.arange(n_pupil) - n_pupil // 2) * delta_m
        self.w = mft_matrix(sampler.angles, self.x, wavelength_m, dtype)
        self.dtype = dtype

    def tilt(self, offset_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Separable pupil factors ``exp(i k theta . r)`` (F, n) along y and x moving the image by ``offset_px``."""
        theta = np.asarray(offset_px, dtype=float) * self.sampler.pixel_scale_rad
        k = 2 * np.pi / self.wavelength
        ex = np.exp(1j * k * theta[:, 0, None] * self.x[None, :]).astype(self.dtype)
        ey = np.exp(1j * k * theta[:, 1, None] * self.x[None, :]).astype(self.dtype)
        return ey, ex

    def stamps(self, amplitude: np.ndarray, phase: np.ndarray, offset_px: np.ndarray) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` from pupil ``amplitude`` (n, n) or (F, n, n) and ``phase`` (F, n, n)."""
        real = np.float32 if self.dtype == np.complex64 else np.float64
        phase = phase.astype(real)
        field = np.empty(phase.shape, dtype=self.dtype)
        field.real = np.cos(phase)
        field.imag = np.sin(phase)
        field *= amplitude.astype(real)
        return self.stamps_from_field(field, offset_px)

    def stamps_from_field(self, field: np.ndarray, offset_px: np.ndarray) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` from complex pupil fields (F, n, n) [incident amplitude 1]."""
        ey, ex = self.tilt(offset_px)
        tilted = field.astype(self.dtype) * ey[:, :, None] * ex[:, None, :]
        return self._stamps(tilted)

    def _stamps(self, field: np.ndarray) -> np.ndarray:
        frames, n, _ = field.shape
        m = self.w.shape[0]
        # two large products instead of 2 F small ones: (F n, n) @ (n, m), then (m, n) @ (n, F m)
        along_x = (field.reshape(frames * n, n) @ self.w.T).reshape(frames, n, m)
        stacked = np.ascontiguousarray(along_x.transpose(1, 0, 2)).reshape(n, frames * m)
        e = (self.w @ stacked).reshape(m, frames, m).transpose(1, 0, 2)
        intensity = (e.real**2 + e.imag**2) * (self.delta**2 / self.wavelength) ** 2
        return self.sampler.bin(intensity).astype(float) / self.area


class RadialRenderer:
    """Stamps from a radially symmetric PSF [sr^-1] tabulated at radii [rad] (analytic Airy, long exposure)."""

    def __init__(self, sampler: StampSampler, theta_rad: np.ndarray, profile: np.ndarray):
        self.sampler, self.theta, self.profile = sampler, np.asarray(theta_rad), np.asarray(profile)

    def stamps(self, offset_px: np.ndarray) -> np.ndarray:
        """Pixel energy fractions ``(F, M, M)`` for sources at ``offset_px`` (F, 2)."""
        a = self.sampler.angles
        theta = np.asarray(offset_px, dtype=float) * self.sampler.pixel_scale_rad
        dx = a[None, None, :] - theta[:, 0, None, None]
        dy = a[None, :, None] - theta[:, 1, None, None]
        r = np.sqrt(dx * dx + dy * dy)
        intensity = np.interp(r, self.theta, self.profile, right=0.0)
        return self.sampler.bin(intensity)
