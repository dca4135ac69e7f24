"""Scene description blocks: the TLE, the observer, the camera geometry and the pointing law.

Their outputs describe the scene and do not change between windows; the blocks that
compute positions (``satellite``, ``star_field``, ``sky_background``) evaluate them.
"""

from __future__ import annotations

import logging
import math
import warnings
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from evsda import library
from evsda.blocks.ports import FocalPlane, SpectralResponse
from evsda.blocks.ports.scene import AZEL, GROUND, RADEC, SPACE, TRACK, Observer, Orbit, Pointing
from evsda.graph import Block, BlockParams, Footprint, Input, Output, ParameterError, RunInfo, UserError, Window
from evsda.graph.files import read_text
from evsda.graph.params import DataFile

from .pointing import moving_law
from .tle import check_propagation, epoch_age_days, parse_tles

log = logging.getLogger(__name__)


class TleAgeWarning(UserWarning):
    """The element set is older (or newer) than ``max_tle_age_days`` at the simulated time."""


class TleSource(Block):
    """A satellite's orbit from a two-line element set (SGP4), checksum-validated.

    Give ``tle_file`` (a path or ``library:tle/iss.tle``) or ``tle_text``; in a file
    holding several satellites pick one with ``select`` (name or NORAD number). At
    setup the element set's age at the run's start is logged, a :class:`TleAgeWarning`
    is issued past ``max_tle_age_days`` (SGP4 errors grow by ~1-3 km per day for LEO,
    Vallado et al. 2006), and SGP4 error codes over the run (e.g. a decayed orbit)
    become a :class:`~evsda.graph.SceneError`.
    """

    type_name = "tle_source"

    class Params(BlockParams):
        tle_file: DataFile | None = Field(None, description="TLE file: a path or library:tle/NAME.tle [-]")
        tle_text: str | None = Field(None, description="TLE given inline (two or three lines) instead of a file [-]")
        select: str = Field("", description="Name or NORAD number of the satellite to take from a file "
                                            "holding several; empty takes the only one [-]")
        max_tle_age_days: float = Field(14.0, gt=0, description="Warn when the TLE epoch is further than this "
                                                                 "from the simulated time [d]")

        @model_validator(mode="after")
        def _one_source(self):
            if (self.tle_file is None) == (self.tle_text is None):
                raise ValueError("give exactly one of tle_file and tle_text")
            return self

    outputs = {"orbit": Output(Orbit, "the selected element set")}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.orbit = self._load()
        self.tle_age_days: float | None = None

    def _load(self) -> Orbit:
        p = self.params
        if p.tle_file is not None:
            try:
                text = read_text(library.resolve(p.tle_file), "TLE file")   # regular UTF-8 file, bounded
            except UserError as exc:
                raise ParameterError(f"{self.label} parameter 'tle_file': {exc}") from None
            source = f"{self.label} tle_file {p.tle_file}"
        else:
            text, source = p.tle_text, f"{self.label} tle_text"
        orbits = parse_tles(text, source)
        if p.select:
            chosen = [o for o in orbits if p.select in (o.catalog_number, o.name) or o.name.upper() == p.select.upper()]
            if not chosen:
                raise ParameterError(f"{source}: no satellite named or numbered {p.select!r}; it holds "
                                     f"{', '.join(f'{o.name} ({o.catalog_number})' for o in orbits[:10])}")
            return chosen[0]
        if len(orbits) > 1:
            raise ParameterError(f"{source} holds {len(orbits)} satellites; choose one with 'select' "
                                 f"(e.g. {orbits[0].catalog_number})")
        return orbits[0]

    def setup(self, run: RunInfo) -> None:
        super().setup(run)
        who = self.label
        self.tle_age_days = epoch_age_days(self.orbit, run.epoch)
        log.info("%s: %s (%s) TLE epoch %s is %.2f days from the run start", who, self.orbit.name,
                 self.orbit.catalog_number, self.orbit.epoch_utc, self.tle_age_days)
        end_age = epoch_age_days(self.orbit, run.epoch) + run.duration_ns / 86400e9
        if max(abs(self.tle_age_days), abs(end_age)) > self.params.max_tle_age_days:
            warnings.warn(f"{who}: the TLE of {self.orbit.name} (epoch {self.orbit.epoch_utc}) is "
                          f"{self.tle_age_days:.1f} days from the simulated time, more than max_tle_age_days="
                          f"{self.params.max_tle_age_days:g}; positions may be off by kilometres", TleAgeWarning,
                          stacklevel=2)
        check_propagation(self.orbit, run.epoch, 0, run.duration_ns, who)

    def step(self, window: Window) -> dict:
        return {"orbit": self.orbit}


