"""Point sources in the frames of a frame sensor, without ground truth: the baseline of the event detector.

Each frame is one look. Its background level and per-pixel noise are measured in the frame itself,
robustly (:func:`background_level`: the mean and the standard deviation of the pixels within
``CLIP_SIGMA`` noise of the level, corrected for the clipping; sources are a few pixels of many, and the median
absolute deviation alone is biased by the frame's whole-DN steps);
a box of ``box_px x box_px`` pixels at every position sums the frame less the background, and the
sum's significance is ``z = S / (box sigma)``, Gaussian under the background alone (sky, dark and
read noise: the CCD equation's background term, Howell 2006, *Handbook of CCD Astronomy*, Eq. 4.4).
The threshold ``z`` holds the false alarms to ``false_alarm_rate_per_hour_per_mpx`` per hour of
exposure given every box position as a trial (:mod:`.significance`); boxes within
``merge_radius_px`` of a more significant one are the same source, whose position is the
centroid of the background-subtracted pixels around the box. A single frame measures no velocity
(NaN). Nothing here reads the simulation's truth.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scipy import stats

from evsda.blocks.ports import Detections, Frame
from evsda.graph import Block, BlockParams, Input, Output, Window

from .event_detector import concatenate_detections, merge_candidates
from .significance import local_p_threshold

MAD_TO_SIGMA = 1.4826            # sigma of a normal distribution per median absolute deviation [1]
CLIP_SIGMA = 4.0                 # pixels this many sigma from the level are left out of the noise estimate [1]
CLIPPED_STD = float(stats.truncnorm(-CLIP_SIGMA, CLIP_SIGMA).std())   # std of a normal clipped there, per sigma [1]
QUANTISATION_SIGMA_DN = 12 ** -0.5   # noise of rounding to whole DN, the floor of a noiseless frame [DN]


class FrameDetector(Block):
    """Sources in single frames: box sums over a robust background, Gaussian threshold at a false-alarm rate."""

    type_name = "frame_detector"

    class Params(BlockParams):
        box_px: int = Field(2, ge=1, le=15, description="Side of the summing box [pixel]")
        false_alarm_rate_per_hour_per_mpx: float = Field(1.0, gt=0, description="False alarms the threshold "
                                                         "allows per hour of exposure per megapixel [h^-1 Mpixel^-1]")
        merge_radius_px: float = Field(3.0, gt=0, description="Boxes closer than this are one detection [pixel]")
        gain_e_per_dn: float = Field(1.0, gt=0, description="Gain of the sensor, to report counts in electrons "
                                                            "[electron DN^-1]")

    inputs = {"frames": Input(Frame, "frames of a frame sensor [DN]")}
    outputs = {"detections": Output(Detections, "detections in the frames that ended in the window")}

    def step(self, window: Window, frames: Frame) -> dict:
        p = self.params
        looks = [self.detect(frames.image[k].astype(np.float64), int(frames.t_start_ns[k]), frames)
                 for k in range(frames.image.shape[0])]
        return {"detections": concatenate_detections(looks, frames.focal_plane, frames.exposure_ns,
                                                     p.false_alarm_rate_per_hour_per_mpx)}

    def detect(self, image: np.ndarray, start_ns: int, frames: Frame) -> Detections:
        """The detections of one frame exposed from ``start_ns``."""
        p, fp = self.params, frames.focal_plane
        exposure_ns = int(frames.exposure_ns)
        far = p.false_alarm_rate_per_hour_per_mpx
        level, sigma = background_level(image)
        b = p.box_px
        excess = image - level
        cumulative = np.pad(excess, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
        box = cumulative[b:, b:] - cumulative[:-b, b:] - cumulative[b:, :-b] + cumulative[:-b, :-b]
        z = box / (b * sigma)
        n_pixels = fp.width_px * fp.height_px
        p_thr = local_p_threshold(far, exposure_ns / 1e9, n_pixels, box.size)
        z_thr = float(stats.norm.isf(p_thr))
        rows, cols = np.nonzero(z >= z_thr)
        none = Detections.none(fp, exposure_ns, far, [start_ns])
        if rows.size == 0:
            return none
        order = np.argsort(-z[rows, cols], kind="stable")
        rows, cols = rows[order], cols[order]
        centres = np.stack([cols + (b - 1) / 2, rows + (b - 1) / 2], -1).astype(float)
        keep = merge_candidates(centres, np.zeros_like(centres), exposure_ns / 1e9, p.merge_radius_px)
        positions = np.array([_centroid(excess, centres[k], b) for k in keep]).reshape(-1, 2)
        zs = z[rows[keep], cols[keep]]
        pvalue = stats.norm.sf(zs)
        n = keep.size
        nan = np.full(n, np.nan)
        return Detections(fp, exposure_ns, far, np.array([start_ns], np.int64),
                          np.full(n, start_ns + exposure_ns // 2, np.int64), np.full(n, start_ns + exposure_ns, np.int64),
                          positions[:, 0], positions[:, 1], nan, nan.copy(), box[rows[keep], cols[keep]] * p.gain_e_per_dn,
                          np.zeros(n), np.minimum(zs, 38.0), np.minimum(1.0, pvalue * box.size))


def background_level(image: np.ndarray, iterations: int = 3) -> tuple[float, float]:
    """Background level and per-pixel noise of a frame [DN]: the mean, and the standard deviation divided by
    that of a normal distribution clipped at ``CLIP_SIGMA``, of the pixels within ``CLIP_SIGMA`` noise of the
    level (started from the median and the median absolute deviation, refined ``iterations`` times; the median
    of whole DN is off by up to half a DN); at least the rounding noise."""
    level = float(np.median(image))
    sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(image - level))), QUANTISATION_SIGMA_DN)
    for _ in range(iterations):
        near = image[np.abs(image - level) <= CLIP_SIGMA * sigma]
        if near.size < 2:
            break
        level, sigma = float(near.mean()), max(float(near.std()) / CLIPPED_STD, QUANTISATION_SIGMA_DN)
    return level, sigma


def _centroid(excess: np.ndarray, centre: np.ndarray, box: int) -> np.ndarray:
    """Centroid of the positive background-subtracted pixels within ``box / 2 + 1`` of ``centre`` [pixel]."""
    half = box / 2 + 1
    h, w = excess.shape
    c0, c1 = int(max(0, np.floor(centre[0] - half))), int(min(w, np.ceil(centre[0] + half) + 1))
    r0, r1 = int(max(0, np.floor(centre[1] - half))), int(min(h, np.ceil(centre[1] + half) + 1))
    patch = np.clip(excess[r0:r1, c0:c1], 0.0, None)
    total = patch.sum()
    if total <= 0:
        return centre
    yy, xx = np.mgrid[r0:r1, c0:c1]
    return np.array([(patch * xx).sum() / total, (patch * yy).sum() / total])
