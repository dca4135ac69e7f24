"""The sensor frame versus time: boresight ``b``, image right ``r`` and image up ``u`` in the GCRS.

The frame is right-handed with ``r = b x u``: looking along ``b`` with ``u`` up, ``r``
is to the right, so the image shows the sky as seen, not mirrored (north up puts east
on the left). Reference up directions:

* ``stare`` and ``track`` from the ground: ``u = d b / d elevation``, the direction of
  increasing elevation at the boresight's azimuth, which stays defined at the zenith;
* ``sidereal`` and ``track`` from space: ``u = d b / d declination`` (towards celestial
  north), defined at the celestial poles too.

``roll`` then turns ``u`` towards ``r`` by the roll angle.
"""

from __future__ import annotations

from datetime import datetime

import numpy as np
from skyfield.api import Star

from evsda.blocks.ports.scene import SIDEREAL, STARE, TRACK, Pointing
from evsda.graph import ParameterError

from .geometry import NS_PER_S, KnotGrid, ObserverModel, apparent_position, satellite_track, unit


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
        elif pointing.mode != STARE:
            raise ParameterError(f"pointing: unknown mode {pointing.mode!r}; expected stare, sidereal or track")

    def frame(self, t_ns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Boresight, right and up unit vectors at ``t_ns``, each ``[n, 3]`` (GCRS)."""
        t_ns = np.atleast_1d(np.asarray(t_ns, dtype=np.float64))
        p = self.pointing
        if p.mode == STARE:
            b, u = self._from_horizon(t_ns, *direction_from_azel(np.radians(p.azimuth_deg),
                                                                  np.radians(p.elevation_deg)))
        elif p.mode == SIDEREAL:
            b = self._sidereal_boresight(t_ns)
            u = north_of(b)
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

    def zenith_angle(self, t_ns, b: np.ndarray) -> np.ndarray:
        """Zenith angle of the boresight [rad]; NaN for a space observer (no atmosphere)."""
        if not self.observer.observer.is_ground:
            return np.full(len(b), np.nan)
        _, _, up = self.observer.enu(t_ns)
        return np.arccos(np.clip(np.einsum("ij,ij->i", b, up), -1.0, 1.0))


def seconds(t_ns) -> np.ndarray:
    """Nanoseconds to seconds."""
    return np.asarray(t_ns, dtype=np.float64) / NS_PER_S
