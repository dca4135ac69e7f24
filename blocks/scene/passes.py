"""The pass finder: when is the satellite in the field of view, sunlit and observable?

:func:`find_passes` scans a time range coarsely, samples finely only where the
satellite can be near the field (the angular speed bounds how far it moves between
coarse samples), and refines each start and end by bisection. A satellite that never
enters the field gets its closest approach, so :func:`require_pass` can say in one
sentence how far it missed, and when.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timedelta

import numpy as np

from evsda.graph import SceneError

from . import projection
from .geometry import NS_PER_S
from .view import SatelliteView, ViewSamples


@dataclass(frozen=True)
class Pass:
    """An interval ``[start_ns, stop_ns]`` during which the satellite is observable in the field."""

    start_ns: int
    stop_ns: int
    epoch: datetime
    starts_before_range: bool = False     # already observable at the start of the searched range
    ends_after_range: bool = False        # still observable at its end

    @property
    def start_utc(self) -> datetime:
        return self.epoch + timedelta(microseconds=self.start_ns / 1000)

    @property
    def stop_utc(self) -> datetime:
        return self.epoch + timedelta(microseconds=self.stop_ns / 1000)

    @property
    def duration_s(self) -> float:
        return (self.stop_ns - self.start_ns) / NS_PER_S

    def __str__(self) -> str:
        before = " (already under way at the start)" if self.starts_before_range else ""
        after = " (still under way at the end)" if self.ends_after_range else ""
        return f"{iso(self.start_utc)} to {iso(self.stop_utc)}, {self.duration_s:.3f} s{before}{after}"


@dataclass
class PassReport:
    """What :func:`find_passes` found in ``[start_ns, stop_ns]``."""

    start_ns: int
    stop_ns: int
    epoch: datetime
    passes: list[Pass] = field(default_factory=list)
    in_fov: list[Pass] = field(default_factory=list)       # intervals in the field, whatever else holds
    closest_t_ns: int = 0                                   # closest approach to the field
    closest_outside_rad: float = np.inf                     # angle from the field's edge then (0 if inside)
    closest_boresight_rad: float = np.inf                   # angle from the boresight then
    samples: ViewSamples | None = None                      # the scan's samples (for plots)
    blocked_by: dict[str, float] = field(default_factory=dict)  # share of in-field samples failing each condition


def iso(when: datetime) -> str:
    """``2023-03-20T03:00:00.123Z``: UTC to the millisecond."""
    return when.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


def _intervals(t_ns: np.ndarray, mask: np.ndarray) -> list[tuple[int, int]]:
    """Index pairs ``(first, last)`` of runs of True in ``mask``."""
    if not mask.any():
        return []
    padded = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


def _scan_times(view: SatelliteView, start_ns: int, stop_ns: int, coarse_ns: int) -> np.ndarray:
    """Coarse samples everywhere plus fine samples wherever the satellite may be near the field."""
    coarse = np.unique(np.append(np.arange(start_ns, stop_ns, coarse_ns, dtype=np.int64), stop_ns))
    samples = view.sample(coarse)
    radius = projection.radius_rad(view.focal_plane)
    half_w, half_h = projection.half_extent_rad(view.focal_plane)
    # angular speed of the satellite relative to the boresight, bounded by finite differences
    # over each coarse step and by the two endpoints' speeds (a crossing between samples moves
    # at least as fast as the chord); doubled for margin
    dt_s = np.diff(coarse) / NS_PER_S
    chord = np.abs(np.diff(samples.boresight_angle_rad))
    endpoint_speed = _angular_speed(view, coarse)
    speed = 2.0 * np.maximum(chord / dt_s, np.maximum(endpoint_speed[:-1], endpoint_speed[1:]) + 1e-6)
    near = np.minimum(samples.boresight_angle_rad[:-1], samples.boresight_angle_rad[1:]) - speed * dt_s <= radius
    fine_parts = [coarse]
    for i in np.flatnonzero(near):
        step = max(1_000_000, int(0.1 * min(half_w, half_h) / speed[i] * NS_PER_S))
        fine_parts.append(np.arange(coarse[i], coarse[i + 1], min(step, coarse_ns), dtype=np.int64))
    return np.unique(np.concatenate(fine_parts))


def _angular_speed(view: SatelliteView, t_ns: np.ndarray) -> np.ndarray:
    """Upper bound of the satellite's apparent angular speed relative to the sensor frame [rad/s]."""
    r_sat, v_sat = view.track.state(t_ns.astype(np.float64))
    r_obs, v_obs = view.observer_model.state(t_ns.astype(np.float64))
    rel, vel = r_sat - r_obs, v_sat - v_obs
    dist = np.linalg.norm(rel, axis=-1)
    transverse = np.linalg.norm(np.cross(rel, vel), axis=-1) / dist**2
    frame = 7.3e-5 if view.observer.is_ground else 2 * np.linalg.norm(v_obs, axis=-1) / np.linalg.norm(r_obs, axis=-1)
    return transverse + np.maximum(frame, view.pointing_model.moving_rate_bound_rad_s())


