"""One satellite seen by one observer through one pointed sensor: where it is, whether it can be seen, how bright.

:class:`SatelliteView` evaluates, at any sample times, the satellite's apparent
direction, its focal-plane position (gnomonic projection), the visibility conditions
(in the field of view, sunlit, above the horizon or not behind the Earth, observer in
darkness or Sun away from the boresight) and its brightness (paper Eq. 1-2 with a
phase function, range and extinction). The satellite block, the pass finder and the
Fig. 2 plot all use it, so they can never disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

import numpy as np

from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import Observer, Orbit, Pointing

from . import projection, radiometry, spectra
from .geometry import C_M_PER_S, NS_PER_S, Track, apparent_position, satellite_track, sun_track, unit
from .pointing import azel_from_enu, shared_models
from .reflectors import FacetReflector
from .visibility import EARTH_RADIUS_M, lit_fraction, segment_hits_sphere

PLATE_NORMALS = ("nadir", "sun", "observer", "bisector")


@dataclass(frozen=True)
class Reflector:
    """How the satellite reflects sunlight: a diffuse sphere of cross-section ``area_m2`` or a flat plate.

    A plate's normal follows ``plate_normal``: ``nadir`` (facing the Earth's centre),
    ``sun`` (a Sun-tracking panel), ``observer``, or ``bisector`` (halfway between Sun
    and observer: the brightest orientation).
    """

    shape: str = "sphere"
    area_m2: float = 1.0
    albedo: float = 0.2
    plate_normal: str = "nadir"


@dataclass
class ViewSamples:
    """Everything :class:`SatelliteView` knows at a set of sample times (arrays ``[n]``)."""

    t_ns: np.ndarray
    x_px: np.ndarray                 # focal-plane column, NaN behind the sensor [pixel]
    y_px: np.ndarray                 # focal-plane row [pixel]
    in_fov: np.ndarray               # bool
    lit_fraction: np.ndarray         # visible fraction of the solar disc [1]
    above_horizon: np.ndarray        # bool: above the elevation limit / line of sight clears the Earth
    observer_dark: np.ndarray        # bool: Sun low enough (ground) / far enough from the boresight (space)
    azimuth_rad: np.ndarray          # satellite azimuth (ground observer; NaN from space) [rad]
    elevation_rad: np.ndarray        # satellite elevation [rad]
    sun_elevation_rad: np.ndarray    # Sun's elevation at the observer [rad]
    range_m: np.ndarray              # light-time distance [m]
    phase_angle_rad: np.ndarray      # Sun-satellite-observer angle [rad]
    boresight_angle_rad: np.ndarray  # angle between the satellite and the boresight [rad]
    outside_angle_rad: np.ndarray    # angle from the satellite to the nearest point of the field [rad]
    zenith_angle_rad: np.ndarray     # boresight zenith angle (NaN from space) [rad]
    boresight_azimuth_rad: np.ndarray  # boresight azimuth, from north through east (NaN from space) [rad]
    field_rotation_rad: np.ndarray   # image up from the local elevation towards azimuth (NaN from space) [rad]
    photon_flux: np.ndarray          # at the aperture, after the atmosphere, in the detector's response [photon s^-1 m^-2]
    magnitude: np.ndarray            # apparent magnitude in the band [mag]

    @property
    def sunlit(self) -> np.ndarray:
        return self.lit_fraction > 0.0

    @property
    def observable(self) -> np.ndarray:
        return self.in_fov & self.sunlit & self.above_horizon & self.observer_dark


class SharedGeometry:
    """What every satellite seen by one observer through one pointed sensor shares: observer, pointing, Sun."""

    def __init__(self, observer: Observer, pointing: Pointing, epoch: datetime, knot_step_ns: int):
        self.observer_model, self.pointing_model = shared_models(observer, pointing, epoch, knot_step_ns)
        self.sun = sun_track(epoch, knot_step_ns)


class SatelliteView:
    """Geometry, visibility and brightness of ``orbit`` seen from ``observer`` with ``pointing``."""

    def __init__(self, orbit: Orbit, observer: Observer, pointing: Pointing, focal_plane: FocalPlane,
                 epoch: datetime, knot_step_ns: int = 10 * 10**9, reflector: Reflector | FacetReflector = Reflector(),
                 band: radiometry.Band = radiometry.V_BAND, *, shared: "SharedGeometry | None" = None,
                 track: Track | None = None):
        """``shared`` lets many satellites reuse one observer, pointing and Sun; ``track`` replaces the
        orbit's TLE lines (e.g. elements read from an OMM catalogue)."""
        self.orbit, self.observer, self.focal_plane = orbit, observer, focal_plane
        self.epoch = epoch
        self.reflector, self.band = reflector, band
        shared = shared or SharedGeometry(observer, pointing, epoch, knot_step_ns)
        self.observer_model, self.pointing_model, self.sun = shared.observer_model, shared.pointing_model, shared.sun
        target = getattr(self.pointing_model, "target", None)      # a tracking pointing's own orbit
        if track is None and target is not None and (pointing.target_line1, pointing.target_line2) == (
                orbit.line1, orbit.line2) and (target.grid.epoch, target.grid.step_ns) == (epoch, knot_step_ns):
            track = target        # the tracked satellite itself: one track, its states computed once a window
        self.track = track or satellite_track(epoch, knot_step_ns, orbit.line1, orbit.line2)

    def sample(self, t_ns) -> ViewSamples:
        t_ns = np.atleast_1d(np.asarray(t_ns))
        t = t_ns.astype(np.float64)
        obs = self.observer
        apparent = apparent_position(self.track, self.observer_model, t)
        range_m = np.linalg.norm(apparent, axis=-1)
        s = apparent / range_m[:, None]
        b, r, u = self.pointing_model.frame(t)
        sb, sr, su = (np.einsum("ij,ij->i", s, axis) for axis in (b, r, u))
        xi, eta = projection.tangent_plane(sb, sr, su)
        x, y = projection.to_pixels(xi, eta, self.focal_plane)
        in_fov = projection.inside(x, y, self.focal_plane)

        r_sat, v_sat = self.track.state(t)
        r_obs, _ = self.observer_model.state(t)
        r_sun, _ = self.sun.state(t)
        fraction = lit_fraction(r_sat, r_sun)
        east, north, up = self.observer_model.enu(t)
        elevation = np.arcsin(np.clip(np.einsum("ij,ij->i", s, up), -1.0, 1.0))
        to_sun_obs = unit(r_sun - r_obs)
        sun_elevation = np.arcsin(np.clip(np.einsum("ij,ij->i", to_sun_obs, up), -1.0, 1.0))
        if obs.is_ground:
            azimuth, _ = azel_from_enu(np.einsum("ij,ij->i", s, east), np.einsum("ij,ij->i", s, north), 0.0)
            above = elevation >= np.radians(obs.min_elevation_deg)
            dark = sun_elevation <= np.radians(obs.max_sun_elevation_deg)
        else:
            azimuth = np.full(len(t), np.nan)
            above = ~segment_hits_sphere(r_obs, r_sat, EARTH_RADIUS_M + obs.min_grazing_altitude_m)
            dark = np.einsum("ij,ij->i", to_sun_obs, b) <= np.cos(np.radians(obs.sun_exclusion_deg))

        to_sun = unit(r_sun - r_sat)
        to_observer = unit(r_obs - r_sat)
        phase = np.arccos(np.clip(np.einsum("ij,ij->i", to_sun, to_observer), -1.0, 1.0))
        zenith_boresight, azimuth_boresight, field_rotation = (angle.copy() for angle in
                                                               self.pointing_model.boresight_angles(t))
        if isinstance(self.reflector, FacetReflector):
            # the attitude at the emission time: light leaves the body range/c before it arrives
            reflectance = self.reflector.reflectance_m2_sr(t - range_m / C_M_PER_S * NS_PER_S, r_sat, v_sat, to_sun,
                                                           to_observer)
            flux = self._facet_photon_flux(reflectance, r_sat, r_sun, range_m, fraction, elevation)
        else:
            flux = self._photon_flux(phase, to_sun, to_observer, r_sat, r_sun, range_m, fraction, elevation)
        return ViewSamples(
            t_ns=t_ns, x_px=x, y_px=y, in_fov=in_fov, lit_fraction=fraction, above_horizon=above,
            observer_dark=dark, azimuth_rad=azimuth, elevation_rad=elevation, sun_elevation_rad=sun_elevation,
            range_m=range_m, phase_angle_rad=phase, boresight_angle_rad=np.arccos(np.clip(sb, -1.0, 1.0)),
            outside_angle_rad=projection.angle_outside(xi, eta, sb, self.focal_plane, b, r, u, s),
            zenith_angle_rad=zenith_boresight, boresight_azimuth_rad=azimuth_boresight,
            field_rotation_rad=field_rotation, magnitude=radiometry.magnitude(flux, self.band),
            photon_flux=flux * spectra.sun_band_factor(self.focal_plane.spectral_response))

    def _photon_flux(self, phase, to_sun, to_observer, r_sat, r_sun, range_m, fraction, elevation):
        """Paper Eq. 1-2 with the reflector's phase function, the penumbra and the atmosphere."""
        ref = self.reflector
        if ref.shape == "sphere":
            phase_function = radiometry.lambertian_sphere_phase(phase)
        else:
            normal = {"nadir": lambda: -unit(r_sat), "sun": lambda: to_sun, "observer": lambda: to_observer,
                      "bisector": lambda: unit(to_sun + to_observer)}[ref.plate_normal]()
            phase_function = radiometry.flat_plate_phase(normal, to_sun, to_observer)
        flux = radiometry.reflected_photon_flux(self.band, ref.albedo, ref.area_m2, phase_function, range_m,
                                                sun_distance_m=np.linalg.norm(r_sun - r_sat, axis=-1))
        if self.observer.is_ground:
            flux = flux * radiometry.transmission(self.observer.extinction_mag_per_airmass, np.pi / 2 - elevation)
        return np.nan_to_num(flux * fraction, nan=0.0)

    def _facet_photon_flux(self, reflectance, r_sat, r_sun, range_m, fraction, elevation):
        """A facet model's reflectance to flux, with the penumbra and the atmosphere."""
        flux = radiometry.photon_flux_of_reflectance(self.band, reflectance, range_m,
                                                     sun_distance_m=np.linalg.norm(r_sun - r_sat, axis=-1))
        if self.observer.is_ground:
            flux = flux * radiometry.transmission(self.observer.extinction_mag_per_airmass, np.pi / 2 - elevation)
        return np.nan_to_num(flux * fraction, nan=0.0)
