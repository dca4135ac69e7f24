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
            out[frames] = self.renderer(zenith_rad[frames[0]]).stamps(offset[frames])
        return out

    def forget(self) -> None:
        """Drop the renderers (the sampling they were made with changed)."""
        self._renderers.clear()
