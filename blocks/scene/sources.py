"""Scene description blocks: the TLE, the observer, the camera geometry and the pointing law.

Their outputs describe the scene and do not change between windows; the blocks that
compute positions (``satellite``, ``star_field``, ``sky_background``) evaluate them.
"""

from __future__ import annotations

import logging
import math
import warnings
from typing import Literal

from pydantic import Field, model_validator

from evsda import library
from evsda.blocks.ports import FocalPlane
from evsda.blocks.ports.scene import GROUND, SIDEREAL, SPACE, STARE, TRACK, Observer, Orbit, Pointing
from evsda.graph import Block, BlockParams, Input, Output, ParameterError, RunInfo, Window
from evsda.graph.params import DataFile

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
            path = library.resolve(p.tle_file)
            try:
                text = path.read_text()
            except OSError as exc:
                raise ParameterError(f"{self.type_name} '{self.name}' parameter 'tle_file': cannot read "
                                     f"{p.tle_file!r} ({exc.strerror or exc})") from None
            source = f"{self.type_name} '{self.name}' tle_file {p.tle_file}"
        else:
            text, source = p.tle_text, f"{self.type_name} '{self.name}' tle_text"
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
        who = f"{self.type_name} '{self.name}'"
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

    def step(self, window: Window) -> dict:
        p = self.params
        return {"observer": Observer(name=p.name, kind=GROUND, latitude_deg=p.latitude_deg,
                                     longitude_deg=p.longitude_deg, altitude_m=p.altitude_m,
                                     min_elevation_deg=p.min_elevation_deg,
                                     max_sun_elevation_deg=p.max_sun_elevation_deg,
                                     extinction_mag_per_airmass=p.extinction_mag_per_airmass)}


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
    ``f = width * pitch / (2 tan(fov/2))``.
    """

    type_name = "camera"

    class Params(BlockParams):
        width_px: int = Field(1280, gt=0, le=65535, description="Pixel columns [pixel]")
        height_px: int = Field(720, gt=0, le=65535, description="Pixel rows [pixel]")
        pixel_pitch_m: float = Field(4.86e-6, gt=0, lt=1e-3, description="Pixel pitch [m]")
        focal_length_m: float | None = Field(None, gt=0, description="Effective focal length [m]")
        fov_x_deg: float | None = Field(None, gt=0, lt=180, description="Full horizontal field of view, "
                                                                       "instead of the focal length [deg]")

        @model_validator(mode="after")
        def _one_scale(self):
            if (self.focal_length_m is None) == (self.fov_x_deg is None):
                raise ValueError("give exactly one of focal_length_m and fov_x_deg (the telescope's focal length: "
                                 "scenes set it on a sensor preset's camera, set: {camera.focal_length_m: ...})")
            return self

    outputs = {"focal_plane": Output(FocalPlane, "the detector geometry")}

    @property
    def focal_plane(self) -> FocalPlane:
        p = self.params
        focal = p.focal_length_m
        if focal is None:
            focal = p.width_px * p.pixel_pitch_m / (2.0 * math.tan(math.radians(p.fov_x_deg) / 2.0))
        return FocalPlane(p.width_px, p.height_px, p.pixel_pitch_m, focal)

    def step(self, window: Window) -> dict:
        return {"focal_plane": self.focal_plane}


class PointingLaw(Block):
    """Where the sensor looks: stare at azimuth/elevation, track sidereally at RA/Dec, or track a satellite.

    See :class:`~evsda.blocks.ports.scene.Pointing` for the frame and roll conventions.
    ``track`` needs the target's orbit on the ``target`` input.
    """

    type_name = "pointing"

    class Params(BlockParams):
        mode: Literal["stare", "sidereal", "track"] = Field("stare", description="Pointing law [-]")
        azimuth_deg: float = Field(0.0, ge=0, le=360, description="Stare azimuth, from north through east [deg]")
        elevation_deg: float = Field(90.0, ge=-90, le=90, description="Stare elevation [deg]")
        ra_deg: float = Field(0.0, ge=0, lt=360, description="Sidereal: ICRS right ascension of the field [deg]")
        dec_deg: float = Field(0.0, ge=-90, le=90, description="Sidereal: ICRS declination of the field [deg]")
        roll_deg: float = Field(0.0, ge=-360, le=360, description="Rotation of the sensor about the boresight, "
                                "image up turning towards image right [deg]")

    inputs = {"target": Input(Orbit, "orbit to rate-track (mode 'track' only)", required=False)}
    outputs = {"pointing": Output(Pointing, "the pointing law")}

    def step(self, window: Window, target: Orbit | None = None) -> dict:
        p = self.params
        if p.mode == TRACK and target is None:
            raise ParameterError(f"{self.type_name} '{self.name}': mode 'track' needs a tle_source connected "
                                 f"to its 'target' input")
        return {"pointing": Pointing(
            mode={"stare": STARE, "sidereal": SIDEREAL, "track": TRACK}[p.mode], azimuth_deg=p.azimuth_deg,
            elevation_deg=p.elevation_deg, ra_deg=p.ra_deg, dec_deg=p.dec_deg, roll_deg=p.roll_deg,
            target_name=target.name if target else "", target_line1=target.line1 if target else "",
            target_line2=target.line2 if target else "")}
