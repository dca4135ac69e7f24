"""Point sources and streaks found in the recorded events alone: a velocity-matched filter with a
false-alarm rate set against the background measured in the same events.

The event stream is cut into looks of ``look_s`` on one global grid (look ``k`` spans
``[k look, (k+1) look)`` of readout time, so results do not depend on the executor's windows).
In each look:

1. events are thinned (:func:`.matched_filter.thin_events`): a pixel's events within ``dedup_s`` of
   its previous one are merged (a shot-noise event and its rebound one refractory period later
   count once), optionally at most ``max_events_per_pixel`` per look; pixels whose count was
   improbably high for the background in ``hot_pixel_looks`` of the previous looks (hot pixels) are
   left out (:meth:`hot_pixels`): a moving source raises a pixel's count for a look or two, a hot
   pixel in look after look (a source that stays on one pixel for that long looks the same);
2. the background density ``rho`` [events pixel^-1 look^-1] is measured from the thinned events
   themselves, robust to sources (:func:`.matched_filter.background_density`); a look with no
   background event takes Gehrels' (1986, Table 1) one-sided 84 % upper limit, 1.841 events over
   the detector, so a threshold is never set against zero;
3. for every trial velocity (|v| up to ``max_rate_px_s``, spaced ``velocity_step_px / look_s``), the
   events are moved back to the look's middle and counted in ``box_px x box_px`` boxes (the local
   maxima of the box counts are the candidates); a box whose
   centre stays on the detector for a fraction ``f`` of the look expects ``mu = rho box^2 f`` events
   of background, and its count ``k`` has the Poisson p-value ``P(N >= k | mu)``;
4. a box is a detection when that p-value is below the threshold that holds the expected false
   alarms to ``false_alarm_rate_per_hour_per_mpx`` given the look's trials (every box position times
   every trial velocity: :func:`.significance.local_p_threshold`); boxes of one source at several
   velocities and positions are merged to the most significant within ``merge_radius_px``, whose
   position and velocity are refined by least squares on its events (:func:`.matched_filter.refine`).

Nothing here reads the simulation's truth (event causes, source positions): the threshold comes
from the false-alarm rate and the measured background only.
"""

from __future__ import annotations

import logging
import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator
from scipy.spatial import cKDTree

from evsda.blocks.ports import Detections, Events, FocalPlane
from evsda.graph import NS_PER_S, Block, BlockParams, Footprint, Input, Output, RunInfo, SceneError, Window

from . import matched_filter as mf
from .significance import gaussian_sigma, local_p_threshold, poisson_count_threshold, poisson_p_value

ZERO_COUNT_UPPER_LIMIT = 1.841      # Gehrels 1986, Table 1: 84.13 % one-sided upper limit for 0 observed events
log = logging.getLogger(__name__)


