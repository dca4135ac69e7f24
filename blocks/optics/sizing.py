"""Sampling of the optics, chosen once per run: stamp width, sub-pixels, pupil grid and layer screens.

Each size follows from the telescope, the band, the pixel scale, the tolerance and the
Fried parameter ``r0`` of the first line of sight, designed for ``0.75 r0`` (about 25
degrees more zenith angle near 45 degrees):

* the stamp encloses all but ``tolerance / 2`` of the long-exposure (or Airy) PSF's power
  (:func:`.psf.long_exposure_encircled_energy`);
* ``sqrt(0.12 / tolerance)`` sub-pixels per ``lambda / 2D`` (clipped to 1-4): the midpoint
  rule then misplaces about ``0.03 (sub-pixels per lambda/2D)^-2`` of the flux (:mod:`.render`,
  tests/optics), a quarter of the tolerance;
* pupil samples ``min(D/24, r0/4, lambda / (1.25 M p))`` apart: the far field of a pupil sampled
  every ``delta`` repeats every ``lambda / delta`` [rad], so the stamp of ``M`` pixels of ``p``
  [rad] stays inside one period with a quarter to spare (no wrapped light);
* each layer's screen sampled at a sixth of its own ``r0_i`` (between the pupil spacing and
  ``D/8``), its window the pupil's footprint and half as much again, plus the B-spline's
  2-sample support each side (:mod:`.screen_kernels`).

The result is kept in the block's state, so that a resumed run samples as the first did.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from evsda.graph import ParameterError

from .atmosphere import Atmosphere
from .paths import LOG
from .psf import ENCIRCLED_FREQUENCIES, encircled_energy, long_exposure_transfer
from .render import oversampling_for
from .screen_kernels import MARGIN
from .telescope import Telescope

#: sub-pixel samples across a stamp at most (the renderers' tables grow with its square) [1]
MAX_SUBPIXELS_PER_AXIS = 2048
#: the design r0 is this fraction of the first line of sight's [1]
DESIGN_R0_FRACTION = 0.75


@dataclass(frozen=True)
class PupilGeometry:
    """Sampling chosen once per run (kept in the block's state so a resumed run is identical)."""

    n_pupil: int                 # pupil samples across the grid
    delta_m: float               # pupil sample spacing [m]
    stamp_size: int              # stamp width [pixel]
    oversample: int              # sub-pixels per pixel along an axis
    layer_delta_m: tuple         # screen sample spacing of each layer [m]
    layer_n: tuple               # screen window width of each layer [samples]

    def state(self) -> dict:
        """The geometry as plain numbers and lists (a checkpoint's form)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_state(cls, state: dict) -> PupilGeometry:
        return cls(int(state["n_pupil"]), float(state["delta_m"]), int(state["stamp_size"]),
                   int(state["oversample"]), tuple(float(v) for v in state["layer_delta_m"]),
                   tuple(int(v) for v in state["layer_n"]))


def stamp_width_px(telescope: Telescope, wavelength_m: float, pixel_scale_rad: float, r0_m: float,
                   outer_scale_m: float, tolerance: float) -> int:
    """Odd stamp width [pixel], 3 to 129, enclosing all but ``tolerance / 2`` of the long-exposure PSF's power."""
    theta = np.arange(1, 1025) * pixel_scale_rad / 4
    # the first radius enclosing 1 - tolerance / 2, by bisection (numpy's searchsorted, side "left"): the
    # encircled energy at ~10 radii instead of 1024 (each a sum over 8192 frequencies of one transfer function)
    transfer = long_exposure_transfer(telescope, wavelength_m, r0_m, outer_scale_m, ENCIRCLED_FREQUENCIES)
    low, high = 0, theta.size
    while low < high:
        mid = low + (high - low) // 2
        if encircled_energy(transfer, theta[mid:mid + 1])[0] < 1 - tolerance / 2:
            low = mid + 1
        else:
            high = mid
    radius = theta[min(low, theta.size - 1)]
    return int(np.clip(2 * np.ceil(radius / pixel_scale_rad) + 1, 3, 129))


def pupil_grid(diameter_m: float, wavelength_m: float, pixel_scale_rad: float, r0_m: float,
               stamp_size: int) -> tuple[int, float]:
    """Even pupil grid width [samples] and spacing [m]: ``min(D/24, r0/4, lambda / (1.25 M p))``, one spare sample
    each side."""
    delta = min(diameter_m / 24, r0_m / 4, wavelength_m / (1.25 * stamp_size * pixel_scale_rad))
    n_pupil = int(np.ceil(diameter_m / delta)) + 2
    n_pupil += n_pupil % 2
    return n_pupil, diameter_m / (n_pupil - 2)


def layer_grids(atmosphere: Atmosphere, wavelength_m: float, zenith_rad: float, diameter_m: float,
                pupil_delta_m: float, footprint_m: float) -> tuple[tuple, tuple]:
    """Each layer's screen spacing [m] (``r0_i / 6`` at the design r0, between the pupil spacing and ``D/8``)
    and even window width [samples]."""
    layer_delta, layer_n = [], []
    for r0_l in DESIGN_R0_FRACTION * atmosphere.layer_r0(wavelength_m, zenith_rad):
        step = float(np.clip(r0_l / 6, pupil_delta_m, diameter_m / 8))
        across = int(np.ceil(footprint_m / step))
        # the footprint, half as much again (transverse drift, and the stencil's reach for the large
        # scales: columns 3, 7, 15, ... back, beyond the footprint's width) and the spline's support
        n = across + across // 2 + 2 * MARGIN + 2
        layer_delta.append(step)
        layer_n.append(n + n % 2)
    return tuple(layer_delta), tuple(layer_n)


def choose_geometry(telescope: Telescope, wavelength_m: float, pixel_scale_rad: float,
                    atmosphere: Atmosphere | None, zenith_rad: float, r0_m: float, *, tolerance: float,
                    stamp_size_px: int | None = None, pupil_samples: int | None = None,
                    label: str = "optics") -> PupilGeometry:
    """The run's sampling for a first line of sight at ``zenith_rad`` with Fried parameter ``r0_m`` [m]
    (inf above the atmosphere); ``stamp_size_px`` and ``pupil_samples`` override the automatic sizes;
    ``label`` names the block in messages.

    A PSF so much smaller than a pixel that a stamp would need more than ``MAX_SUBPIXELS_PER_AXIS``
    sub-pixels across is a :class:`~evsda.graph.ParameterError` naming both widths.
    """
    d, lam, p = telescope.diameter_m, wavelength_m, pixel_scale_rad
    r0 = DESIGN_R0_FRACTION * r0_m
    outer_scale_m = atmosphere.L0 if atmosphere is not None else np.inf
    size = int(stamp_size_px) if stamp_size_px is not None else stamp_width_px(telescope, lam, p, r0, outer_scale_m,
                                                                               tolerance)
    oversample = oversampling_for(p, d, lam, float(np.clip(np.sqrt(0.12 / tolerance), 1.0, 4.0)))
    if size * oversample > MAX_SUBPIXELS_PER_AXIS:
        arcsec = 180 / np.pi * 3600
        raise ParameterError(
            f"{label}: the PSF is far smaller than a pixel (diffraction width lambda/D = {lam / d * arcsec:.3g} "
            f"arcsec, a pixel {p * arcsec:.3g} arcsec): rendering it would take {oversample} x {oversample} sub-pixels "
            f"per pixel, {size * oversample} across a stamp (at most {MAX_SUBPIXELS_PER_AXIS}); lengthen the focal "
            f"length or shrink the pixels")
    if pupil_samples is not None:
        n_pupil, delta = int(pupil_samples), d / (int(pupil_samples) - 2)
    else:
        n_pupil, delta = pupil_grid(d, lam, p, r0, size)
    layer_delta, layer_n = (), ()
    if atmosphere is not None:
        layer_delta, layer_n = layer_grids(atmosphere, lam, zenith_rad if np.isfinite(zenith_rad) else 0.0, d,
                                           delta, n_pupil * delta)
    LOG.info("%s: pupil %d x %d samples of %.3g mm, stamps %d x %d pixels with %d x %d sub-pixels, "
             "layer screens %s samples of %s mm", label, n_pupil, n_pupil, delta * 1e3, size, size,
             oversample, oversample, list(layer_n), [round(s * 1e3, 2) for s in layer_delta])
    return PupilGeometry(n_pupil, delta, size, oversample, layer_delta, layer_n)
