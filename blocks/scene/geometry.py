"""Positions and directions in the GCRS at millisecond cadence, from Skyfield at a coarse cadence.

Skyfield (Rhodes 2019) computes every position here, but only on a coarse grid of
*knots* ``k * knot_step`` that is global to the run (so results never depend on how a
run is cut into windows). Between knots:

* a body's GCRS position is a cubic Hermite interpolation of Skyfield's position and
  velocity at the two neighbouring knots (error below ``h**4/384 * |r''''|``: under a
  micrometre for a LEO orbit with ``h = 10 s``);
* the GCRS <- ITRS rotation is Skyfield's matrix at the nearest knot followed by the
  Earth's rotation about the CIP through the elapsed angle (precession-nutation and
  polar motion change by microarcseconds in a few seconds).

``benchmarks/scene_geometry.py`` measures both against Skyfield called at every sample.
All vectors are metres (m/s for velocities) in the GCRS, arrays shaped ``[n, 3]``.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime

import numpy as np
from skyfield.api import EarthSatellite, wgs84
from skyfield.errors import EphemerisRangeError
from skyfield.framelib import itrs

from evsda.blocks.ports.scene import Observer
from evsda.graph import NS_PER_S, SceneError

from .ephemeris import planets, skyfield_time, timescale
from .tle import earth_satellite

C_M_PER_S = 299_792_458.0                      # speed of light [m/s]
#: Earth rotation rate [rad per UT1 second]: d(ERA)/dt = 2 pi * 1.00273781191135448 / 86400
#: (IERS Conventions 2010, Eq. 5.15)
OMEGA_EARTH_RAD_S = 2.0 * np.pi * 1.00273781191135448 / 86400.0


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to unit length along its last axis."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def consecutive_rows(kept_t: np.ndarray, t_ns: np.ndarray) -> slice | None:
    """The rows of the ascending sample times ``kept_t`` that are ``t_ns`` (a run of consecutive ones, compared
    as bytes in ``kept_t``'s type), or None."""
    first = int(np.searchsorted(kept_t, t_ns[0]))
    rows = slice(first, first + len(t_ns))
    return rows if kept_t[rows].tobytes() == np.asarray(t_ns, kept_t.dtype).tobytes() else None


class Recent:
    """The last few results of a function of sample times, returned again for the same times.

    Within one window a block asks its models for the same samples several times (the
    pointing frame, the observer's horizon axes and position, a track's state): the
    second and later asks are served from here, the same arrays, made read-only so that
    no caller can change what another is given. Keyed by the times' shape and bytes (float
    ns, never NaN or -0): one comparison of bytes for each kept entry instead of an array
    comparison (~17 asks a window from a satellite's view, most of them for kept times).

    The scene's models are shared by its blocks (``pointing.shared_models``), which a pipelined run steps
    on several threads up to a few windows apart, each asking for a few sets of times a window: ``size`` keeps
    all of them, so that a block finds what another computed for the same times instead of computing it again
    (with 4 kept, a pipelined pass computed the stars' pointing frames, the tracked satellite's apparent places
    and states a second time, ~30 % more computations than one step at a time).
    """

    def __init__(self, size: int = 32):
        self._size = size
        self._entries: list[tuple[tuple, np.ndarray, object]] = []        # (key, times, result)

    def get(self, t: np.ndarray, compute: Callable[[np.ndarray], object]):
        """``compute(t)``, or its result for equal ``t`` kept from an earlier call, or the rows of a kept result
        whose times hold ``t`` as a run of consecutive samples (each model here works sample by sample, so those
        rows are what ``compute(t)`` makes: a block that samples several windows at once serves the others)."""
        key = (t.shape, t.tobytes())
        for kept, _, result in self._entries:
            if kept == key:
                return result
        result = self._rows_within(t)
        if result is None:
            result = compute(t)
            for array in (result if isinstance(result, tuple) else (result,)):
                array.flags.writeable = False
        times = t.copy()
        times.flags.writeable = False
        self._entries = [(key, times, result), *self._entries[: self._size - 1]]
        return result

    def _rows_within(self, t: np.ndarray):
        """The rows of a kept result whose times hold ``t`` as consecutive samples, or None."""
        if t.ndim != 1 or not t.size:
            return None
        first, last = t[0], t[-1]
        for _, times, result in self._entries:
            if times.ndim == 1 and times.size > t.size and times[0] <= first and last <= times[-1]:
                start = int(np.searchsorted(times, first))
                rows = slice(start, start + t.size)
                if times[rows].tobytes() == t.tobytes():
                    return tuple(a[rows] for a in result) if isinstance(result, tuple) else result[rows]
        return None


def hermite(t0_s: np.ndarray, h_s: float, p0, v0, p1, v1, t_s: np.ndarray):
    """Cubic Hermite interpolation of position ``p`` and velocity ``v`` between two knots.

    ``t0_s`` is the left knot time of each sample and ``h_s`` the knot spacing; returns
    the interpolated position and its time derivative (the interpolated velocity).
    """
    s = ((t_s - t0_s) / h_s)[:, None]
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    pos = h00 * p0 + h10 * h_s * v0 + h01 * p1 + h11 * h_s * v1
    d00, d10, d01, d11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
    vel = (d00 * p0 + d01 * p1) / h_s + d10 * v0 + d11 * v1
    return pos, vel


class KnotGrid:
    """Values of an expensive function of time on the knots ``k * step_ns``, computed once each."""

    def __init__(self, epoch: datetime, step_ns: int, evaluate: Callable, max_cached: int = 4096):
        if step_ns <= 0:
            raise ValueError("knot step must be positive")
        self.epoch = epoch
        self.step_ns = int(step_ns)
        self._evaluate = evaluate      # evaluate(skyfield Time of n knots) -> tuple of [n, ...] arrays
        self._cache: dict[int, tuple] = {}
        self._max_cached = max_cached

    def values(self, k: np.ndarray) -> tuple[np.ndarray, ...]:
        """The function's values at knot indices ``k`` (any shape of integers)."""
        k = np.asarray(k, dtype=np.int64)
        if k.size and k.min() == k.max():         # one knot interval (the usual window): its values repeated
            (row,) = self._rows([int(k.flat[0])])
            position = np.zeros(k.shape, np.intp)
            return tuple(value[None][position] for value in row)       # (a gather keeps each value's layout)
        wanted = np.unique(k)
        rows = self._rows(wanted.tolist())
        position = np.searchsorted(wanted, k)
        return tuple(np.stack([row[m] for row in rows])[position] for m in range(len(rows[0])))

    def _rows(self, indices: list[int]) -> list[tuple]:
        """The values at each knot of ``indices``, evaluated together for the knots not kept yet."""
        cache = self._cache       # one grid may serve blocks on several threads: read and fill this dict only
        rows = [cache.get(i) for i in indices]
        missing = [i for i, row in zip(indices, rows) if row is None]
        if not missing:
            return rows
        if len(cache) + len(missing) > self._max_cached:
            self._cache = cache = {}
        t = skyfield_time(self.epoch, np.array(missing, dtype=np.int64) * self.step_ns)
        try:
            results = self._evaluate(t)
        except EphemerisRangeError:
            raise SceneError(f"the scene needs the Sun, the Moon or the Earth's motion from JPL DE421, which "
                             f"covers 1899-07-29 to 2053-10-09 UTC; the run asks for {t[0].utc_iso()} to "
                             f"{t[-1].utc_iso()}. Move the run's start inside DE421's span") from None
        made = {index: tuple(r[j] for r in results) for j, index in enumerate(missing)}
        cache.update(made)
        return [row if row is not None else made[i] for i, row in zip(indices, rows)]


class Track:
    """A body's GCRS (or barycentric) position and velocity, Hermite-interpolated between knots."""

    def __init__(self, epoch: datetime, knot_step_ns: int, evaluate: Callable):
        self.grid = KnotGrid(epoch, knot_step_ns, evaluate)
        self._recent = Recent()
        self._apparent: dict[int, tuple[object, Recent]] = {}     # id(observer) -> (observer, its recent places)

    def apparent_places(self, observer) -> Recent:
        """The last few apparent places of this body seen by ``observer`` (see :func:`apparent_position`)."""
        kept = self._apparent.get(id(observer))
        if kept is None:           # (kept here, the observer keeps its id)
            kept = self._apparent.setdefault(id(observer), (observer, Recent()))
        return kept[1]

    def state(self, t_ns) -> tuple[np.ndarray, np.ndarray]:
        """Position [m] and velocity [m/s] at ``t_ns`` (float ns after the epoch allowed; read-only arrays)."""
        return self._recent.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._state)

    def _state(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        step = self.grid.step_ns
        k = np.floor(t_ns / step).astype(np.int64)
        p0, v0 = self.grid.values(k)
        p1, v1 = self.grid.values(k + 1)
        return hermite(k * (step / NS_PER_S), step / NS_PER_S, p0, v0, p1, v1, t_ns / NS_PER_S)


def _vectors(position) -> tuple[np.ndarray, np.ndarray]:
    return position.xyz.m.T.copy(), position.velocity.m_per_s.T.copy()


def satellite_track(epoch: datetime, knot_step_ns: int, line1: str, line2: str) -> Track:
    """GCRS position/velocity of an SGP4 satellite (Skyfield ``EarthSatellite``)."""
    satellite = earth_satellite(line1, line2)
    return Track(epoch, knot_step_ns, lambda t: _vectors(satellite.at(t)))


def satrec_track(epoch: datetime, knot_step_ns: int, satrec) -> Track:
    """GCRS position/velocity of SGP4 elements already in an ``sgp4`` ``Satrec`` (e.g. read from an OMM)."""
    satellite = EarthSatellite.from_satrec(satrec, timescale())
    return Track(epoch, knot_step_ns, lambda t: _vectors(satellite.at(t)))


def sun_track(epoch: datetime, knot_step_ns: int) -> Track:
    """Geometric geocentric position/velocity of the Sun (JPL DE421)."""
    eph = planets()
    sun = eph["sun"] - eph["earth"]
    return Track(epoch, knot_step_ns, lambda t: _vectors(sun.at(t)))


def earth_barycentric_track(epoch: datetime, knot_step_ns: int) -> Track:
    """Barycentric position/velocity of the Earth's centre (JPL DE421), for aberration."""
    earth = planets()["earth"]
    return Track(epoch, knot_step_ns, lambda t: _vectors(earth.at(t)))


class EarthRotation:
    """The GCRS <- ITRS rotation matrix at any time (Skyfield's at the nearest knot, then ERA)."""

    def __init__(self, epoch: datetime, knot_step_ns: int):
        self.grid = KnotGrid(epoch, knot_step_ns, lambda t: (np.moveaxis(itrs.rotation_at(t), -1, 0)
                                                             .transpose(0, 2, 1).copy(),))
        self._recent = Recent()

    def matrices(self, t_ns) -> np.ndarray:
        """``[n, 3, 3]`` matrices taking ITRS vectors to the GCRS (read-only)."""
        return self._recent.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._matrices)

    def _matrices(self, t_ns: np.ndarray) -> np.ndarray:
        step = self.grid.step_ns
        k = np.rint(t_ns / step).astype(np.int64)
        (m_k,) = self.grid.values(k)
        angle = OMEGA_EARTH_RAD_S * (t_ns - k * step) / NS_PER_S
        c, s = np.cos(angle), np.sin(angle)
        rz = np.zeros((len(t_ns), 3, 3))
        rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
        return m_k @ rz

    def pole(self, t_ns) -> np.ndarray:
        """The Earth's rotation axis (ITRS z) in the GCRS, ``[n, 3]``."""
        return self.matrices(t_ns)[:, :, 2]


