"""The sensor frame versus time: boresight ``b``, image right ``r`` and image up ``u`` in the GCRS.

The frame is right-handed with ``r = b x u``: looking along ``b`` with ``u`` up, ``r``
is to the right, so the image shows the sky as seen, not mirrored (north up puts east
on the left). Reference up directions:

* ``stare`` and ``track`` from the ground: ``u = d b / d elevation``, the direction of
  increasing elevation at the boresight's azimuth, which stays defined at the zenith;
* ``sidereal`` and ``track`` from space: ``u = d b / d declination`` (towards celestial
  north), defined at the celestial poles too;
* ``scan``, ``raster`` and ``slew``: the same as ``stare`` in azimuth/elevation
  coordinates, as ``sidereal`` in RA/Dec, at the boresight's current position
  (:mod:`evsda.blocks.scene.scanning` gives the coordinates versus time). RA/Dec
  positions are made apparent with the observer's aberration (Kaplan et al. 1989), as
  Skyfield's ``apparent()`` does for a star, without the Sun's light deflection
  (< 0.02 arcsec more than 20 deg from the Sun).

``roll`` then turns ``u`` towards ``r`` by the roll angle.
"""

from __future__ import annotations

import threading
from datetime import datetime

import numpy as np
from skyfield.api import Star

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import AZEL, RADEC, RASTER, SCAN, SIDEREAL, SLEW, STARE, TRACK, Observer, Pointing
from evsda.graph import ParameterError

from . import projection
from .geometry import (NS_PER_S, OMEGA_EARTH_RAD_S, KnotGrid, ObserverModel, Recent, aberrate,
                       apparent_position, satellite_track, unit)
from .scanning import Raster, Scan, Slew, unit_from_lonlat

#: the scene blocks refuse a moving pointing law that moves the sky by more than this between samples [pixel]
MAX_STEP_PX = 1.0
#: a slew must keep this far from the zenith or celestial pole, where the image's up direction turns fast [deg]
POLE_CLEARANCE_DEG = 1.0


def direction_from_azel(azimuth_rad, elevation_rad) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction and its d/d(elevation) in east-north-up components, each ``[..., 3]``."""
    sa, ca, se, ce = np.sin(azimuth_rad), np.cos(azimuth_rad), np.sin(elevation_rad), np.cos(elevation_rad)
    direction = np.stack([sa * ce, ca * ce, se], axis=-1)
    up = np.stack([-sa * se, -ca * se, ce], axis=-1)
    return direction, up


def azel_from_enu(e, n, u) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (from north through east, in [0, 2 pi)) and elevation [rad] of ENU components."""
    azimuth = np.mod(np.arctan2(e, n), 2.0 * np.pi)
    elevation = np.arctan2(u, np.hypot(e, n))
    return azimuth, elevation


def north_of(b: np.ndarray) -> np.ndarray:
    """``d b / d declination`` for unit vectors ``b`` in equatorial (GCRS) axes."""
    ra = np.arctan2(b[:, 1], b[:, 0])
    dec = np.arcsin(np.clip(b[:, 2], -1.0, 1.0))
    return np.stack([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)], axis=-1)


