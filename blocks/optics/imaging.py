"""A telescope looking through a layered atmosphere at point sources: stamps of pixel energies.

:class:`Imager` is the optics stage as a plain Python object (the ``optics`` block wraps
it): give it the telescope, the focal plane, the band's wavelength and an atmosphere
(or ``None`` above it) and the block's ``Params``, then ask for stamps of a source along its track::

    imager = Imager(Telescope(0.35, 0.3), focal_plane, 550e-9, Atmosphere.hufnagel_valley(),
                    PointSourceOptics.Params())
    origin, stamps, paths = imager.render("sat", t_s, x_px, y_px, zenith_rad, range_m)

``stamps[k]`` holds the fraction of the power incident on the collecting area that lands
in each pixel of the stamp whose first pixel is ``origin[k]`` (x, y).

Geometry of frozen flow (Taylor's hypothesis; Poyneer et al. 2009): layer ``l`` at
altitude ``h`` is a screen moving with its wind ``v``; the line of sight to a source at
sky offset ``theta`` from the boresight crosses it at slant distance ``L = h sec(zeta)``,
so the pupil's footprint on the screen is centred at ``L theta - v t`` and, for a source
at range ``R``, shrunk by ``1 - L/R`` (the cone of a finite-range source). A satellite
crossing the field therefore sweeps the high layers at ``L dtheta/dt``, much faster than
the wind. Each source sees its own screens: sources a few arcseconds apart are already
beyond the isoplanatic angle (``theta0 ~ 7 urad`` for HV5/7).
"""

from __future__ import annotations

import threading
import zlib
from collections import Counter
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from evsda.blocks.ports import FocalPlane
from evsda.graph import ParameterError

from .atmosphere import Atmosphere
from .fft_screens import fft_phase_screens
from .paths import LOG, PATHS, PROBE_FRAMES, PathChoice, pick, scintillation_error, total_variation
from .psf import long_exposure_encircled_energy, long_exposure_profile
from .pupil_path import PupilPath
from .reference_path import FAR_RANGE_M, ReferencePath
from .render import PupilRenderer, RadialRenderer, StampSampler, oversampling_for, stamp_placement
from .screen_kernels import MARGIN

if TYPE_CHECKING:
    from .block import PointSourceOptics
#: zenith-angle bin of path decisions [rad] and range bin (ratio) [1]
ZENITH_BIN_RAD = np.deg2rad(1.0)
RANGE_BIN_RATIO = 1.05
#: the pupil path's error against the reference is measured on coarser bins: 10 degrees, factors of 2 in range
PUPIL_ERROR_ZENITH_BIN_RAD = np.deg2rad(10.0)
#: reference propagations per pupil-error bin: at least the first, more (up to the second) while the
#: tolerance lies within two standard errors of their mean, so a close call is decided on the mean
#: error rather than on the luck of three frames
REFERENCE_PROBE_FRAMES = (3, 12)

MAX_SUBPIXELS_PER_AXIS = 2048     # sub-pixel samples across a stamp (the renderers' tables grow with its square) [1]


@dataclass(frozen=True)
class PupilGeometry:
    """Sampling chosen once per run (kept in the block's state so a resumed run is identical)."""

    n_pupil: int                 # pupil samples across the grid
    delta_m: float               # pupil sample spacing [m]
    stamp_size: int              # stamp width [pixel]
    oversample: int              # sub-pixels per pixel along an axis
    layer_delta_m: tuple         # screen sample spacing of each layer [m]
    layer_n: tuple               # screen window width of each layer [samples]


