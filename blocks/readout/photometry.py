"""Aperture photometry of frame-sensor frames: per-source SNR and limiting magnitude.

For each frame and each source seen during the whole exposure, the aperture is every
pixel whose centre lies within ``aperture_radius_px`` of the source's path during the
exposure (a trailed satellite gets a capsule, a star a disc), and the sky annulus the
pixels between ``annulus_inner_px`` and ``annulus_outer_px`` of it. With the gain ``g``:

* source electrons ``N* = g * (sum of the aperture - n_pix * median(annulus))``,
* per-pixel noise ``σ = g * 1.4826 * MAD(annulus)`` (read, dark and sky noise together),
* the CCD equation (Howell, *Handbook of CCD Astronomy*, 2nd ed. 2006, Eq. 4.4 with the
  background-estimate term of Merline & Howell 1995)::

      SNR = N* / sqrt(N* + n_pix (1 + n_pix / n_B) σ²)

* the electrons a source would need for ``SNR = S`` (the same equation solved for N*):
  ``N_lim = (S² + sqrt(S⁴ + 4 S² n_pix (1 + n_pix/n_B) σ²)) / 2``, and the limiting
  magnitude ``m_lim = m + 2.5 log10(N* / N_lim)`` (Pogson) from the source's magnitude m.

Figures are averaged over the frames in which each source was measured and returned
as :class:`Metrics` (``frame_snr_<id>``, ``frame_limiting_mag_<id>``, ...), next to the
event sensor's :class:`~.metrics.EventMetrics` for a limiting-magnitude trade study.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from evsda.blocks.ports import Frame, Metrics, PointSources
from evsda.graph import Block, BlockParams, Input, Output, Window

from .metrics import densify

MAD_TO_SIGMA = 1.4826      # sigma of a normal distribution per median absolute deviation [1]


class FramePhotometry(Block):
    """Per-source SNR and limiting magnitude in frames (aperture photometry, CCD equation)."""

    type_name = "frame_photometry"
    is_sink = True

    class Params(BlockParams):
        aperture_radius_px: float = Field(3.0, gt=0, description="Aperture: pixels this close to the source's "
                                                                 "path during the exposure [pixel]")
        annulus_inner_px: float = Field(6.0, gt=0, description="Inner radius of the sky annulus [pixel]")
        annulus_outer_px: float = Field(10.0, gt=0, description="Outer radius of the sky annulus [pixel]")
        gain_e_per_dn: float = Field(1.0, gt=0, description="Gain of the frame sensor that made the frames "
                                                            "[electron DN^-1]")
        snr_threshold: float = Field(5.0, gt=0, description="SNR of a detection, for the limiting magnitude [1]")

        @model_validator(mode="after")
        def _radii_ordered(self):
            if not self.aperture_radius_px <= self.annulus_inner_px < self.annulus_outer_px:
                raise ValueError("need aperture_radius_px <= annulus_inner_px < annulus_outer_px, got "
                                 f"{self.aperture_radius_px}, {self.annulus_inner_px}, {self.annulus_outer_px}")
            return self

    inputs = {"frames": Input(Frame, "frames of a frame sensor [DN]"),
              "sources": Input(PointSources, "where the sources are, and their magnitudes")}
    outputs = {"metrics": Output(Metrics, "per-source SNR, detection fraction and limiting magnitude")}
    state = ("per_source", "last_sample")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.per_source = {}       # id -> {"frames", "snr_sum", "detected", "m_lim_sum", "m_lim_frames"}
        self.last_sample = None    # the previous window's last source sample: {"t_ns", "x", "y", "mag"}

    def step(self, window: Window, frames: Frame, sources: PointSources) -> dict:
        t, x, y, mag = self._samples(sources)
        for k in range(frames.image.shape[0]):
            t0 = int(frames.t_start_ns[k])
            t1 = t0 + int(frames.exposure_ns)
            image = frames.image[k].astype(np.float64)
            for s, sid in enumerate(sources.source_id.tolist()):
                path, m = _path(t, x[:, s], y[:, s], mag[:, s], t0, t1)
                if path is None:
                    continue
                measured = self.measure(image, path)
                if measured is not None:
                    self._add(str(sid), *measured, m)
        return {"metrics": self.summary()}

    def finish(self) -> dict:
        return {"metrics": self.summary()}

    def _samples(self, sources: PointSources):
        t, x, y, mag = (np.asarray(a) for a in (sources.t_ns, sources.x_px, sources.y_px, sources.magnitude))
        last = self.last_sample
        if last is not None and len(last["x"]) == x.shape[1]:
            t = np.concatenate([[last["t_ns"]], t])
            x, y, mag = (np.concatenate([np.asarray(last[k], float)[None], a]) for k, a in
                         (("x", x), ("y", y), ("mag", mag)))
        if t.size:
            self.last_sample = {"t_ns": int(t[-1]), "x": x[-1].tolist(), "y": y[-1].tolist(), "mag": mag[-1].tolist()}
        return t.astype(np.int64), x.astype(float), y.astype(float), mag.astype(float)

    def measure(self, image: np.ndarray, path: np.ndarray):
        """``(N*, SNR, N_lim)`` of the source along ``path`` (points [n, 2], x and y) in ``image`` [DN],
        or None if its sky annulus leaves the frame."""
        p = self.params
        h, w = image.shape
        lo = np.floor(path.min(axis=0) - p.annulus_outer_px).astype(int)
        hi = np.ceil(path.max(axis=0) + p.annulus_outer_px).astype(int) + 1
        if lo[0] < 0 or lo[1] < 0 or hi[0] > w or hi[1] > h:
            return None
        cut = image[lo[1]:hi[1], lo[0]:hi[0]]
        yy, xx = np.mgrid[lo[1]:hi[1], lo[0]:hi[0]]
        distance = _distance_to_points(xx.astype(float), yy.astype(float), path)
        aperture = distance <= p.aperture_radius_px
        annulus = (distance > p.annulus_inner_px) & (distance <= p.annulus_outer_px)
        n_pix, n_b = int(aperture.sum()), int(annulus.sum())
        sky = cut[annulus]
        background = float(np.median(sky))
        sigma_e = p.gain_e_per_dn * MAD_TO_SIGMA * float(np.median(np.abs(sky - background)))
        signal_e = p.gain_e_per_dn * (float(cut[aperture].sum()) - n_pix * background)
        noise_term = n_pix * (1 + n_pix / n_b) * sigma_e**2
        variance = max(signal_e, 0.0) + noise_term
        snr = signal_e / np.sqrt(variance) if variance > 0 else 0.0
        s2 = p.snr_threshold**2
        n_lim = (s2 + np.sqrt(s2 * s2 + 4 * s2 * noise_term)) / 2
        return signal_e, snr, n_lim

    def _add(self, sid: str, signal_e: float, snr: float, n_lim: float, magnitude: float) -> None:
        entry = self.per_source.setdefault(sid, {"frames": 0, "snr_sum": 0.0, "detected": 0,
                                                 "m_lim_sum": 0.0, "m_lim_frames": 0})
        entry["frames"] += 1
        entry["snr_sum"] += float(snr)
        entry["detected"] += int(snr >= self.params.snr_threshold)
        if signal_e > 0 and np.isfinite(magnitude):
            entry["m_lim_sum"] += float(magnitude + 2.5 * np.log10(signal_e / n_lim))
            entry["m_lim_frames"] += 1

    def summary(self) -> Metrics:
        values, units = {}, {}
        limits = []
        for sid, e in sorted(self.per_source.items()):
            values[f"frame_snr_{sid}"] = e["snr_sum"] / e["frames"]
            values[f"frame_detected_fraction_{sid}"] = e["detected"] / e["frames"]
            values[f"frame_measurements_{sid}"] = e["frames"]
            units.update({f"frame_snr_{sid}": "1", f"frame_detected_fraction_{sid}": "1",
                          f"frame_measurements_{sid}": "frame"})
            if e["m_lim_frames"]:
                m_lim = e["m_lim_sum"] / e["m_lim_frames"]
                values[f"frame_limiting_mag_{sid}"] = m_lim
                units[f"frame_limiting_mag_{sid}"] = "mag"
                limits.append(m_lim)
        if limits:
            values["frame_limiting_magnitude"] = float(np.median(limits))
            units["frame_limiting_magnitude"] = "mag"
        return Metrics(values, units)


def _path(t, x, y, mag, t0: int, t1: int):
    """The source's path through the exposure ``[t0, t1]`` (linear between samples, held after
    the last one, densified to 0.5 pixel) and its mean magnitude; ``(None, nan)`` unless
    it was observed throughout (a sample at or before ``t0`` and no NaN up to ``t1``)."""
    if t.size == 0 or t[0] > t0:
        return None, np.nan
    j0 = int(np.searchsorted(t, t0, side="right")) - 1
    j1 = min(int(np.searchsorted(t, t1, side="left")), t.size - 1)
    span = slice(j0, j1 + 1)
    if not (np.all(np.isfinite(x[span])) and np.all(np.isfinite(y[span]))):
        return None, np.nan
    inner = t[span][(t[span] > t0) & (t[span] < t1)]
    times = np.concatenate([[t0], inner, [t1]]).astype(float)
    xs = np.interp(times, t[span].astype(float), x[span])
    ys = np.interp(times, t[span].astype(float), y[span])
    finite_mag = mag[span][np.isfinite(mag[span])]
    m = float(finite_mag.mean()) if finite_mag.size else np.nan
    return densify(np.stack([xs, ys], axis=1)), m


def _distance_to_points(xx: np.ndarray, yy: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance from each pixel centre to the nearest of ``points`` [pixel] (points 0.5 pixel apart)."""
    best = np.full(xx.shape, np.inf)
    for px, py in points:
        np.minimum(best, np.hypot(xx - px, yy - py), out=best)
    return best
