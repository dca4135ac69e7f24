"""What the detector's pixels can see of a source: their response time, their threshold, the turbulence they average.

An event pixel does not see the irradiance of one render time. Its photoreceptor low-passes the
photocurrent with the time constant ``tau = 1 / (2 pi f_3dB)`` (paper Eq. 16; the preset's cutoff law
at the pixel's current), and it fires only when its log intensity moves by a threshold ``theta``
(paper Eq. 17). So:

* a source that cannot move any pixel's log intensity by the smallest threshold of the array, even
  with all of its flux in that pixel, makes no event of its own whatever its PSF (it only adds
  to the mean photocurrent, which the long-exposure PSF gets right). A source streaking at ``v``
  pixels per second stays on one pixel at most ``sqrt(2) / v`` (a point crossing the diagonal),
  and a first-order filter driven by a step ``dy`` for a time ``t`` moves by at most
  ``dy (1 - exp(-t / tau))``;
* a source whose turbulence decorrelates many times within ``tau`` shows the pixels the average
  of many short exposures, which tends to the long-exposure PSF (Fried 1966; Roddier 1981).

The turbulence of one layer decorrelates as its footprint moves across the pupil: frozen flow
(Taylor's hypothesis) with the footprint's velocity in the optics' own kinematics
(:meth:`.Imager.footprints`: ``L omega - v_wind``, ``L`` the slant distance and ``omega`` the
rate of the source's line of sight in the ground frame: its apparent rate on a staring mount, the
mount's rate for a tracked satellite, the sidereal rate for a star seen from a tracking mount). The image's tilt, the largest part of a short exposure's
departure from the long exposure when the pixels are larger than ``lambda / r0``, changes over a
shift of one aperture diameter ``D`` (the tilt's temporal spectrum has its corner at
``0.3 v / D``, Conan, Rousset & Madec 1995, JOSA A 12, 1559), the speckle over ``0.31 r0``
(Roddier 1981's coherence time ``tau_0 = 0.31 r0 / v``). Taking ``D`` for every layer is the
conservative choice. A first-order filter of time constant ``tau`` reduces the variance of a
process with correlation time ``t_c`` by ``t_c / (t_c + tau)`` (exponential autocorrelation), so
each layer contributes its share ``c_i`` of the phase variance (``Cn^2 dh`` fraction) divided by
``K_i = 1 + tau / t_i`` to the fluctuation left after the pixel's filter, and

    K_eff = 1 / sum_i (c_i / K_i)

independent short exposures is what the pixel's filter averages. :class:`.PathChooser` turns
``K_eff`` into an error with the probe frames' own error-against-frames curve.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evsda.graph import ParameterError

if TYPE_CHECKING:                       # the pixel package is imported only by a run that names a detector
    from evsda.blocks.pixel.model import PixelModel
    from evsda.blocks.pixel.params import DvsPixelParams

#: threshold margin: the smallest threshold of the array is the mean less this many of its
#: pixel-to-pixel standard deviations (fewer than 3 in 10 million Gaussian draws lie below) [1]
THRESHOLD_SIGMAS = 5.0


def load_pixel_params(path: Path, label: str) -> DvsPixelParams:
    """The ``dvs_pixel`` block's parameters in a sensor preset (a graph file) [-]."""
    import yaml

    from evsda.blocks.pixel.params import DvsPixelParams
    try:
        # libyaml's parser where PyYAML has it (the same document, ~15x faster: ~5 ms of window 0's first step)
        document = yaml.load(Path(path).read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except (OSError, yaml.YAMLError) as exc:
        raise ParameterError(f"{label} parameter 'detector': cannot read {path}: {exc}") from None
    blocks = (document or {}).get("blocks") or {}
    pixels = [b for b in blocks.values() if isinstance(b, dict) and b.get("type") == "dvs_pixel"]
    if len(pixels) != 1:
        raise ParameterError(f"{label} parameter 'detector': expected a sensor preset with one 'dvs_pixel' block, "
                             f"found {len(pixels)} in {path}")
    try:
        return DvsPixelParams(**(pixels[0].get("params") or {}))
    except ValueError as exc:
        raise ParameterError(f"{label} parameter 'detector': the dvs_pixel block of {path}: {exc}") from None


@dataclass(frozen=True)
class PixelView:
    """The detector's pixels as the path choice needs them: response time and threshold at a photon flux.

    Fluxes are photons per second on one pixel [photon s^-1] at the band's wavelength.
    """

    model: PixelModel

    @classmethod
    def of(cls, params: DvsPixelParams, pixel_area_m2: float, wavelength_m: float) -> "PixelView":
        from evsda.blocks.pixel.model import PixelModel
        return cls(PixelModel(params, float(pixel_area_m2), float(wavelength_m)))

    @property
    def threshold_min(self) -> float:
        """The smallest contrast threshold of the array [1] (ln units): mean less ``THRESHOLD_SIGMAS`` spreads."""
        p = self.model.params
        return max(min(p.threshold_on, p.threshold_off) - THRESHOLD_SIGMAS * p.threshold_sigma, p.threshold_floor)

    def log_step(self, source_photon_s: float, floor_photon_s: float) -> float:
        """Change of the photoreceptor's log output [1] when ``source_photon_s`` lands on a pixel that sees
        ``floor_photon_s`` (paper Eqs. 12-15: the lin-log response, dark current included)."""
        y = self.model.drive(np.array([floor_photon_s, floor_photon_s + source_photon_s]), distinct=True).y
        return float(y[1] - y[0])

    def seen_step(self, source_photon_s: float, floor_photon_s: float, rate_px_s: float) -> float:
        """The largest change of the filtered log output [1] a source can make on one pixel: the full
        :meth:`log_step` times ``1 - exp(-t / tau)`` for the longest stay ``t = sqrt(2) / rate`` on a pixel
        (the whole step for a still source), ``tau`` at the brighter current (the faster response)."""
        step = self.log_step(source_photon_s, floor_photon_s)
        if not rate_px_s > 0:
            return step
        tau = self.response_time_s(floor_photon_s + source_photon_s)
        return step if tau <= 0 else step * -np.expm1(-np.sqrt(2.0) / rate_px_s / tau)

    def response_time_s(self, photon_s):
        """The photoreceptor's time constant ``1 / (2 pi f_3dB)`` at this flux [s] (paper Eq. 16, the preset's
        cutoff law; 0 without a filter); a float for a number, an array for an array of fluxes."""
        eps = self.model.drive(np.atleast_1d(np.asarray(photon_s, dtype=float)), distinct=True).eps
        # backward Euler gain eps = w / (w + 1), w = 2 pi dt f_3dB, so tau = dt / w = dt (1 - eps) / eps
        with np.errstate(divide="ignore", invalid="ignore"):
            tau = np.where(eps >= 1.0, 0.0, self.model.dt_s * (1.0 - eps) / eps)
        return float(tau[0]) if np.ndim(photon_s) == 0 else tau.reshape(np.shape(photon_s))


def averaged_frames(tau_s: float, cn2_fraction: np.ndarray, speed_m_s: np.ndarray, diameter_m: float) -> float:
    """``K_eff`` [1]: independent short exposures a first-order filter of time constant ``tau_s`` averages
    (module docstring) for layers holding ``cn2_fraction`` of the turbulence whose footprints move at
    ``speed_m_s`` across an aperture ``diameter_m``."""
    c = np.asarray(cn2_fraction, dtype=float)
    with np.errstate(divide="ignore"):
        shift_time = np.where(np.asarray(speed_m_s) > 0, diameter_m / np.asarray(speed_m_s, dtype=float), np.inf)
    k = 1.0 + tau_s / shift_time
    return float(1.0 / np.sum(c / k))


def footprint_speeds(altitude_m: np.ndarray, wind_m_s: np.ndarray, zenith_rad: float, rate_rad_s: float) -> np.ndarray:
    """The slowest each layer's footprint can move [m/s] for a source at angular rate ``rate_rad_s`` in an
    unknown direction: ``| L |omega| - |v_wind| |`` (``L = h sec zeta``; :meth:`.Imager.footprints`)."""
    slant = np.asarray(altitude_m, dtype=float) / np.cos(zenith_rad)
    return np.abs(slant * rate_rad_s - np.asarray(wind_m_s, dtype=float))
