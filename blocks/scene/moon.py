"""Where the Moon and the Sun are for an observer, from the bundled JPL DE421 ephemeris.

The Moon's and the Sun's geocentric positions come from DE421 (``skyfield-data``) at
knots, Hermite-interpolated in between (:mod:`.geometry`); directions from the
observer are geometric (the Moon's light time of 1.3 s moves it by under 1 arcsec, and
aberration by 20 arcsec: both far below what sky brightness or an exclusion angle can
resolve). DE421 covers 1899-07-29 to 2053-10-09; a run outside that span is one
:class:`~evsda.graph.SceneError` naming both spans.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

import numpy as np

from evsda.graph import SceneError

from .ephemeris import planets, timescale
from .geometry import NS_PER_S, ObserverModel, Track, _vectors, sun_track, unit
from .visibility import EARTH_RADIUS_M, segment_hits_sphere

#: Mean Earth-Moon distance (semi-major axis of the lunar orbit), the distance K&S (1991) Eq. 8's
#: lunar illuminance refers to [m]
MOON_MEAN_DISTANCE_M = 384_400e3
MOON_RADIUS_M = 1_737_400.0          # IAU mean radius of the Moon [m]


def ephemeris_span() -> tuple[datetime, datetime]:
    """First and last UTC instants every DE421 segment covers."""
    ts = timescale()
    starts, ends = zip(*(segment.time_range(ts) for segment in planets().segments))
    return max(starts).utc_datetime(), min(ends).utc_datetime()


def require_ephemeris(epoch: datetime, start_ns: int, stop_ns: int, who: str) -> None:
    """A :class:`SceneError` unless ``[epoch + start, epoch + stop]`` lies inside DE421's span."""
    first, last = ephemeris_span()
    begin = epoch + timedelta(microseconds=start_ns / 1000)
    end = epoch + timedelta(microseconds=stop_ns / 1000)
    if begin < first or end > last:
        raise SceneError(f"{who}: the Moon's position comes from JPL DE421, which covers {first:%Y-%m-%d %H:%M} "
                         f"to {last:%Y-%m-%d %H:%M} UTC; the run spans {begin:%Y-%m-%d %H:%M:%S} to "
                         f"{end:%Y-%m-%d %H:%M:%S} UTC. Move the run's start inside DE421's span")


def moon_track(epoch: datetime, knot_step_ns: int) -> Track:
    """Geometric geocentric position/velocity of the Moon (JPL DE421)."""
    eph = planets()
    moon = eph["moon"] - eph["earth"]
    return Track(epoch, knot_step_ns, lambda t: _vectors(moon.at(t)))


@dataclass
class MoonSamples:
    """The Moon and the Sun seen by the observer at sample times (arrays ``[n]``, vectors ``[n, 3]``)."""

    direction: np.ndarray            # unit vector observer -> Moon (GCRS axes)
    distance_m: np.ndarray           # observer-Moon distance [m]
    phase_angle_rad: np.ndarray      # Sun-Moon-observer angle: 0 at full Moon, pi at new Moon [rad]
    elevation_rad: np.ndarray        # the Moon's elevation (ground; NaN from space) [rad]
    up: np.ndarray                   # bool: the Moon's centre is above the horizon (ground) / not behind the Earth
    sun_elevation_rad: np.ndarray    # the Sun's elevation at the observer [rad]

    def separation_rad(self, boresight: np.ndarray) -> np.ndarray:
        """Angle between the Moon's centre and unit vectors ``boresight`` ``[n, 3]`` [rad]."""
        return np.arccos(np.clip(np.einsum("ij,ij->i", self.direction, boresight), -1.0, 1.0))

    @property
    def illuminated_fraction(self) -> np.ndarray:
        """Fraction of the Moon's disc that is lit, ``(1 + cos alpha) / 2`` [1]."""
        return 0.5 * (1.0 + np.cos(self.phase_angle_rad))


class MoonModel:
    """The Moon and the Sun for one observer at any time after ``epoch``."""

    def __init__(self, observer: ObserverModel, epoch: datetime, knot_step_ns: int = 10 * NS_PER_S):
        self.observer = observer
        self.moon = moon_track(epoch, knot_step_ns)
        self.sun = sun_track(epoch, knot_step_ns)

    def sample(self, t_ns) -> MoonSamples:
        t = np.atleast_1d(np.asarray(t_ns, dtype=np.float64))
        r_obs, _ = self.observer.state(t)
        r_moon, _ = self.moon.state(t)
        r_sun, _ = self.sun.state(t)
        to_moon = r_moon - r_obs
        distance = np.linalg.norm(to_moon, axis=-1)
        direction = to_moon / distance[:, None]
        phase = np.arccos(np.clip(np.einsum("ij,ij->i", unit(r_sun - r_moon), -direction), -1.0, 1.0))
        _, _, up = self.observer.enu(t)
        sun_elevation = np.arcsin(np.clip(np.einsum("ij,ij->i", unit(r_sun - r_obs), up), -1.0, 1.0))
        if self.observer.observer.is_ground:
            elevation = np.arcsin(np.clip(np.einsum("ij,ij->i", direction, up), -1.0, 1.0))
            visible = elevation > 0.0
        else:
            elevation = np.full(len(t), np.nan)
            visible = ~segment_hits_sphere(r_obs, r_moon, EARTH_RADIUS_M)
        return MoonSamples(direction=direction, distance_m=distance, phase_angle_rad=phase,
                           elevation_rad=elevation, up=visible, sun_elevation_rad=sun_elevation)
