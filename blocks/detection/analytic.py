"""Limiting magnitude from the pixel equations: the cross-check of a simulated limiting-magnitude study.

Event sensor. A source of magnitude ``m`` drifting at ``omega`` pixels per second crosses a pixel
whose centre lies at a perpendicular distance ``d`` from its track. The pixel sees the photon flux
``F_sky + F_m P(r(t))`` [photon s^-1], where ``P`` is the fraction of the PSF falling in a pixel
whose centre is offset ``r`` from the source (the design's own optics, :class:`PsfTable`), and
the dark current. Paper Eqs. 12-15 turn it into the lin-log level ``Y(t)``, Eq. 16 low-passes it
(``dL/dt = 2 pi f_3dB(Y) (Y - L)``, solved exactly for piecewise-constant ``Y``), and the rise
``Delta L`` of the filtered level is what the comparator (Eq. 17) sees. Between events the
junction leak (Eq. 18) walks the comparator's distance to its ON threshold through one threshold
at a steady pace, so at a random moment it is uniform over ``[0, theta_ON)``; a rise ``Delta L``
then gives on average exactly ``Delta L / theta_ON`` ON events (a rise smaller than a threshold
fires with that probability), and the fall back ``max(0, c Delta L / theta_OFF - 1)`` OFF events,
averaged over the per-pixel threshold spread. The fall follows the source's passage with the pixel's
time constant under the sky, ``tau`` (Eq. 16): of a pixel crossed at a uniformly random moment of a
look of ``T`` seconds, the fraction ``c`` of the fall lies inside the look. With the small-signal filter
``L - Y`` decays as ``exp(-t / tau)`` and ``c = 1 - (tau / T)(1 - exp(-T / tau))`` (``c`` -> 1 for a fast
pixel, -> ``T / (2 tau)`` for one much slower than the look, whose OFF events come looks later). With the
large-signal one (``lowpass_form: large_signal``, the first-order log photoreceptor of Delbruck & Mead
1994) ``w = e^-L`` relaxes linearly to ``e^-Y`` at the same rate, so after a rise ``Delta L`` the fall left
at ``t`` is ``-ln(1 - u e^(-t / tau))``, ``u = 1 - e^-Delta L``, and averaging over the crossing moment
(``-ln(1 - z) = sum z^k / k``) gives ``c = 1 - [Li2(u) - Li2(u e^(-T / tau))] / ((T / tau) Delta L)``, Li2 the
dilogarithm: the same ``c`` for a small rise, a larger one for a large rise (the fall starts at the speed
of the brighter current); a detector that reads ON events only counts none of them. Over a look of ``T`` seconds the track passes
``omega T`` pixel centres per unit width of the band around it; the event detector's best box
(:mod:`.event_detector`) collects the events of the pixels within its reach, each moved back to
the look's middle, where they pile at the perpendicular offset of their pixel: the expected
signal ``S(m)`` of the box. The background in the box is ``mu = r_bg T box^2``, with ``r_bg`` the
leak, parasitic and shot-noise rates of Eqs. 18-20 at the sky's level (a shot event's rebound one
refractory period later merged into it, as the detector does; the leaks fire ON events, so a detector
reading ON events only counts them and the ON half of the shot noise), and the detector's threshold
``k`` follows from its false-alarm rate (:mod:`.significance`). Then

    P_d(m) = P(N >= k),   N ~ Poisson(mu + S(m)),

and the magnitudes where ``P_d`` is 0.5 and 0.9 are the analytic limits. A survey that matches its
detections to a star catalogue reports instead the magnitude brighter than which a fraction ``q`` of
the *matched* stars lie (D. G. Monet's 2022 limiting-magnitude figure: ``q`` = 0.9): with star counts
growing as ``10^(a m)`` per unit magnitude up to the catalogue's end ``m_c``, that is the ``M`` with

    int_{-inf}^{M} P_s(m) 10^(a m) dm = q int_{-inf}^{m_c} P_s(m) 10^(a m) dm,

``P_s = (P_d - P_0) / (1 - P_0)`` the detections the star causes (``P_0`` the chance detection
probability, ``P_d`` of a source too faint to add events). The *contrast limit*
is the magnitude at which the best-centred pixel's rise reaches one ON threshold: the condition
``Delta L = theta_ON`` of McMahon-Crabtree & Monet (2021, Applied Optics 60(25), G144), here
with the photoreceptor's lin-log response and bandwidth at the given motion.

Frame sensor (baseline). A source of ``N_e`` electrons in an exposure, a fraction ``f_box`` of
them in the detector's box of ``n`` pixels, each pixel with sky and dark electrons ``B`` and read
noise ``sigma_r``: the box's excess is Gaussian with mean ``f_box N_e`` and variance
``f_box N_e + n (B + sigma_r^2)`` (the CCD equation: Howell 2006, Eq. 4.4); it is detected when it
exceeds ``z sqrt(n (B + sigma_r^2))`` with ``z`` set by the false-alarm rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import optimize, special, stats
from scipy.interpolate import RegularGridInterpolator

from evsda.blocks.pixel.model import PixelModel
from evsda.blocks.pixel.photoreceptor import lin_log

from .significance import local_p_threshold, poisson_count_threshold, poisson_p_value

SAMPLES_PER_PIXEL = 40        # steps of the track per pixel crossed in the filter integration [1]
OFFSETS_PER_PIXEL = 20        # perpendicular offsets per pixel at which a crossing is evaluated [1]


@dataclass(frozen=True)
class PsfTable:
    """Fraction of the PSF in a pixel whose centre is at ``(dx, dy)`` pixels from the source, on a regular grid."""

    offsets_px: np.ndarray        # [n] grid of offsets along each axis [pixel]
    fraction: np.ndarray          # [n, n] (dy, dx) fraction of the source's flux [1]

    @cached_property
    def _interpolator(self) -> RegularGridInterpolator:
        return RegularGridInterpolator((self.offsets_px, self.offsets_px), self.fraction, bounds_error=False,
                                       fill_value=0.0)

    def __call__(self, dx, dy) -> np.ndarray:
        dx, dy = np.broadcast_arrays(np.asarray(dx, float), np.asarray(dy, float))
        return self._interpolator(np.stack([dy.ravel(), dx.ravel()], -1)).reshape(dx.shape)

    @property
    def peak(self) -> float:
        """Largest fraction of the flux one pixel can hold [1]."""
        return float(self.fraction.max())


@dataclass(frozen=True)
class EventDesign:
    """What the analytic event limit needs: the pixel, the PSF, the photon budget, the motion, the detector."""

    pixel: PixelModel
    psf: PsfTable
    flux_mag0_photon_s: float       # photons per second on the detector from a V = 0 source (after extinction) [photon s^-1]
    sky_photon_s: float             # sky photons per second on one pixel [photon s^-1]
    rate_px_s: float                # apparent rate [pixel s^-1]
    direction_deg: float            # direction of motion from +x towards +y [deg]
    look_s: float                   # detector look [s]
    box_px: int                     # detector box side [pixel]
    n_velocities: int               # detector trial velocities [1]
    false_alarm_rate_per_hour_per_mpx: float
    n_pixels: int                   # detector pixels (the trials' count cancels; kept for the threshold formula)
    polarity: str = "both"          # events the detector reads: "both", "on" or "off"


def background_rate_hz(pixel: PixelModel, sky_photon_s: float, polarity: str = "both") -> float:
    """Background events per second of a pixel under the sky alone, as a detector reading ``polarity`` counts
    them [Hz]: the junction leak (Eq. 18) and the parasitic leak (Eq. 19), which lower the comparator's memory
    and so fire ON events, and shot noise of each polarity (Eq. 20; a shot event's rebound is merged into it)."""
    drive = pixel.drive(np.array([sky_photon_s]))
    shot_hz = float(drive.shot_p[0]) / pixel.dt_s                    # one polarity [Hz]
    on_hz = pixel.params.leak_rate_hz + float(drive.parasitic_hz[0]) + shot_hz
    return {"both": on_hz + shot_hz, "on": on_hz, "off": shot_hz}[polarity]


def mean_inverse_threshold(mean: float, sigma: float, floor: float) -> float:
    """``E[1 / theta]`` over the per-pixel thresholds ``max(N(mean, sigma), floor)`` [1]."""
    if sigma <= 0:
        return 1.0 / max(mean, floor)
    z = np.linspace(-6, 6, 2001)
    theta = np.maximum(mean + sigma * z, floor)
    weight = stats.norm.pdf(z)
    return float(np.sum(weight / theta) / np.sum(weight))


def filtered_rise(pixel: PixelModel, flux_t: np.ndarray, dt_s: np.ndarray) -> float:
    """Largest rise of the low-passed lin-log level (Eq. 12-16) above its value under the first flux [1].

    ``flux_t`` [photon s^-1] holds over the steps ``dt_s`` [s]; the one-pole filter relaxes toward each
    step's ``Y`` at the rate ``-ln(1 - eps) / dt`` the pixel model gives (exact for a held input): ``L - Y``
    decays so (small-signal), or ``e^-L - e^-Y`` does (``lowpass_form: large_signal``, :mod:`evsda.blocks.pixel.lowpass`).
    """
    drive = pixel.drive(flux_t)
    rate = -drive.log_a / pixel.dt_s                          # [s^-1]
    large = pixel.params.lowpass_form == "large_signal"
    y = drive.y
    level = y[0]
    top = level
    for k in range(1, y.size):
        decay = math.exp(-rate[k] * dt_s[k])
        if large:
            level = y[k] - math.log1p(math.expm1(min(y[k] - level, 700.0)) * decay)
        else:
            level = y[k] + (level - y[k]) * decay
        top = max(top, level)
    return float(top - y[0])


class EventLimit:
    """Expected events, detection probability and limiting magnitudes of an event sensor (module docstring)."""

    def __init__(self, design: EventDesign):
        self.d = design
        p = design.pixel.params
        self.inv_theta_on = mean_inverse_threshold(p.threshold_on, p.threshold_sigma, p.threshold_floor)
        self.inv_theta_off = mean_inverse_threshold(p.threshold_off, p.threshold_sigma, p.threshold_floor)
        self.background_hz = background_rate_hz(design.pixel, design.sky_photon_s, design.polarity)
        self.mu = self.background_hz * design.look_s * design.box_px**2
        p_thr = local_p_threshold(design.false_alarm_rate_per_hour_per_mpx, design.look_s, design.n_pixels,
                                  design.n_pixels * design.n_velocities)
        self.k_threshold = poisson_count_threshold(self.mu, p_thr)
        angle = math.radians(design.direction_deg)
        self.along = np.array([math.cos(angle), math.sin(angle)])
        self.across = np.array([-math.sin(angle), math.cos(angle)])
        half = design.box_px / 2 + 1.0
        self.offsets = np.arange(-half, half + 1e-9, 1.0 / OFFSETS_PER_PIXEL)

    def source_photon_s(self, magnitude: float) -> float:
        return self.d.flux_mag0_photon_s * 10.0 ** (-0.4 * magnitude)

    def rises(self, magnitude: float) -> np.ndarray:
        """Filtered rise ``Delta L`` of a pixel at each perpendicular offset from the track [1]."""
        d = self.d
        extent = float(np.abs(d.psf.offsets_px).max()) + 1.0
        s = np.arange(-extent, extent, 1.0 / SAMPLES_PER_PIXEL)       # source position along the track [pixel]
        rate = max(d.rate_px_s, 1e-12)
        dt = np.full(s.size, 1.0 / SAMPLES_PER_PIXEL / rate)
        flux = self.source_photon_s(magnitude)
        out = np.empty(self.offsets.size)
        for i, offset in enumerate(self.offsets):
            # pixel centre relative to the source: -(s along + offset across)
            rel = -(s[:, None] * self.along[None, :] + offset * self.across[None, :])
            frac = d.psf(rel[:, 0], rel[:, 1])
            out[i] = filtered_rise(d.pixel, d.sky_photon_s + flux * frac, dt)
        return out

    def expected_events(self, magnitude: float) -> float:
        """Expected signal events ``S(m)`` in the detector's best box over one look [event]."""
        rise = self.rises(magnitude)
        on = rise * self.inv_theta_on
        off = np.maximum(0.0, self.fall_fraction_in_look(rise) * rise * self.inv_theta_off - 1.0)
        per_pixel = {"both": on + off, "on": on, "off": off}[self.d.polarity]
        step = 1.0 / OFFSETS_PER_PIXEL
        # the box reaches across the track over its extent along the direction perpendicular to the motion
        reach = self.d.box_px / max(abs(self.across[0]), abs(self.across[1]))
        width = max(1, int(round(reach / step)))
        window = np.convolve(per_pixel, np.ones(width), mode="valid") * step
        crossed = self.d.rate_px_s * self.d.look_s                     # pixel centres passed per unit width
        return float(crossed * window.max())

    def fall_fraction_in_look(self, rise=0.0):
        """The mean fraction ``c`` of a pixel's fall back to the sky (time constant ``tau`` under the sky, Eq. 16)
        completed within the look ``T`` it was crossed in, after a rise ``rise`` [1] of its filtered level (module
        docstring; the rise matters only in the large-signal form) [1], shaped as ``rise``."""
        drive = self.d.pixel.drive(np.array([self.d.sky_photon_s]))
        x = float(-drive.log_a[0]) / self.d.pixel.dt_s * self.d.look_s          # T / tau [1]
        rise = np.asarray(rise, dtype=float)
        if x <= 0.0:
            return np.zeros_like(rise)[()]                                    # no bandwidth: the level never falls
        if math.isinf(x):
            return np.ones_like(rise)[()]                                     # no low-pass
        small = 1.0 + math.expm1(-x) / x
        if self.d.pixel.params.lowpass_form != "large_signal":
            return np.full_like(rise, small)[()]
        u = -np.expm1(-np.maximum(rise, 1e-300))                           # 1 - e^-Delta L [1]
        dilog = special.spence(1.0 - u) - special.spence(1.0 - u * math.exp(-x))   # Li2(z) = spence(1 - z)
        with np.errstate(invalid="ignore", divide="ignore"):
            large = 1.0 - dilog / (x * rise)
        return np.where(rise > 1e-9, large, small)[()]                     # Delta L -> 0: the small-signal c

    def detection_probability(self, magnitude: float) -> float:
        return float(poisson_p_value(self.k_threshold, self.mu + self.expected_events(magnitude)))

    def magnitude_at(self, probability: float, bright: float = -5.0, faint: float = 30.0) -> float:
        """The magnitude where ``P_d`` falls to ``probability`` (NaN if not within ``[bright, faint]``)."""
        f = lambda m: self.detection_probability(m) - probability       # noqa: E731
        if f(bright) < 0 or f(faint) > 0:
            return float("nan")
        return float(optimize.brentq(f, bright, faint, xtol=1e-3))

    def matched_magnitude(self, fraction: float, slope_dex_per_mag: float, faintest: float, bright: float = 0.0,
                          step: float = 0.2) -> float:
        """The magnitude brighter than which ``fraction`` of the stars this detector finds lie, on a sky whose star
        counts grow as ``10^(slope m)`` up to ``faintest`` (module docstring) [mag]. ``S(m)`` is computed every
        ``step`` magnitudes from ``bright`` (every star brighter is found) and interpolated in log."""
        fine, p_d, chance = self.detection_curve(bright, faintest, step)
        caused = np.clip((p_d - chance) / (1.0 - chance), 0.0, 1.0)
        return matched_fraction_magnitude(fine, caused, slope_dex_per_mag, fraction)

    def detection_curve(self, bright: float, faintest: float, step: float = 0.2) -> tuple[np.ndarray, np.ndarray, float]:
        """``P_d`` on a 0.01 mag grid from ``bright`` to ``faintest`` (``S(m)`` computed every ``step`` magnitudes and
        interpolated in log), and the chance detection probability ``P_0`` [1]."""
        grid = np.arange(bright, faintest + step / 2, step)
        signal = np.array([self.expected_events(m) for m in grid])
        fine = np.arange(bright, faintest + 1e-9, 0.01)
        s_fine = np.exp(np.interp(fine, grid, np.log(np.maximum(signal, 1e-300))))
        return fine, poisson_p_value(self.k_threshold, self.mu + s_fine), float(poisson_p_value(self.k_threshold, self.mu))

    def time_constant_s(self, magnitude: float | None = None) -> float:
        """The photoreceptor's time constant (Eq. 16, ``1 / (2 pi f_3dB)``) under the sky alone, or with the
        whole flux of a source of ``magnitude`` on the pixel [s]."""
        flux = self.d.sky_photon_s + (0.0 if magnitude is None else self.source_photon_s(magnitude))
        drive = self.d.pixel.drive(np.array([flux]))
        return float(self.d.pixel.dt_s / -drive.log_a[0])

    def contrast_limit(self, bright: float = -5.0, faint: float = 30.0) -> float:
        """The magnitude at which the best-centred pixel's filtered rise equals the mean ON threshold."""
        theta = self.d.pixel.params.threshold_on
        f = lambda m: self.rises(m).max() - theta                      # noqa: E731
        if f(bright) < 0 or f(faint) > 0:
            return float("nan")
        return float(optimize.brentq(f, bright, faint, xtol=1e-3))


def matched_fraction_magnitude(magnitudes: np.ndarray, probability: np.ndarray, slope_dex_per_mag: float,
                               fraction: float) -> float:
    """The magnitude brighter than which ``fraction`` of the detected stars lie [mag]: detection probability
    ``probability`` on the ascending grid ``magnitudes``, star counts ``10^(slope m)`` per unit magnitude, every
    star brighter than the grid detected (its share ``10^(slope m_0) / (slope ln 10)`` added at the start)."""
    m = np.asarray(magnitudes, dtype=float)
    density = np.asarray(probability, dtype=float) * 10.0 ** (slope_dex_per_mag * m)
    brighter = 10.0 ** (slope_dex_per_mag * m[0]) / (slope_dex_per_mag * math.log(10.0))
    cumulative = brighter + np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(m))])
    return float(np.interp(fraction * cumulative[-1], cumulative, m))


