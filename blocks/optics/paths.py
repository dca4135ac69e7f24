"""Which PSF path a scene needs: error estimates of the fast paths against the reference, and the choice.

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
  same screens (:meth:`.PathChooser.pupil_error`), decided with the mean's standard error
  (:func:`pupil_verdict`: the ~100x slower reference is taken only when the probes show the pupil
  path's error above the tolerance). The source's own Fresnel number
  ``N_F = D^2 / (lambda R)`` only sets the defocus of a telescope focused at infinity,
  which the pupil path includes exactly (Fresnel approximation); in vacuum the two paths
  are the same physics.
* ``airy`` and ``long_exposure`` vs ``pupil_fft``: measured by a probe, the mean distance
  over ``PROBE_FRAMES`` turbulent pupil-path stamps at random sub-pixel positions (a
  fixed-seed draw, so a choice is a pure function of the conditions); the error against
  the reference adds the pupil path's (triangle inequality).

:class:`PathChooser` makes these estimates once per bin of conditions (1 degree of zenith
angle, 5 % of range; the pupil path's error on coarser bins, which, with the block's ``share_far_probes`` (on by
default), a finite-range bin shares with the far one where its propagation is the far source's:
:meth:`PathChooser._shares_far`) and keeps each choice, so a
choice is a pure function of the bin and of the run's seed. The probes' results are also kept
on disk across runs (:data:`PROBE_CACHE`, keyed by everything they read and this package's source):
a run that meets the same inputs again reads the same numbers instead of measuring them.

**What the pixels see** (with a detector, the block's ``detector``: :mod:`.pixel_view`). The
error that matters is that of the image the pixels respond to, the irradiance low-passed by the
photoreceptor, not that of one render time. Bins then also hold the source's apparent rate, its
flux, the sky and the rate its line of sight turns in the ground frame (factors of 2; the last moves
its footprints through the layers, :meth:`.Imager.sight`: on a tracking mount the satellite's, not the
streaking stars'), and each bin's estimate is taken at the bin's worst edge:

* a source that cannot move any pixel's filtered log intensity by the array's smallest threshold,
  even with all of its flux on one pixel above the darkest sky of the bin for the longest time its
  slowest rate allows (:meth:`.PixelView.seen_step`), takes ``long_exposure`` (it makes no event of
  its own; the long-exposure PSF gives its mean irradiance);
* otherwise the pixel's filter (time constant ``tau`` at the brightest current the source can make)
  averages ``K_eff`` independent short exposures (:func:`.pixel_view.averaged_frames`, at the
  slowest footprint speeds the bin's line-of-sight rate allows), and an analytic path's error is its distance from the
  mean of ``K_eff`` pupil-path frames: ``sqrt(b^2 + s^2 / K)`` fitted to the probe's distances of
  means of 1, 2, 3, 4, 6, 8, 12 and 24 frames held at one position, averaged over 8 positions
  (``b``: the bias left when the turbulence is averaged away, ``s``: one frame's fluctuation).
"""

from __future__ import annotations

import logging
import threading
import zlib
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from evsda.blocks.threads import worker_threads
from evsda.graph.result_cache import ResultCache
from evsda.graph.threads import parallel_map

from .fft_screens import fft_phase_screen_corners
from .pixel_view import averaged_frames, footprint_speeds
from .reference_path import FAR_RANGE_M

if TYPE_CHECKING:
    from .analytic_path import AnalyticPath
    from .imaging import Imager
    from .pixel_view import PixelView

PATHS = ("airy", "long_exposure", "pupil_fft", "reference")
#: the paths rendered from a tabulated radial PSF (:mod:`.analytic_path`)
ANALYTIC_PATHS = ("airy", "long_exposure")
#: turbulent pupil-path frames the analytic paths are measured against [1]
PROBE_FRAMES = 24
LOG = logging.getLogger("evsda.blocks.optics")
#: zenith-angle bin of path decisions [rad] and range bin (ratio) [1]
ZENITH_BIN_RAD = np.deg2rad(1.0)
RANGE_BIN_RATIO = 1.05
#: the pupil path's error against the reference is measured on coarser bins: 10 degrees, factors of 2 in range
PUPIL_ERROR_ZENITH_BIN_RAD = np.deg2rad(10.0)
#: reference propagations per pupil-error bin, made in pairs (the two halves of each FFT draw,
#: :meth:`.ReferencePath.probe_pair`): at least the first, then two more at a time, up to the second,
#: while :func:`pupil_verdict` is open
REFERENCE_PROBE_FRAMES = (4, 24)
#: standard errors of the mean by which the measured pupil error must clear the tolerance: below it, to take
#: the pupil path before the cap; above it on every frame, to reject it for the ~100x slower reference [1]
ACCEPT_STANDARD_ERRORS = 2.0
REJECT_STANDARD_ERRORS = 3.0
#: predictive standard errors by which the frames still to come would have to average above the mean so far for the
#: rejection on every frame to remain possible; beyond them the probes stop, within (:func:`futile_rejection`) [1]
FUTILITY_STANDARD_ERRORS = 3.0
#: frames before a rejection is judged out of reach (a spread from fewer frames of a skewed distribution is too low) [1]
FUTILITY_FRAMES = 6
#: frames per mean in the averaging fit (divisors of PROBE_FRAMES) [1]
AVERAGED_GROUPS = (1, 2, 3, 4, 6, 8, 12, 24)
#: positions (the probe's first sub-pixel offsets) the averaging fit holds its frames at [1]
AVERAGED_POSITIONS = 8
#: the apparent rate below which a source counts as still [pixel/s]
STILL_RATE_PX_S = 1.0
#: bins of what the pixels see: factor 2 of rate [pixel/s], source flux [photon/s] and sky [photon/s per pixel]
SEEN_BIN_RATIO = 2.0
#: the probes' results kept across runs (a sweep repeats conditions), keyed by everything they read (the
#: telescope, atmosphere, band, sampling, tolerance, seed, conditions: ``PathChooser._remembered``) and the
#: source of this package (the code that computes them)
PROBE_CACHE = ResultCache("optics-path-probes", [Path(__file__).parent], ("numpy", "scipy", "numba", "llvmlite"))
#: the block's ``share_far_probes`` (False: every range bin probed on its own, the reference): a finite-range
#: pupil-error bin whose scintillation term is within this fraction of the far bin's, at the same zenith-angle bin,
#: takes the far bin's reference probes (:meth:`PathChooser._shares_far`) [1]
SHARED_FAR_TOLERANCE = 0.05
#: ... and whose source's defocus (telescope focused at infinity) is at most this rms over the pupil [rad]
SHARED_FAR_DEFOCUS_RAD = 0.1


