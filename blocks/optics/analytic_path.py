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

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING

import numba
import numpy as np

from evsda.blocks.threads import worker_threads
from evsda.graph.threads import parallel_map

from .paths import ZENITH_BIN_RAD, conditions_key, representative_conditions
from .psf import HankelKernel, long_exposure_profile
from .render import RadialRenderer

if TYPE_CHECKING:
    from .imaging import Imager

#: samples of the tabulated radial profile, from the centre to past the stamp's corner [1]
PROFILE_SAMPLES = 2048
#: spatial frequencies of the long-exposure profile's Hankel transform, 0 to D/lambda [1]
PROFILE_FREQUENCIES = 2048


@numba.njit(cache=True, nogil=True)
def radial_stamps(angles: np.ndarray, offset_rad: np.ndarray, theta: np.ndarray, profile: np.ndarray, size: int,
                  oversample: int, sub_area: float) -> np.ndarray:
    """Pixel energy fractions ``(F, M, M)`` of the tabulated radial PSF ``profile`` [sr^-1] at radii ``theta``
    for sources at ``offset_rad`` (F, 2) (x, y) from the stamp's centre: :meth:`.RadialRenderer.stamps`, the
    same arithmetic bit for bit, in one compiled pass per frame without temporaries.

    * the radius of each sub-pixel centre, ``sqrt(dx^2 + dy^2)``, and ``np.interp``'s value there (in the
      bracket ``theta[j] <= r < theta[j+1]``, ``profile[j] + slope_j (r - theta[j])``; 0 beyond the table),
      the bracket found from ``r / dtheta`` (the table is uniform) instead of a binary search;
    * :meth:`.StampSampler.bin`'s sum over each pixel's ``oversample^2`` sub-pixels in numpy's order (each
      sub-pixel row by numpy's pairwise sum: eight partial sums, then the tail; the rows in turn), times
      the sub-pixel's solid angle ``sub_area`` [sr].
    """
    n, q, last = angles.size, oversample, theta.size - 1
    first_theta, last_theta = theta[0], theta[last]
    per_step = last / (last_theta - first_theta)
    slope = (profile[1:] - profile[:-1]) / (theta[1:] - theta[:-1])
    out = np.empty((offset_rad.shape[0], size, size))
    intensity = np.empty((n, n))
    dx2, r, guess = np.empty(n), np.empty(n), np.empty(n, np.int64)
    for f in range(offset_rad.shape[0]):
        for ix in range(n):
            dx = angles[ix] - offset_rad[f, 0]
            dx2[ix] = dx * dx
        for iy in range(n):
            dy = angles[iy] - offset_rad[f, 1]
            dy2 = dy * dy
            # a row's radii and first guesses of their brackets in loops without branches (SIMD), then the brackets
            for ix in range(n):
                r[ix] = np.sqrt(dx2[ix] + dy2)
            for ix in range(n):
                steps = (r[ix] - first_theta) * per_step
                guess[ix] = min(int(steps), last - 1) if steps < last else last - 1
            row = intensity[iy]
            for ix in range(n):
                radius = r[ix]
                if radius > last_theta:
                    row[ix] = 0.0
                elif radius == last_theta:
                    row[ix] = profile[last]
                elif radius <= first_theta:
                    row[ix] = profile[0]
                else:
                    j = guess[ix]
                    while j > 0 and theta[j] > radius:
                        j -= 1
                    while j < last - 1 and theta[j + 1] <= radius:
                        j += 1
                    row[ix] = profile[j] if theta[j] == radius else slope[j] * (radius - theta[j]) + profile[j]
        for a in range(size):
            for b in range(size):
                total = 0.0
                for i in range(q):
                    row = intensity[a * q + i, b * q:(b + 1) * q]
                    if q >= 8:
                        r0, r1, r2, r3, r4, r5, r6, r7 = row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7]
                        k = 8
                        while k + 8 <= q:
                            r0 += row[k]
                            r1 += row[k + 1]
                            r2 += row[k + 2]
                            r3 += row[k + 3]
                            r4 += row[k + 4]
                            r5 += row[k + 5]
                            r6 += row[k + 6]
                            r7 += row[k + 7]
                            k += 8
                        partial = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
                        while k < q:
                            partial += row[k]
                            k += 1
                    else:
                        partial = 0.0
                        for k in range(q):
                            partial += row[k]
                    total = partial if i == 0 else total + partial
                out[f, a, b] = total * sub_area
    return out