@dataclass(frozen=True)
class FrameDesign:
    """What the analytic frame limit needs."""

    flux_mag0_e_s: float            # electrons per second from a V = 0 source (QE included) [electron s^-1]
    box_fraction: float             # fraction of a source's electrons in the detector's best box [1]
    background_e: float             # sky and dark electrons per pixel per exposure [electron]
    read_noise_e: float             # [electron]
    exposure_s: float
    box_px: int
    false_alarm_rate_per_hour_per_mpx: float


class FrameLimit:
    """Detection probability and limiting magnitudes of the frame baseline (module docstring)."""

    def __init__(self, design: FrameDesign):
        self.d = design
        p_thr = local_p_threshold(design.false_alarm_rate_per_hour_per_mpx, design.exposure_s, 1_000_000, 1_000_000)
        self.z = float(stats.norm.isf(p_thr))

    def detection_probability(self, magnitude: float) -> float:
        d = self.d
        n = d.box_px**2
        signal = d.flux_mag0_e_s * 10.0 ** (-0.4 * magnitude) * d.exposure_s * d.box_fraction
        noise0 = math.sqrt(n * (d.background_e + d.read_noise_e**2))
        return float(stats.norm.sf((self.z * noise0 - signal) / math.sqrt(signal + noise0**2)))

    def magnitude_at(self, probability: float, bright: float = -5.0, faint: float = 30.0) -> float:
        f = lambda m: self.detection_probability(m) - probability       # noqa: E731
        if f(bright) < 0 or f(faint) > 0:
            return float("nan")
        return float(optimize.brentq(f, bright, faint, xtol=1e-3))
