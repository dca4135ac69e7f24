"""The ``airy`` and ``long_exposure`` paths: tabulated radial PSFs integrated over the pixels
(:class:`.RadialRenderer`).

* ``airy``: the diffraction pattern of the annular aperture (:meth:`.Telescope.airy`; Born &
  Wolf 1999 Sec. 8.5.2, Mahajan 1986), no turbulence;
* ``long_exposure``: the telescope OTF times the atmospheric MTF ``exp(-D_phi(lambda f)/2)``
  (:func:`.psf.long_exposure_profile`; Fried 1966, Roddier 1981) at the ``r0`` of the centre of
  each 1-degree zenith-angle bin (:func:`.paths.conditions_key`); the Airy pattern without
  turbulence.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from .paths import conditions_key, representative_conditions
from .psf import long_exposure_profile
from .render import RadialRenderer

if TYPE_CHECKING:
    from .imaging import Imager

#: samples of the tabulated radial profile, from the centre to past the stamp's corner [1]
PROFILE_SAMPLES = 2048
#: spatial frequencies of the long-exposure profile's Hankel transform, 0 to D/lambda [1]
PROFILE_FREQUENCIES = 2048


@numba.njit(cache=True, nogil=True)
def radial_intensity(angles: np.ndarray, offset_rad: np.ndarray, theta: np.ndarray, profile: np.ndarray) -> np.ndarray:
    """The tabulated radial PSF at every sub-pixel of every frame [sr^-1] ``(F, Mq, Mq)``, for sources at
    ``offset_rad`` (F, 2) (x, y) from the stamp's centre: :meth:`.RadialRenderer.stamps`' ``np.interp`` of the
    sub-pixel radii, the same arithmetic bit for bit (radius ``sqrt(dx^2 + dy^2)``; in the bracket
    ``theta[j] <= r < theta[j+1]``, ``profile[j] + slope_j (r - theta[j])``; 0 beyond the table) in one pass
    without the search: the table is uniform, so ``j`` is ``r / dtheta`` corrected by one at most."""
    n, last = angles.size, theta.size - 1
    per_step = last / (theta[last] - theta[0])
    slope = (profile[1:] - profile[:-1]) / (theta[1:] - theta[:-1])
    out = np.empty((offset_rad.shape[0], n, n))
    for f in range(offset_rad.shape[0]):
        for iy in range(n):
            dy = angles[iy] - offset_rad[f, 1]
            for ix in range(n):
                dx = angles[ix] - offset_rad[f, 0]
                r = np.sqrt(dx * dx + dy * dy)
                if r > theta[last]:
                    out[f, iy, ix] = 0.0
                elif r == theta[last]:
                    out[f, iy, ix] = profile[last]
                elif r <= theta[0]:
                    out[f, iy, ix] = profile[0]
                else:
                    j = min(int((r - theta[0]) * per_step), last - 1)
                    while j > 0 and theta[j] > r:
                        j -= 1
                    while j < last - 1 and theta[j + 1] <= r:
                        j += 1
                    out[f, iy, ix] = profile[j] if theta[j] == r else slope[j] * (r - theta[j]) + profile[j]
    return out


class AnalyticPath:
    """One analytic path (``airy`` or ``long_exposure``); sizing and sampling come from ``imager``."""

    def __init__(self, imager: Imager, path: str):
        self.imager, self.path = imager, path
        self._renderers: dict[tuple[int, int] | None, RadialRenderer] = {}

    def _zenith_key(self, zenith_rad: float) -> tuple[int, int]:
        return conditions_key(zenith_rad, np.inf, self.imager.turbulent(zenith_rad))

    def renderer(self, zenith_rad: float) -> RadialRenderer:
        """The stamp renderer at this zenith angle [rad], made once per zenith-angle bin (once for ``airy``)."""
        imager = self.imager
        r0 = imager.r0(zenith_rad) if self.path == "long_exposure" else np.inf
        key = None if not np.isfinite(r0) else self._zenith_key(zenith_rad)
        if key not in self._renderers:
            if np.isfinite(r0):
                r0 = imager.r0(representative_conditions(key)[0])
            s = imager.sampler
            theta = np.linspace(0.0, (s.size / 2 + 2) * np.sqrt(2) * imager.pixel_scale, PROFILE_SAMPLES)
            if np.isfinite(r0):
                profile = long_exposure_profile(imager.telescope, imager.wavelength, r0, imager.outer_scale_m, theta,
                                                PROFILE_FREQUENCIES)
            else:
                profile = imager.telescope.airy(theta, imager.wavelength)
            self._renderers[key] = RadialRenderer(s, theta, profile)
        return self._renderers[key]

    def render(self, source, t_s, x_px, y_px, zenith_rad, range_m, offset) -> np.ndarray:
        """Stamps (F, M, M) [1] at sub-pixel ``offset`` (F, 2), frames grouped by zenith-angle bin
        (the other arguments, those of every path's ``render``, do not change an analytic PSF)."""
        size = self.imager.geometry.stamp_size
        out = np.zeros((len(zenith_rad), size, size))
        keys = [self._zenith_key(z) for z in zenith_rad]
        for key in sorted(set(keys)):
            frames = np.array([i for i, k in enumerate(keys) if k == key], dtype=int)
            out[frames] = self.stamps(self.renderer(zenith_rad[frames[0]]), offset[frames])
        return out

    @staticmethod
    def stamps(renderer: RadialRenderer, offset_px: np.ndarray) -> np.ndarray:
        """``renderer.stamps(offset_px)``, the same numbers, with the radii and the table read compiled
        (:func:`radial_intensity`; 4-6x faster)."""
        s = renderer.sampler
        offset = np.ascontiguousarray(np.asarray(offset_px, dtype=float) * s.pixel_scale_rad)
        return s.bin(radial_intensity(s.angles, offset, renderer.theta, renderer.profile))

    def forget(self) -> None:
        """Drop the renderers (the sampling they were made with changed)."""
        self._renderers.clear()