def _refine(view: SatelliteView, predicate, t_false: int, t_true: int, resolution_ns: int) -> int:
    """Bisect to the first time (within ``resolution_ns``) at which ``predicate`` holds."""
    while abs(t_true - t_false) > resolution_ns:
        mid = (t_false + t_true) // 2
        if predicate(view.sample(np.array([mid])))[0]:
            t_true = mid
        else:
            t_false = mid
    return t_true


def _passes_of(view, t_ns, mask, predicate, start_ns, stop_ns, resolution_ns, epoch) -> list[Pass]:
    passes = []
    for first, last in _intervals(t_ns, mask):
        a = int(t_ns[first]) if first == 0 else _refine(view, predicate, int(t_ns[first - 1]), int(t_ns[first]),
                                                        resolution_ns)
        b = int(t_ns[last]) if last == len(t_ns) - 1 else _refine(view, predicate, int(t_ns[last + 1]),
                                                                   int(t_ns[last]), resolution_ns)
        passes.append(Pass(a, b, epoch, starts_before_range=(first == 0 and a == start_ns),
                           ends_after_range=(last == len(t_ns) - 1 and b == stop_ns)))
    return passes


def find_passes(view: SatelliteView, start_ns: int, stop_ns: int, *, coarse_step_s: float = 1.0,
                resolution_ns: int = 1_000_000) -> PassReport:
    """Observable passes of ``view``'s satellite between ``start_ns`` and ``stop_ns`` (ns after its epoch).

    Starts and ends are refined by bisection to ``resolution_ns``. A pass already under
    way at ``start_ns`` starts there (and says so).
    """
    coarse_ns = max(resolution_ns, min(int(coarse_step_s * NS_PER_S), max(resolution_ns, (stop_ns - start_ns) // 4)))
    t_ns = _scan_times(view, start_ns, stop_ns, coarse_ns)
    samples = view.sample(t_ns)
    report = PassReport(start_ns, stop_ns, view.epoch, samples=samples)
    report.passes = _passes_of(view, t_ns, samples.observable, lambda s: s.observable, start_ns, stop_ns,
                               resolution_ns, view.epoch)
    report.in_fov = _passes_of(view, t_ns, samples.in_fov, lambda s: s.in_fov, start_ns, stop_ns,
                               resolution_ns, view.epoch)
    i = int(np.nanargmin(np.where(np.isfinite(samples.outside_angle_rad), samples.outside_angle_rad, np.inf)))
    report.closest_t_ns = int(t_ns[i])
    report.closest_outside_rad = float(samples.outside_angle_rad[i])
    report.closest_boresight_rad = float(samples.boresight_angle_rad[i])
    inside = samples.in_fov
    if inside.any():
        report.blocked_by = {
            "in the Earth's shadow": float(np.mean(~samples.sunlit[inside])),
            "below the horizon limit" if view.observer.is_ground else "behind the Earth":
                float(np.mean(~samples.above_horizon[inside])),
            "in daylight (Sun above the darkness limit)" if view.observer.is_ground else "too close to the Sun":
                float(np.mean(~samples.observer_dark[inside])),
        }
    return report


def require_pass(report: PassReport, who: str, satellite: str) -> None:
    """Raise one clear :class:`SceneError` if ``report`` has no observable pass."""
    if report.passes:
        return
    start, stop = iso(report.epoch + timedelta(microseconds=report.start_ns / 1000)), \
        iso(report.epoch + timedelta(microseconds=report.stop_ns / 1000))
    if not report.in_fov:
        when = iso(report.epoch + timedelta(microseconds=report.closest_t_ns / 1000))
        raise SceneError(
            f"{who}: {satellite} never enters the field of view between {start} and {stop}; closest approach "
            f"{np.degrees(report.closest_outside_rad):.3f} deg outside the field's edge "
            f"({np.degrees(report.closest_boresight_rad):.3f} deg from the boresight) at {when}; "
            f"change the pointing, the start time or the duration (`evsda plot-pass` shows the track)")
    reasons = [f"{name} ({100 * share:.0f}% of the time)" for name, share in report.blocked_by.items() if share > 0]
    crossing = "; ".join(str(p) for p in report.in_fov)
    raise SceneError(f"{who}: {satellite} crosses the field of view ({crossing}) but is never observable "
                     f"there: {', '.join(reasons)}")
