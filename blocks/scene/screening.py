"""Which of thousands of catalogued objects can cross the field of view during a run: a cheap, safe screen.

All objects are propagated together with ``sgp4``'s vectorised ``SatrecArray`` on a coarse
grid (``coarse_step``, 10 s by default), rotated from TEME to the GCRS with Skyfield's
matrix (as ``EarthSatellite.at()`` does), and compared with the boresight. Over each
coarse interval ``[t_a, t_b]`` of length ``h`` the angle ``theta`` between an object and the
boresight cannot fall below

    theta_min = (theta_a + theta_b - (omega_object + omega_boresight) h) / 2,

where ``omega_object <= V / rho_min`` bounds the object's angular speed seen from the
observer (``V`` the relative speed at the ends plus ``a_max h``, ``rho_min`` the range's lower
bound ``(rho_a + rho_b - V h) / 2``) and ``omega_boresight`` bounds the boresight's. Intervals
where ``theta_min`` exceeds the field's corner radius plus ``margin`` are dropped (no
crossing is possible there); the others are screened again on a ``fine_step`` grid (0.5 s),
object by object, and what survives is the list of short intervals per object in which it
may be in the field. Only those objects, and only in those intervals, are then propagated
at the run's cadence (:mod:`evsda.blocks.scene.satellite_catalog`), so the cost grows with
the objects that cross the field, not with the catalogue.

The screen ignores light time and aberration (together < 1e-4 rad for an Earth orbiter)
and is checked against a brute-force propagation of every object at 0.1 s in
``tests/scene/test_scene_catalog.py`` and ``benchmarks/catalog_screening.py``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np
from sgp4.api import SatrecArray
from skyfield.sgp4lib import TEME

from . import projection
from .ephemeris import NS_PER_DAY, skyfield_time
from .geometry import NS_PER_S
from .pointing import PointingModel
from .visibility import EARTH_RADIUS_M

#: relative acceleration of object and observer: gravity at the Earth's surface twice (a space observer
#: falls too), 2 x 9.82 m/s^2, rounded up [m/s^2]
MAX_RELATIVE_ACCELERATION_M_S2 = 20.0
#: closer than this the angular-speed bound is useless and the interval is kept [m]
MIN_RANGE_BOUND_M = 1000.0
#: spacing of the boresight samples that bound its angular speed [ns]
BORESIGHT_PROBE_NS = 50_000_000


@dataclass
class ScreenResult:
    """Per screened object, the intervals ``[(start_ns, stop_ns), ...]`` in which it may be in the field."""

    n_objects: int
    intervals: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    failed: dict[int, str] = field(default_factory=dict)        # object index -> why SGP4 could not follow it
    n_coarse_candidates: int = 0
    seconds: float = 0.0


@dataclass
class _Geometry:
    theta: np.ndarray          # angle from the boresight [rad], [N, T]
    range_m: np.ndarray        # [N, T]
    speed_m_s: np.ndarray      # relative speed [m/s], [N, T]
    failed: np.ndarray         # bool [N, T]: SGP4 error or below the Earth's surface


def boresight_rate_bound(pointing: PointingModel, start_ns: int, stop_ns: int) -> float:
    """Upper bound of the boresight's angular speed in the GCRS over the run [rad/s].

    The larger of the moving law's analytic bound and 1.25 times the fastest motion
    between boresight samples 50 ms apart (covers stares, sidereal tracking and tracking
    a satellite), plus the Earth's rotation rate as a floor.
    """
    n = int(max(2, (stop_ns - start_ns) // BORESIGHT_PROBE_NS + 2))
    t = np.linspace(start_ns, stop_ns, n)
    b, _, _ = pointing.frame(t)
    chord = np.arccos(np.clip(np.sum(b[1:] * b[:-1], axis=-1), -1.0, 1.0))
    dt_s = (t[1] - t[0]) / NS_PER_S
    sampled = float(chord.max(initial=0.0)) / dt_s if dt_s > 0 else 0.0
    return max(pointing.moving_rate_bound_rad_s(), 1.25 * sampled) + 7.3e-5


class Screen:
    """Screens one catalogue for one observer, pointing and focal plane over ``[start_ns, stop_ns]``."""

    def __init__(self, satrecs: list, pointing: PointingModel, focal_plane, epoch: datetime, start_ns: int,
                 stop_ns: int, coarse_step_ns: int = 10 * NS_PER_S, fine_step_ns: int = NS_PER_S // 2,
                 margin_rad: float = 1e-3):
        self.satrecs = satrecs
        self.pointing = pointing
        self.observer = pointing.observer
        self.epoch = epoch
        self.start_ns, self.stop_ns = int(start_ns), int(stop_ns)
        self.coarse_step_ns = int(min(coarse_step_ns, max(fine_step_ns, stop_ns - start_ns)))
        self.fine_step_ns = int(min(fine_step_ns, self.coarse_step_ns))
        self.radius_rad = projection.radius_rad(focal_plane) + margin_rad
        days = epoch.timestamp() / 86400.0                          # UTC days since 1970 (Julian date 2440587.5)
        self.jd_whole, self.jd_fraction = 2440587.5 + np.floor(days), days - np.floor(days)
        self.omega_boresight = boresight_rate_bound(pointing, self.start_ns, self.stop_ns)

    def _grid(self, step_ns: int) -> np.ndarray:
        t = np.arange(self.start_ns, self.stop_ns, step_ns, dtype=np.int64)
        return np.append(t, self.stop_ns)

    def _frame_quantities(self, t_ns: np.ndarray):
        """TEME->GCRS matrices, observer position/velocity and boresight at ``t_ns``."""
        t = t_ns.astype(np.float64)
        teme = TEME.rotation_at(skyfield_time(self.epoch, t))              # [3, 3, T]: r_teme = R r_gcrs
        r_obs, v_obs = self.observer.state(t)
        b, _, _ = self.pointing.frame(t)
        return teme, r_obs, v_obs, b

    def _geometry(self, r_km, v_km_s, errors, teme, r_obs, v_obs, b) -> _Geometry:
        """Angles, ranges and speeds of objects ``[N, T, 3]`` (TEME, km) against the frame quantities."""
        r = np.einsum("jit,ntj->nti", teme, r_km) * 1000.0
        v = np.einsum("jit,ntj->nti", teme, v_km_s) * 1000.0
        relative = r - r_obs[None]
        range_m = np.linalg.norm(relative, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_theta = np.einsum("ntk,tk->nt", relative, b) / range_m
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
        speed = np.linalg.norm(v - v_obs[None], axis=-1)
        failed = (errors != 0) | ~np.isfinite(range_m) | (np.linalg.norm(r, axis=-1) < EARTH_RADIUS_M)
        return _Geometry(theta, range_m, speed, failed)

    def _possible(self, g: _Geometry, h_s: np.ndarray) -> np.ndarray:
        """Whether each interval between consecutive samples may hold a crossing, ``[N, T-1]``."""
        speed = np.maximum(g.speed_m_s[:, 1:], g.speed_m_s[:, :-1]) + MAX_RELATIVE_ACCELERATION_M_S2 * h_s
        range_min = (g.range_m[:, 1:] + g.range_m[:, :-1] - speed * h_s) / 2.0
        with np.errstate(divide="ignore", invalid="ignore"):
            omega = np.where(range_min > MIN_RANGE_BOUND_M, speed / range_min, np.inf)
        theta_min = (g.theta[:, 1:] + g.theta[:, :-1] - (omega + self.omega_boresight) * h_s) / 2.0
        bad = g.failed[:, 1:] | g.failed[:, :-1]
        return (theta_min <= self.radius_rad) & ~bad

    def _propagate(self, satrecs: list, t_ns: np.ndarray):
        jd_whole = np.full(len(t_ns), self.jd_whole)
        fraction = self.jd_fraction + t_ns.astype(np.float64) / NS_PER_DAY
        errors, r_km, v_km_s = SatrecArray(satrecs).sgp4(jd_whole, fraction)
        return r_km, v_km_s, errors

    def run(self) -> ScreenResult:
        started = time.perf_counter()
        result = ScreenResult(n_objects=len(self.satrecs))
        if not self.satrecs:
            return result
        coarse = self._grid(self.coarse_step_ns)
        frame = self._frame_quantities(coarse)
        r_km, v_km_s, errors = self._propagate(self.satrecs, coarse)
        g = self._geometry(r_km, v_km_s, errors, *frame)
        for n in np.flatnonzero(g.failed.any(axis=1)):
            k = int(np.argmax(g.failed[n]))
            code = int(errors[n, k])
            result.failed[int(n)] = (f"SGP4 error {code}" if code else "below the Earth's surface") + \
                f" at t = {coarse[k] / NS_PER_S:.1f} s"
        possible = self._possible(g, np.diff(coarse)[None, :] / NS_PER_S)
        candidates = np.flatnonzero(possible.any(axis=1))
        result.n_coarse_candidates = int(candidates.size)
        if candidates.size:
            self._refine(candidates, coarse, possible[candidates], result)
        result.seconds = time.perf_counter() - started
        return result

    def _refine(self, candidates: np.ndarray, coarse: np.ndarray, possible: np.ndarray, result: ScreenResult):
        """Screen the candidates' possible coarse intervals again at the fine step."""
        fine_all = self._grid(self.fine_step_ns)
        wanted = np.zeros(len(fine_all), bool)
        per_object = []
        for row in possible:
            mask = np.zeros(len(fine_all), bool)
            for k in np.flatnonzero(row):
                mask |= (fine_all >= coarse[k]) & (fine_all <= coarse[k + 1])
            per_object.append(mask)
            wanted |= mask
        times = fine_all[wanted]
        frame = self._frame_quantities(times)
        index_of = np.full(len(fine_all), -1)
        index_of[wanted] = np.arange(len(times))
        r_km, v_km_s, errors = self._propagate([self.satrecs[n] for n in candidates], times)
        g = self._geometry(r_km, v_km_s, errors, *frame)
        for row, (n, mask) in enumerate(zip(candidates, per_object)):
            where = index_of[mask]                         # this object's fine samples, in time order
            t = times[where]
            sub = _Geometry(g.theta[row:row + 1, where], g.range_m[row:row + 1, where],
                            g.speed_m_s[row:row + 1, where], g.failed[row:row + 1, where])
            ok = self._possible(sub, np.diff(t)[None, :] / NS_PER_S)[0]
            contiguous = np.diff(np.flatnonzero(mask)) == 1          # a gap between coarse intervals is no interval
            ok &= contiguous
            intervals = _merge([(int(t[k]), int(t[k + 1])) for k in np.flatnonzero(ok)])
            if intervals:
                result.intervals[int(n)] = intervals


def _merge(intervals: list[tuple[int, int]]) -> list[tuple[int, int]]:
    """Join touching or overlapping intervals (sorted input)."""
    merged: list[tuple[int, int]] = []
    for a, b in intervals:
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return merged
