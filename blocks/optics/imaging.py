"""A telescope looking through a layered atmosphere at point sources: stamps of pixel energies.

:class:`Imager` is the optics stage as a plain Python object (the ``optics`` block wraps
it): give it the telescope, the focal plane, the band's wavelength and an atmosphere
(or ``None`` above it) and the block's ``Params``, then ask for stamps of a source along its track::

    imager = Imager(Telescope(0.35, 0.3), focal_plane, 550e-9, Atmosphere.hufnagel_valley(),
                    PointSourceOptics.Params())
    origin, stamps, paths = imager.render("sat", t_s, x_px, y_px, zenith_rad, range_m,
                                          azimuth_rad=boresight_azimuth, rotation_rad=field_rotation)

``stamps[k]`` holds the fraction of the power incident on the collecting area that lands
in each pixel of the stamp whose first pixel is ``origin[k]`` (x, y).

Geometry of frozen flow (Taylor's hypothesis; Poyneer et al. 2009): layer ``l`` at
altitude ``h`` is a screen fixed to the ground and moving with its wind ``v``. The line of
sight to a source at zenith angle ``z`` and azimuth ``A`` crosses it at the horizontal offset
``h tan(z) (sin A, cos A)`` from the telescope (flat, horizontal layers), so two directions
``theta`` apart cross it ``h theta sec z`` apart across the beam: the geometry behind the
isoplanatic angle (Roddier 1981, Prog. Optics 19, 281; Fried 1982; Hardy 1998, Adaptive Optics
for Astronomical Telescopes, Eq. 3.61). The pupil's footprint on the screen is centred there
minus ``v t`` and, for a source at range ``R``, shrunk by ``1 - L/R`` (``L = h sec z`` the slant
distance; the cone of a finite-range source). The direction is the source's own, in the ground
frame (:meth:`Imager.sight`): a mount tracking a satellite at ``omega`` sweeps the satellite's
footprint across each layer at ``L omega`` (77 m/s at ``L`` = 4.4 km for 1 deg/s), while the stars'
footprints, fixed in azimuth and elevation but for the sidereal rate, move with the wind
only. Each source sees its own screens: sources a few arcseconds apart are already beyond
the isoplanatic angle (``theta0 ~ 7 urad`` for HV5/7). On equivalent layers each source's footprints also move at
its own winds, which keep its footprints' speed moment (:meth:`Imager.source_flow`, :mod:`.equivalent_layers`), fixed at
its first two render times or, with ``follow_sight_rate``, those of its line of sight's rate at each render time.

The pieces, one module each: the sampling (:mod:`.sizing`), the path choice and its error
estimates (:mod:`.paths`), and the paths, ``airy`` and ``long_exposure``
(:mod:`.analytic_path`), ``pupil_fft`` (:mod:`.pupil_path`) and ``reference``
(:mod:`.reference_path`). :class:`Imager` holds what they share: the line of sight's
turbulence, the sampling, the pupil renderer, the frozen-flow footprints and the seeds.
"""

from __future__ import annotations

import threading
import zlib
from collections import Counter
from typing import TYPE_CHECKING

import numpy as np

from evsda.blocks.ports import FocalPlane

from .analytic_path import AnalyticPath
from .atmosphere import Atmosphere
from .equivalent_layers import follow_drift, footprint_winds, member_columns
from .paths import ANALYTIC_PATHS, PATHS, PathChooser
from .pupil_path import PupilPath, layer_columns
from .reference_path import ReferencePath
from .render import PupilRenderer, StampSampler, stamp_placement
from .sizing import PupilGeometry, choose_geometry

if TYPE_CHECKING:
    from .block import PointSourceOptics
    from .pixel_view import PixelView
    from .telescope import Telescope

#: longest a source's screens are kept out of view when no layer's wind limits it sooner [s]: what sources that never
#: come back hold (a 60 s tracked pass sweeps ~26 stars a second out of view)
MAX_HOLD_S = 1.0


def line_of_sight(theta: np.ndarray, zenith_rad, azimuth_rad, rotation_rad) -> tuple[np.ndarray, ...]:
    """East, north and up components (not normalised) of the directions at detector offsets ``theta`` (..., 2)
    (x right, y down) [rad] from a boresight at zenith angle ``z``, azimuth ``A`` (from north through east) and
    field rotation ``psi`` (the image's up axis turned from the local elevation direction towards increasing
    azimuth) [rad]: ``b + alpha a + epsilon e`` (inverse gnomonic projection, Calabretta & Greisen 2002 Sec. 5.1.1),
    ``alpha, epsilon`` the offsets along azimuth and elevation, ``a``, ``e`` their unit vectors at the boresight."""
    return line_of_sight_at(theta[..., 0], -theta[..., 1], zenith_rad, azimuth_rad, rotation_rad)


