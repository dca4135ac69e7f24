"""How often a source's PSF must be rendered: a render interval per source from what its pixels can follow.

The optics renders on one global grid of render times, ``k dt`` (``dt = 1 / render_rate_hz``, the base
cadence). A source's irradiance on its pixels changes on three time scales:

* the speckle's and tilt's correlation time along its line of sight, Roddier's coherence time
  ``tau0 = 0.314 r0 / v_bar`` (Roddier 1981, Prog. Optics 19, 281; Hardy 1998, Adaptive Optics for
  Astronomical Telescopes, Ch. 3; Kellerer & Tokovinin 2007, A&A 461, 775, Table 1): the lag at which the
  phase structure function of frozen-flow layers, ``D(t) = 6.88 (v_bar t / r0)^(5/3)`` (Fried 1966), reaches
  1 rad^2, so ``0.314 = 6.88^(-3/5)``; ``v_bar = (sum_i c_i v_i^(5/3))^(3/5)`` is the ``Cn^2 dh``-weighted
  5/3-moment (``c_i`` the layers' fractions) of the layers' speeds relative to the source's footprint. A line of
  sight turning at ``omega`` sweeps its footprint through layer ``i`` at ``L_i omega`` (``L_i = h_i sec z``, the
  optics' own frozen flow, :meth:`.Imager.footprints_of`) against the layer's wind ``v_i``; the block's
  per-frame inputs give ``|omega|`` but not its direction against the wind, so the speed is taken at its
  largest, ``L_i |omega| + |v_i|``: the shortest ``tau0`` (``r0`` along the line of sight at the band's
  wavelength, ``r0(z) = r0(0) cos(z)^(3/5)``, Hardy 1998 Eq. 3.40);
* its image's pixel-crossing time on the detector, ``1 / rate`` (the apparent rate [pixel/s]);
* the response time of the pixels it lights, ``tau_pix = 1 / (2 pi f_3dB)`` at the brightest current it can
  make, all of its collected flux on one pixel over the sky (paper Eq. 16, :meth:`.PixelView.response_time_s`,
  as the path choice takes it): the pixels average what changes faster.

The interval must resolve all three. The image's motion is a hard bound: the held image must not jump by more
than one pixel when the next stamp is rendered, the scene's own limit on a sampled source (docs/scene.md), so
``m dt <= 1 / rate``. The turbulence and the pixels' response are time constants of correlations, not edges,
and a factor calibrated on one scene (docs/speed.md) says how many of them a held stamp may span:
``m dt <= factor min(tau0, tau_pix)``. A source is rendered every ``m``-th render time, ``m`` the largest power
of two within both (at least 1). The pixels' response enters as a bound, never as a licence: a pixel slower than
the image averages its speckle, but where the held image sits decides how long each pixel is lit, which no
filter restores, and a pixel faster than the hold follows its steps. Powers of two nest: a source whose interval
changes keeps rendering on a subset of the same render times. Render time ``k`` is rendered where ``k`` is a
multiple of that time's ``m``, where the source was not in view at the render time before (the first of a
stretch in view), or where its path differs from the held stamp's; in between, the last rendered stamp (its
energy fractions and placement) is held, times the source's flux at each render time (a glint or a change of
range at the base rate): the zero-order hold the base cadence itself gives the irradiance between render times,
at ``m dt``. A stamp shifted by the image's motion instead would be exact only where that motion is a whole
number of pixels; otherwise the sub-pixel part of the motion is lost and, where the source crosses a pixel
boundary, the image jumps by a whole pixel, back and forth along the track: not a physical image, where the hold
is the base cadence's own approximation at a longer interval. Every quantity is a held input of that render
time, so the frames rendered do not depend on how the run is cut into windows.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .atmosphere import Atmosphere
    from .pixel_view import PixelView

#: Roddier's coherence-time constant, 6.88^(-3/5) [1] (Fried 1966's 6.88; Roddier 1981)
RODDIER_TAU0 = 6.88 ** (-3 / 5)
#: the largest interval's exponent: m <= 2^MAX_DOUBLINGS render times (a still source in vacuum would hold forever)
MAX_DOUBLINGS = 30


def coherence_time_s(r0_m, cn2_fraction: np.ndarray, speed_m_s: np.ndarray) -> np.ndarray:
    """Roddier's ``tau0 = 0.314 r0 / v_bar`` [s] (module docstring) for layers holding ``cn2_fraction`` of the
    turbulence whose footprints move at ``speed_m_s`` (layers, ...) [m/s] along a line of sight of Fried parameter
    ``r0_m`` (...) [m]; infinite without turbulence or motion."""
    c = np.asarray(cn2_fraction, dtype=float).reshape((-1,) + (1,) * (np.ndim(speed_m_s) - 1))
    terms = c * np.abs(np.asarray(speed_m_s, dtype=float)) ** (5 / 3)
    # summed layer by layer, in order: the same bits for any number of frames (numpy sums a single frame's 8 or more
    # layers pairwise)
    total = terms[0].copy()
    for term in terms[1:]:
        total += term
    v_bar = total ** (3 / 5)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(v_bar > 0, RODDIER_TAU0 * np.asarray(r0_m, dtype=float) / v_bar, np.inf)


def fastest_footprint_speeds(altitude_m: np.ndarray, wind_m_s: np.ndarray, zenith_rad, rate_rad_s) -> np.ndarray:
    """The fastest each layer's footprint can move against its air [m/s], (layers, frames): ``L |omega| + |v|``
    (``L = h sec z``; :meth:`.Imager.footprints_of`), for lines of sight at ``zenith_rad`` turning at ``rate_rad_s``
    in the ground frame (frames,)."""
    slant = np.asarray(altitude_m, dtype=float)[:, None] / np.cos(np.asarray(zenith_rad, dtype=float))[None]
    wind = np.abs(np.asarray(wind_m_s, dtype=float))[:, None]
    return slant * np.abs(np.asarray(rate_rad_s, dtype=float))[None] + wind


def longest_interval_s(coherence_s, crossing_s, response_s, factor: float) -> np.ndarray:
    """The longest render interval [s]: ``min(1 / rate, factor min(tau0, tau_pix))`` (module docstring)."""
    return np.minimum(crossing_s, factor * np.minimum(coherence_s, response_s))


def interval_multiples(longest_s, cadence_ns: int) -> np.ndarray:
    """``m`` [1]: the largest power of two with ``m cadence <= longest_s`` (at least 1; unknown: 1)."""
    ratio = np.asarray(longest_s, dtype=float) / (cadence_ns * 1e-9)
    doublings = np.clip(np.floor(np.log2(np.where(ratio > 0, ratio, 1.0))), 0, MAX_DOUBLINGS)   # log2(inf): the cap
    doublings = np.where(np.isnan(ratio), 0, doublings)
    return (2 ** doublings.astype(np.int64)).astype(np.int64)


class RenderInterval:
    """Each frame's render interval ``m`` for a source (module docstring), from the block's per-frame inputs.

    ``atmosphere`` None (vacuum) leaves ``tau0`` infinite; ``pixels`` None (no ``detector``) leaves ``tau_pix``
    unbounded (the pixels' response is unknown; the other two bounds stand). ``factor`` [1]: how many of ``tau0``
    or ``tau_pix`` a held stamp may span.
    """

    def __init__(self, atmosphere: Atmosphere | None, wavelength_m: float, pixel_scale_rad: float,
                 pixels: PixelView | None, factor: float):
        self.pixels, self.factor, self.pixel_scale = pixels, float(factor), float(pixel_scale_rad)
        self.layers = None
        if atmosphere is not None and atmosphere.layers and atmosphere.total_cn2_dh > 0:
            cn2 = np.array([layer.cn2_dh for layer in atmosphere.layers])
            self.layers = (cn2 / cn2.sum(), np.array([layer.altitude_m for layer in atmosphere.layers]),
                           np.array([layer.wind_speed_m_s for layer in atmosphere.layers]),
                           atmosphere.r0(wavelength_m, 0.0))

    def coherence_s(self, zenith_rad: np.ndarray, sight_rate_px_s: np.ndarray) -> np.ndarray:
        """``tau0`` [s] of each frame's line of sight (module docstring); infinite in vacuum or above the air."""
        zenith = np.asarray(zenith_rad, dtype=float)
        if self.layers is None:
            return np.full(zenith.shape, np.inf)
        fraction, altitude, wind, r0_zenith = self.layers
        turbulent = np.isfinite(zenith)
        z = np.where(turbulent, zenith, 0.0)
        omega = np.where(np.isfinite(sight_rate_px_s), sight_rate_px_s, 0.0) * self.pixel_scale     # [rad/s]
        tau0 = coherence_time_s(r0_zenith * np.cos(z) ** (3 / 5), fraction,
                                fastest_footprint_speeds(altitude, wind, z, omega))
        return np.where(turbulent, tau0, np.inf)

    def response_s(self, source_photon_s: np.ndarray, sky_photon_s: np.ndarray) -> np.ndarray:
        """``tau_pix`` [s] with all of the source's collected flux on one pixel over the sky (no bound, infinite,
        without a detector: the pixels are unknown)."""
        source = np.asarray(source_photon_s, dtype=float)
        if self.pixels is None:
            return np.full(source.shape, np.inf)
        return self.pixels.response_time_s(source + np.asarray(sky_photon_s, dtype=float))

    def multiples(self, cadence_ns: int, seen: np.ndarray, zenith_rad: np.ndarray) -> np.ndarray:
        """``m`` [1] of each frame; ``seen`` (frames, 4): apparent rate [pixel/s], collected flux [photon/s], sky
        [photon/s per pixel], rate of the line of sight in the ground frame [pixel/s] (the block's ``seen``).
        An unknown rate (the run's first input sample) renders every render time."""
        seen = np.asarray(seen, dtype=float)
        rate = seen[:, 0]
        with np.errstate(divide="ignore"):
            crossing = np.where(rate > 0, 1.0 / np.where(rate > 0, rate, 1.0), np.inf)
        longest = longest_interval_s(self.coherence_s(zenith_rad, seen[:, 3]), crossing,
                                     self.response_s(seen[:, 1], seen[:, 2]), self.factor)
        known = np.isfinite(rate) & np.isfinite(seen[:, 3])
        return np.where(known, interval_multiples(longest, cadence_ns), 1)
