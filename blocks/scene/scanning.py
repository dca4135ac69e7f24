"""Moving pointing laws: constant-rate scans, rasters with turnarounds, and slews with acceleration limits.

Each law gives the boresight's two coordinates versus time in one coordinate system:
the observer's horizon (azimuth from north through east, elevation) or the ICRS (right
ascension, declination). :class:`~evsda.blocks.scene.pointing.PointingModel` turns them
into the sensor frame; here there is only kinematics, in degrees and seconds.

Rest-to-rest moves follow the time-optimal profile of a drive limited in rate and
acceleration (bang-coast-bang, e.g. Siciliano et al. 2009, *Robotics*, Sec. 4.2.1,
"trapezoidal velocity profile"): accelerate at ``a`` to the rate limit ``v``, coast,
decelerate at ``a``; a move shorter than ``v**2 / a`` never reaches ``v`` (triangular
profile, peak rate ``sqrt(d a)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Move:
    """A rest-to-rest move over ``distance`` with rate limit ``max_rate`` and acceleration limit ``max_accel``.

    Units are any angle unit ``u``: distance [u], rate [u/s], acceleration [u/s^2].
    """

    distance: float
    max_rate: float
    max_accel: float

    @property
    def peak_rate(self) -> float:
        """The highest rate reached [u/s]: the limit, or ``sqrt(d a)`` for a short move."""
        return float(min(self.max_rate, np.sqrt(self.distance * self.max_accel)))

    @property
    def accel_time(self) -> float:
        """Duration of each of the acceleration and deceleration ramps [s]."""
        return self.peak_rate / self.max_accel

    @property
    def duration(self) -> float:
        """Total time of the move [s]."""
        if self.distance <= 0:
            return 0.0
        cruise = self.distance / self.peak_rate - self.accel_time
        return 2.0 * self.accel_time + max(cruise, 0.0)

    def position(self, tau_s) -> np.ndarray:
        """Distance covered ``tau_s`` seconds after the start (0 before, ``distance`` after) [u]."""
        tau = np.clip(np.asarray(tau_s, dtype=np.float64), 0.0, self.duration)
        a, v, ta, total = self.max_accel, self.peak_rate, self.accel_time, self.duration
        ramp_up = 0.5 * a * tau**2
        cruise = 0.5 * a * ta**2 + v * (tau - ta)
        left = total - tau
        ramp_down = self.distance - 0.5 * a * left**2
        return np.where(tau < ta, ramp_up, np.where(tau <= total - ta, cruise, ramp_down))


@dataclass(frozen=True)
class Scan:
    """Constant rates in both coordinates from ``(lon0, lat0)`` at the run's start [deg, deg/s]."""

    lon0_deg: float
    lat0_deg: float
    lon_rate_deg_s: float
    lat_rate_deg_s: float

    def coordinates(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Longitude-like (azimuth or RA) and latitude-like (elevation or Dec) coordinates [deg]."""
        t = np.asarray(t_s, dtype=np.float64)
        return self.lon0_deg + self.lon_rate_deg_s * t, self.lat0_deg + self.lat_rate_deg_s * t

    def max_coordinate_rates(self) -> tuple[float, float]:
        return abs(self.lon_rate_deg_s), abs(self.lat_rate_deg_s)


@dataclass(frozen=True)
class Segment:
    """One move of a raster: along ``axis`` (0 longitude, 1 latitude) from ``start`` by ``sign * move.distance``."""

    t_start_s: float
    axis: int
    start: tuple[float, float]
    sign: float
    move: Move


class Raster:
    """A serpentine raster: rows along the longitude coordinate, stepped in latitude, run back and forth.

    Rows are ``width_deg`` long (in the longitude coordinate), centred on ``lon0``; row
    ``k`` of ``rows`` sits at latitude ``lat0 + (k - (rows - 1) / 2) * row_step_deg``.
    The boresight starts at rest at the western (lower longitude) end of row 0, sweeps the
    row with a rate limit of ``scan_rate`` (constant in the middle, ramps at both ends
    within the row), steps to the next row at up to ``step_rate``, and sweeps it the other
    way. After the last row the pattern runs back row by row to the first, and repeats.
    Every move uses the acceleration limit ``max_accel``.
    """

    def __init__(self, lon0_deg: float, lat0_deg: float, width_deg: float, rows: int, row_step_deg: float,
                 scan_rate_deg_s: float, step_rate_deg_s: float, max_accel_deg_s2: float):
        self.scan_rate, self.step_rate = scan_rate_deg_s, step_rate_deg_s
        row_lats = lat0_deg + (np.arange(rows) - (rows - 1) / 2.0) * row_step_deg
        # rows 0 .. n-1 .. 1, then again: an even number of sweeps, so each period starts where the last ended
        order = list(range(rows)) + list(range(rows - 2, 0, -1)) if rows > 1 else [0, 0]
        sweep = Move(width_deg, scan_rate_deg_s, max_accel_deg_s2)
        step = Move(abs(row_step_deg), step_rate_deg_s, max_accel_deg_s2)
        segments, t, lon = [], 0.0, lon0_deg - width_deg / 2.0
        direction = 1.0
        for i, row in enumerate(order):
            segments.append(Segment(t, 0, (lon, float(row_lats[row])), direction, sweep))
            t += sweep.duration
            lon += direction * width_deg
            direction = -direction
            following = order[(i + 1) % len(order)]
            if following != row:
                sign = float(np.sign(row_lats[following] - row_lats[row]))
                segments.append(Segment(t, 1, (lon, float(row_lats[row])), sign, step))
                t += step.duration
        self.segments = segments
        self.period_s = t
        self.row_lats = row_lats

    def coordinates(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.mod(np.asarray(t_s, dtype=np.float64), self.period_s)
        starts = np.array([s.t_start_s for s in self.segments])
        index = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        lon, lat = np.empty(t.shape), np.empty(t.shape)
        for k, segment in enumerate(self.segments):
            mask = index == k
            if not mask.any():
                continue
            moved = segment.sign * segment.move.position(t[mask] - segment.t_start_s)
            lon[mask], lat[mask] = segment.start
            if segment.axis == 0:
                lon[mask] += moved
            else:
                lat[mask] += moved
        return lon, lat

    def max_coordinate_rates(self) -> tuple[float, float]:
        rates = [(s.move.peak_rate, s.axis) for s in self.segments]
        return (max((r for r, a in rates if a == 0), default=0.0), max((r for r, a in rates if a == 1), default=0.0))


def unit_from_lonlat(lon_deg, lat_deg) -> np.ndarray:
    """Unit vectors ``[..., 3]`` with longitude measured from +x towards +y and latitude towards +z."""
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)


def lonlat_from_unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`unit_from_lonlat` [deg]."""
    lon = np.degrees(np.arctan2(v[..., 1], v[..., 0]))
    lat = np.degrees(np.arcsin(np.clip(v[..., 2], -1.0, 1.0)))
    return lon, lat


class Slew:
    """A slew along the great circle from ``(lon0, lat0)`` to ``(lon1, lat1)`` starting at ``start_s``.

    The angle along the great circle follows a :class:`Move` limited by ``max_rate`` and
    ``max_accel`` (on-sky degrees); before the slew the boresight holds the first
    pointing, after it the second.
    """

    def __init__(self, lon0_deg: float, lat0_deg: float, lon1_deg: float, lat1_deg: float, start_s: float,
                 max_rate_deg_s: float, max_accel_deg_s2: float):
        self.a = unit_from_lonlat(lon0_deg, lat0_deg)
        self.b = unit_from_lonlat(lon1_deg, lat1_deg)
        self.angle_rad = float(np.arccos(np.clip(self.a @ self.b, -1.0, 1.0)))
        self.start_s = start_s
        self.move = Move(np.degrees(self.angle_rad), max_rate_deg_s, max_accel_deg_s2)
        self.lon0_deg = lon0_deg

    def _slerp(self, fraction: np.ndarray) -> np.ndarray:
        theta = self.angle_rad
        if theta < 1e-12:
            return np.broadcast_to(self.a, fraction.shape + (3,)).copy()
        f = fraction[..., None]
        return (np.sin((1 - f) * theta) * self.a + np.sin(f * theta) * self.b) / np.sin(theta)

    def path_closest_to_pole_deg(self) -> float:
        """Smallest angle between the slew's path and either coordinate pole [deg]."""
        f = np.linspace(0.0, 1.0, 2001)
        _, lat = lonlat_from_unit(self._slerp(f))
        return float(90.0 - np.abs(lat).max())

    def coordinates(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = np.asarray(t_s, dtype=np.float64)
        total = self.move.distance
        fraction = self.move.position(t - self.start_s) / total if total > 0 else np.zeros(t.shape)
        lon, lat = lonlat_from_unit(self._slerp(fraction))
        # keep the starting longitude's branch so the azimuth never jumps by 360 deg mid-run
        lon = self.lon0_deg + (np.mod(lon - self.lon0_deg + 180.0, 360.0) - 180.0)
        return lon, lat

    def max_coordinate_rates(self) -> tuple[float, float]:
        """Upper bounds of the longitude and latitude coordinate rates along the path [deg/s]."""
        f = np.linspace(0.0, 1.0, 4001)
        lon, lat = lonlat_from_unit(self._slerp(f))
        dtheta = self.move.distance / (len(f) - 1)
        if dtheta == 0:
            return 0.0, 0.0
        dlon = np.abs(np.mod(np.diff(lon) + 180.0, 360.0) - 180.0) / dtheta
        dlat = np.abs(np.diff(lat)) / dtheta
        peak = self.move.peak_rate
        return float(dlon.max() * peak), float(dlat.max() * peak)
