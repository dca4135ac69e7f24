"""Port types of the scene stage: what a satellite is, where it is seen from, where the sensor looks.

These are descriptions, not time series: each block that needs positions evaluates them
at its own cadence (see :mod:`evsda.blocks.scene.geometry`). They hold only strings and
numbers so that they serialise into a run store as attributes.
"""

from __future__ import annotations

from dataclasses import dataclass

from evsda.graph.ports import PortValue


@dataclass(frozen=True, eq=False)
class Orbit(PortValue):
    """A two-line element set (TLE) for the SGP4 propagator, already checksum-validated."""

    unit = "-"
    name: str                                # satellite name (line 0), e.g. "ISS (ZARYA)"
    catalog_number: str                      # NORAD catalogue number, e.g. "25544"
    line1: str                               # TLE line 1 (69 characters)
    line2: str                               # TLE line 2 (69 characters)
    epoch_utc: str                           # element-set epoch, ISO 8601 UTC


GROUND = "ground"
SPACE = "space"


@dataclass(frozen=True, eq=False)
class Observer(PortValue):
    """Where the sensor is: a ground site or a spacecraft on its own TLE, with its observing limits.

    Ground sites use ``latitude_deg``, ``longitude_deg``, ``altitude_m`` (WGS84), the
    horizon limit ``min_elevation_deg``, the darkness limit ``max_sun_elevation_deg`` and
    the atmosphere's extinction ``extinction_mag_per_airmass``. Space observers use
    ``line1``/``line2`` (their TLE), ``min_grazing_altitude_m`` (the line of sight must
    clear the Earth by this height) and ``sun_exclusion_deg`` (no observation with the
    Sun closer than this to the boresight).
    """

    unit = "-"
    name: str
    kind: str                                # GROUND or SPACE
    latitude_deg: float = 0.0                # geodetic latitude (ground) [deg]
    longitude_deg: float = 0.0               # east longitude (ground) [deg]
    altitude_m: float = 0.0                  # height above the WGS84 ellipsoid (ground) [m]
    min_elevation_deg: float = 0.0           # lowest observable elevation (ground) [deg]
    max_sun_elevation_deg: float = -12.0     # observe only while the Sun is below this (ground) [deg]
    extinction_mag_per_airmass: float = 0.0  # atmospheric extinction coefficient in the band (ground) [mag]
    line1: str = ""                          # TLE line 1 (space)
    line2: str = ""                          # TLE line 2 (space)
    min_grazing_altitude_m: float = 100e3    # line of sight must clear the Earth by this (space) [m]
    sun_exclusion_deg: float = 30.0          # minimum Sun-boresight angle (space) [deg]

    @property
    def is_ground(self) -> bool:
        return self.kind == GROUND


STARE = "stare"
SIDEREAL = "sidereal"
TRACK = "track"
SCAN = "scan"
RASTER = "raster"
SLEW = "slew"
MOVING_MODES = (SCAN, RASTER, SLEW)
AZEL = "azel"
RADEC = "radec"


@dataclass(frozen=True, eq=False)
class Pointing(PortValue):
    """The pointing law of the sensor: where the boresight looks and how the sensor is rolled.

    * ``stare``: fixed azimuth/elevation in the observer's local horizon frame (stars drift);
    * ``sidereal``: fixed ICRS right ascension/declination (stars stay put, satellites streak);
    * ``track``: the boresight follows the apparent direction of the target TLE;
    * ``scan``: constant rates in azimuth/elevation or RA/Dec (``coordinates``) from the
      start pointing (``azimuth_deg``/``elevation_deg`` or ``ra_deg``/``dec_deg``);
    * ``raster``: a serpentine raster around the start pointing, rows along azimuth or RA,
      with rate- and acceleration-limited turnarounds (:class:`~evsda.blocks.scene.scanning.Raster`);
    * ``slew``: a rate- and acceleration-limited great-circle slew from the start pointing
      to ``to_lon_deg``/``to_lat_deg`` at ``slew_start_s``.

    Times of the moving laws count from the run's start. Azimuth and RA rates are rates of
    the coordinate: the sky moves ``cos(elevation)`` (or ``cos(Dec)``) times as fast.

    ``roll_deg`` turns the sensor about the boresight: 0 puts the image's up axis (-y, row
    0 at the top) towards the zenith (stare, track from the ground) or towards celestial
    north (sidereal, track from space); positive roll turns the image's up axis towards
    the image's right.
    """

    unit = "-"
    mode: str                                # STARE, SIDEREAL or TRACK
    azimuth_deg: float = 0.0                 # stare: azimuth, from north through east [deg]
    elevation_deg: float = 90.0              # stare: elevation above the horizon [deg]
    ra_deg: float = 0.0                      # sidereal: ICRS right ascension [deg]
    dec_deg: float = 0.0                     # sidereal: ICRS declination [deg]
    roll_deg: float = 0.0                    # rotation about the boresight [deg]
    target_name: str = ""                    # track: the target's name
    target_line1: str = ""                   # track: the target's TLE line 1
    target_line2: str = ""                   # track: the target's TLE line 2
    coordinates: str = AZEL                  # scan, raster, slew: AZEL (horizon) or RADEC (ICRS)
    lon_rate_deg_s: float = 0.0              # scan: azimuth or RA coordinate rate [deg/s]
    lat_rate_deg_s: float = 0.0              # scan: elevation or Dec rate [deg/s]
    raster_width_deg: float = 0.0            # raster: row length in azimuth or RA [deg]
    raster_rows: int = 1                     # raster: number of rows [1]
    raster_row_step_deg: float = 0.0         # raster: elevation or Dec step between rows [deg]
    scan_rate_deg_s: float = 0.0             # raster: rate limit along the rows [deg/s]
    to_lon_deg: float = 0.0                  # slew: final azimuth or RA [deg]
    to_lat_deg: float = 0.0                  # slew: final elevation or Dec [deg]
    slew_start_s: float = 0.0                # slew: start time after the run's start [s]
    max_rate_deg_s: float = 0.0              # raster row steps, slew: rate limit [deg/s]
    max_acceleration_deg_s2: float = 0.0     # raster, slew: acceleration limit [deg/s^2]

    @property
    def is_moving(self) -> bool:
        """A scan, raster or slew: the boresight moves across the sky at commanded rates."""
        return self.mode in MOVING_MODES