class GroundSite(Block):
    """A ground observer (WGS84 geodetic position) with its horizon, darkness and extinction limits."""

    type_name = "ground_site"

    class Params(BlockParams):
        name: str = Field("site", description="Site name [-]")
        latitude_deg: float = Field(ge=-90, le=90, description="Geodetic latitude, north positive [deg]")
        longitude_deg: float = Field(ge=-180, le=360, description="Longitude, east positive [deg]")
        altitude_m: float = Field(0.0, ge=-500, le=9000, description="Height above the WGS84 ellipsoid [m]")
        min_elevation_deg: float = Field(10.0, ge=-5, le=90, description="Lowest elevation at which the "
                                                                         "satellite is observable [deg]")
        max_sun_elevation_deg: float = Field(-12.0, ge=-90, le=90, description="Observe only while the Sun is "
                                             "below this elevation (-12 = nautical twilight) [deg]")
        extinction_mag_per_airmass: float = Field(0.2, ge=0, le=5, description="Atmospheric extinction "
                                                  "coefficient in the band (V: ~0.1-0.3 at observatory sites) [mag]")

    outputs = {"observer": Output(Observer, "the ground site")}

    _observer: Observer | None = None      # the same (frozen) value every window: its readers hash it once

    def step(self, window: Window) -> dict:
        p = self.params
        if self._observer is None:
            self._observer = Observer(name=p.name, kind=GROUND, latitude_deg=p.latitude_deg,
                                      longitude_deg=p.longitude_deg, altitude_m=p.altitude_m,
                                      min_elevation_deg=p.min_elevation_deg,
                                      max_sun_elevation_deg=p.max_sun_elevation_deg,
                                      extinction_mag_per_airmass=p.extinction_mag_per_airmass)
        return {"observer": self._observer}


class SpaceObserver(Block):
    """A space-based observer flying on its own TLE (connect a ``tle_source`` to ``orbit``)."""

    type_name = "space_observer"

    class Params(BlockParams):
        min_grazing_altitude_m: float = Field(100e3, ge=0, description="The line of sight to the target must "
                                              "clear the Earth's surface by this height [m]")
        sun_exclusion_deg: float = Field(30.0, ge=0, le=180, description="No observation while the Sun is "
                                         "closer than this to the boresight [deg]")

    inputs = {"orbit": Input(Orbit, "the observing spacecraft's element set")}
    outputs = {"observer": Output(Observer, "the spacecraft as an observer")}

    def step(self, window: Window, orbit: Orbit) -> dict:
        p = self.params
        return {"observer": Observer(name=orbit.name, kind=SPACE, line1=orbit.line1, line2=orbit.line2,
                                     min_grazing_altitude_m=p.min_grazing_altitude_m,
                                     sun_exclusion_deg=p.sun_exclusion_deg)}


