"""Scoring a detector against the truth: detection probability, false alarms, astrometry, latency.

For every look a detector reports (:class:`~evsda.blocks.ports.Detections`), each true source
(:class:`~evsda.blocks.ports.PointSources`) that is observable during the whole look and lies at
least ``edge_margin_px`` inside the detector at the look's middle has one *opportunity*. It is
*detected* in that look when a detection of the look lies within ``match_radius_px`` of the
source's position at the look's middle (the position interpolated linearly between the source's
samples), and, if ``max_velocity_error_px_s`` is set, the detection's velocity is that close to
the source's. Each detection goes to the nearest source within the radius. A detection near none
whose track (its position moved with its velocity) passes within the radius of a source at some
sample of the look found a source that entered or left the detector during the look
(``detections_of_partly_seen_sources``: no opportunity, no false alarm); any other is a false
alarm. Figures:

* ``detection_probability``: detected opportunities over opportunities (all sources), and per
  magnitude bin of ``magnitude_bin_mag`` (``pd_m<centre>``, with ``opportunities_m<centre>`` and
  ``detected_m<centre>`` for binomial uncertainties);
* ``false_alarm_rate_per_hour_per_mpx``: false alarms per hour of looks per megapixel;
* astrometric error: distance between a matched detection and its source [pixel] (rms and
  median; also in arcsec with the focal plane's pixel scale), and the velocity error;
* time to first detection: from the first sample at which a source is on the detector to the
  time its first matched detection could be reported (the end of the look) [s].

This block reads the truth; the detector it scores does not.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from evsda.blocks.ports import Detections, Metrics, PointSources
from evsda.graph import NS_PER_S, Block, BlockParams, Input, InputError, Output, Window

ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0
SAMPLES_PER_LOOK = 64          # source samples kept per look (positions interpolated in between)


class DetectionScoring(Block):
    """Detections against the true sources: P_d per source and magnitude, false alarms, astrometry, latency."""

    type_name = "detection_scoring"
    is_sink = True

    class Params(BlockParams):
        match_radius_px: float = Field(3.0, gt=0, description="A detection this close to a source's position at "
                                                              "the look's middle is that source [pixel]")
        max_velocity_error_px_s: float | None = Field(None, gt=0, description="If set, a match also needs the "
                                                      "detection's velocity this close to the source's [pixel s^-1]")
        edge_margin_px: float = Field(2.0, ge=0, description="A source gives an opportunity only this far inside "
                                                             "the detector [pixel]")
        magnitude_bin_mag: float = Field(0.5, gt=0, description="Width of the magnitude bins of P_d [mag]")
        max_sources_reported: int = Field(32, ge=0, description="Sources given their own P_d and first-detection "
                                                                "figures (the brightest first) [1]")

    inputs = {"detections": Input(Detections, "what a detector reported"),
              "sources": Input(PointSources, "the true sources", multi=True)}
    outputs = {"metrics": Output(Metrics, "detection probability, false alarms, astrometric error, latency")}
    state = ("history_t", "history_x", "history_y", "source_ids", "source_mag", "first_seen_ns", "first_detected_ns",
             "per_source", "totals", "errors", "focal_plane")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.history_t = np.zeros(0, np.int64)      # [n_h] sample times kept
        self.history_x = None                       # float32 [n_h, n_src]
        self.history_y = None
        self.source_ids = None                      # str [n_src]
        self.source_mag = None                      # float64 [n_src] brightest magnitude seen
        self.first_seen_ns = None                   # int64 [n_src] first sample on the detector (-1: never)
        self.first_detected_ns = None               # int64 [n_src] first matched detection's report time (-1)
        self.per_source = None                      # int64 [n_src, 2] opportunities, detected
        self.totals = {"looks": 0, "detections": 0, "false_alarms": 0, "partly_seen": 0, "look_ns": 0,
                       "far_target": 0.0}
        self.errors = np.zeros((0, 2))              # [n_matched, 2] position error [px], velocity error [px/s]
        self.focal_plane = None

    def step(self, window: Window, detections: Detections, sources: list[PointSources]) -> dict:
        fp = detections.focal_plane
        self.focal_plane = fp
        self._remember(sources, fp, detections.look_ns)
        for start in detections.look_start_ns.tolist():
            self._score_look(int(start), detections)
        self._forget(window.stop_ns - 2 * max(detections.look_ns, 1))
        return {"metrics": self.summary()}

    def finish(self) -> dict:
        return {"metrics": self.summary()}

    # -- the truth ---------------------------------------------------------------------------------
    def _remember(self, sources: list[PointSources], fp, look_ns: int) -> None:
        if not sources:
            raise InputError(f"{self.label} needs at least one PointSources input")
        ids = np.concatenate([s.source_id.astype(str) for s in sources])
        t = sources[0].t_ns
        if any(s.t_ns.shape != t.shape or np.any(s.t_ns != t) for s in sources[1:]):
            raise InputError(f"{self.label}: its source inputs are sampled at different times; give them "
                             f"the same cadence_s")
        x = np.concatenate([s.x_px for s in sources], axis=1)
        y = np.concatenate([s.y_px for s in sources], axis=1)
        mag = np.concatenate([s.magnitude for s in sources], axis=1)
        if self.source_ids is None:
            n = ids.size
            self.source_ids = ids
            self.source_mag = np.full(n, np.inf)
            self.first_seen_ns = np.full(n, -1, np.int64)
            self.first_detected_ns = np.full(n, -1, np.int64)
            self.per_source = np.zeros((n, 2), np.int64)
            self.history_x = np.zeros((0, n), np.float32)
            self.history_y = np.zeros((0, n), np.float32)
        elif ids.shape != self.source_ids.shape or np.any(ids != self.source_ids):
            raise InputError(f"{self.label}: the sources changed between windows ({self.source_ids.size} "
                             f"then {ids.size}); scoring needs the same sources in every window")
        if t.size == 0:
            return
        with np.errstate(invalid="ignore"):
            finite_mag = np.where(np.isfinite(mag), mag, np.inf)
        self.source_mag = np.minimum(self.source_mag, finite_mag.min(axis=0))
        on = _on_detector(x, y, fp, 0.0)
        seen = on.any(axis=0) & (self.first_seen_ns < 0)
        self.first_seen_ns[seen] = t[np.argmax(on[:, seen], axis=0)]
        t, x, y = _decimate(t, x, y, look_ns // SAMPLES_PER_LOOK)
        self.history_t = np.concatenate([self.history_t, t])
        self.history_x = np.concatenate([self.history_x, x.astype(np.float32)])
        self.history_y = np.concatenate([self.history_y, y.astype(np.float32)])

    def _forget(self, before_ns: int) -> None:
        keep = self.history_t >= before_ns
        if keep.all():
            return
        # keep one sample before the cut (sample and hold / interpolation at the edge)
        first = max(0, int(np.argmax(keep)) - 1) if keep.any() else max(0, self.history_t.size - 1)
        self.history_t = self.history_t[first:]
        self.history_x = self.history_x[first:]
        self.history_y = self.history_y[first:]

    def _positions(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """Every source's position and velocity at ``t_ns`` (linear between samples; NaN if unknown)."""
        t = self.history_t
        n = self.source_ids.size
        nan = np.full((n, 2), np.nan)
        if t.size < 2 or t_ns < t[0] or t_ns > t[-1]:
            return nan, nan.copy()
        i = int(np.clip(np.searchsorted(t, t_ns, side="right") - 1, 0, t.size - 2))
        dt = (t[i + 1] - t[i]) / NS_PER_S
        a = (t_ns - t[i]) / NS_PER_S / dt
        p0 = np.stack([self.history_x[i], self.history_y[i]], -1).astype(float)
        p1 = np.stack([self.history_x[i + 1], self.history_y[i + 1]], -1).astype(float)
        return p0 + a * (p1 - p0), (p1 - p0) / dt

    # -- one look ---------------------------------------------------------------------------------
    def _score_look(self, start_ns: int, detections: Detections) -> None:
        look_ns = detections.look_ns
        fp = self.focal_plane
        mid = start_ns + look_ns // 2
        position, velocity = self._positions(mid)
        inside = (self.history_t >= start_ns) & (self.history_t < start_ns + look_ns)
        observable = np.isfinite(self.history_x[inside]).all(axis=0) if inside.any() \
            else np.zeros(self.source_ids.size, bool)
        observable &= np.isfinite(position).all(axis=1)
        opportunity = observable & _on_detector(position[:, 0], position[:, 1], fp, self.params.edge_margin_px)
        mine = detections.t_ns == mid
        det_xy = np.stack([detections.x_px[mine], detections.y_px[mine]], -1)
        det_v = np.stack([detections.vx_px_s[mine], detections.vy_px_s[mine]], -1)
        t_reported = detections.t_reported_ns[mine]
        self.totals["looks"] += 1
        self.totals["detections"] += int(mine.sum())
        self.totals["look_ns"] = look_ns
        self.totals["far_target"] = detections.false_alarm_rate_per_hour_per_mpx
        self.per_source[opportunity, 0] += 1
        detected = np.zeros(self.source_ids.size, bool)
        candidates = np.flatnonzero(np.isfinite(position).all(axis=1))
        errors = []
        for d in range(det_xy.shape[0]):
            distance = np.hypot(*(position[candidates] - det_xy[d]).T) if candidates.size else np.zeros(0)
            ok = distance <= self.params.match_radius_px
            if self.params.max_velocity_error_px_s is not None and candidates.size:
                dv = np.hypot(*(velocity[candidates] - det_v[d]).T)
                ok &= ~(dv > self.params.max_velocity_error_px_s)
            if not ok.any():
                if self._on_a_track(det_xy[d], det_v[d], mid, inside):
                    self.totals["partly_seen"] += 1
                else:
                    self.totals["false_alarms"] += 1
                continue
            k = np.flatnonzero(ok)[np.argmin(distance[ok])]
            s = candidates[k]
            errors.append((distance[k], float(np.hypot(*(velocity[s] - det_v[d])))))
            if opportunity[s] and not detected[s]:
                detected[s] = True
                if self.first_detected_ns[s] < 0:
                    self.first_detected_ns[s] = int(t_reported[d])
        self.per_source[detected, 1] += 1
        if errors:
            self.errors = np.concatenate([self.errors, np.array(errors)])

    def _on_a_track(self, xy: np.ndarray, v: np.ndarray, mid_ns: int, inside: np.ndarray) -> bool:
        """Whether a detection's track (its position moved with its velocity, or held where it has none) passes
        within the match radius of a source's sampled position at some sample of the look: a source that left
        or entered the detector during the look, seen by the detector but given no opportunity."""
        if not inside.any():
            return False
        dt = (self.history_t[inside] - mid_ns) / NS_PER_S
        velocity = np.where(np.isfinite(v), v, 0.0)
        track = xy[None, :] + dt[:, None] * velocity[None, :]                       # [n_s, 2]
        sx, sy = self.history_x[inside].astype(float), self.history_y[inside].astype(float)
        with np.errstate(invalid="ignore"):
            near = np.hypot(sx - track[:, 0:1], sy - track[:, 1:2]) <= self.params.match_radius_px
            gate = self.params.max_velocity_error_px_s
            if gate is not None and dt.size > 1:
                # the source's velocity at each sample (finite differences) must match the detection's as well
                vx, vy = np.gradient(sx, dt, axis=0), np.gradient(sy, dt, axis=0)
                near &= np.hypot(vx - velocity[0], vy - velocity[1]) <= gate
        return bool(near.any())

    # -- the figures ------------------------------------------------------------------------------
    def summary(self) -> Metrics:
        values, units = {}, {}

        def put(name, value, unit):
            values[name], units[name] = value, unit

        tot = self.totals
        put("looks", tot["looks"], "1")
        put("detections", tot["detections"], "detection")
        if self.per_source is None or self.focal_plane is None:
            return Metrics(values, units)
        fp = self.focal_plane
        opp, det = self.per_source[:, 0], self.per_source[:, 1]
        put("opportunities", int(opp.sum()), "1")
        put("detected_opportunities", int(det.sum()), "1")
        put("detection_probability", float(det.sum() / opp.sum()) if opp.sum() else float("nan"), "1")
        hours = tot["looks"] * tot["look_ns"] / NS_PER_S / 3600.0
        mpx = fp.width_px * fp.height_px / 1e6
        put("false_alarms", tot["false_alarms"], "detection")
        put("detections_of_partly_seen_sources", tot["partly_seen"], "detection")
        put("false_alarm_rate_per_hour_per_mpx", tot["false_alarms"] / (hours * mpx) if hours else float("nan"),
            "h^-1 Mpixel^-1")
        put("false_alarm_rate_target_per_hour_per_mpx", tot["far_target"], "h^-1 Mpixel^-1")
        put("sources_with_opportunities", int((opp > 0).sum()), "1")
        put("sources_detected", int((det > 0).sum()), "1")
        if self.errors.size:
            position, speed = self.errors[:, 0], self.errors[:, 1]
            put("astrometric_error_px_rms", float(np.sqrt(np.mean(position**2))), "pixel")
            put("astrometric_error_px_median", float(np.median(position)), "pixel")
            put("astrometric_error_arcsec_rms", float(np.sqrt(np.mean(position**2))) * fp.pixel_scale_rad
                * ARCSEC_PER_RAD, "arcsec")
            finite = np.isfinite(speed)
            if finite.any():
                put("velocity_error_px_s_rms", float(np.sqrt(np.mean(speed[finite] ** 2))), "pixel s^-1")
        latency = (self.first_detected_ns - self.first_seen_ns) / NS_PER_S
        found = (self.first_detected_ns >= 0) & (self.first_seen_ns >= 0)
        if found.any():
            put("time_to_first_detection_s_median", float(np.median(latency[found])), "s")
            put("time_to_first_detection_s_max", float(np.max(latency[found])), "s")
        width = self.params.magnitude_bin_mag
        scored = opp > 0
        if scored.any():
            bins = np.floor(self.source_mag[scored] / width + 0.5) * width
            for centre in np.unique(bins):
                here = np.flatnonzero(scored)[bins == centre]
                n_opp, n_det = int(opp[here].sum()), int(det[here].sum())
                tag = f"m{centre:.2f}"
                put(f"opportunities_{tag}", n_opp, "1")
                put(f"detected_{tag}", n_det, "1")
                put(f"pd_{tag}", n_det / n_opp, "1")
        order = np.argsort(self.source_mag, kind="stable")[: self.params.max_sources_reported]
        for s in order[opp[order] > 0]:
            sid = self.source_ids[s]
            put(f"pd_{sid}", float(det[s] / opp[s]), "1")
            if found[s]:
                put(f"first_detection_s_{sid}", float(latency[s]), "s")
        return Metrics(values, units)


def _decimate(t: np.ndarray, x: np.ndarray, y: np.ndarray, every_ns: int):
    """The first sample of every ``every_ns`` of the global time grid, NaN where any sample it stands for is NaN
    (a source that left the field for one sample is not observable over that stretch)."""
    if t.size < 2 or every_ns <= t[1] - t[0]:
        return t, x, y
    group = t // every_ns
    starts = np.flatnonzero(np.r_[True, group[1:] != group[:-1]])
    lost = np.logical_or.reduceat(~(np.isfinite(x) & np.isfinite(y)), starts, axis=0)
    xs, ys = x[starts].copy(), y[starts].copy()
    xs[lost], ys[lost] = np.nan, np.nan
    return t[starts], xs, ys


def _on_detector(x, y, fp, margin: float):
    """Whether positions lie at least ``margin`` pixels inside the detector (NaN: no)."""
    with np.errstate(invalid="ignore"):
        return ((x >= -0.5 + margin) & (x < fp.width_px - 0.5 - margin)
                & (y >= -0.5 + margin) & (y < fp.height_px - 0.5 - margin))