def spherical_wave_ratio(layers, zenith_rad: float, range_m: float) -> float:
    """The ratio [1] of the Rytov variance of a point source at slant range ``range_m`` [m] to that of a plane wave
    through the same ``layers`` at zenith angle ``zenith_rad`` (rad): ``sum J z^(5/6) (1 - z/R)^(5/6) / sum J
    z^(5/6)``, each layer's ``J = Cn^2 dh`` at slant distance ``z`` from the aperture (weak fluctuations, Andrews &
    Phillips 2005, Laser Beam Propagation through Random Media, 2nd ed., Ch. 8: the spherical wave's
    ``[z (1 - z/R)]^(5/6)`` against the plane wave's ``z^(5/6)``); 0 where a turbulent layer is not before the
    source."""
    cn2 = np.array([layer.cn2_dh for layer in layers])
    slant = np.array([layer.altitude_m for layer in layers]) / np.cos(zenith_rad)
    turbulent = (cn2 > 0) & (slant > 0)
    cn2, slant = cn2[turbulent], slant[turbulent]
    if not cn2.size or slant.max() >= range_m:
        return 0.0 if cn2.size else 1.0
    plane = cn2 * slant ** (5 / 6)
    return float(np.sum(plane * (1.0 - slant / range_m) ** (5 / 6)) / np.sum(plane))


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


def pick(estimates: dict[str, float], tolerance: float, context: str,
         kept: dict[str, str] | None = None) -> PathChoice:
    """The cheapest path whose estimated error is within ``tolerance`` (the reference otherwise); ``kept``: paths
    within it by a verdict on their estimate's precision though the estimate is above it, each with why."""
    kept = kept or {}
    for path in PATHS:
        if estimates.get(path, np.inf) <= tolerance or path in kept:
            break
    others = ", ".join(f"{p} {estimates[p]:.3g}" for p in PATHS if p in estimates and p != path)
    error = estimates.get(path, 0.0)
    if path == "reference":
        reason = f"path 'reference': no faster path within tolerance {tolerance:g} ({context}; other paths: {others})"
    else:
        verdict = kept[path] if path in kept and error > tolerance else f"<= tolerance {tolerance:g}"
        reason = f"path '{path}': estimated error {error:.3g} {verdict} ({context}; other paths: {others})"
    return PathChoice(path, dict(estimates), reason)


@dataclass(frozen=True)
class PupilError:
    """The pupil path's error against the reference in one bin: ``error``, the larger of the measured mean and
    the scintillation term [1]; the mean's ``standard_error`` [1] over ``frames`` reference frames; ``within``:
    :func:`pupil_verdict`'s answer; ``verdict``: why, in words."""

    error: float
    standard_error: float
    frames: int
    within: bool
    verdict: str


def futile_rejection(mean: float, spread: float, n: int, tolerance: float, cap: int) -> float | None:
    """How many predictive standard errors [1] above the mean of the ``n`` frames so far the ``cap - n`` frames
    still to come would have to average for the mean of all ``cap`` to clear ``tolerance`` by
    :data:`REJECT_STANDARD_ERRORS` standard errors (taken at the spread so far, ``spread``, their sample standard
    deviation [1]); None when that is not more than :data:`FUTILITY_STANDARD_ERRORS`, or no frame is left.

    The rejection on every frame needs ``mean_cap - 3 spread / sqrt(cap) > tolerance``, so the frames left must
    average ``need = (cap (tolerance + 3 spread / sqrt(cap)) - n mean) / (cap - n)``. What they average is
    predicted about the mean so far with the standard error ``spread sqrt(1 / (cap - n) + 1 / n)`` (their own
    spread and the mean's uncertainty: the predictive distribution of a normal mean, Spiegelhalter, Freedman &
    Blackburn 1986, Controlled Clinical Trials 7, 8, Eq. 2): a rejection further than 3 of them away is
    stochastically curtailed (Lan, Simon & Halperin 1982, Commun. Statist. C 1, 207).
    """
    left = cap - n
    if left <= 0:
        return None
    need = (cap * (tolerance + REJECT_STANDARD_ERRORS * spread / np.sqrt(cap)) - n * mean) / left
    predicted = spread * np.sqrt(1.0 / left + 1.0 / n)
    if need - mean <= FUTILITY_STANDARD_ERRORS * predicted:
        return None
    return float((need - mean) / predicted) if predicted > 0 else float("inf")


def pupil_verdict(distances: list[float], scintillation: float, tolerance: float,
                  frames: tuple[int, int] = REFERENCE_PROBE_FRAMES, curtail: bool = True) -> tuple[bool, str] | None:
    """Whether the pupil path is within ``tolerance`` from the reference frames measured so far, with why; None
    while the probes should measure more.

    The tolerance is the user's budget for the *expected* fraction of the flux a path misplaces, and the frames
    measure it with a standard error ``se`` (their spread / sqrt(count)); the scintillation term is a floor:

    * within, once ``frames[0]`` frames are in, when ``max(mean + 2 se, scintillation) <= tolerance``
      (:data:`ACCEPT_STANDARD_ERRORS`): the error is clearly within the budget;
    * beyond when the scintillation term alone is above it (no frame needed), or on all ``frames[1]`` frames
      when ``mean - 3 se > tolerance`` (:data:`REJECT_STANDARD_ERRORS`): the error is shown to exceed the
      budget, and only then is the ~100x slower reference taken (rejecting on fewer frames would save probe
      time only where the run then costs ~100x more; a few frames of a skewed distribution understate its
      spread);
    * otherwise within at ``frames[1]`` frames: the error cannot be told from the budget at the probes'
      precision (the mean is at most ``tolerance + 3 se``), and a path ~100x slower is not taken on that (by the
      mean alone, an error equal to the tolerance would go either way by the seed);
    * with ``curtail``, within before ``frames[1]``, from :data:`FUTILITY_FRAMES` on, once that rejection is out of
      reach (:func:`futile_rejection`): the verdict of all ``frames[1]`` frames, but for ~0.1 % of the seeds of an
      error between 1.2x and 3x the tolerance (close calls the full rule rejects), on fewer frames.
    """
    if scintillation > tolerance:
        return False, f"> tolerance {tolerance:g}: the scintillation term alone exceeds it"
    n = len(distances)
    if n < frames[0]:
        return None
    mean = float(np.mean(distances))
    spread = float(np.std(distances, ddof=1))
    se = float(spread / np.sqrt(n))
    high = max(mean + ACCEPT_STANDARD_ERRORS * se, scintillation)
    if high <= tolerance:
        return True, f"<= tolerance {tolerance:g} at {ACCEPT_STANDARD_ERRORS:g} standard errors ({high:.3g})"
    if n < frames[1]:
        if not curtail or n < FUTILITY_FRAMES:
            return None
        futile = futile_rejection(mean, spread, n, tolerance, frames[1])
        if futile is None:
            return None
        return True, (f"<= tolerance {tolerance:g}: rejecting it on {frames[1]} frames would need the "
                      f"{frames[1] - n} left {futile:.2g} predictive standard errors above the mean of {n}")
    low = max(mean - REJECT_STANDARD_ERRORS * se, scintillation)
    if low > tolerance:
        return False, f"> tolerance {tolerance:g} at {REJECT_STANDARD_ERRORS:g} standard errors ({low:.3g})"
    return True, (f"+- {se:.2g} (1 SE) is not shown above tolerance {tolerance:g} on {n} reference frames "
                  f"(mean - {REJECT_STANDARD_ERRORS:g} SE = {low:.3g}): within the budget at the probes' precision")