class AnalyticPath:
    """One analytic path (``airy`` or ``long_exposure``); sizing and sampling come from ``imager``."""

    def __init__(self, imager: Imager, path: str):
        self.imager, self.path = imager, path
        self._renderers: dict[tuple[int, int] | None, RadialRenderer] = {}
        # the long-exposure tables' Bessel functions, shared by every zenith-angle bin's table
        self._kernel = HankelKernel()

    def _zenith_key(self, zenith_rad: float) -> tuple[int, int]:
        return conditions_key(zenith_rad, np.inf, self.imager.turbulent(zenith_rad))

    def table_key(self, zenith_rad: float) -> tuple[tuple[int, int] | None, float]:
        """The key of this zenith angle's table (None: the Airy pattern, one for all) and its ``r0`` [m] (that of
        the centre of the zenith-angle bin; inf: no turbulence, or ``airy``)."""
        imager = self.imager
        r0 = imager.r0(zenith_rad) if self.path == "long_exposure" else np.inf
        if not np.isfinite(r0):
            return None, np.inf
        key = self._zenith_key(zenith_rad)
        return key, imager.r0(representative_conditions(key)[0])

    def renderer(self, zenith_rad: float) -> RadialRenderer:
        """The stamp renderer at this zenith angle [rad], made once per zenith-angle bin (once for ``airy``); a
        long-exposure table's two halves on two threads where the process has them free (:func:`.parallel_map`)."""
        key, _ = self.table_key(zenith_rad)
        if key not in self._renderers:
            parts = parallel_map(lambda part: part(), self.table_parts(zenith_rad), worker_threads())
            self.keep_table(zenith_rad, parts)
        return self._renderers[key]

    def table_parts(self, zenith_rad: float) -> list[Callable[[], np.ndarray]]:
        """What makes this zenith angle's table, in parts to compute on any threads and give :meth:`keep_table` in
        order: the long-exposure profile [sr^-1] in two halves of the radii (the same numbers as the whole: the
        profile is computed radius by radius, in blocks of 512 radii, which both halves keep: PROFILE_SAMPLES / 2
        is a multiple of 512), or the Airy pattern whole; none when the table is made."""
        imager = self.imager
        key, r0 = self.table_key(zenith_rad)
        if key in self._renderers:
            return []
        theta = self._radii()
        if not np.isfinite(r0):
            return [lambda: imager.telescope.airy(theta, imager.wavelength)]
        return [functools.partial(long_exposure_profile, imager.telescope, imager.wavelength, r0, imager.outer_scale_m,
                                  half, PROFILE_FREQUENCIES, self._kernel)
                for half in np.split(theta, [theta.size // 2])]

    def keep_table(self, zenith_rad: float, parts: list[np.ndarray]) -> RadialRenderer:
        """Keep the renderer of this zenith angle's table from its parts (:meth:`table_parts`' values, in order)."""
        key, _ = self.table_key(zenith_rad)
        self._renderers[key] = RadialRenderer(self.imager.sampler, self._radii(), np.concatenate(parts))
        return self._renderers[key]

    def _radii(self) -> np.ndarray:
        """The table's radii [rad], from the centre to past the stamp's corner."""
        s = self.imager.sampler
        return np.linspace(0.0, (s.size / 2 + 2) * np.sqrt(2) * self.imager.pixel_scale, PROFILE_SAMPLES)

    def render(self, source, t_s, sight, zenith_rad, range_m, offset) -> np.ndarray:
        """Stamps (F, M, M) [1] at sub-pixel ``offset`` (F, 2), frames grouped by zenith-angle bin
        (the other arguments, those of every path's ``render``, do not change an analytic PSF)."""
        size = self.imager.geometry.stamp_size
        out = np.zeros((len(zenith_rad), size, size))
        # each frame's zenith-angle bin, conditions_key's numbers array-wise (-1: no turbulence)
        zenith_rad = np.asarray(zenith_rad, dtype=float)
        turbulent = np.isfinite(zenith_rad) & (self.imager.atmosphere is not None)
        with np.errstate(invalid="ignore"):
            bins = np.where(turbulent, np.floor(zenith_rad / ZENITH_BIN_RAD), -1.0).astype(np.int64)
        for key in np.unique(bins):
            frames = np.flatnonzero(bins == key)
            out[frames] = self.stamps(self.renderer(zenith_rad[frames[0]]), offset[frames])
        return out

    @staticmethod
    def stamps(renderer: RadialRenderer, offset_px: np.ndarray) -> np.ndarray:
        """``renderer.stamps(offset_px)``, the same numbers, compiled (:func:`radial_stamps`)."""
        s = renderer.sampler
        offset = np.ascontiguousarray(np.asarray(offset_px, dtype=float) * s.pixel_scale_rad)
        return radial_stamps(s.angles, offset, renderer.theta, renderer.profile, s.size, s.oversample,
                             (s.pixel_scale_rad / s.oversample) ** 2)

    def forget(self) -> None:
        """Drop the renderers and the tables' Bessel functions (the sampling they were made with changed)."""
        self._renderers.clear()
        self._kernel = HankelKernel()