class Imager:
    """Point-source imaging through turbulence with a choice of PSF paths (:mod:`.paths`).

    The coordinator: it sizes the sampling, chooses each frame's path, renders the analytic
    paths and hands the others to :class:`.PupilPath` and :class:`.ReferencePath`, which
    keep their own screens. ``params`` is the ``optics`` block's ``Params``.
    """

    def __init__(self, telescope, focal_plane: FocalPlane, wavelength_m: float, atmosphere: Atmosphere | None,
                 params: PointSourceOptics.Params, *, seed: tuple = (0,), name: str = "optics"):
        self.telescope, self.focal_plane, self.wavelength = telescope, focal_plane, float(wavelength_m)
        self.atmosphere = atmosphere if atmosphere is not None and atmosphere.layers else None
        self.tolerance, self.forced_path, self.focus = float(params.tolerance), params.psf_path, params.focus
        self.revisit_s, self.pupil_samples = params.screen_revisit_s, params.pupil_samples
        self.stamp_size_px, self.seed, self.name = params.stamp_size_px, tuple(int(s) for s in seed), name
        self.pixel_scale = focal_plane.pixel_scale_rad
        self.boresight = np.array([(focal_plane.width_px - 1) / 2, (focal_plane.height_px - 1) / 2])
        self.geometry: PupilGeometry | None = None
        self.pupil = PupilPath(self, params.screen_method, params.screen_update, params.n_zernike_modes)
        self.reference = ReferencePath(self, params.grid_size)
        self._choices: dict[tuple, PathChoice] = {}
        self._pupil_errors: dict[tuple, float] = {}
        self._profiles: dict[tuple, RadialRenderer] = {}
        self._pupil_renderer: PupilRenderer | None = None
        self._amplitude: np.ndarray | None = None
        #: PSFs rendered so far by each path (benchmarks compare the block's cost with theirs)
        self.frames_rendered: Counter = Counter()
        self._count_lock = threading.Lock()

    # -- turbulence strength ----------------------------------------------------------------------
    def turbulent(self, zenith_rad: float) -> bool:
        return self.atmosphere is not None and bool(np.isfinite(zenith_rad))

    def r0(self, zenith_rad: float) -> float:
        """Fried parameter of the line of sight at the band's wavelength [m] (inf above the atmosphere)."""
        return self.atmosphere.r0(self.wavelength, zenith_rad) if self.turbulent(zenith_rad) else np.inf

    # -- sampling, fixed at first use ------------------------------------------------------------
    def ensure_geometry(self, zenith_rad: float) -> PupilGeometry:
        if self.geometry is not None:
            return self.geometry
        d, lam, p, tol = self.telescope.diameter_m, self.wavelength, self.pixel_scale, self.tolerance
        # design for r0 at 0.75 x its first value: about 25 degrees more zenith angle near 45 degrees
        r0 = 0.75 * self.r0(zenith_rad)
        if self.stamp_size_px is not None:
            size = int(self.stamp_size_px)
        else:
            # enclose all but half the tolerance of the long-exposure (or Airy) PSF's power
            theta = np.arange(1, 1025) * p / 4
            enclosed = long_exposure_encircled_energy(self.telescope, lam, r0, self.outer_scale_m, theta)
            radius = theta[min(np.searchsorted(enclosed, 1 - tol / 2), theta.size - 1)]
            size = int(np.clip(2 * np.ceil(radius / p) + 1, 3, 129))
        # midpoint-rule error ~ 0.03 (sub-pixels per lambda/2D)^-2 (tests/optics), a quarter of the tolerance
        density = float(np.clip(np.sqrt(0.12 / tol), 1.0, 4.0))
        oversample = oversampling_for(p, d, lam, density)
        if size * oversample > MAX_SUBPIXELS_PER_AXIS:
            arcsec = 180 / np.pi * 3600
            raise ParameterError(
                f"{self.name}: the PSF is far smaller than a pixel (diffraction width lambda/D = {lam / d * arcsec:.3g} "
                f"arcsec, a pixel {p * arcsec:.3g} arcsec): rendering it would take {oversample} x {oversample} sub-pixels "
                f"per pixel, {size * oversample} across a stamp (at most {MAX_SUBPIXELS_PER_AXIS}); lengthen the focal "
                f"length or shrink the pixels")
        if self.pupil_samples is not None:
            n_pupil = int(self.pupil_samples)
            delta = d / (n_pupil - 2)
        else:
            delta = min(d / 24, r0 / 4, lam / (1.25 * size * p))
            n_pupil = int(np.ceil(d / delta)) + 2
            n_pupil += n_pupil % 2
            delta = d / (n_pupil - 2)
        footprint = n_pupil * delta
        layer_delta, layer_n = [], []
        if self.atmosphere is not None:
            layer_r0 = 0.75 * self.atmosphere.layer_r0(lam, zenith_rad if np.isfinite(zenith_rad) else 0.0)
            for r0_l in layer_r0:
                step = float(np.clip(r0_l / 6, delta, d / 8))
                across = int(np.ceil(footprint / step))
                # the footprint, half as much again (transverse drift, and the stencil's reach for the large
                # scales: columns 3, 7, 15, ... back, beyond the footprint's width) and the margins
                n = across + across // 2 + 2 * MARGIN + 2
                layer_delta.append(step)
                layer_n.append(n + n % 2)
        self.geometry = PupilGeometry(n_pupil, delta, size, oversample, tuple(layer_delta), tuple(layer_n))
        LOG.info("%s: pupil %d x %d samples of %.3g mm, stamps %d x %d pixels with %d x %d sub-pixels, "
                 "layer screens %s samples of %s mm", self.name, n_pupil, n_pupil, delta * 1e3, size, size,
                 oversample, oversample, list(layer_n), [round(s * 1e3, 2) for s in layer_delta])
        return self.geometry

    @property
    def outer_scale_m(self) -> float:
        """Von Karman outer scale L0 of the atmosphere [m] (inf without one)."""
        return self.atmosphere.L0 if self.atmosphere is not None else np.inf

    @property
    def sampler(self) -> StampSampler:
        g = self.geometry
        return StampSampler(g.stamp_size, self.pixel_scale, g.oversample)

    @property
    def pupil_renderer(self) -> PupilRenderer:
        if self._pupil_renderer is None:
            g = self.geometry
            self._pupil_renderer = PupilRenderer(self.sampler, g.n_pupil, g.delta_m, self.wavelength,
                                                 self.telescope.collecting_area_m2)
            self._amplitude = self.telescope.pupil(g.n_pupil, g.delta_m)
        return self._pupil_renderer

    @property
    def pupil_amplitude(self) -> np.ndarray:
        self.pupil_renderer
        return self._amplitude

    # -- path choice ------------------------------------------------------------------------------
    def conditions_key(self, zenith_rad: float, range_m: float) -> tuple:
        z = -1 if not self.turbulent(zenith_rad) else int(np.floor(zenith_rad / ZENITH_BIN_RAD))
        r = -1 if not np.isfinite(range_m) or range_m >= FAR_RANGE_M else int(np.floor(np.log(range_m) / np.log(RANGE_BIN_RATIO)))
        return z, r

    def _representative(self, key: tuple) -> tuple[float, float]:
        z, r = key
        zenith = np.nan if z < 0 else (z + 0.5) * ZENITH_BIN_RAD
        range_m = np.inf if r < 0 else RANGE_BIN_RATIO ** (r + 0.5)
        return zenith, range_m

    def choose(self, zenith_rad: float, range_m: float, source: str = "") -> PathChoice:
        """The path for these conditions (forced, or the cheapest within tolerance); logged once per condition."""
        key = self.conditions_key(zenith_rad, range_m)
        if key not in self._choices:
            self.ensure_geometry(zenith_rad)
            zenith, range_rep = self._representative(key)
            context = self._context(zenith, range_rep)
            if self.forced_path != "auto":
                choice = PathChoice(self.forced_path, {}, f"path '{self.forced_path}' forced by psf_path ({context})")
            else:
                choice = pick(self.estimate_errors(zenith, range_rep), self.tolerance, context)
            self._choices[key] = choice
            LOG.info("%s%s: %s", self.name, f" source {source}" if source else "", choice.reason)
        return self._choices[key]

    def _context(self, zenith: float, range_m: float) -> str:
        d = self.telescope.diameter_m
        parts = []
        if self.turbulent(zenith):
            parts.append(f"D/r0 = {d / self.r0(zenith):.3g} at zenith angle {np.rad2deg(zenith):.1f} deg")
        else:
            parts.append("no atmosphere")
        if np.isfinite(range_m):
            parts.append(f"Fresnel number D^2/(lambda R) = {d**2 / (self.wavelength * range_m):.3g}")
        return ", ".join(parts)

    def estimate_errors(self, zenith_rad: float, range_m: float) -> dict[str, float]:
        """Estimated error [1] of each path against the reference (:mod:`.paths`)."""
        pupil_error = self.pupil_error(zenith_rad, range_m)
        rng = np.random.Generator(np.random.PCG64(zlib.crc32(repr((zenith_rad, range_m, self.seed)).encode())))
        offsets = rng.uniform(-0.5, 0.5, (PROBE_FRAMES, 2))
        frames = PROBE_FRAMES if self.turbulent(zenith_rad) else 1
        offsets = offsets[:frames]
        phase = self._probe_phase(rng, zenith_rad, range_m, frames)
        pupil = self.pupil_renderer.stamps(self.pupil_amplitude, phase, offsets)
        flux = pupil.sum(axis=(1, 2)).mean()
        estimates = {"reference": 0.0, "pupil_fft": pupil_error}
        for name in ("airy", "long_exposure"):
            analytic = self.radial_renderer(name, zenith_rad).stamps(offsets)
            estimates[name] = float(total_variation(analytic, pupil, flux).mean()) + pupil_error
        if not self.turbulent(zenith_rad):
            estimates.pop("long_exposure")
        return estimates

    def pupil_error(self, zenith_rad: float, range_m: float) -> float:
        """Estimated error of ``pupil_fft`` against ``reference`` [1] (:mod:`.paths`), cached on coarse bins.

        The larger of the scintillation term ``sigma_I / sqrt(2 pi)`` and the mean distance
        between the two paths over independent screens at the bin's conditions (each path fed
        the same screens, :meth:`.ReferencePath.pupil_phase`): ``REFERENCE_PROBE_FRAMES[0]`` of them,
        and more, up to ``REFERENCE_PROBE_FRAMES[1]``, while the tolerance lies within two
        standard errors of their mean. A scintillation term above the tolerance settles it alone.
        """
        if not self.turbulent(zenith_rad):
            return 0.0
        z_bin = int(np.floor(zenith_rad / PUPIL_ERROR_ZENITH_BIN_RAD))
        r_bin = -1 if not np.isfinite(range_m) or range_m >= FAR_RANGE_M else int(np.floor(np.log2(range_m)))
        key = (z_bin, r_bin)
        if key not in self._pupil_errors:
            zenith = (z_bin + 0.5) * PUPIL_ERROR_ZENITH_BIN_RAD
            distance = FAR_RANGE_M if r_bin < 0 else 2.0 ** (r_bin + 0.5)
            sigma2 = self.atmosphere.scintillation_index(self.telescope.diameter_m, self.wavelength, zenith, distance)
            scintillation = scintillation_error(sigma2)
            measured = []
            offset = np.zeros((1, 2))
            least, most = REFERENCE_PROBE_FRAMES
            while scintillation <= self.tolerance and len(measured) < most:
                probe = f"__probe {key} {len(measured)}"
                field = self.reference.field(probe, 0.0, *self.boresight, zenith, distance, slack=1.0)
                phase = self.reference.pupil_phase(probe, 0.0, *self.boresight, zenith, distance)
                del self.reference.screens[probe]
                reference = self.pupil_renderer.stamps_from_field(field[None], offset)
                fast = self.pupil_renderer.stamps(self.pupil_amplitude, phase[None], offset)
                measured.append(float(total_variation(fast, reference, reference.sum())[0]))
                if len(measured) >= least:
                    error = np.std(measured, ddof=1) / np.sqrt(len(measured))
                    if abs(np.mean(measured) - self.tolerance) > 2 * error:
                        break
            self._pupil_errors[key] = max(float(np.mean(measured)) if measured else 0.0, scintillation)
            LOG.info("%s: pupil_fft vs reference at zenith angle %.0f deg, range %.3g m: error %.3g "
                     "(%d reference frames; scintillation index %.3g)", self.name, np.rad2deg(zenith), distance,
                     self._pupil_errors[key], len(measured), sigma2)
        return self._pupil_errors[key]

    def _probe_phase(self, rng, zenith_rad: float, range_m: float, frames: int) -> np.ndarray:
        g = self.geometry
        phase = np.zeros((frames, g.n_pupil, g.n_pupil))
        phase += self.defocus(np.full(frames, range_m))
        if self.turbulent(zenith_rad):
            r0 = self.r0(zenith_rad)
            for k in range(0, frames, 2):
                pair = fft_phase_screens(rng, 2 * g.n_pupil, g.delta_m, r0, self.outer_scale_m)
                for j, screen in enumerate(pair[: min(2, frames - k)]):
                    phase[k + j] += screen[: g.n_pupil, : g.n_pupil]
        return phase

    # -- analytic PSFs ---------------------------------------------------------------------------
    def radial_renderer(self, path: str, zenith_rad: float) -> RadialRenderer:
        r0 = self.r0(zenith_rad) if path == "long_exposure" else np.inf
        key = (path, None if not np.isfinite(r0) else self.conditions_key(zenith_rad, np.inf))
        if key not in self._profiles:
            if path == "long_exposure" and np.isfinite(r0):
                r0 = self.r0(self._representative(key[1])[0])
            s = self.sampler
            theta = np.linspace(0.0, (s.size / 2 + 2) * np.sqrt(2) * self.pixel_scale, 2048)
            if np.isfinite(r0):
                profile = long_exposure_profile(self.telescope, self.wavelength, r0, self.outer_scale_m, theta, 2048)
            else:
                profile = self.telescope.airy(theta, self.wavelength)
            self._profiles[key] = RadialRenderer(s, theta, profile)
        return self._profiles[key]

    def defocus(self, range_m: np.ndarray) -> np.ndarray:
        """Pupil phase [rad] of a finite-range source for a telescope focused at infinity, ``pi r^2/(lambda R)``."""
        g = self.geometry
        x = (np.arange(g.n_pupil) - g.n_pupil // 2) * g.delta_m
        r2 = x[None, :] ** 2 + x[:, None] ** 2
        if self.focus == "source":
            return np.zeros((len(range_m), 1, 1))
        curvature = np.where(np.isfinite(range_m), 1.0 / np.asarray(range_m, dtype=float), 0.0)
        return np.pi / self.wavelength * curvature[:, None, None] * r2[None]

    # -- rendering --------------------------------------------------------------------------------
    def prepare(self, source: str, zenith_rad: np.ndarray, range_m: np.ndarray) -> None:
        """Make the path choices and shared tables a track needs, so that sources can then render concurrently."""
        range_m = np.asarray(range_m, dtype=float)
        zenith_rad = np.broadcast_to(np.asarray(zenith_rad, dtype=float), range_m.shape)
        self.ensure_geometry(float(zenith_rad[0]) if len(zenith_rad) else np.nan)
        self.pupil_renderer
        for z, r in zip(zenith_rad, range_m):
            if self.conditions_key(z, r) not in self._choices:
                path = self.choose(z, r, source).path
                if path in ("airy", "long_exposure"):
                    self.radial_renderer(path, z)
        if self.pupil.screen_method == "zernike" and self.atmosphere:
            self.pupil.pupil_modes

    def render(self, source: str, t_s: np.ndarray, x_px: np.ndarray, y_px: np.ndarray,
               zenith_rad: np.ndarray, range_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Stamps along a track: ``origin`` (F, 2) int32, energy fractions (F, M, M) [1], path per frame."""
        t_s, x_px, y_px = (np.asarray(a, dtype=float) for a in (t_s, x_px, y_px))
        zenith_rad = np.broadcast_to(np.asarray(zenith_rad, dtype=float), t_s.shape)
        range_m = np.broadcast_to(np.asarray(range_m, dtype=float), t_s.shape)
        self.ensure_geometry(float(zenith_rad[0]) if len(zenith_rad) else np.nan)
        origin, offset = stamp_placement(x_px, y_px, self.geometry.stamp_size)
        size = self.geometry.stamp_size
        stamps = np.zeros((len(t_s), size, size))
        paths = [self.choose(z, r, source).path for z, r in zip(zenith_rad, range_m)]
        for path in PATHS:
            idx = np.array([i for i, p in enumerate(paths) if p == path], dtype=int)
            if idx.size == 0:
                continue
            with self._count_lock:
                self.frames_rendered[path] += int(idx.size)
            if path in ("airy", "long_exposure"):
                for key in sorted({self.conditions_key(z, np.inf) for z in zenith_rad[idx]}):
                    sub = idx[[self.conditions_key(z, np.inf) == key for z in zenith_rad[idx]]]
                    stamps[sub] = self.radial_renderer(path, zenith_rad[sub[0]]).stamps(offset[sub])
            elif path == "pupil_fft":
                stamps[idx] = self.pupil.render(source, t_s[idx], x_px[idx], y_px[idx], zenith_rad[idx],
                                                range_m[idx], offset[idx])
            else:
                stamps[idx] = self.reference.render(source, t_s[idx], x_px[idx], y_px[idx], zenith_rad[idx],
                                                    range_m[idx], offset[idx])
        return origin, stamps, paths

    def source_seed(self, source: str, family: int) -> tuple:
        """Seed of a source's screens: family 0 the pupil path's, 1 the reference path's."""
        return (*self.seed, zlib.crc32(source.encode()), family)

    def epochs_of(self, t_s: np.ndarray) -> np.ndarray:
        """Screen epoch of each time [1]: all screens are redrawn every ``screen_revisit_s``."""
        if not self.revisit_s:
            return np.zeros(t_s.shape, dtype=np.int64)
        return np.floor(t_s / self.revisit_s + 1e-9).astype(np.int64)

    def footprints(self, layer, t_s, x_px, y_px, zenith_rad, range_m):
        """Footprint centre on a layer (F, 2) (x, y) [m] and its scale (F,) [1]."""
        slant = layer.altitude_m / np.cos(zenith_rad)
        theta = (np.stack([x_px, y_px], axis=-1) - self.boresight) * self.pixel_scale
        centre = slant[:, None] * theta - layer.wind_m_s[None, :] * t_s[:, None]
        scale = np.where(np.isfinite(range_m), 1.0 - slant / np.where(np.isfinite(range_m), range_m, 1.0), 1.0)
        return centre, scale

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "geometry": None if self.geometry is None else {k: (list(v) if isinstance(v, tuple) else v)
                                                            for k, v in asdict(self.geometry).items()},
            "screens": self.pupil.state(),
            "reference_screens": self.reference.state(),
        }

    def set_state(self, state: dict) -> None:
        geometry = state.get("geometry")
        self.geometry = None if geometry is None else PupilGeometry(
            int(geometry["n_pupil"]), float(geometry["delta_m"]), int(geometry["stamp_size"]),
            int(geometry["oversample"]), tuple(float(v) for v in geometry["layer_delta_m"]),
            tuple(int(v) for v in geometry["layer_n"]))
        self._pupil_renderer = None
        self._profiles.clear()
        self._choices.clear()
        self._pupil_errors.clear()
        self.pupil.set_state(state.get("screens") or {})
        self.reference.set_state(state.get("reference_screens") or {})