def conditions_key(zenith_rad: float, range_m: float, turbulent: bool) -> tuple[int, int]:
    """Bin of the conditions one path choice holds for: ``ZENITH_BIN_RAD`` of zenith angle (-1 without
    turbulence) and ``RANGE_BIN_RATIO`` of range (-1 at or beyond ``FAR_RANGE_M``)."""
    z = -1 if not turbulent else int(np.floor(zenith_rad / ZENITH_BIN_RAD))
    far = not np.isfinite(range_m) or range_m >= FAR_RANGE_M
    r = -1 if far else int(np.floor(np.log(range_m) / np.log(RANGE_BIN_RATIO)))
    return z, r


def seen_key(rate_px_s: float, source_photon_s: float, sky_photon_s: float,
             sight_rate_px_s: float | None = None) -> tuple[int, int, int, int]:
    """Bin of what the pixels see: factors of ``SEEN_BIN_RATIO`` of the apparent rate (-1 below
    ``STILL_RATE_PX_S`` or unknown), of the source's collected flux and of the sky per pixel (-1 below 1),
    and of the rate its line of sight turns in the ground frame [pixel/s] (as the apparent rate; a staring
    mount's, the apparent rate, when not given)."""
    def log_bin(value: float, least: float) -> int:
        return int(np.floor(np.log(value) / np.log(SEEN_BIN_RATIO))) if value >= least else -1
    rate = float(rate_px_s) if np.isfinite(rate_px_s) else 0.0
    sight = rate if sight_rate_px_s is None else float(sight_rate_px_s) if np.isfinite(sight_rate_px_s) else 0.0
    return (log_bin(rate, STILL_RATE_PX_S), log_bin(float(source_photon_s), 1.0), log_bin(float(sky_photon_s), 1.0),
            log_bin(sight, STILL_RATE_PX_S))


def seen_edges(key: tuple[int, int, int, int]) -> tuple[float, float, float, float, float]:
    """The bin's worst edges: slowest rate [pixel/s], brightest source [photon/s], darkest and brightest sky
    [photon/s per pixel] (each the one that makes the pixels see more of the turbulence), and the slowest turn
    of the line of sight [pixel/s]."""
    rate, flux, sky, sight = key
    edge = SEEN_BIN_RATIO
    return (0.0 if rate < 0 else edge**rate, edge ** (flux + 1) if flux >= 0 else 1.0,
            0.0 if sky < 0 else edge**sky, 1.0 if sky < 0 else edge ** (sky + 1), 0.0 if sight < 0 else edge**sight)


def fit_averaged(frames: np.ndarray, distances: np.ndarray) -> tuple[float, float]:
    """``(b, s)`` [1] of ``d(K)^2 = b^2 + s^2 / K`` by least squares on the squares (both clipped at 0)."""
    a = np.stack([np.ones(len(frames)), 1.0 / np.asarray(frames, dtype=float)], axis=1)
    (b2, s2), *_ = np.linalg.lstsq(a, np.asarray(distances, dtype=float) ** 2, rcond=None)
    if s2 < 0:
        b2, s2 = float(np.mean(np.asarray(distances) ** 2)), 0.0
    if b2 < 0:
        b2, s2 = 0.0, float(np.sum(np.asarray(distances) ** 2 / frames) / np.sum(1.0 / np.asarray(frames) ** 2))
    return float(np.sqrt(b2)), float(np.sqrt(s2))


def averaged_distance(fit: tuple[float, float], k_eff: float) -> float:
    """The distance [1] of the mean of ``k_eff`` frames from the fit ``(b, s)`` of :func:`fit_averaged`."""
    b, s = fit
    return float(np.sqrt(b * b + s * s / max(k_eff, 1.0)))


def representative_conditions(key: tuple[int, int]) -> tuple[float, float]:
    """The zenith angle [rad] (NaN: no turbulence) and range [m] (inf: far) at the centre of a bin."""
    z, r = key
    zenith = np.nan if z < 0 else (z + 0.5) * ZENITH_BIN_RAD
    range_m = np.inf if r < 0 else RANGE_BIN_RATIO ** (r + 0.5)
    return zenith, range_m