class EventDetector(Block):
    """Sources and streaks in the events alone: velocity-matched filter, Poisson threshold at a false-alarm rate."""

    type_name = "event_detector"
    is_sink = False

    class Params(BlockParams):
        look_s: float = Field(0.5, gt=0, le=600, description="Integration time of one look [s]")
        max_rate_px_s: float = Field(10.0, ge=0, description="Fastest apparent motion searched [pixel s^-1]")
        min_rate_px_s: float = Field(0.0, ge=0, description="Slowest apparent motion searched (0 includes "
                                                            "static sources) [pixel s^-1]")
        velocity_step_px: float = Field(1.0, gt=0, le=4, description="Spacing of the trial velocities as the drift "
                                                                     "it makes over one look [pixel]")
        box_px: int = Field(2, ge=1, le=9, description="Side of the counting box of the compensated image [pixel]")
        false_alarm_rate_per_hour_per_mpx: float = Field(1.0, gt=0, description="False alarms the threshold "
                                                         "allows per hour per megapixel [h^-1 Mpixel^-1]")
        dedup_s: float = Field(1e-3, ge=0, description="A pixel's events closer than this to its previous event "
                                                        "are merged into it [s]")
        max_events_per_pixel: int = Field(0, ge=0, description="Events one pixel may contribute to one look "
                                                               "(0: no limit) [1]")
        hot_pixel_p_value: float = Field(1e-6, gt=0, lt=1, description="A pixel's count in a look this improbable "
                                         "for the background marks it as a hot pixel for that look [1]")
        hot_pixel_looks: int = Field(3, ge=1, description="Looks a pixel must be marked hot in before it is "
                                                          "left out of the following looks [1]")
        polarity: Literal["both", "on", "off"] = Field("both", description="Which events are used [-]")
        tile_px: int = Field(32, ge=4, description="Tiles over which the background density is measured [pixel]")
        min_exposure: float = Field(0.5, gt=0, le=1, description="Boxes on the detector for less than this "
                                                                 "fraction of a look are not tested [1]")
        merge_radius_px: float = Field(3.0, gt=0, description="Boxes closer than this at the look's middle are "
                                                              "one detection [pixel]")
        max_trial_velocities: int = Field(20_000, ge=1, description="Refuse searches with more trial velocities "
                                                                     "than this (cost grows with their number) [1]")

        @model_validator(mode="after")
        def _rates(self):
            if self.min_rate_px_s > self.max_rate_px_s:
                raise ValueError(f"min_rate_px_s ({self.min_rate_px_s}) exceeds max_rate_px_s "
                                 f"({self.max_rate_px_s})")
            n = mf.velocity_grid(self.max_rate_px_s, self.min_rate_px_s, self.look_s, self.velocity_step_px).shape[0]
            if n == 0:
                raise ValueError(f"no trial velocity between min_rate_px_s = {self.min_rate_px_s} and max_rate_px_s "
                                 f"= {self.max_rate_px_s} on a grid {self.velocity_step_px / self.look_s:g} "
                                 f"pixel/s apart; widen the range or lengthen look_s")
            if n > self.max_trial_velocities:
                raise ValueError(f"{n} trial velocities (max_rate_px_s {self.max_rate_px_s} over looks of "
                                 f"{self.look_s} s, {self.velocity_step_px / self.look_s:g} pixel/s apart) exceed "
                                 f"max_trial_velocities = {self.max_trial_velocities}; shorten look_s, lower "
                                 f"max_rate_px_s or raise the limit")
            return self

    inputs = {"events": Input(Events, "events as the readout records them (readout time is used)")}
    outputs = {"detections": Output(Detections, "detections of the looks that ended in the window")}
    state = ("look_index", "buffer_t", "buffer_x", "buffer_y", "last_t_ns", "look_counts", "hot_looks",
             "events_seen", "focal_plane")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.look_index = 0                  # the look being filled
        self.buffer_t = np.zeros(0, np.int64)
        self.buffer_x = np.zeros(0, np.uint16)
        self.buffer_y = np.zeros(0, np.uint16)
        self.last_t_ns = None                # int64 per pixel: time of its last event (any look)
        self.look_counts = None              # int32 per pixel: events kept in the current look
        self.hot_looks = None                # int32 per pixel: closed looks in which its count was improbably high
        self.events_seen = 0
        self.focal_plane = None
        p = self.params
        self.velocities = mf.velocity_grid(p.max_rate_px_s, p.min_rate_px_s, p.look_s, p.velocity_step_px)

    @property
    def look_ns(self) -> int:
        return max(1, round(self.params.look_s * NS_PER_S))

    def footprint(self, run: RunInfo) -> Footprint:
        return Footprint(bytes_per_pixel=8 + 4 + 4 + 4 * 4)   # last time, look count, hot looks, counting map (padded)

    # -- the stream --------------------------------------------------------------------------------
    def step(self, window: Window, events: Events) -> dict:
        fp = events.focal_plane
        if self.focal_plane is None:
            self.focal_plane = fp
            self.last_t_ns = np.full(fp.width_px * fp.height_px, np.iinfo(np.int64).min // 2, np.int64)
            self.look_counts = np.zeros(fp.width_px * fp.height_px, np.int32)
            self.hot_looks = np.zeros(fp.width_px * fp.height_px, np.int32)
        self.events_seen += len(events)
        t, x, y = events.t_readout_ns, events.x, events.y
        if self.params.polarity != "both":
            keep = events.p > 0 if self.params.polarity == "on" else events.p < 0
            t, x, y = t[keep], x[keep], y[keep]
        finished: list[Detections] = []
        look = t // self.look_ns
        for index in np.unique(look):
            while self.look_index < index:                  # looks with no more events to come
                finished.append(self._close_look())
            self._add(t[look == index], x[look == index], y[look == index])
        while (self.look_index + 1) * self.look_ns <= window.stop_ns:
            finished.append(self._close_look())
        far = self.params.false_alarm_rate_per_hour_per_mpx
        return {"detections": concatenate_detections(finished, fp, self.look_ns, far)}

    def finish(self) -> dict:
        if self.events_seen == 0:
            raise SceneError(f"{self.label}: the sensor recorded no events in the whole run, not even "
                             f"noise: there is nothing to detect and no background to set a threshold against "
                             f"(check the sensor's irradiance and its noise rates)")
        return {}

    def _add(self, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        width = self.focal_plane.width_px
        pixel = y.astype(np.int64) * width + x.astype(np.int64)
        keep = mf.thin_events(t, pixel, self.last_t_ns, self.look_counts, round(self.params.dedup_s * NS_PER_S),
                              self.params.max_events_per_pixel)
        self.buffer_t = np.concatenate([self.buffer_t, t[keep]])
        self.buffer_x = np.concatenate([self.buffer_x, x[keep]])
        self.buffer_y = np.concatenate([self.buffer_y, y[keep]])

    def hot_pixels(self) -> np.ndarray:
        """Pixels marked hot in at least ``hot_pixel_looks`` closed looks: left out of the next look."""
        return self.hot_looks >= self.params.hot_pixel_looks

    def _close_look(self) -> Detections:
        start = self.look_index * self.look_ns
        width = self.focal_plane.width_px
        touched = self.buffer_y.astype(np.int64) * width + self.buffer_x.astype(np.int64)
        use = ~self.hot_pixels()[touched]
        found, rho = self.detect(self.buffer_t[use], self.buffer_x[use], self.buffer_y[use], start)
        if touched.size:
            # a pixel's count this look against the background density measured in it (Poisson, per pixel)
            pixels, counts = np.unique(touched, return_counts=True)
            hot = counts >= poisson_count_threshold(max(rho, ZERO_COUNT_UPPER_LIMIT / self.look_counts.size),
                                                    self.params.hot_pixel_p_value)
            self.hot_looks[pixels[hot]] += 1
        self.look_counts[touched] = 0
        self.buffer_t = np.zeros(0, np.int64)
        self.buffer_x = np.zeros(0, np.uint16)
        self.buffer_y = np.zeros(0, np.uint16)
        self.look_index += 1
        return found

    # -- one look -----------------------------------------------------------------------------------
    def detect(self, t_ns: np.ndarray, x: np.ndarray, y: np.ndarray, start_ns: int) -> tuple[Detections, float]:
        """The detections of the look starting at ``start_ns`` from its thinned events, and the background
        density measured in them [event pixel^-1]."""
        p, fp = self.params, self.focal_plane
        look_s = self.look_ns / NS_PER_S
        far = p.false_alarm_rate_per_hour_per_mpx
        none = Detections.none(fp, self.look_ns, far, [start_ns])
        width, height = fp.width_px, fp.height_px
        n_pixels = width * height
        if t_ns.size == 0:
            return none, 0.0
        measured = mf.background_density(x, y, width, height, p.tile_px)
        rho = max(measured, ZERO_COUNT_UPPER_LIMIT / n_pixels)
        mu_full = rho * p.box_px**2
        p_thr = local_p_threshold(far, look_s, n_pixels, n_pixels * self.velocities.shape[0])
        k_min = poisson_count_threshold(mu_full * p.min_exposure, p_thr)
        mid_ns = start_ns + self.look_ns // 2
        t_rel = (t_ns - mid_ns) / NS_PER_S
        xs, ys = x.astype(np.float64), y.astype(np.float64)
        pad = int(math.ceil(p.max_rate_px_s * look_s / 2)) + p.box_px
        capacity = 1 << 18
        while True:
            rows, found = mf.candidate_boxes(t_rel, xs, ys, self.velocities, p.box_px, pad, width, height, k_min,
                                             capacity)
            if found >= 0:
                break
            capacity *= 4
        if found == 0:
            return none, measured
        rows = rows[:found]                          # one row per velocity and box
        v = self.velocities[rows[:, 0]]
        centre = rows[:, 1:3] - pad + (p.box_px - 1) / 2
        exposure = mf.exposure_fraction(centre[:, 0], centre[:, 1], v[:, 0], v[:, 1], look_s, width, height)
        counts = rows[:, 3].astype(float)
        mu = mu_full * exposure
        pvalue = poisson_p_value(counts, mu)
        ok = (exposure >= p.min_exposure) & (pvalue <= p_thr)
        if not ok.any():
            return none, measured
        order = np.flatnonzero(ok)[np.lexsort((-counts[ok], pvalue[ok]))]
        chosen = merge_candidates(centre[order], v[order], look_s, p.merge_radius_px)
        picks = order[chosen]
        dv = p.velocity_step_px / look_s
        refined = [mf.refine(t_rel, xs, ys, centre[i], v[i], p.box_px, dv) for i in picks]
        n = picks.size
        trials = n_pixels * self.velocities.shape[0]
        return Detections(
            fp, self.look_ns, far, np.array([start_ns], np.int64), np.full(n, mid_ns, np.int64),
            np.full(n, start_ns + self.look_ns, np.int64), np.array([r[0][0] for r in refined]),
            np.array([r[0][1] for r in refined]), np.array([r[1][0] for r in refined]),
            np.array([r[1][1] for r in refined]), counts[picks], mu[picks], gaussian_sigma(pvalue[picks]),
            np.minimum(1.0, pvalue[picks] * trials)), measured


def merge_candidates(centres: np.ndarray, velocities: np.ndarray, look_s: float, radius: float) -> np.ndarray:
    """Indices of the candidates (in order of preference) kept when each suppresses the later ones whose
    track comes within ``radius`` of its own at some time of the look: a trial velocity near the right one
    piles a bright source's events into boxes offset along the error, which are the same source."""
    reach = radius + np.ptp(velocities, axis=0).max(initial=0.0) * look_s if len(velocities) else radius
    tree = cKDTree(centres)
    suppressed = np.zeros(centres.shape[0], bool)
    kept = []
    for i in range(centres.shape[0]):
        if suppressed[i]:
            continue
        kept.append(i)
        near = np.array(tree.query_ball_point(centres[i], reach), np.int64)
        dc = centres[near] - centres[i]
        dv = velocities[near] - velocities[i]
        speed2 = (dv**2).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.clip(np.where(speed2 > 0, -(dc * dv).sum(axis=1) / speed2, 0.0), -look_s / 2, look_s / 2)
        closest = np.hypot(*(dc + dv * t[:, None]).T)
        suppressed[near[closest <= radius]] = True
    return np.array(kept, np.int64)


def concatenate_detections(parts: list[Detections], fp: FocalPlane, look_ns: int, far: float) -> Detections:
    """The detections of several looks as one table (none: an empty one), with the look length [ns] and the
    false-alarm rate ``far`` [h^-1 Mpixel^-1] the detector was set to."""
    if not parts:
        return Detections.none(fp, look_ns, far)
    fields = ("look_start_ns", "t_ns", "t_reported_ns", "x_px", "y_px", "vx_px_s", "vy_px_s", "counts", "background",
              "significance_sigma", "false_alarm_probability")
    joined = {f: np.concatenate([getattr(d, f) for d in parts]) for f in fields}
    return Detections(fp, look_ns, far, **joined)