class Camera(Block):
    """The focal plane behind the telescope: pixel grid, pitch and focal length (or field of view).

    Give ``focal_length_m``, or ``fov_x_deg`` (full horizontal field), from which
    ``f = width * pitch / (2 tan(fov/2))``. The detector's spectral response (which photons the scene counts
    for it, :class:`~evsda.blocks.ports.SpectralResponse` and :mod:`evsda.blocks.scene.spectra`) travels
    with the focal plane.
    """

    type_name = "camera"

    class Params(BlockParams):
        width_px: int = Field(1280, gt=0, le=65535, description="Pixel columns [pixel]")
        height_px: int = Field(720, gt=0, le=65535, description="Pixel rows [pixel]")
        pixel_pitch_m: float = Field(4.86e-6, gt=0, lt=1e-3, description="Pixel pitch [m]")
        focal_length_m: float | None = Field(None, gt=0, description="Effective focal length [m]")
        fov_x_deg: float | None = Field(None, gt=0, lt=180, description="Full horizontal field of view, "
                                                                       "instead of the focal length [deg]")
        spectral_response: Literal["V", "silicon"] = Field(
            "V", description="Which photons the detector counts: 'V' the V band (no spectral curve), 'silicon' a "
                             "silicon photodiode's quantum efficiency against wavelength, 1 at 550 nm (the pixel's "
                             "quantum_efficiency is the QE there) [-]")
        silicon_depth_m: float = Field(3e-6, gt=0, le=1e-3, description="Depth of silicon whose carriers the "
                                       "photodiode collects (spectral_response: silicon) [m]")
        filter: Literal["none", "V"] = Field("none", description="Filter in front of a silicon detector [-]")

        @model_validator(mode="after")
        def _one_scale(self):
            if (self.focal_length_m is None) == (self.fov_x_deg is None):
                raise ValueError("give exactly one of focal_length_m and fov_x_deg (the telescope's focal length: "
                                 "scenes set it on a sensor preset's camera, set: {camera.focal_length_m: ...})")
            if self.filter != "none" and self.spectral_response == "V":
                raise ValueError("a filter needs spectral_response: silicon (the 'V' response is already the V band)")
            return self

    outputs = {"focal_plane": Output(FocalPlane, "the detector geometry")}

    def footprint(self, run: RunInfo) -> Footprint:
        """The sensor this camera defines (its pixel count is checked against the limits before a run)."""
        return Footprint(pixels=self.params.width_px * self.params.height_px)

    @property
    def focal_plane(self) -> FocalPlane:
        p = self.params
        focal = p.focal_length_m
        if focal is None:
            focal = p.width_px * p.pixel_pitch_m / (2.0 * math.tan(math.radians(p.fov_x_deg) / 2.0))
        if p.spectral_response == "V":
            return FocalPlane(p.width_px, p.height_px, p.pixel_pitch_m, focal)
        return FocalPlane(p.width_px, p.height_px, p.pixel_pitch_m, focal,
                          SpectralResponse("silicon", p.silicon_depth_m, p.filter))

    _focal_plane: FocalPlane | None = None      # the same (frozen) value every window: its readers hash it once

    def step(self, window: Window) -> dict:
        if self._focal_plane is None:
            self._focal_plane = self.focal_plane
        return {"focal_plane": self._focal_plane}