class PathChooser:
    """The path of each bin of conditions and the error estimates behind it, each made once and kept.

    Reads the telescope, atmosphere, sampling, renderers and paths of ``imager``;
    ``forced_path`` is the block's ``psf_path`` (``auto``: the cheapest within ``imager.tolerance``);
    ``share_far`` its ``share_far_probes`` (:meth:`_shares_far`).
    """

    def __init__(self, imager: Imager, forced_path: str, pixels: PixelView | None = None, share_far: bool = False):
        self.imager, self.forced_path, self.pixels = imager, forced_path, pixels
        self._choices: dict[tuple, PathChoice] = {}
        self._pupil_errors: dict[tuple, float] = {}
        self._estimates: dict[tuple, tuple[dict, dict]] = {}
        self._ahead: dict[tuple, Any] = {}       # probes made by probe_ahead, until their bins' choices take them
        self._scintillation: dict[tuple, float] = {}   # scintillation index of each pupil-error bin
        self.share_far = bool(share_far)
        self._shared_far: dict[tuple, bool] = {}        # whether a finite-range pupil-error bin takes the far one's

    def key(self, zenith_rad: float, range_m: float, seen: tuple | None = None) -> tuple:
        """The bin of these conditions (:func:`conditions_key`), with what the pixels see
        (``seen``: rate [pixel/s], source flux [photon/s], sky [photon/s per pixel] and, optionally, the line of
        sight's rate in the ground frame [pixel/s]; :func:`seen_key`)
        when the chooser knows the detector and decides (``psf_path: auto``) in turbulence."""
        key = conditions_key(zenith_rad, range_m, self.imager.turbulent(zenith_rad))
        if seen is None or self.pixels is None or self.forced_path != "auto" or key[0] < 0:
            return key
        return key + seen_key(*seen)

    def keys(self, zenith_rad: np.ndarray, range_m: np.ndarray, seen: np.ndarray | None = None) -> list[tuple]:
        """:meth:`key` of every frame (``seen`` (F, 3) or (F, 4), or None), the same numbers computed array-wise."""
        z, r = np.asarray(zenith_rad, dtype=float), np.asarray(range_m, dtype=float)
        turbulent = np.isfinite(z) & (self.imager.atmosphere is not None)
        with np.errstate(invalid="ignore", divide="ignore"):
            z_bin = np.where(turbulent, np.floor(z / ZENITH_BIN_RAD), -1.0).astype(np.int64).tolist()
            far = ~np.isfinite(r) | (r >= FAR_RANGE_M)
            r_bin = np.where(far, -1.0, np.floor(np.log(np.where(far, 1.0, r)) / np.log(RANGE_BIN_RATIO)))
            r_bin = r_bin.astype(np.int64).tolist()
            if seen is None or self.pixels is None or self.forced_path != "auto":
                return list(zip(z_bin, r_bin))
            seen = np.asarray(seen, dtype=float)
            rate = np.where(np.isfinite(seen[:, 0]), seen[:, 0], 0.0)
            sight = rate if seen.shape[1] < 4 else np.where(np.isfinite(seen[:, 3]), seen[:, 3], 0.0)
            bins = []
            for value, least in ((rate, STILL_RATE_PX_S), (seen[:, 1], 1.0), (seen[:, 2], 1.0),
                                 (sight, STILL_RATE_PX_S)):
                above = value >= least
                logs = np.floor(np.log(np.where(above, value, 1.0)) / np.log(SEEN_BIN_RATIO))
                bins.append(np.where(above, logs, -1.0).astype(np.int64).tolist())
        if min(z_bin, default=0) >= 0:                       # every frame in turbulence: all six numbers
            return list(zip(z_bin, r_bin, *bins))
        return [(z, r) if z < 0 else (z, r, *extra) for z, r, *extra in zip(z_bin, r_bin, *bins)]

    def is_chosen(self, zenith_rad: float, range_m: float, seen: tuple | None = None) -> bool:
        return self.key(zenith_rad, range_m, seen) in self._choices

    def choose(self, zenith_rad: float, range_m: float, source: str = "", seen: tuple | None = None) -> PathChoice:
        """The path for these conditions (forced, or the cheapest within tolerance); logged once per bin."""
        return self.choose_key(self.key(zenith_rad, range_m, seen), zenith_rad, source)

    def choose_key(self, key: tuple, zenith_rad: float, source: str = "") -> PathChoice:
        """The path of a bin (:meth:`key`) met at ``zenith_rad`` [rad]: made and logged the first time."""
        if key not in self._choices:
            self.imager.ensure_geometry(zenith_rad)
            zenith, range_rep = representative_conditions(key[:2])
            context = self._context(zenith, range_rep)
            if self.forced_path != "auto":
                choice = PathChoice(self.forced_path, {}, f"path '{self.forced_path}' forced by psf_path ({context})")
            elif len(key) > 2:
                choice = self._choose_seen(zenith, range_rep, key[2:], context)
            else:
                choice = pick(self.estimate_errors(zenith, range_rep), self.imager.tolerance, context,
                              self.kept(zenith, range_rep))
            self._choices[key] = choice
            LOG.info("%s%s: %s", self.imager.label, f" source {source}" if source else "", choice.reason)
        return self._choices[key]

    def _context(self, zenith_rad: float, range_m: float) -> str:
        """The conditions that set the errors, in words: ``D/r0`` and the source's Fresnel number ``D^2/(lambda R)``."""
        imager = self.imager
        d = imager.telescope.diameter_m
        parts = []
        if imager.turbulent(zenith_rad):
            parts.append(f"D/r0 = {d / imager.r0(zenith_rad):.3g} at zenith angle {np.rad2deg(zenith_rad):.1f} deg")
        else:
            parts.append("no atmosphere")
        if np.isfinite(range_m):
            parts.append(f"Fresnel number D^2/(lambda R) = {d**2 / (imager.wavelength * range_m):.3g}")
        return ", ".join(parts)

    def estimate_errors(self, zenith_rad: float, range_m: float) -> dict[str, float]:
        """Estimated error [1] of each path against the reference (module docstring): the analytic paths'
        mean distance from ``PROBE_FRAMES`` pupil-path stamps (one without turbulence) plus the pupil path's."""
        return dict(self._probe(zenith_rad, range_m)[0])

    def _seen_step(self, seen: tuple[int, int, int, int]) -> float:
        """The most a source of this bin of what the pixels see can move a pixel's filtered log intensity [1]
        (:meth:`.PixelView.seen_step` at the bin's worst edges)."""
        rate_px_s, source, sky_low, _, _ = seen_edges(seen)
        return self.pixels.seen_step(source, sky_low, rate_px_s)

    def _probed(self, key: tuple) -> tuple[float, float] | None:
        """The conditions (zenith angle [rad], range [m]) whose probes (:meth:`_probe`) the choice of bin ``key``
        makes, or None where it makes none (a forced path; a source no pixel can see, :meth:`_choose_seen`)."""
        if self.forced_path != "auto":
            return None
        if len(key) > 2 and self._seen_step(key[2:]) < self.pixels.threshold_min:
            return None
        return representative_conditions(key[:2])

    def probe_ahead(self, zenith_rad: np.ndarray, range_m: np.ndarray, seen: np.ndarray | None,
                    visible: np.ndarray, end_bins: list[tuple] | None = None) -> None:
        """Make, side by side on the process's cores, every probe that the choices of a window's bins (:meth:`keys`)
        will need and that no earlier choice made: the reference frame pairs of every pupil-error bin and the
        analytic-path probes of every bin, in one schedule (:meth:`_measure`). The choices then take them as they
        are made, in the same order and with the same numbers as without this call (each probe is a function of its
        bin and the seed alone, each bin's verdict taken pair by pair in order).

        ``zenith_rad``, ``range_m`` (frames, tracks), ``seen`` (frames, tracks, 3 or 4) as for :meth:`keys`, and
        ``visible`` (frames, tracks): the frames in view. Only each track's first and last frame in view are
        looked at (0.4 ms a window for all of them, at every window; a bin met only in between is probed when its
        choice is made, as without this call); ``end_bins``: their bins (:meth:`keys`), every track's first frame's then
        every track's last frame's, where the caller has them already (the block's keys of every frame in view).

        A window's sources meet several bins at once (the first window of a run all of them): made one choice
        after another, each bin's probes ran alone, on both cores only where a bin had two frame pairs to
        measure at a time."""
        if end_bins is None:
            tracks = np.flatnonzero(visible.any(axis=0))
            if not tracks.size:
                return
            first = visible[:, tracks].argmax(axis=0)
            last = len(visible) - 1 - visible[::-1, tracks].argmax(axis=0)
            at = (np.concatenate([first, last]), np.concatenate([tracks, tracks]))
            seen = None if seen is None else np.asarray(seen, dtype=float)[at]
            end_bins = self.keys(np.asarray(zenith_rad, dtype=float)[at], np.asarray(range_m, dtype=float)[at], seen)
        wanted: dict[tuple[float, float], None] = {}
        for key in dict.fromkeys(end_bins):
            if key not in self._choices:
                conditions = self._probed(key)
                if conditions is not None and conditions not in self._estimates:
                    wanted[conditions] = None
        runs: dict[tuple, tuple[_PairRun, dict]] = {}
        analytic: dict[float, list[tuple[float, float]]] = {}      # by zenith angle: the bins sharing a table
        for zenith, range_m_ in wanted:
            reference = self._reference_bin(zenith, range_m_)
            if reference is not None:
                key, conditions, _ = reference
                if key not in self._pupil_errors and key not in runs and not self._made("reference", conditions):
                    runs[key] = (_PairRun(key, conditions["zenith_rad"], conditions["range_m"],
                                          conditions["scintillation"], self.imager.tolerance), conditions)
            if not self._made("analytic", {"zenith_rad": zenith, "range_m": range_m_}):
                analytic.setdefault(zenith, []).append((zenith, range_m_))
        if not runs and not analytic:
            return
        made = self._measure([run for run, _ in runs.values()], list(analytic.values()))
        for key, (_, conditions) in runs.items():
            self._ahead[self._ahead_key("reference", conditions)] = made["reference", key]
        for group in analytic.values():
            for zenith, range_m_ in group:
                conditions = {"zenith_rad": zenith, "range_m": range_m_}
                self._ahead[self._ahead_key("analytic", conditions)] = made["analytic", (zenith, range_m_)]

    def _made(self, probe: str, conditions: dict) -> bool:
        """Whether a probe's result is already at hand: made ahead, or kept across runs (:meth:`_remembered`)."""
        if self._ahead_key(probe, conditions) in self._ahead:
            return True
        return PROBE_CACHE.folder() is not None and PROBE_CACHE.get(self._cache_key(probe, conditions))[0]

    def _measure(self, runs: list[_PairRun], analytic: list[list[tuple[float, float]]]) -> dict[tuple, Any]:
        """The reference frame pairs of ``runs`` until each one's verdict, and the analytic-path probes of
        ``analytic`` (groups of conditions, one group per zenith-angle bin: they share its long-exposure table), on
        every core (:func:`.parallel_map`). Each thread takes, in turn:

        * the pupil renderer (made once; where it holds the run's first call of compiled code, that loads Numba's
          typing and target contexts, ~0.2 s of interpreter, which every compiled call waits for), else
        * a part of a group's analytic-path tables (:meth:`.AnalyticPath.table_parts`: a long-exposure table's
          two halves; the profile's Bessel functions leave the interpreter free, so they run while the renderer
          is made), else
        * a bin's first pairs (which every verdict needs; the first of every bin before the second of any, so that
          two threads do not make the same grid's screen spectra and transfer functions side by side), else an
          analytic group, else
        * the next pair of a bin none of whose pairs is being measured, else (rather than idle) the next pair of
          any open bin (dropped after its first frame if a pair before it decides: at most one a thread), but for a
          bin whose pair being measured would decide were its frames the mean so far (:meth:`_PairRun.likely_decided`):
          the thread waits for that pair instead (a pair made to be dropped costs a pair's CPU and saves no wall).

        A pair's screens and Fresnel propagations need no renderer: they do not wait for it, only their stamps do
        (a thread that would wait makes table parts meanwhile).

        Returns ``{("reference", key): (distances, verdict), ("analytic", conditions): (distances, fits)}``."""
        least = (REFERENCE_PROBE_FRAMES[0] + 1) // 2
        groups = list(enumerate(analytic))
        # each group's tables not made yet (path, zenith angle, parts' values) and their parts as units
        tables: list[list[tuple[AnalyticPath, float, list]]] = [[] for _ in groups]
        parts, planned = [], set()
        for i, group in groups:
            zenith = group[0][0]
            for name in ANALYTIC_PATHS:
                path = self.imager.path_named[name]
                todo = path.table_parts(zenith)
                if todo and (name, path.table_key(zenith)[0]) not in planned:
                    planned.add((name, path.table_key(zenith)[0]))
                    tables[i].append((path, zenith, [None] * len(todo)))
                    parts += [("part", i, len(tables[i]) - 1, j, part) for j, part in enumerate(todo)]
        left = [sum(len(values) for _, _, values in group) for group in tables]
        tabled = [threading.Event() for _ in groups]
        for i, count in enumerate(left):
            if not count:
                tabled[i].set()
        rendering = threading.Event()
        lock = threading.Lock()
        changed = threading.Condition(lock)        # a unit ended: a pair's verdict may have moved, or one failed
        renderer: list[bool] = []
        failed: list[bool] = []
        out: dict[tuple, Any] = {}

        def next_unit() -> tuple | None:
            if failed:
                return None
            if not renderer:
                renderer.append(True)
                return ("renderer",)
            if parts:
                return parts.pop(0)
            first = [run for run in runs if run.verdict is None and run.taken < least]
            if first:                              # bin by bin (its grid's spectra, transfer functions: made once)
                run = min(first, key=lambda run: run.taken)
                return "pair", run, run.take()
            if groups:
                return ("analytic", *groups.pop(0))
            for run in runs:
                if run.open() and run.running == 0:
                    return "pair", run, run.take()
            likely = [run for run in runs if run.open() and run.likely_decided()]
            for run in runs:
                if run.open() and run not in likely:
                    return "pair", run, run.take()
            return ("wait",) if likely else None

        def made(event: threading.Event, make: Callable[[], Any]) -> None:
            try:
                make()
            except BaseException:
                failed.append(True)
                raise
            finally:
                event.set()                        # threads waiting for it go on (and stop if it failed)

        def rendered() -> bool:
            """Wait for the renderer, making table parts meanwhile; False if a unit failed."""
            while not rendering.is_set():
                with lock:
                    unit = parts.pop(0) if parts and not failed else None
                if unit is None:
                    rendering.wait()
                else:
                    run_unit(unit)
            return not failed

        def run_unit(unit: tuple) -> None:
            kind = unit[0]
            if kind == "renderer":
                return made(rendering, lambda: self.imager.pupil_renderer)
            if kind == "part":
                _, i, t, j, part = unit
                try:
                    tables[i][t][2][j] = part()
                except BaseException:
                    failed.append(True)
                    tabled[i].set()
                    raise
                with lock:
                    left[i] -= 1
                    last = not left[i]
                if last:                           # the group's last part: its tables kept, its probes go on
                    made(tabled[i], lambda: [path.keep_table(zenith, values) for path, zenith, values in tables[i]])
                return None
            if kind == "analytic":
                _, i, group = unit
                rendering.wait()
                tabled[i].wait()
                if failed:
                    return
                for zenith, range_m in group:
                    value = self._analytic_distances(zenith, range_m)
                    with lock:
                        out["analytic", (zenith, range_m)] = value
            elif not failed:
                _, run, pair = unit
                # a pair taken while one before it was being measured is dropped after its first frame if that
                # one decided (the verdict, once taken, stays)
                values = self._pair_distances(run.key, run.zenith_rad, run.range_m, pair,
                                              lambda: run.verdict is None, rendered)
                if failed:
                    return
                with lock:
                    run.done(pair, values)

        def worker(_: int) -> None:
            while True:
                with lock:
                    unit = next_unit()
                    while unit == ("wait",):
                        changed.wait()
                        unit = next_unit()
                if unit is None:
                    return
                try:
                    run_unit(unit)
                except BaseException:
                    failed.append(True)
                    raise
                finally:
                    with lock:
                        changed.notify_all()

        threads = worker_threads()
        parallel_map(worker, range(threads), threads)
        for run in runs:
            out["reference", run.key] = (run.measured, run.verdict)
        return out

    def _probe(self, zenith_rad: float, range_m: float) -> tuple[dict[str, float], dict[str, tuple[float, float]]]:
        """The instantaneous estimates of :meth:`estimate_errors` and, for each analytic path, the fit
        ``(b, s)`` of its distance from means of frames at one position (:func:`fit_averaged`); kept per bin
        (and across runs, :meth:`_remembered`)."""
        cache = (zenith_rad, range_m)
        if cache in self._estimates:
            return self._estimates[cache]
        pupil_error = self.pupil_error(zenith_rad, range_m)
        distances, fits = self._remembered(
            "analytic", {"zenith_rad": zenith_rad, "range_m": range_m},
            lambda: self._analytic_distances(zenith_rad, range_m),
            lambda value: {"distances": value[0], "fits": value[1]},
            lambda stored: ({str(k): float(v) for k, v in stored["distances"].items()},
                            {str(k): (float(b), float(s)) for k, (b, s) in stored["fits"].items()}))
        estimates = {"reference": 0.0, "pupil_fft": pupil_error}
        for name in ANALYTIC_PATHS:
            if name in distances:
                estimates[name] = distances[name] + pupil_error
        self._estimates[cache] = (estimates, fits)
        return self._estimates[cache]

    def _analytic_distances(self, zenith_rad: float, range_m: float) -> tuple[dict[str, float],
                                                                               dict[str, tuple[float, float]]]:
        """Each analytic path's mean distance [1] from ``PROBE_FRAMES`` pupil-path stamps (one, and ``airy``
        alone, without turbulence) and, when the chooser knows the detector, its averaging fit."""
        imager = self.imager
        rng = np.random.Generator(np.random.PCG64(zlib.crc32(repr((zenith_rad, range_m, imager.seed)).encode())))
        offsets = rng.uniform(-0.5, 0.5, (PROBE_FRAMES, 2))
        frames = PROBE_FRAMES if imager.turbulent(zenith_rad) else 1
        offsets = offsets[:frames]
        phase = self._probe_phase(rng, zenith_rad, range_m, frames)
        pupil = imager.pupil_renderer.stamps(imager.pupil_amplitude, phase, offsets)
        flux = pupil.sum(axis=(1, 2)).mean()
        distances = {}
        fits = {}
        for name in ANALYTIC_PATHS:
            path = imager.path_named[name]
            analytic = path.stamps(path.renderer(zenith_rad), offsets)     # compiled, the renderer's numbers
            distances[name] = float(total_variation(analytic, pupil, flux).mean())
        if not imager.turbulent(zenith_rad):
            distances.pop("long_exposure")
        elif self.pixels is not None:
            # the same screens held at each of AVERAGED_POSITIONS positions: how an analytic path's distance
            # falls as the frames at one position are averaged (a pixel's share of a PSF depends on where it sits)
            means = {name: np.zeros(len(AVERAGED_GROUPS)) for name in ANALYTIC_PATHS}
            positions = offsets[:AVERAGED_POSITIONS]
            held = np.stack([imager.path_named[name].stamps(imager.path_named[name].renderer(zenith_rad), positions)
                             for name in ANALYTIC_PATHS])         # each path's stamp at each position
            ends = np.cumsum([0, *(PROBE_FRAMES // k for k in AVERAGED_GROUPS)])
            grouped = np.empty((ends[-1], *pupil.shape[1:]), pupil.dtype)   # every group's means, one after another
            for p, offset in enumerate(positions):
                still = np.broadcast_to(offset, offsets.shape)
                pupil = imager.pupil_renderer.stamps(imager.pupil_amplitude, phase, still)
                for k, start, stop in zip(AVERAGED_GROUPS, ends[:-1], ends[1:]):
                    np.mean(pupil.reshape(-1, k, *pupil.shape[1:]), axis=1, out=grouped[start:stop])
                # each path's distance from each mean: the sums of total_variation one frame at a time
                distance = total_variation(grouped, held[:, p, None], flux)
                for i, name in enumerate(ANALYTIC_PATHS):
                    means[name] += [float(distance[i, start:stop].mean()) for start, stop in zip(ends[:-1], ends[1:])]
            for name in ANALYTIC_PATHS:
                fits[name] = fit_averaged(np.array(AVERAGED_GROUPS), means[name] / AVERAGED_POSITIONS)
        return distances, fits

    def _remembered(self, probe: str, conditions: dict, compute: Callable[[], Any], encode: Callable[[Any], Any],
                    decode: Callable[[Any], Any]) -> Any:
        """A probe's result, taken from the cache of probe results kept across runs (:data:`PROBE_CACHE`) when
        the same probe was made on the same inputs before, else ``compute()``'d and kept.

        The key is everything a probe reads besides the code (whose digest the cache adds): the probe's name
        and ``conditions`` (the bin's zenith angle and range, which with the seed name its random streams), the
        telescope, wavelength, atmosphere (every layer and the outer scale), pixel scale, sampling (the pupil
        and stamp grids, the layers' screens), the reference grid, tolerance, focus, the run's seed, whether
        the detector's averaging is probed, whether finite-range bins share the far bin's probes (``share_far``),
        and the probes' frame counts and bins. With the cache off (``EVSDA_CACHE=off``) the key is not made (~1 ms
        of the interpreter each: the dataclasses' copies)."""
        ahead = self._ahead.pop(self._ahead_key(probe, conditions), None)
        made = compute if ahead is None else lambda: ahead
        if PROBE_CACHE.folder() is None:
            return made()
        return PROBE_CACHE.remember(self._cache_key(probe, conditions), made, encode, decode)

    @staticmethod
    def _ahead_key(probe: str, conditions: dict) -> tuple[str, str]:
        """The name of a probe's result in :attr:`_ahead` (made by :meth:`probe_ahead`)."""
        return probe, repr(sorted(conditions.items()))

    def _cache_key(self, probe: str, conditions: dict) -> dict:
        """The key of a probe's result in :data:`PROBE_CACHE` (:meth:`_remembered`)."""
        imager = self.imager
        return {"probe": probe, "conditions": conditions,
               "telescope": asdict(imager.telescope), "wavelength_m": imager.wavelength,
               "atmosphere": None if imager.atmosphere is None else asdict(imager.atmosphere),
               "pixel_scale_rad": imager.pixel_scale, "geometry": imager.geometry.state(),
               "grid_size": imager.reference.grid_size, "tolerance": imager.tolerance, "focus": imager.focus,
               "seed": list(imager.seed), "averaging": self.pixels is not None, "share_far": self.share_far,
               "frames": [PROBE_FRAMES, list(REFERENCE_PROBE_FRAMES), list(AVERAGED_GROUPS), AVERAGED_POSITIONS,
                          ACCEPT_STANDARD_ERRORS, REJECT_STANDARD_ERRORS, FUTILITY_STANDARD_ERRORS,
                          FUTILITY_FRAMES, PUPIL_ERROR_ZENITH_BIN_RAD]}

    def _choose_seen(self, zenith_rad: float, range_m: float, seen: tuple[int, int, int, int],
                     context: str) -> PathChoice:
        """The choice for a bin of what the pixels see (module docstring): ``long_exposure`` for a source no pixel
        can see, else the cheapest path whose distance from the mean of the frames the pixels average is in tolerance."""
        imager, pixels = self.imager, self.pixels
        rate_px_s, source, sky_low, sky_high, sight_px_s = seen_edges(seen)
        step = self._seen_step(seen)
        if step < pixels.threshold_min:          # no probe needed: whatever the PSF, no pixel fires
            reason = (f"path 'long_exposure': the source cannot make a pixel fire: at most {source:.3g} photon/s on "
                      f"one pixel over a sky of {sky_low:.3g}, at >= {rate_px_s:.3g} pixel/s, moves its filtered log "
                      f"intensity by {step:.3g} < the smallest threshold {pixels.threshold_min:.3g} ({context})")
            return PathChoice("long_exposure", {}, reason)
        instantaneous, fits = self._probe(zenith_rad, range_m)
        tau = pixels.response_time_s(source + sky_high)
        atmosphere = imager.atmosphere
        cn2 = np.array([layer.cn2_dh for layer in atmosphere.layers])
        speeds = footprint_speeds(np.array([layer.altitude_m for layer in atmosphere.layers]),
                                  np.array([layer.wind_speed_m_s for layer in atmosphere.layers]), zenith_rad,
                                  sight_px_s * imager.pixel_scale)
        k_eff = averaged_frames(tau, cn2 / cn2.sum(), speeds, imager.telescope.diameter_m)
        estimates = dict(instantaneous)
        for name, fit in fits.items():
            estimates[name] = averaged_distance(fit, k_eff) + estimates["pupil_fft"]
        seen_context = (f"{context}; the pixels average {k_eff:.3g} short exposures: tau {tau * 1e3:.3g} ms at "
                        f"{source:.3g} photon/s on a pixel, rate >= {rate_px_s:.3g} pixel/s, line of sight "
                        f">= {sight_px_s:.3g} pixel/s")
        return pick(estimates, imager.tolerance, seen_context, self.kept(zenith_rad, range_m))

    def pupil_error(self, zenith_rad: float, range_m: float) -> float:
        """Estimated error of ``pupil_fft`` against ``reference`` [1] (module docstring): :meth:`pupil_estimate`'s."""
        return self.pupil_estimate(zenith_rad, range_m).error

    def kept(self, zenith_rad: float, range_m: float) -> dict[str, str]:
        """``{'pupil_fft': why}`` where the pupil path is within tolerance by :func:`pupil_verdict` (else empty)."""
        if not self.imager.turbulent(zenith_rad):
            return {}
        estimate = self.pupil_estimate(zenith_rad, range_m)
        return {"pupil_fft": estimate.verdict} if estimate.within else {}

    def pupil_estimate(self, zenith_rad: float, range_m: float) -> PupilError:
        """The pupil path's error against the reference (:class:`PupilError`), kept per coarse bin.

        The larger of the scintillation term ``sigma_I / sqrt(2 pi)`` and the mean distance
        between the two paths over independent screens at the bin's conditions (each path fed
        the same screens, :meth:`.ReferencePath.pupil_phase`), measured frame pair by frame pair until
        :func:`pupil_verdict` decides. A scintillation term above the tolerance settles it alone.
        """
        reference = self._reference_bin(zenith_rad, range_m)
        if reference is None:
            return PupilError(0.0, 0.0, 0, True, "(no turbulence)")
        key, conditions, sigma2 = reference
        if key not in self._pupil_errors:
            zenith, distance = conditions["zenith_rad"], conditions["range_m"]
            scintillation = conditions["scintillation"]
            measured, (within, verdict) = self._remembered(
                "reference", conditions, lambda: self._reference_distances(key, zenith, distance, scintillation),
                lambda value: {"distances": value[0], "within": value[1][0], "verdict": value[1][1]},
                lambda stored: ([float(d) for d in stored["distances"]], (bool(stored["within"]),
                                                                         str(stored["verdict"]))))
            n = len(measured)
            se = float(np.std(measured, ddof=1) / np.sqrt(n)) if n > 1 else 0.0
            error = max(float(np.mean(measured)) if n else 0.0, scintillation)
            self._pupil_errors[key] = PupilError(error, se, n, within, verdict)
            LOG.info("%s: pupil_fft vs reference at zenith angle %.0f deg, range %.3g m: error %.3g +- %.2g "
                     "(%d reference frames; scintillation index %.3g): %s pupil_fft", self.imager.label,
                     np.rad2deg(zenith), distance, error, se, n, sigma2, "keeps" if within else "rejects")
        return self._pupil_errors[key]

    def _reference_bin(self, zenith_rad: float, range_m: float) -> tuple[tuple[int, int], dict, float] | None:
        """The pupil-error bin of these conditions, its probe's conditions (the bin's zenith angle [rad] and
        range [m], the scintillation term [1] there) and the scintillation index [1] it comes from; None without
        turbulence. With ``share_far``, a finite-range bin like the far one (:meth:`_shares_far`) is the far bin."""
        imager = self.imager
        if not imager.turbulent(zenith_rad):
            return None
        z_bin = int(np.floor(zenith_rad / PUPIL_ERROR_ZENITH_BIN_RAD))
        r_bin = -1 if not np.isfinite(range_m) or range_m >= FAR_RANGE_M else int(np.floor(np.log2(range_m)))
        if r_bin >= 0 and self.share_far and self._shares_far(z_bin, r_bin):
            r_bin = -1
        key = (z_bin, r_bin)
        zenith = (z_bin + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD
        distance = FAR_RANGE_M if r_bin < 0 else 2.0 ** (r_bin + 0.5)
        sigma2 = self._bin_scintillation(key, zenith, distance)
        return key, {"bin": list(key), "zenith_rad": zenith, "range_m": distance,
                     "scintillation": scintillation_error(sigma2)}, sigma2

    def _bin_scintillation(self, key: tuple[int, int], zenith_rad: float, range_m: float) -> float:
        """The aperture-averaged scintillation index [1] of pupil-error bin ``key`` at its probe's conditions, kept."""
        if key not in self._scintillation:
            imager = self.imager
            self._scintillation[key] = imager.atmosphere.scintillation_index(
                imager.telescope.diameter_m, imager.wavelength, zenith_rad, range_m)
        return self._scintillation[key]

    def _shares_far(self, z_bin: int, r_bin: int) -> bool:
        """Whether finite-range pupil-error bin ``(z_bin, r_bin)`` takes the far bin's reference probes (with
        ``share_far``, the block's ``share_far_probes``): at its nearest range ``2^r_bin`` [m] and the bin's zenith
        angle, within :data:`SHARED_FAR_TOLERANCE`,

        * the diffraction between the layers and the aperture, which the pupil path drops, is the far source's: the
          spherical wave's Rytov variance is the plane wave's (:func:`spherical_wave_ratio`), and the
          aperture-averaged scintillation term (:func:`scintillation_error` of :meth:`.Atmosphere.scintillation_index`,
          the pupil path's error floor) is the far bin's; and
        * the source's defocus for a telescope focused at infinity, ``pi r^2 / (lambda R)`` (in both paths alike),
          is at most :data:`SHARED_FAR_DEFOCUS_RAD` rms over the pupil (``c a^2 / sqrt(12)`` for a filled pupil of
          radius ``a``, its largest for any obstruction: ``r^2`` is uniform over an annulus), a Strehl ratio
          above 0.99 (Marechal: ``exp(-sigma^2)``; Born & Wolf 1999 Sec. 9.1).

        Kept per bin; logged when shared."""
        key = (z_bin, r_bin)
        if key not in self._shared_far:
            imager = self.imager
            zenith = (z_bin + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD
            nearest = 2.0**r_bin
            ratio = spherical_wave_ratio(imager.atmosphere.layers, zenith, nearest)
            shared = ratio >= 1.0 - SHARED_FAR_TOLERANCE
            if shared:
                far = scintillation_error(self._bin_scintillation((z_bin, -1), zenith, FAR_RANGE_M))
                near = scintillation_error(imager.atmosphere.scintillation_index(
                    imager.telescope.diameter_m, imager.wavelength, zenith, nearest))
                radius = imager.telescope.diameter_m / 2
                defocus = float(imager.defocus_curvature(np.array([nearest]))[0]) * radius**2 / np.sqrt(12.0)
                shared = abs(near - far) <= SHARED_FAR_TOLERANCE * far and defocus <= SHARED_FAR_DEFOCUS_RAD
            self._shared_far[key] = shared
            if shared:
                LOG.info("%s: pupil_fft vs reference at zenith angle %.0f deg, ranges from %.3g m: the far bin's "
                         "probes (share_far_probes): Rytov variance %.3g of the far one's, scintillation term "
                         "%.3g against %.3g far, defocus %.2g rad rms", imager.label, np.rad2deg(zenith), nearest,
                         ratio, near, far, defocus)
        return self._shared_far[key]

    def _reference_distances(self, key: tuple, zenith_rad: float, range_m: float,
                             scintillation: float) -> tuple[list[float], tuple[bool, str]]:
        """Distances [1] between pupil-path and reference stamps fed the same fresh screens, one frame each, until
        :func:`pupil_verdict` decides, and its verdict.

        Frames come in pairs whose screens are the two halves of the same FFT draws
        (:meth:`.ReferencePath.probe_pair`); each pair's screens have their own seed (the probe's name), so
        pairs are measured on every core (:meth:`_measure`), the verdict taken pair by pair in order (pairs past
        it are dropped), so the frames and the verdict are those of one pair at a time, whatever the threads."""
        run = _PairRun(key, zenith_rad, range_m, scintillation, self.imager.tolerance)
        return self._measure([run], [])["reference", key]

    def _pair_distances(self, key: tuple, zenith_rad: float, range_m: float, pair: int,
                        needed: Callable[[], bool] = lambda: True,
                        rendered: Callable[[], bool] = lambda: True) -> list[float] | None:
        """The distances [1] of frame pair ``pair`` of the reference probe of pupil-error bin ``key`` (its screens
        named by the bin and the pair: the same numbers on any thread, in any order); None, with what is left of it
        unmade, where ``needed()`` says that the pair is no longer needed: after its first frame, before each layer's
        screen and each propagation (:meth:`.ReferencePath.field`) and before the stamps.

        Both frames' fields are made first, without the pupil renderer; then ``rendered()`` (which returns once
        the renderer is made: False if that failed, and the pair is dropped), then their stamps."""
        imager = self.imager
        offset = np.zeros((1, 2))
        names = (f"__probe {key} {2 * pair}", f"__probe {key} {2 * pair + 1}")
        made = []
        frames = imager.reference.probe_pair(names, zenith_rad, range_m, needed)
        try:
            for frame in frames:
                made.append(frame)
                if len(made) == 1 and not needed():
                    return None
        finally:
            frames.close()
        if len(made) < 2 or not needed() or not rendered():
            return None
        out = []
        for before, phase in made:
            field = before * imager.pupil_amplitude          # the reference field (ReferencePath.field's numbers)
            stamp = imager.pupil_renderer.stamps_from_field(field[None], offset)
            fast = imager.pupil_renderer.stamps(imager.pupil_amplitude, phase[None], offset)
            out.append(float(total_variation(fast, stamp, stamp.sum())[0]))
        return out

    def _probe_phase(self, rng: np.random.Generator, zenith_rad: float, range_m: float, frames: int) -> np.ndarray:
        """Pupil phase [rad] (frames, n, n) of the probe: defocus plus independent FFT screens at the sight line's r0."""
        imager = self.imager
        g = imager.geometry
        phase = np.zeros((frames, g.n_pupil, g.n_pupil))
        phase += imager.defocus(np.full(frames, range_m))
        if imager.turbulent(zenith_rad):
            r0 = imager.r0(zenith_rad)
            for k in range(0, frames, 2):
                # both screens of a 2n x 2n FFT draw, only their n x n corners transformed and summed (the numbers
                # of fft_phase_screens' corners)
                pair = fft_phase_screen_corners(rng, 2 * g.n_pupil, g.n_pupil, g.delta_m, r0, imager.outer_scale_m)
                for j, screen in enumerate((pair.real, pair.imag)[: min(2, frames - k)]):
                    phase[k + j] += screen
        return phase

    def forget(self) -> None:
        """Drop every choice and estimate (the sampling they were made with changed)."""
        self._choices.clear()
        self._pupil_errors.clear()
        self._estimates.clear()
        self._ahead.clear()
        self._scintillation.clear()
        self._shared_far.clear()


class _PairRun:
    """One pupil-error bin's reference frame pairs as threads measure them (:meth:`PathChooser._measure`), and the
    verdict (:func:`pupil_verdict`) taken on them pair by pair in order: ``measured``, the distances of the pairs up
    to the one that decided, and ``verdict`` are those of the pairs measured one after another."""

    def __init__(self, key: tuple, zenith_rad: float, range_m: float, scintillation: float, tolerance: float):
        self.key, self.zenith_rad, self.range_m = key, zenith_rad, range_m
        self.scintillation, self.tolerance = scintillation, tolerance
        self.taken = 0                          # pairs handed to threads
        self.running = 0                        # of which not done yet
        self.pairs: dict[int, list[float]] = {}
        self.measured: list[float] = []
        self.verdict = pupil_verdict([], scintillation, tolerance)

    def open(self) -> bool:
        """Whether another pair may be needed: no verdict yet, pairs left."""
        return self.verdict is None and 2 * self.taken < REFERENCE_PROBE_FRAMES[1]

    def likely_decided(self) -> bool:
        """Whether the one pair being measured would decide the verdict, with the pairs done beside it, were its two
        frames the mean of those done (a guess: it only spares making a pair that would be dropped)."""
        known = [*self.measured, *(d for pair in sorted(self.pairs) if pair >= len(self.measured) // 2
                                   for d in self.pairs[pair])]
        if self.running != 1 or not known:
            return False
        mean = float(np.mean(known))
        frames = list(self.measured)
        for pair in range(len(self.measured) // 2, self.taken):
            frames += self.pairs[pair] if pair in self.pairs else [mean, mean]
            if pupil_verdict(frames, self.scintillation, self.tolerance) is not None:
                return True
        return False

    def take(self) -> int:
        self.taken += 1
        self.running += 1
        return self.taken - 1

    def done(self, pair: int, distances: list[float] | None) -> None:
        """Pair ``pair``'s distances (None: dropped, after the verdict); the verdict moves on over every pair done in
        order."""
        self.running -= 1
        self.pairs[pair] = distances
        while self.verdict is None and len(self.measured) // 2 in self.pairs:
            self.measured.extend(self.pairs[len(self.measured) // 2])
            self.verdict = pupil_verdict(self.measured, self.scintillation, self.tolerance)