def line_of_sight_at(xi: np.ndarray, eta: np.ndarray, zenith_rad, azimuth_rad, rotation_rad) -> tuple[np.ndarray, ...]:
    """:func:`line_of_sight` at offsets ``xi`` right and ``eta`` up on the image [rad] given apart (each one array,
    the same numbers: no stacked or strided offsets)."""
    c, s = np.cos(rotation_rad), np.sin(rotation_rad)
    alpha, epsilon = xi * c + eta * s, eta * c - xi * s                                   # along azimuth, elevation
    sa, ca, sz, cz = np.sin(azimuth_rad), np.cos(azimuth_rad), np.sin(zenith_rad), np.cos(zenith_rad)
    return sa * sz + alpha * ca - epsilon * sa * cz, ca * sz - alpha * sa - epsilon * ca * cz, cz + epsilon * sz


def _per_row(*values) -> tuple:
    """``values`` as float arrays (None as NaN, as ``np.asarray`` gives it), each (T, N) one whose every row holds one
    value as its first column (T, 1) (a window's boresight beside each of its tracks)."""
    out = []
    for value in values:
        value = np.asarray(value, dtype=float)
        if value.ndim == 2 and value.shape[1] > 1 and same_bits(value, value[:, :1]):
            value = value[:, :1]
        out.append(value)
    return tuple(out)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether float64 ``a`` and ``b`` (broadcast) hold the same bits everywhere (signed zeros and NaNs too)."""
    return bool((a.view(np.uint64) == b.view(np.uint64)).all())


def _along(values, t_s: np.ndarray) -> np.ndarray:
    """``values`` as floats, one per frame of ``t_s`` (a scalar broadcast)."""
    values = np.asarray(values, dtype=float)
    return values if values.shape == t_s.shape else np.broadcast_to(values, t_s.shape)


class Imager:
    """Point-source imaging through turbulence with a choice of PSF paths (:mod:`.paths`).

    The coordinator: it fixes the sampling at first use (:mod:`.sizing`), asks its
    :class:`.PathChooser` for each frame's path and hands the frames to that path's object
    (:class:`.AnalyticPath`, :class:`.PupilPath`, :class:`.ReferencePath`), which keep their own
    tables and screens. ``params`` is the ``optics`` block's ``Params``; ``label`` names the block in
    messages and log lines (:attr:`~evsda.graph.block.Block.label`); ``pixels``, the detector's pixels
    (:class:`.PixelView`), lets ``auto`` choose from what they see (:mod:`.paths`).
    """

    def __init__(self, telescope: Telescope, focal_plane: FocalPlane, wavelength_m: float,
                 atmosphere: Atmosphere | None, params: PointSourceOptics.Params, *, seed: tuple = (0,),
                 label: str = "optics", pixels: PixelView | None = None):
        self.telescope, self.wavelength = telescope, float(wavelength_m)
        self.atmosphere = atmosphere if atmosphere is not None and atmosphere.layers else None
        self.tolerance, self.focus = float(params.tolerance), params.focus
        self.revisit_s, self.pupil_samples = params.screen_revisit_s, params.pupil_samples
        self.stamp_size_px, self.seed, self.label = params.stamp_size_px, tuple(int(s) for s in seed), label
        self.pixel_scale = focal_plane.pixel_scale_rad                 # [rad]
        self.boresight = np.array([(focal_plane.width_px - 1) / 2, (focal_plane.height_px - 1) / 2])  # [pixel]
        self.geometry: PupilGeometry | None = None
        self.chooser = PathChooser(self, params.psf_path, pixels, params.share_far_probes)
        self.pupil = PupilPath(self, params.screen_method, params.screen_update, params.n_zernike_modes)
        self.reference = ReferencePath(self, params.grid_size)
        #: each path's renderer by name
        self.path_named = {"airy": AnalyticPath(self, "airy"), "long_exposure": AnalyticPath(self, "long_exposure"),
                           "pupil_fft": self.pupil, "reference": self.reference}
        self._pupil_renderer: PupilRenderer | None = None
        self._amplitude: np.ndarray | None = None
        #: PSFs rendered so far by each path (benchmarks compare the block's cost with theirs)
        self.frames_rendered: Counter = Counter()
        self._count_lock = threading.Lock()
        #: screens dropped so far per source that has left the view (:meth:`forget`): its next screens are the
        #: draw of this generation, never a reused seed stream
        self.generations: dict[str, int] = {}
        #: the screens' frame: the boresight's azimuth, zenith angle and field rotation [rad] at the first render
        #: time that has them (:meth:`set_frame`, :meth:`sight`); None until then
        self.frame: tuple[float, float, float] | None = None
        #: the last render time [ns] at which each source whose screens are held was in view (:meth:`release`)
        self.last_seen_ns: dict[str, int] = {}
        #: :attr:`hold_ns` and the geometry it was worked out for
        self._hold: tuple[PupilGeometry | None, int | None] = (None, None)
        #: on equivalent layers, each source's own frozen flow (:meth:`source_flow`): its first render time [s], its
        #: line of sight then (2,) [1] and, from its second render time on, its winds (L, 2) [m/s]
        self.flows: dict[str, tuple[float, np.ndarray, np.ndarray | None]] = {}
        #: with ``follow_sight_rate`` (:meth:`source_flow`) instead: each source's last render time [s], its line of
        #: sight then (2,) [1], its footprints' drift (L, 2) [m] and, from its second render time on, its winds then
        #: (L, 2) [m/s]
        self.follow_sight_rate = bool(params.follow_sight_rate)
        self.drifts: dict[str, tuple[float, np.ndarray, np.ndarray, np.ndarray | None]] = {}
        self._members: tuple | None = None              # member_columns of the atmosphere, made at first use
        #: :meth:`hold_of` of each source with its own winds, and the geometry and winds it was worked out for
        self._holds: dict[str, tuple[PupilGeometry, np.ndarray, int]] = {}

    # -- turbulence strength ----------------------------------------------------------------------
    def turbulent(self, zenith_rad: float) -> bool:
        return self.atmosphere is not None and bool(np.isfinite(zenith_rad))

    def r0(self, zenith_rad: float) -> float:
        """Fried parameter of the line of sight at the band's wavelength [m] (inf above the atmosphere)."""
        return self.atmosphere.r0(self.wavelength, zenith_rad) if self.turbulent(zenith_rad) else np.inf

    @property
    def outer_scale_m(self) -> float:
        """Von Karman outer scale L0 of the atmosphere [m] (inf without one)."""
        return self.atmosphere.L0 if self.atmosphere is not None else np.inf

    # -- sampling, fixed at first use ------------------------------------------------------------
    def ensure_geometry(self, zenith_rad: float) -> PupilGeometry:
        """The run's sampling (:mod:`.sizing`), chosen for the first line of sight it is asked for."""
        if self.geometry is None:
            self.geometry = choose_geometry(self.telescope, self.wavelength, self.pixel_scale, self.atmosphere,
                                            zenith_rad, self.r0(zenith_rad), tolerance=self.tolerance,
                                            stamp_size_px=self.stamp_size_px, pupil_samples=self.pupil_samples,
                                            label=self.label)
        return self.geometry

    @property
    def sampler(self) -> StampSampler:
        g = self.geometry
        return StampSampler(g.stamp_size, self.pixel_scale, g.oversample)

    @property
    def pupil_renderer(self) -> PupilRenderer:
        """Stamps from pupil phases or fields on the run's pupil grid (``pupil_fft``, ``reference``, the probes)."""
        if self._pupil_renderer is None:
            g = self.geometry
            # the amplitude first: a thread that finds the renderer made (the reference probes run on threads)
            # must find the amplitude too
            self._amplitude = self.telescope.pupil(g.n_pupil, g.delta_m)
            self._pupil_renderer = PupilRenderer(self.sampler, g.n_pupil, g.delta_m, self.wavelength,
                                                 self.telescope.collecting_area_m2)
        return self._pupil_renderer

    @property
    def pupil_amplitude(self) -> np.ndarray:
        """The aperture's transmission on the pupil grid (n, n) [1]."""
        self.pupil_renderer
        return self._amplitude

    # -- what every path shares -------------------------------------------------------------------
    def defocus(self, range_m: np.ndarray) -> np.ndarray:
        """Pupil phase [rad] of a finite-range source for a telescope focused at infinity, ``pi r^2/(lambda R)``."""
        if self.focus == "source":
            return np.zeros((len(range_m), 1, 1))
        g = self.geometry
        x = (np.arange(g.n_pupil) - g.n_pupil // 2) * g.delta_m
        r2 = x[None, :] ** 2 + x[:, None] ** 2
        return self.defocus_curvature(range_m)[:, None, None] * r2[None]

    def defocus_curvature(self, range_m: np.ndarray) -> np.ndarray:
        """``c`` [rad m^-2] of :meth:`defocus`'s phase ``c r^2``: ``pi / (lambda R)``, 0 when focused on the source."""
        if self.focus == "source":
            return np.zeros(len(range_m))
        curvature = np.where(np.isfinite(range_m), 1.0 / np.asarray(range_m, dtype=float), 0.0)
        return np.pi / self.wavelength * curvature

    def source_seed(self, source: str, family: int) -> tuple:
        """Seed of a source's screens: family 0 the pupil path's, 1 the reference path's, in the source's
        generation ``g`` (screens dropped so far, :meth:`forget`) as the word ``family + 2 g``."""
        return (*self.seed, zlib.crc32(source.encode()), family + 2 * self.generations.get(source, 0))

    def _screen_stores(self) -> tuple[dict, ...]:
        """The dicts that hold screens by source: the pupil path's (FFT and modal) and the reference path's."""
        return self.pupil.screens, self.pupil.modal_screens, self.reference.screens

    def holding(self) -> set[str]:
        """Sources whose screens are held (pupil or reference path)."""
        return set().union(*self._screen_stores())

    def forget(self, sources) -> None:
        """Drop the screens of sources that have left the view; one that comes back gets a new independent
        draw (its generation, :meth:`source_seed`). A source with no screens is left as it is."""
        for source in sources:
            held = [store.pop(source, None) for store in self._screen_stores()]
            self.last_seen_ns.pop(source, None)
            self.flows.pop(source, None)
            self.drifts.pop(source, None)
            self._holds.pop(source, None)
            if any(h is not None for h in held):
                self.generations[source] = self.generations.get(source, 0) + 1

    @property
    def hold_ns(self) -> int:
        """How long [ns] a source's screens are kept after its last render time in view.

        Frozen flow carries a layer's footprint ``|v| t`` across its screen; a screen's window holds
        ``n delta`` of it (:mod:`.sizing`), so after ``min over layers of n delta / |v|`` some layer's
        footprint has left the window it had and would need the screen continued farther than the
        screen kept: the screens are dropped then (a layer without wind limits nothing); at most
        ``MAX_HOLD_S`` (the memory held for sources that never come back). Worked out once a geometry.
        """
        geometry, hold = self._hold
        if geometry is not self.geometry or hold is None:
            limit = MAX_HOLD_S
            if self.atmosphere is not None and self.geometry is not None:
                for layer, n, delta in zip(self.atmosphere.layers, self.geometry.layer_n, self.geometry.layer_delta_m):
                    if layer.cn2_dh > 0 and layer.wind_speed_m_s > 0:
                        limit = min(limit, n * delta / layer.wind_speed_m_s)
            hold = int(round(limit * 1e9))
            self._hold = (self.geometry, hold)
        return hold

    def own_winds(self, source: str) -> np.ndarray | None:
        """A source's own winds (L, 2) [m/s] (:meth:`source_flow`): fixed at its first two render times, or with
        ``follow_sight_rate`` those of its last render time; None before its second render time or without them."""
        drifting = self.drifts.get(source)
        if drifting is not None:
            return drifting[3]
        flow = self.flows.get(source)
        return None if flow is None else flow[2]

    def hold_of(self, source: str) -> int:
        """:attr:`hold_ns` for one source: with its own winds (:meth:`own_winds`), the screens' window over their
        speeds, ``min over layers of n delta / |w|``, at most ``MAX_HOLD_S``; worked out once for its geometry and
        winds (every window asks it of every held source)."""
        winds = self.own_winds(source)
        if winds is None or self.geometry is None:
            return self.hold_ns
        kept = self._holds.get(source)
        if kept is not None and kept[0] is self.geometry and kept[1] is winds:
            return kept[2]
        limit = MAX_HOLD_S
        for layer, wind, n, delta in zip(self.atmosphere.layers, winds, self.geometry.layer_n,
                                         self.geometry.layer_delta_m):
            speed = float(np.hypot(wind[0], wind[1]))
            if layer.cn2_dh > 0 and speed > 0:
                limit = min(limit, n * delta / speed)
        hold = int(round(limit * 1e9))
        self._holds[source] = (self.geometry, winds, hold)
        return hold

    def keeps(self, source: str, t_ns: int) -> bool:
        """Whether a source in view again at render time ``t_ns`` continues its held screens (:meth:`hold_of`)."""
        seen = self.last_seen_ns.get(source)
        return seen is not None and int(t_ns) - seen <= self.hold_of(source)

    def seen(self, source: str, t_ns: int) -> None:
        """Record render time ``t_ns`` [ns] as the last a source was in view, if it holds screens."""
        if any(source in store for store in self._screen_stores()):
            self.last_seen_ns[source] = int(t_ns)

    def release(self, t_ns: int) -> None:
        """Drop the screens of sources not in view since ``hold_ns`` or more before render time ``t_ns``: none can
        keep them at a later render time. Reads render times only, so windows and resumes do not change it."""
        gone = [s for s in sorted(self.holding()) if int(t_ns) - self.last_seen_ns.get(s, -2**62) >= self.hold_of(s)]
        self.forget(gone)

    def epochs_of(self, t_s: np.ndarray) -> np.ndarray:
        """Screen epoch of each time [1]: all screens are redrawn every ``screen_revisit_s``."""
        if not self.revisit_s:
            return np.zeros(t_s.shape, dtype=np.int64)
        return np.floor(t_s / self.revisit_s + 1e-9).astype(np.int64)

    # -- where the lines of sight cross the layers --------------------------------------------------
    def set_frame(self, azimuth_rad: float, zenith_rad: float, rotation_rad: float) -> None:
        """Fix the screens' frame to the boresight's azimuth, zenith angle and field rotation [rad] at the run's
        first render time that has them (:meth:`sight`); later calls leave it as it is."""
        if self.frame is None and np.isfinite([azimuth_rad, zenith_rad, rotation_rad]).all():
            self.frame = (float(azimuth_rad), float(zenith_rad), float(rotation_rad))

    def sight(self, x_px, y_px, zenith_rad, azimuth_rad=None, rotation_rad=None) -> np.ndarray:
        """Where each frame's line of sight crosses the layers, per metre of altitude, in the screens' frame
        (F, 2) [1]: a layer at altitude ``h`` holds the footprint's centre at ``h sight - v t`` (:meth:`footprints`).

        The source's direction follows from its pixel (inverse gnomonic projection, :mod:`evsda.blocks.scene.
        projection`) and the boresight's azimuth ``A``, zenith angle ``z`` and field rotation ``psi`` (the image's
        up axis turned from the local elevation direction towards increasing azimuth; ``PointSources``): with
        ``alpha, epsilon`` its offsets along azimuth and elevation, its ENU direction is ``b + alpha a + epsilon e``
        (``a``, ``e`` the unit azimuth and elevation directions at the boresight ``b``) and a horizontal layer
        is crossed at ``g = (s_E, s_N) / s_U`` per metre of altitude (``tan z (sin A, cos A)``).

        The screens' frame is fixed to the ground at the first render time (:meth:`set_frame`; ``A0, z0, psi0``):
        ``g`` less the boresight's ``g0`` there, its horizontal component towards azimuth ``A0`` times ``cos z0``
        (the plane across the beam: two directions ``theta`` apart then sit ``theta sec z0`` apart whichever way,
        Fried 1982), turned onto the detector's axes at that time. At that time a source at pixel offset ``theta``
        [rad] sits at ``theta sec z0`` to first order, as a staring mount's sources always do. Not modelled: the
        pupil's turn against the ground-fixed screens as the mount turns in azimuth or the field rotates, and the
        ``cos z`` of the elevation direction when ``z`` departs from ``z0`` (the footprint is read as a round
        aperture on grids along the frame's axes; isotropic turbulence keeps the PSF's statistics; over the 10 s
        tracked pass of benchmarks/end_to_end.yaml: 3.2 deg of azimuth, ``cos z / cos z0`` 1.078 at its end).

        Without the boresight's azimuth (``azimuth_rad`` None or NaN: sources given on the focal plane only) the
        sources are taken as seen from a staring mount: ``theta sec z`` with the frame on the detector's axes.
        """
        x_px, y_px = np.asarray(x_px, dtype=float), np.asarray(y_px, dtype=float)
        # the offsets' two components apart, and a boresight the same in every column (a window's tracks side by
        # side) as one column: the same numbers element by element, broadcast (its sines and cosines once a frame)
        zenith, azimuth, rotation = _per_row(zenith_rad, azimuth_rad, rotation_rad)
        zenith = np.where(np.isfinite(zenith), zenith, 0.0)
        theta_x = (x_px - self.boresight[0]) * self.pixel_scale                          # (right, down) [rad]
        theta_y = (y_px - self.boresight[1]) * self.pixel_scale
        secant = np.cos(zenith)
        staring = (theta_x / secant, theta_y / secant)
        if azimuth_rad is None or self.frame is None:
            return np.stack(staring, axis=-1)
        known = np.isfinite(azimuth) & np.isfinite(rotation)
        east, north, up = line_of_sight_at(theta_x, -theta_y, zenith, azimuth, rotation)
        a0, z0, psi0 = self.frame
        with np.errstate(invalid="ignore", divide="ignore"):
            ge, gn = east / up - np.sin(a0) * np.tan(z0), north / up - np.cos(a0) * np.tan(z0)
        along_azimuth = ge * np.cos(a0) - gn * np.sin(a0)                                 # [1] per metre of altitude
        outwards = (ge * np.sin(a0) + gn * np.cos(a0)) * np.cos(z0)
        grounded = (along_azimuth * np.cos(psi0) + outwards * np.sin(psi0),
                    outwards * np.cos(psi0) - along_azimuth * np.sin(psi0))
        return np.stack([np.where(known, g, s) for g, s in zip(grounded, staring)], axis=-1)

    def placement(self, x_px, y_px, zenith_rad, azimuth_rad=None, rotation_rad=None) -> tuple[np.ndarray, ...]:
        """Stamp origins (..., 2) int32 and sub-pixel offsets (..., 2) [pixel] (:func:`.stamp_placement`) and lines
        of sight (..., 2) [1] (:meth:`sight`) of frames of any shape: a window's render times by its tracks in one
        call, element by element, so the same numbers as a track's frames alone (:meth:`render`'s ``placed``)."""
        origin, offset = stamp_placement(x_px, y_px, self.geometry.stamp_size)
        return origin, offset, self.sight(x_px, y_px, zenith_rad, azimuth_rad, rotation_rad)

    def footprints(self, layer, t_s, sight, zenith_rad, range_m):
        """Footprint centre on a layer (F, 2) (x, y) [m], ``h sight - v t`` (:meth:`sight`), and its scale (F,) [1]."""
        centre, scale = self.footprints_of([layer], t_s, sight, zenith_rad, range_m)
        return centre[0], scale[0]

    @staticmethod
    def footprints_of(layers, t_s, sight, zenith_rad, range_m):
        """:meth:`footprints` of every layer at once: centres (L, F, 2) [m] and scales (L, F) [1], ``1 - L / R`` for a
        source at range ``R`` (``L = h sec z`` the slant distance to the layer)."""
        return Imager.footprints_at(*layer_columns(layers)[:2], t_s, sight, zenith_rad, range_m)

    @staticmethod
    def footprints_at(altitude, wind, t_s, sight, zenith_rad, range_m):
        """:meth:`footprints_of` from the layers' altitudes (L, 1) [m] and winds (L, 1, 2) [m/s] (:func:`layer_columns`,
        which a caller may keep)."""
        slant = altitude / np.cos(zenith_rad)
        centre = altitude[:, :, None] * np.asarray(sight, dtype=float) - wind * np.asarray(t_s)[:, None]
        finite = np.isfinite(range_m)
        scale = np.where(finite, 1.0 - slant / np.where(finite, range_m, 1.0), 1.0)
        return centre, scale

    def source_flow(self, source: str, t_s: np.ndarray,
                    sight: np.ndarray) -> tuple[np.ndarray, np.ndarray | None] | None:
        """A source's own winds (L, 2) [m/s] and the times (F,) [s] they carry its footprints over, on equivalent
        layers (:attr:`.Atmosphere.members`; None on a profile's own layers, whose winds serve every source); with
        ``follow_sight_rate``, its footprints' drifts (L, F, 2) [m] and None (:meth:`source_drift`).

        Its footprints sit at ``h sight - w (t - t0)``: ``w`` from :func:`.footprint_winds` for the rate ``s'`` of its
        line of sight between its first render time ``t0`` and its second (``sight`` (F, 2) at ``t_s`` (F,), these
        frames'), so that its footprints' ``sum J |u|^(5/3)`` is the full profile's at that ``s'``. Measured from
        render times only, so the same however the run is cut into windows; at ``t0`` the winds play no part (zero
        until they are known). Kept with the screens (:meth:`forget`)."""
        if self.atmosphere is None or self.atmosphere.members is None:
            return None
        if self.follow_sight_rate:
            return self.source_drift(source, t_s, sight), None
        flow = self.flows.get(source)
        if flow is None:
            flow = self.flows[source] = (float(t_s[0]), np.array(sight[0], dtype=float), None)
        start, first_sight, winds = flow
        if winds is None:
            later = np.flatnonzero(t_s > start)
            if later.size:
                k = int(later[0])
                rate = (np.asarray(sight[k], dtype=float) - first_sight) / (float(t_s[k]) - start)
                winds = footprint_winds(self.atmosphere, np.where(np.isfinite(rate), rate, 0.0))
                self.flows[source] = (start, first_sight, winds)
        if winds is None:
            winds = np.zeros((len(self.atmosphere.layers), 2))
        return winds, np.asarray(t_s, dtype=float) - start

    def source_drift(self, source: str, t_s: np.ndarray, sight: np.ndarray) -> np.ndarray:
        """With ``follow_sight_rate``: a source's footprints' drifts (L, F, 2) [m] at render times ``t_s`` (F,) [s]
        along ``sight`` (F, 2): its footprints sit at ``h sight - drift``, the drift zero at its first render time
        and growing by ``w(s') dt`` from each render time to the next, ``w(s')`` :func:`.footprint_winds`' for the
        line of sight's rate ``s'`` between them (:func:`.follow_drift`), so that its footprints' ``sum J
        |u|^(5/3)`` is the full profile's at every render time (fixed winds keep it at the first ``s'`` only:
        ~1 % off over a 3-minute tracked pass, docs/optics.md). Advanced render time by render time and kept with
        the screens (:meth:`forget`, checkpoints), so the same however the run is cut into windows."""
        if self._members is None:
            self._members = member_columns(self.atmosphere)
        t_s = np.ascontiguousarray(t_s, dtype=float)
        sight = np.ascontiguousarray(sight, dtype=float)
        held = self.drifts.get(source)
        count = len(self.atmosphere.layers)
        if not len(t_s):
            return np.empty((count, 0, 2))
        if held is None:
            held = (float(t_s[0]), sight[0].copy(), np.zeros((count, 2)), None)
        last_t, last_sight, drift, winds = held
        last_sight, drift = last_sight.copy(), drift.copy()           # a checkpoint taken before keeps its numbers
        now = np.zeros((count, 2)) if winds is None else winds.copy()
        out = np.empty((count, len(t_s), 2))
        last_t, advanced = follow_drift(*self._members, t_s, sight, last_t, last_sight, drift, now, out)
        self.drifts[source] = (float(last_t), last_sight, drift, now if winds is not None or advanced else None)
        return out

    # -- rendering --------------------------------------------------------------------------------
    def _paths(self, source: str, zenith_rad: np.ndarray, range_m: np.ndarray, seen: np.ndarray | None,
               prepare: bool = False, keys: list[tuple] | None = None) -> list[str]:
        """Each frame's path: the choice of its bin (:meth:`.PathChooser.keys`, or ``keys`` made for these frames),
        made at the first frame of each bin in order (and, with ``prepare``, the analytic path's table for that
        frame's zenith angle)."""
        if keys is None:
            keys = self.chooser.keys(zenith_rad, range_m, seen)
        if keys and keys.count(keys[0]) == len(keys):  # one bin throughout (the usual track): its first frame's
            path = self.chooser.choose_key(keys[0], float(zenith_rad[0]), source).path
            if prepare and path in ANALYTIC_PATHS:
                self.path_named[path].renderer(zenith_rad[0])
            return [path] * len(keys)
        # each bin's first frame (the smallest index, written last), in the order the frames meet them
        first = dict(zip(reversed(keys), range(len(keys) - 1, -1, -1)))
        chosen = {}
        for key, i in sorted(first.items(), key=lambda item: item[1]):
            chosen[key] = path = self.chooser.choose_key(key, float(zenith_rad[i]), source).path
            if prepare and path in ANALYTIC_PATHS:
                self.path_named[path].renderer(zenith_rad[i])
        return list(map(chosen.__getitem__, keys))

    def prepare(self, source: str, zenith_rad: np.ndarray, range_m: np.ndarray,
                seen: np.ndarray | None = None, keys: list[tuple] | None = None) -> list[str]:
        """Make the path choices and shared tables a track needs, so that sources can then render concurrently;
        returns each frame's path (for :meth:`render`'s ``paths``).

        ``seen`` (F, 3): each frame's apparent rate [pixel/s], collected source flux [photon/s] and sky
        [photon/s per pixel], for a chooser that knows the detector (:meth:`.PathChooser.key`); ``keys``: these
        frames' bins, if made already (:meth:`.PathChooser.keys` of many tracks' frames at once)."""
        range_m, zenith_rad = np.asarray(range_m, dtype=float), np.asarray(zenith_rad, dtype=float)
        if zenith_rad.shape != range_m.shape:
            zenith_rad = np.broadcast_to(zenith_rad, range_m.shape)
        self.ensure_geometry(float(zenith_rad[0]) if len(zenith_rad) else np.nan)
        self.pupil_renderer
        paths = self._paths(source, zenith_rad, range_m, seen, prepare=True, keys=keys)
        if self.pupil.screen_method == "zernike" and self.atmosphere:
            self.pupil.pupil_modes
        return paths

    def render(self, source: str, t_s: np.ndarray, x_px: np.ndarray, y_px: np.ndarray,
               zenith_rad: np.ndarray, range_m: np.ndarray, seen: np.ndarray | None = None, *,
               azimuth_rad: np.ndarray | None = None, rotation_rad: np.ndarray | None = None,
               paths: list[str] | None = None,
               placed: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Stamps along a track: ``origin`` (F, 2) int32, energy fractions (F, M, M) [1], path per frame
        (``seen``: as for :meth:`prepare`; ``azimuth_rad``, ``rotation_rad``: the boresight's azimuth and the field
        rotation of each frame, :meth:`sight`; ``paths``: these frames' paths as :meth:`prepare` returned them, the
        same choices without looking each frame's bin up again; ``placed``: these frames' :meth:`placement`, made
        for a whole window at once, instead of from ``x_px``, ``y_px`` and the boresight here)."""
        t_s = np.asarray(t_s, dtype=float)
        zenith_rad, range_m = _along(zenith_rad, t_s), _along(range_m, t_s)
        self.ensure_geometry(float(zenith_rad[0]) if len(zenith_rad) else np.nan)
        size = self.geometry.stamp_size
        if paths is None:
            paths = self._paths(source, zenith_rad, range_m, seen)
        if placed is None:
            if azimuth_rad is not None:
                azimuth_rad, rotation_rad = _along(azimuth_rad, t_s), _along(rotation_rad, t_s)
            placed = self.placement(np.asarray(x_px, dtype=float), np.asarray(y_px, dtype=float), zenith_rad,
                                    azimuth_rad, rotation_rad)
        origin, offset, sight = placed
        if len(set(paths)) == 1:                      # one path throughout (the usual stretch): all frames at once
            path = str(paths[0])
            with self._count_lock:
                self.frames_rendered[path] += len(t_s)
            return origin, self.path_named[path].render(source, t_s, sight, zenith_rad, range_m, offset), paths
        stamps = np.zeros((len(t_s), size, size))
        named = np.asarray(paths, dtype=str)
        for path in PATHS:
            idx = np.flatnonzero(named == path)
            if idx.size == 0:
                continue
            with self._count_lock:
                self.frames_rendered[path] += int(idx.size)
            stamps[idx] = self.path_named[path].render(source, t_s[idx], sight[idx], zenith_rad[idx], range_m[idx],
                                                       offset[idx])
        return origin, stamps, paths

    def renders_together(self, path: str) -> bool:
        """Whether frames of ``path`` can render several sources in one call (:meth:`render_many`)."""
        return path == "pupil_fft" and self.pupil.batches()

    def render_many(self, sources: list[str], t_s: np.ndarray, zenith_rad: np.ndarray, range_m: np.ndarray,
                    placed: tuple[np.ndarray, ...]) -> np.ndarray:
        """:meth:`render`'s stamps (S, F, M, M) [1] of several sources at the same times ``t_s`` (F,) [s], every frame
        on the ``pupil_fft`` path (:meth:`renders_together`): ``zenith_rad``, ``range_m`` (S, F), ``placed`` their
        :meth:`placement` (S, F, ...). Each source's stamps are those of its own :meth:`render`, bit for bit (its own
        screens, the same steps frame by frame), for one walk of all their screens and one stamps call."""
        count, frames = np.shape(zenith_rad)
        with self._count_lock:
            self.frames_rendered["pupil_fft"] += count * frames
        origin, offset, sight = placed
        return self.pupil.render_many(sources, np.asarray(t_s, dtype=float), np.asarray(sight, dtype=float),
                                      np.asarray(zenith_rad, dtype=float), np.asarray(range_m, dtype=float),
                                      np.asarray(offset, dtype=float))

    # -- checkpoint -------------------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "geometry": None if self.geometry is None else self.geometry.state(),
            "screens": self.pupil.state(),
            "reference_screens": self.reference.state(),
            "generations": dict(self.generations),
            "frame": None if self.frame is None else list(self.frame),
            "last_seen_ns": dict(self.last_seen_ns),
            **({"flows": {source: [start, first_sight.tolist(), None if winds is None else winds.tolist()]
                          for source, (start, first_sight, winds) in self.flows.items()}} if self.flows else {}),
            **({"drifts": {source: [last_t, last_sight.tolist(), drift.tolist(),
                                    None if winds is None else winds.tolist()]
                           for source, (last_t, last_sight, drift, winds) in self.drifts.items()}}
               if self.drifts else {}),
        }

    def set_state(self, state: dict) -> None:
        geometry = state.get("geometry")
        self.geometry = None if geometry is None else PupilGeometry.from_state(geometry)
        self._pupil_renderer = None
        for path in ANALYTIC_PATHS:
            self.path_named[path].forget()
        self.chooser.forget()
        self.generations = {str(k): int(v) for k, v in (state.get("generations") or {}).items()}
        frame = state.get("frame")
        self.frame = None if frame is None else tuple(float(v) for v in frame)
        self.last_seen_ns = {str(k): int(v) for k, v in (state.get("last_seen_ns") or {}).items()}
        self.flows = {str(k): (float(start), np.array(first_sight, dtype=float),
                               None if winds is None else np.array(winds, dtype=float))
                      for k, (start, first_sight, winds) in (state.get("flows") or {}).items()}
        self.drifts = {str(k): (float(last_t), np.array(last_sight, dtype=float), np.array(drift, dtype=float),
                                None if winds is None else np.array(winds, dtype=float))
                       for k, (last_t, last_sight, drift, winds) in (state.get("drifts") or {}).items()}
        self.pupil.modal_screens = {}
        self.pupil.set_state(state.get("screens") or {})
        self.reference.set_state(state.get("reference_screens") or {})