class PointingLaw(Block):
    """Where the sensor looks: stare, track sidereally or a satellite, scan, raster, or slew.

    See :class:`~evsda.blocks.ports.scene.Pointing` for the frame and roll conventions.
    ``track`` needs the target's orbit on the ``target`` input. ``scan``, ``raster`` and
    ``slew`` start from ``azimuth_deg``/``elevation_deg`` (``coordinates: azel``) or
    ``ra_deg``/``dec_deg`` (``coordinates: radec``) at the run's start:

    * ``scan``: constant coordinate rates (``azimuth_rate_deg_s``, ``elevation_rate_deg_s``
      or ``ra_rate_deg_s``, ``dec_rate_deg_s``); an azimuth or RA rate moves the sky
      ``cos(elevation)`` or ``cos(Dec)`` times as fast;
    * ``raster``: ``raster_rows`` rows ``raster_width_deg`` long in azimuth or RA, centred on
      the start pointing and ``raster_row_step_deg`` apart, swept at ``scan_rate_deg_s``
      back and forth (serpentine), row steps at up to ``max_rate_deg_s``, every move
      limited to ``max_acceleration_deg_s2`` (:class:`~evsda.blocks.scene.scanning.Raster`);
    * ``slew``: at ``slew_start_s``, along the great circle to ``to_azimuth_deg``/
      ``to_elevation_deg`` (or ``to_ra_deg``/``to_dec_deg``) at up to ``max_rate_deg_s``
      and ``max_acceleration_deg_s2``, holding the pointing before and after.
    """

    type_name = "pointing"

    class Params(BlockParams):
        mode: Literal["stare", "sidereal", "track", "scan", "raster", "slew"] = Field(
            "stare", description="Pointing law [-]")
        azimuth_deg: float = Field(0.0, ge=0, le=360, description="Stare azimuth, from north through east (the "
                                   "start of a scan, raster centre or slew start in azel) [deg]")
        elevation_deg: float = Field(90.0, ge=-90, le=90, description="Stare elevation (or start, in azel) [deg]")
        ra_deg: float = Field(0.0, ge=0, lt=360, description="Sidereal: ICRS right ascension of the field (or "
                              "start, in radec) [deg]")
        dec_deg: float = Field(0.0, ge=-90, le=90, description="Sidereal: ICRS declination of the field (or start, "
                               "in radec) [deg]")
        roll_deg: float = Field(0.0, ge=-360, le=360, description="Rotation of the sensor about the boresight, "
                                "image up turning towards image right [deg]")
        coordinates: Literal["azel", "radec"] = Field("azel", description="Coordinates of a scan, raster or slew: "
                                                      "azimuth/elevation (horizon) or RA/Dec (ICRS) [-]")
        azimuth_rate_deg_s: float = Field(0.0, ge=-360, le=360, description="Scan: azimuth rate (coordinates "
                                          "azel) [deg/s]")
        elevation_rate_deg_s: float = Field(0.0, ge=-90, le=90, description="Scan: elevation rate (azel) [deg/s]")
        ra_rate_deg_s: float = Field(0.0, ge=-360, le=360, description="Scan: right ascension rate (radec) [deg/s]")
        dec_rate_deg_s: float = Field(0.0, ge=-90, le=90, description="Scan: declination rate (radec) [deg/s]")
        raster_width_deg: float = Field(0.0, ge=0, le=360, description="Raster: row length in azimuth or RA [deg]")
        raster_rows: int = Field(1, ge=1, le=10000, description="Raster: number of rows [1]")
        raster_row_step_deg: float = Field(0.0, ge=-90, le=90, description="Raster: elevation or Dec step from "
                                           "one row to the next (positive: upwards/north) [deg]")
        scan_rate_deg_s: float | None = Field(None, gt=0, le=360, description="Raster: rate along the rows "
                                              "(azimuth or RA coordinate rate) [deg/s]")
        to_azimuth_deg: float | None = Field(None, ge=0, le=360, description="Slew: final azimuth (azel) [deg]")
        to_elevation_deg: float | None = Field(None, ge=-90, le=90, description="Slew: final elevation (azel) [deg]")
        to_ra_deg: float | None = Field(None, ge=0, lt=360, description="Slew: final right ascension (radec) [deg]")
        to_dec_deg: float | None = Field(None, ge=-90, le=90, description="Slew: final declination (radec) [deg]")
        slew_start_s: float = Field(0.0, ge=0, description="Slew: start time after the run's start [s]")
        max_rate_deg_s: float | None = Field(None, gt=0, le=360, description="Raster row steps and slews: the "
                                             "mount's rate limit [deg/s]")
        max_acceleration_deg_s2: float | None = Field(None, gt=0, le=1e4, description="Raster and slew: the "
                                                      "mount's acceleration limit [deg/s^2]")

        @model_validator(mode="after")
        def _law_complete(self):
            other = ("ra_rate_deg_s", "dec_rate_deg_s") if self.coordinates == "azel" else \
                ("azimuth_rate_deg_s", "elevation_rate_deg_s")
            if self.mode == "scan" and any(getattr(self, name) for name in other):
                raise ValueError(f"a scan in coordinates {self.coordinates} takes "
                                 f"{' and '.join(n for n in self._rates() if n not in other)}, not "
                                 f"{' or '.join(other)}")
            needed = {"raster": ("scan_rate_deg_s", "max_rate_deg_s", "max_acceleration_deg_s2"),
                      "slew": (("to_azimuth_deg", "to_elevation_deg") if self.coordinates == "azel" else
                               ("to_ra_deg", "to_dec_deg")) + ("max_rate_deg_s", "max_acceleration_deg_s2")}
            missing = [name for name in needed.get(self.mode, ()) if getattr(self, name) is None]
            if missing:
                raise ValueError(f"mode {self.mode} (coordinates {self.coordinates}) needs {', '.join(missing)}")
            if self.mode == "raster" and self.raster_width_deg <= 0:
                raise ValueError("mode raster needs raster_width_deg > 0")
            if self.mode == "raster" and self.raster_rows > 1 and self.raster_row_step_deg == 0:
                raise ValueError("a raster of several rows needs raster_row_step_deg (not 0)")
            return self

        @staticmethod
        def _rates() -> tuple[str, ...]:
            return ("azimuth_rate_deg_s", "elevation_rate_deg_s", "ra_rate_deg_s", "dec_rate_deg_s")

    inputs = {"target": Input(Orbit, "orbit to rate-track (mode 'track' only)", required=False)}
    outputs = {"pointing": Output(Pointing, "the pointing law")}
    _pointing_of: tuple[Orbit | None, Pointing] | None = None      # (target, its pointing) of the last window

    def pointing(self, target: Orbit | None = None) -> Pointing:
        """The :class:`Pointing` these parameters describe."""
        p = self.params
        azel = p.coordinates == "azel"
        to_lon, to_lat = (p.to_azimuth_deg, p.to_elevation_deg) if azel else (p.to_ra_deg, p.to_dec_deg)
        return Pointing(
            mode=p.mode, azimuth_deg=p.azimuth_deg,
            elevation_deg=p.elevation_deg, ra_deg=p.ra_deg, dec_deg=p.dec_deg, roll_deg=p.roll_deg,
            target_name=target.name if target else "", target_line1=target.line1 if target else "",
            target_line2=target.line2 if target else "",
            coordinates=AZEL if azel else RADEC,
            lon_rate_deg_s=p.azimuth_rate_deg_s if azel else p.ra_rate_deg_s,
            lat_rate_deg_s=p.elevation_rate_deg_s if azel else p.dec_rate_deg_s,
            raster_width_deg=p.raster_width_deg, raster_rows=p.raster_rows,
            raster_row_step_deg=p.raster_row_step_deg, scan_rate_deg_s=p.scan_rate_deg_s or 0.0,
            to_lon_deg=to_lon or 0.0, to_lat_deg=to_lat or 0.0, slew_start_s=p.slew_start_s,
            max_rate_deg_s=p.max_rate_deg_s or 0.0, max_acceleration_deg_s2=p.max_acceleration_deg_s2 or 0.0)

    def setup(self, run: RunInfo) -> None:
        super().setup(run)
        pointing = self.pointing()
        if pointing.is_moving:
            self._check_range(pointing, run.duration_ns / 1e9)

    def _check_range(self, pointing: Pointing, duration_s: float) -> None:
        """A moving law must keep its latitude coordinate (elevation or Dec) in [-90, 90] deg over the run."""
        try:
            law = moving_law(pointing)
        except ParameterError as exc:
            raise ParameterError(f"{self.label}: {str(exc).removeprefix('pointing: ')}") from None
        t = np.linspace(0.0, duration_s, max(2, int(duration_s / 0.01) + 1))
        _, lat = law.coordinates(t)
        outside = np.flatnonzero(np.abs(lat) > 90.0)
        if outside.size:
            name = "elevation" if pointing.coordinates == AZEL else "declination"
            i = outside[0]
            raise ParameterError(f"{self.label}: the {pointing.mode} reaches {name} "
                                 f"{lat[i]:.3f} deg at t = {t[i]:.3f} s, beyond the pole; change the start, the "
                                 f"rates or the run's duration")

    def step(self, window: Window, target: Orbit | None = None) -> dict:
        if self.params.mode == TRACK and target is None:
            raise ParameterError(f"{self.label}: mode 'track' needs a tle_source connected "
                                 f"to its 'target' input")
        if self._pointing_of is None or self._pointing_of[0] is not target:
            self._pointing_of = (target, self.pointing(target))    # the same value while the target is
        return {"pointing": self._pointing_of[1]}