def apply_roll(b, u, roll_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Right and up axes after turning the up axis by ``roll_rad`` towards the right axis."""
    r = np.cross(b, u)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    return c * r - s * u, c * u + s * r


class PointingModel:
    """A :class:`Pointing` law evaluated for one observer: the sensor frame at any time."""

    def __init__(self, pointing: Pointing, observer: ObserverModel, epoch: datetime, knot_step_ns: int):
        self.pointing = pointing
        self.observer = observer
        self._recent = Recent()       # shared by the scene's blocks (shared_models), a window or two apart
        self._recent_angles = Recent()
        if pointing.mode == TRACK:
            if not (pointing.target_line1 and pointing.target_line2):
                raise ParameterError("pointing: mode 'track' needs a target orbit (connect a tle_source to its "
                                     "'target' input)")
            self.target = satellite_track(epoch, knot_step_ns, pointing.target_line1, pointing.target_line2)
        elif pointing.mode == SIDEREAL:
            star = Star(ra_hours=pointing.ra_deg / 15.0, dec_degrees=pointing.dec_deg)
            sky_observer = observer.skyfield_observer()
            self.field = KnotGrid(epoch, knot_step_ns,
                                  lambda t: (unit(sky_observer.at(t).observe(star).apparent().xyz.m.T),))
        elif pointing.is_moving:
            self.law = moving_law(pointing)
        elif pointing.mode != STARE:
            raise ParameterError(f"pointing: unknown mode {pointing.mode!r}; expected stare, sidereal, track, "
                                 f"scan, raster or slew")

    def frame(self, t_ns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Boresight, right and up unit vectors at ``t_ns``, each ``[n, 3]`` (GCRS; read-only arrays)."""
        return self._recent.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._frame)

    def _frame(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = self.pointing
        if p.mode == STARE:
            b, u = self._from_horizon(t_ns, *direction_from_azel(np.radians(p.azimuth_deg),
                                                                  np.radians(p.elevation_deg)))
        elif p.mode == SIDEREAL:
            b = self._sidereal_boresight(t_ns)
            u = north_of(b)
        elif p.is_moving:
            b, u = self._moving(t_ns)
        else:
            b = unit(apparent_position(self.target, self.observer, t_ns))
            if self.observer.observer.is_ground:
                east, north, up = self.observer.enu(t_ns)
                az, el = azel_from_enu(*(np.einsum("ij,ij->i", b, axis) for axis in (east, north, up)))
                b_enu, u_enu = direction_from_azel(az, el)
                u = u_enu[:, :1] * east + u_enu[:, 1:2] * north + u_enu[:, 2:] * up
            else:
                u = north_of(b)
        r, u = apply_roll(b, u, np.radians(p.roll_deg))
        return b, r, u

    def _from_horizon(self, t_ns, b_enu, u_enu):
        east, north, up = self.observer.enu(t_ns)
        b = b_enu[0] * east + b_enu[1] * north + b_enu[2] * up
        u = u_enu[0] * east + u_enu[1] * north + u_enu[2] * up
        return b, u

    def _moving(self, t_ns) -> tuple[np.ndarray, np.ndarray]:
        """Boresight and up of a scan, raster or slew at ``t_ns`` (GCRS)."""
        lon, lat = self.law.coordinates(t_ns / NS_PER_S)
        if self.pointing.coordinates == AZEL:
            b_enu, u_enu = direction_from_azel(np.radians(lon), np.radians(lat))
            east, north, up = self.observer.enu(t_ns)
            b = b_enu[:, :1] * east + b_enu[:, 1:2] * north + b_enu[:, 2:] * up
            u = u_enu[:, :1] * east + u_enu[:, 1:2] * north + u_enu[:, 2:] * up
            return b, u
        _, v_observer = self.observer.state(t_ns)
        _, v_earth = self.observer.earth.state(t_ns)
        b = unit(aberrate(unit_from_lonlat(lon, lat), v_earth + v_observer))
        return b, north_of(b)

    def moving_rate_bound_rad_s(self) -> float:
        """Upper bound of the sensor frame's angular speed in the GCRS for a moving law [rad/s]; 0 otherwise.

        The frame turns with the coordinate rates (azimuth about the vertical, elevation
        about a horizontal axis, or RA and Dec likewise) plus the horizon frame's own
        rotation: the Earth's (ground) or the orbital rate (space); the magnitude of a sum
        of rotations is at most the sum of their rates.
        """
        if not self.pointing.is_moving:
            return 0.0
        lon_rate, lat_rate = self.law.max_coordinate_rates()
        rate = np.radians(lon_rate + lat_rate)
        if self.pointing.coordinates == AZEL:
            rate += OMEGA_EARTH_RAD_S if self.observer.observer.is_ground else self._orbital_rate()
        return float(rate)

    def _orbital_rate(self) -> float:
        r, v = self.observer.state(np.array([0.0]))
        return float(2.0 * np.linalg.norm(v) / np.linalg.norm(r))

    def sky_step_px(self, focal_plane: FocalPlane, cadence_ns: int, start_ns: int, stop_ns: int) -> float:
        """Largest distance a fixed sky direction moves on the detector between two samples ``cadence_ns`` apart.

        Measured at the boresight and the four detector corners over ``[start_ns, stop_ns]``
        (up to 4000 sample pairs, at least one every 10 ms for runs up to 40 s) [pixel].
        """
        n = int(min(4000, max(2, (stop_ns - start_ns) // 10_000_000 + 1)))
        t0 = np.linspace(start_ns, max(start_ns, stop_ns - cadence_ns), n)
        frames0 = self.frame(t0)
        frames1 = self.frame(t0 + cadence_ns)
        w, h = focal_plane.width_px, focal_plane.height_px
        points = [((w - 1) / 2, (h - 1) / 2), (-0.5, -0.5), (w - 0.5, -0.5), (-0.5, h - 0.5), (w - 0.5, h - 0.5)]
        step = 0.0
        for x, y in points:
            direction = projection.deproject(np.full(n, x), np.full(n, y), *frames0, focal_plane)
            x1, y1 = projection.project(direction, *frames1, focal_plane)
            step = max(step, float(np.nanmax(np.hypot(x1 - x, y1 - y))))
        return step

    def _sidereal_boresight(self, t_ns):
        """The apparent place of the field centre, linearly interpolated between knots.

        Aberration moves it by at most ~1e-4 arcsec per second, so the interpolation
        error is far below a microarcsecond.
        """
        step = self.field.step_ns
        k = np.floor(t_ns / step).astype(np.int64)
        (b0,) = self.field.values(k)
        (b1,) = self.field.values(k + 1)
        w = ((t_ns - k * step) / step)[:, None]
        return unit((1 - w) * b0 + w * b1)

    def boresight_angles(self, t_ns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The boresight's zenith angle, its azimuth and the field rotation at ``t_ns`` [rad] (:meth:`zenith_angle`
        and :meth:`horizon` of the frame at those times; read-only arrays, kept like the frame for the scene's
        other blocks)."""
        return self._recent_angles.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._boresight_angles)

    def _boresight_angles(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        b, _, u = self.frame(t_ns)
        return (self.zenith_angle(t_ns, b), *self.horizon(t_ns, b, u))

    def horizon(self, t_ns, b: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The boresight's azimuth (from north through east) and the field rotation [rad] at
        ``t_ns``, for the sensor frame's boresight ``b`` and image up ``u`` ([n, 3], GCRS); NaN from space.

        The field rotation is the angle from the local elevation direction at the boresight (``d b / d el``,
        :func:`direction_from_azel`) to ``u``, positive towards increasing azimuth: the roll for ``stare``,
        ``track`` from the ground and azimuth/elevation scans; for ``sidereal`` it also holds the parallactic
        angle, which turns through the run.
        """
        n = len(b)
        if not self.observer.observer.is_ground:
            return np.full(n, np.nan), np.full(n, np.nan)
        east, north, up = self.observer.enu(t_ns)
        azimuth, elevation = azel_from_enu(*(np.einsum("ij,ij->i", b, axis) for axis in (east, north, up)))
        _, rising = direction_from_azel(azimuth, elevation)
        rising = rising[:, :1] * east + rising[:, 1:2] * north + rising[:, 2:] * up
        turning = np.cos(azimuth)[:, None] * east - np.sin(azimuth)[:, None] * north
        rotation = np.arctan2(np.einsum("ij,ij->i", u, turning), np.einsum("ij,ij->i", u, rising))
        return azimuth, rotation

    def zenith_angle(self, t_ns, b: np.ndarray) -> np.ndarray:
        """Zenith angle of the boresight [rad]; NaN for a space observer (no atmosphere)."""
        if not self.observer.observer.is_ground:
            return np.full(len(b), np.nan)
        _, _, up = self.observer.enu(t_ns)
        return np.arccos(np.clip(np.einsum("ij,ij->i", b, up), -1.0, 1.0))


def moving_law(pointing: Pointing):
    """The :mod:`~evsda.blocks.scene.scanning` law of a scan, raster or slew, checked."""
    p = pointing
    if p.coordinates not in (AZEL, RADEC):
        raise ParameterError(f"pointing: unknown coordinates {p.coordinates!r}; expected azel or radec")
    lon0, lat0 = (p.azimuth_deg, p.elevation_deg) if p.coordinates == AZEL else (p.ra_deg, p.dec_deg)
    if p.mode == SCAN:
        return Scan(lon0, lat0, p.lon_rate_deg_s, p.lat_rate_deg_s)
    if p.mode == RASTER:
        return Raster(lon0, lat0, p.raster_width_deg, p.raster_rows, p.raster_row_step_deg, p.scan_rate_deg_s,
                      p.max_rate_deg_s, p.max_acceleration_deg_s2)
    slew = Slew(lon0, lat0, p.to_lon_deg, p.to_lat_deg, p.slew_start_s, p.max_rate_deg_s, p.max_acceleration_deg_s2)
    clearance = slew.path_closest_to_pole_deg()
    if clearance < POLE_CLEARANCE_DEG:
        pole = "the zenith or nadir" if p.coordinates == AZEL else "a celestial pole"
        raise ParameterError(f"pointing: the slew passes {clearance:.2f} deg from {pole}, where the image's up "
                             f"direction is undefined; keep it {POLE_CLEARANCE_DEG:g} deg away (split it in two)")
    return slew


_FINGERPRINTS: dict[int, tuple[object, str]] = {}
_FINGERPRINTS_KEPT = 32


def fingerprint(value) -> str:
    """``value.fingerprint()`` (a frozen port value), kept for the last few values by identity: the values a
    source block hands on unchanged every window (the site, the camera's focal plane, a pointing law) are
    hashed once, not once a window by every block that reads them."""
    kept = _FINGERPRINTS.get(id(value))
    if kept is not None and kept[0] is value:       # (kept here, the value keeps its id)
        return kept[1]
    digest = value.fingerprint()
    if len(_FINGERPRINTS) >= _FINGERPRINTS_KEPT:
        _FINGERPRINTS.clear()
    _FINGERPRINTS[id(value)] = (value, digest)
    return digest


_SHARED_MODELS: dict[tuple, tuple[ObserverModel, PointingModel]] = {}
_SHARED_LOCK = threading.Lock()
_SHARED_KEPT = 8


def shared_models(observer: Observer, pointing: Pointing, epoch: datetime,
                  knot_step_ns: int) -> tuple[ObserverModel, PointingModel]:
    """The observer and pointing models for these inputs, one pair per process.

    The scene's blocks that see through the same pointed sensor (the satellites, the stars,
    the sky) sample its frame at the same times each window: with one pair of models they
    compute it, and the observer's state and horizon axes, once, not once per block. The
    models only cache what they compute (knot values, the last few samples' results, as
    read-only arrays), so a block gets the same values whether or not another asked first.
    """
    key = (fingerprint(observer), fingerprint(pointing), epoch, int(knot_step_ns))
    with _SHARED_LOCK:
        models = _SHARED_MODELS.get(key)
        if models is None:
            observer_model = ObserverModel(observer, epoch, knot_step_ns)
            models = (observer_model, PointingModel(pointing, observer_model, epoch, knot_step_ns))
            while len(_SHARED_MODELS) >= _SHARED_KEPT:
                del _SHARED_MODELS[next(iter(_SHARED_MODELS))]
            _SHARED_MODELS[key] = models
    return models


def check_sampling(model: PointingModel, focal_plane: FocalPlane, cadence_ns: int, start_ns: int, stop_ns: int,
                   who: str) -> None:
    """Refuse a scan, raster or slew that moves the sky by more than :data:`MAX_STEP_PX` between samples.

    A source sampled every ``cadence_ns`` and held in between jumps by that step; beyond
    one pixel its image hops instead of sweeping over the pixels. The error gives the
    largest usable rates (the commanded ones scaled to one pixel per sample) and the
    largest usable cadence.
    """
    p = model.pointing
    if not p.is_moving:
        return
    step = model.sky_step_px(focal_plane, cadence_ns, start_ns, stop_ns)
    if step <= MAX_STEP_PX:
        return
    scale = MAX_STEP_PX / step
    rates = {SCAN: [("azimuth" if p.coordinates == AZEL else "ra") + "_rate_deg_s", p.lon_rate_deg_s,
                    ("elevation" if p.coordinates == AZEL else "dec") + "_rate_deg_s", p.lat_rate_deg_s],
             RASTER: ["scan_rate_deg_s", p.scan_rate_deg_s, "max_rate_deg_s", p.max_rate_deg_s],
             SLEW: ["max_rate_deg_s", p.max_rate_deg_s]}[p.mode]
    usable = ", ".join(f"{name} = {abs(value) * scale:.4g}" for name, value in zip(rates[::2], rates[1::2]) if value)
    arcsec = focal_plane.pixel_scale_rad * 180 / np.pi * 3600
    raise ParameterError(
        f"{who}: the {p.mode} moves the sky by up to {step:.3g} pixels between samples {cadence_ns / NS_PER_S:g} s "
        f"apart ({arcsec:.3g} arcsec per pixel), more than the {MAX_STEP_PX:g} pixel a sampled source may jump; the "
        f"largest usable rates at this cadence are about {usable} deg/s (or sample every "
        f"{cadence_ns * scale / NS_PER_S:.3g} s or faster: cadence_s here, and the optics' render_rate_hz)")


def seconds(t_ns) -> np.ndarray:
    """Nanoseconds to seconds."""
    return np.asarray(t_ns, dtype=np.float64) / NS_PER_S
