"""Which PSF path a scene needs: error estimates of the fast paths against the reference.

Paths, cheapest first:

* ``airy`` -- the analytic diffraction-limited PSF of the annular aperture, no turbulence;
* ``long_exposure`` -- the analytic long-exposure seeing PSF (telescope OTF x atmospheric MTF);
* ``pupil_fft`` -- the far-field (Fraunhofer) image of the aperture times ``exp(i phase)``,
  the turbulent phase being the sum of the layers' screens along the line of sight;
* ``reference`` -- the paper's Eq. 3-4: Fresnel propagation from the source through every
  layer, then the telescope.

The error of a path is the expected *fraction of the source's flux it puts in the wrong
pixels* relative to the reference, ``E[ sum |S_path - S_ref| ] / (2 F)`` (the total-variation
distance between pixel-integrated stamps of total flux ``F``).

* ``pupil_fft`` vs ``reference``: the pupil path keeps the phase of every layer along the
  straight line of sight but drops what diffraction between the layers and the aperture
  does (the near-field / geometric-optics approximation, good when the Fresnel scale
  ``sqrt(lambda h)`` of each layer is small against the scales that matter): amplitude
  fluctuations (scintillation) and the phase they exchange with. The flux fluctuation
  alone misplaces ``E|dF|/2F = sigma_I / sqrt(2 pi)`` of the flux, with the
  aperture-averaged ``sigma_I`` of :meth:`.Atmosphere.scintillation_index`; the block takes
  the larger of that and the distance measured on a few reference propagations fed the
  same screens (:meth:`.Imager.pupil_error`). The source's own Fresnel number
  ``N_F = D^2 / (lambda R)`` only sets the defocus of a telescope focused at infinity,
  which the pupil path includes exactly (Fresnel approximation); in vacuum the two paths
  are the same physics.
* ``airy`` and ``long_exposure`` vs ``pupil_fft``: measured by a probe, the mean distance
  over ``PROBE_FRAMES`` turbulent pupil-path stamps at random sub-pixel positions (a
  fixed-seed draw, so a choice is a pure function of the conditions); the error against
  the reference adds the pupil path's (triangle inequality).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

PATHS = ("airy", "long_exposure", "pupil_fft", "reference")
PROBE_FRAMES = 24
LOG = logging.getLogger("evsda.blocks.optics")


@dataclass(frozen=True)
class PathChoice:
    """The chosen path, every path's estimated error [1] and a sentence saying why."""

    path: str
    estimates: dict = field(default_factory=dict)
    reason: str = ""


def total_variation(a: np.ndarray, b: np.ndarray, flux: np.ndarray | float) -> np.ndarray:
    """``sum |a - b| / (2 flux)`` over the last two axes [1]."""
    return np.abs(a - b).sum(axis=(-2, -1)) / (2 * np.asarray(flux, dtype=float))


def scintillation_error(sigma_i2: float) -> float:
    """Expected flux misplaced by ignoring scintillation, ``E|dF| / 2F = sigma_I / sqrt(2 pi)`` [1]."""
    return float(np.sqrt(max(sigma_i2, 0.0)) / np.sqrt(2 * np.pi))


def pick(estimates: dict[str, float], tolerance: float, context: str) -> PathChoice:
    """The cheapest path whose estimated error is within ``tolerance`` (the reference otherwise)."""
    for path in PATHS:
        if estimates.get(path, np.inf) <= tolerance:
            break
    others = ", ".join(f"{p} {estimates[p]:.3g}" for p in PATHS if p in estimates and p != path)
    reason = (f"path '{path}': estimated error {estimates.get(path, 0.0):.3g} <= tolerance {tolerance:g} "
              f"({context}; other paths: {others})")
    return PathChoice(path, dict(estimates), reason)