def enu_axes_itrs(latitude_deg: float, longitude_deg: float) -> np.ndarray:
    """Rows east, north, up of the local geodetic horizon frame, in ITRS coordinates."""
    lat, lon = np.radians(latitude_deg), np.radians(longitude_deg)
    east = [-np.sin(lon), np.cos(lon), 0.0]
    north = [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)]
    up = [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]
    return np.array([east, north, up])


class ObserverModel:
    """An :class:`Observer` evaluated in the GCRS: position, velocity, local horizon axes."""

    def __init__(self, observer: Observer, epoch: datetime, knot_step_ns: int):
        self.observer = observer
        self.epoch = epoch
        self.rotation = EarthRotation(epoch, knot_step_ns)
        self.earth = earth_barycentric_track(epoch, knot_step_ns)
        if observer.is_ground:
            self.site = wgs84.latlon(observer.latitude_deg, observer.longitude_deg, elevation_m=observer.altitude_m)
            self.r_itrs = np.asarray(self.site.itrs_xyz.m)
            self.enu_itrs = enu_axes_itrs(observer.latitude_deg, observer.longitude_deg)
        else:
            self.track = satellite_track(epoch, knot_step_ns, observer.line1, observer.line2)
        self._recent_state, self._recent_enu = Recent(), Recent()

    def state(self, t_ns) -> tuple[np.ndarray, np.ndarray]:
        """Geocentric GCRS position [m] and velocity [m/s] (read-only arrays)."""
        return self._recent_state.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._state)

    def _state(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.observer.is_ground:
            return self.track.state(t_ns)
        m = self.rotation.matrices(t_ns)
        omega_cross_r = OMEGA_EARTH_RAD_S * np.array([-self.r_itrs[1], self.r_itrs[0], 0.0])
        return m @ self.r_itrs, m @ omega_cross_r

    def enu(self, t_ns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """East, north and up unit vectors in the GCRS, each ``[n, 3]``.

        Ground: the geodetic horizon frame. Space: up is the geocentric radial direction
        and north points to the Earth's rotation axis. Read-only arrays.
        """
        return self._recent_enu.get(np.atleast_1d(np.asarray(t_ns, dtype=np.float64)), self._enu)

    def _enu(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self.observer.is_ground:
            m = self.rotation.matrices(t_ns)
            east, north, up = (m @ axis for axis in self.enu_itrs)
            return east, north, up
        position, _ = self.track.state(t_ns)
        up = unit(position)
        east = unit(np.cross(self.rotation.pole(t_ns), up))
        return east, np.cross(up, east), up

    def skyfield_observer(self):
        """The observer as a Skyfield vector function from the solar-system barycentre."""
        earth = planets()["earth"]
        if self.observer.is_ground:
            return earth + self.site
        return earth + earth_satellite(self.observer.line1, self.observer.line2)


def aberrate(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Apply relativistic aberration for an observer moving at ``velocity`` [m/s] to ``position`` [m].

    The formula of Kaplan et al. (1989, AJ 97, 1197; NOVAS ``aberration``), as Skyfield's
    ``add_aberration`` uses it; the length of ``position`` is kept as the light-time distance.
    """
    distance = np.linalg.norm(position, axis=-1, keepdims=True)
    speed = np.linalg.norm(velocity, axis=-1, keepdims=True)
    beta = speed / C_M_PER_S
    cos_d = np.sum(position * velocity, axis=-1, keepdims=True) / (distance * speed)
    gamma_inv = np.sqrt(1.0 - beta * beta)
    p = beta * cos_d
    q = (1.0 + p / (1.0 + gamma_inv)) * distance / C_M_PER_S
    return (gamma_inv * position + q * velocity) / (1.0 + p)


def apparent_position(target: Track, observer: ObserverModel, t_ns) -> np.ndarray:
    """Apparent place of an Earth-orbiting target as seen by ``observer`` [m, GCRS axes].

    Light-time: the target is taken at ``t - tau`` with ``tau = |r| / c`` (two
    iterations), and the Earth's barycentric motion during ``tau`` is included, so the
    result is the barycentric computation of Skyfield's ``observe()``; then aberration
    with the observer's barycentric velocity (Skyfield's ``apparent()`` without the
    microarcsecond gravitational deflection of a target this close). The last few results
    are kept per target and observer (read-only arrays): a tracked satellite's pointing and
    its view ask for the same samples.
    """
    t_ns = np.atleast_1d(np.asarray(t_ns, dtype=np.float64))
    return target.apparent_places(observer).get(t_ns, lambda t: _apparent_position(target, observer, t))


def _apparent_position(target: Track, observer: ObserverModel, t_ns: np.ndarray) -> np.ndarray:
    r_obs, v_obs = observer.state(t_ns)
    _, v_earth = observer.earth.state(t_ns)
    tau_s = np.zeros(len(t_ns))
    for _ in range(3):
        r_target, _ = target.state(t_ns - tau_s * NS_PER_S)
        relative = r_target - r_obs - v_earth * tau_s[:, None]
        tau_s = np.linalg.norm(relative, axis=-1) / C_M_PER_S
    return aberrate(relative, v_earth + v_obs)
